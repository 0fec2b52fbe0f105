"""The suites' shared harness: thread pinning, seeds, CPU-second timing with its own floor, run metadata, results
as JSON (benchmarks/schema.json) and the Markdown page rendered from them; one place, so every suite's numbers
are taken and recorded the same way."""
from __future__ import annotations

import base64
import contextlib
import copy
import datetime
import fcntl
import hashlib
import importlib.metadata
import io
import json
import math
import os
import platform
import random
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
SCHEMA_PATH = Path(__file__).resolve().parent / "schema.json"
#: the results format's version (schema.json's "schema" constant)
SCHEMA = "neumat-bench/1"
#: distributions whose versions every results file records
PACKAGES = ("neumat", "torch", "numpy", "mitsuba", "moderngl", "slangpy", "ray")


def pin_threads(threads: int) -> None:
    """Run torch, OpenMP/MKL children and llvmpipe on `threads` threads (set before any timing)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "LP_NUM_THREADS"):
        os.environ[var] = str(threads)
    torch.set_num_threads(threads)


def seed_all(seed: int) -> None:
    """Seed Python, NumPy and torch."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def cpu_seconds(fn: Callable[[], object], repeats: int = 5, min_seconds: float = 0.02, grad: bool = False) -> float:
    """CPU seconds of one call of fn: the best of `repeats` samples, each enough calls to last `min_seconds`
    of CPU time (after one untimed warm-up call); CPU time, not wall time, so other users' load counts less."""
    with torch.set_grad_enabled(grad):
        fn()
        calls = 1
        while True:
            sample = _cpu_time(fn, calls)
            if sample >= min_seconds or calls >= 2 ** 20:
                break
            calls *= 2 if sample <= 0 else max(2, min(64, math.ceil(1.2 * min_seconds / sample)))
        best = min([sample] + [_cpu_time(fn, calls) for _ in range(repeats - 1)])
    return best / calls


def _cpu_time(fn: Callable[[], object], calls: int) -> float:
    start = time.process_time()
    for _ in range(calls):
        fn()
    return time.process_time() - start


def timer_floor(repeats: int = 5, min_seconds: float = 0.02) -> float:
    """`cpu_seconds` of an empty call: below this a timing measures the harness, not the code."""
    return cpu_seconds(lambda: None, repeats, min_seconds)


def sgemm_flops_per_second(n: int = 512, repeats: int = 5, min_seconds: float = 0.02) -> float:
    """This machine's fp32 matrix-product rate on the current threads (torch.mm of n x n matrices, 2 n^3 FLOPs):
    the bound that '% of sgemm' divides by."""
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(n, n, generator=g), torch.rand(n, n, generator=g)
    return 2 * n ** 3 / cpu_seconds(lambda: torch.mm(a, b), repeats, min_seconds)


def code() -> dict:
    """The code as it is now: its commit and whether it differs from it (`_dirty`)."""
    return {"commit": _git("rev-parse", "HEAD"), "dirty": _dirty()}


def machine(code_now: dict) -> dict:
    """Where and with what a run was made: commit, versions, threads, CPU model, device, load; the commit and
    dirtiness `code_now` (read by `code()` when the run started)."""
    return {
        **code_now,
        "host": platform.node(),
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "threads": torch.get_num_threads(),
        "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
        "load": [round(x, 2) for x in os.getloadavg()],
        "python": platform.python_version(),
        "versions": {p: _version(p) for p in PACKAGES},
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "cpu_kernels": _cpu_kernels(),
    }


def _cpu_kernels() -> str:
    """Whether models evaluated through `neumat.nn.cpu_kernels` in this run ("on", or "off: " and why)."""
    from neumat.nn import cpu_kernels

    why = cpu_kernels.unavailable()
    return "on" if why is None else f"off: {why}"


def _dirty() -> bool:
    """Whether the code differs from its commit: tracked files changed outside benchmarks/results and the studies'
    results folders (a ledger that a run appends to, or results it writes, are not the code that made them)."""
    return bool(_git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)benchmarks/results",
                     ":(exclude,glob)benchmarks/studies/*/results/**"))


def _git(*args: str, cwd: Path | None = None) -> str:
    """git's answer in the checkout (or the one at `cwd`), or "unknown" (no git, or a copy of the tree without its
    .git)."""
    try:
        out = subprocess.run(["git", *args], cwd=cwd or ROOT, capture_output=True, text=True)
    except OSError:
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


class Run:
    """One suite run: its options, the tables and skips it records, and the results document built from them."""

    def __init__(self, suite, quick: bool, seed: int, threads: int, repeats: int, argv: list[str],
                 work: Path | None = None, ledger: Path | None = None, shard: tuple[int, int] = (0, 1),
                 scratch: Path | None = None) -> None:
        self.suite, self.quick, self.seed, self.threads, self.repeats = suite, quick, seed, threads, repeats
        self.work, self.shard, self.scratch = work, shard, scratch
        self.ledger = Ledger(ledger) if ledger is not None else None
        self.reused: list[str] = []  # commits of the ledger entries this run took instead of running the job
        self.job_times: list[tuple[float | None, float | None]] = []  # (wall, CPU) seconds of each job, as recorded
        self.command = shlex.join(["python", "-m", "benchmarks", *argv])
        self.tables: list[dict] = []
        self.skipped: list[dict] = []
        self.protocol: dict[str, str] = {}
        self.min_seconds = 0.005 if quick else 0.05
        self.started = time.perf_counter()

    def progress(self, text: str) -> None:
        """One line on stderr with the wall time so far: a full run takes hours, and says where it is."""
        minutes, seconds = divmod(int(time.perf_counter() - self.started), 60)
        shard = f" [shard {self.shard[0]}/{self.shard[1]}]" if self.shard[1] > 1 else ""
        print(f"[{minutes:3d}:{seconds:02d}] {self.suite.NAME}{shard}: {text}", file=sys.stderr, flush=True)

    def time(self, fn: Callable[[], object], grad: bool = False) -> float:
        """`cpu_seconds` at this run's repeats and sample length."""
        return cpu_seconds(fn, self.repeats, self.min_seconds, grad)

    def table(self, name: str, title: str, rows: list[dict], notes: str = "", figure: dict | None = None) -> None:
        """Record a table: rows of {column: number, text, bool or None}, columns in the first row's order; `figure`
        ({"caption": text, "png": `png_base64(...)`}) a picture shown under it (`write` puts it in a PNG file)."""
        columns = list(dict.fromkeys(k for row in rows for k in row))
        self.tables.append({"name": name, "title": title, "columns": columns, "rows": [_plain(r) for r in rows],
                            "notes": notes, **({"figure": figure} if figure is not None else {})})
        self.progress(f"table '{name}' done ({len(rows)} rows)")

    @contextlib.contextmanager
    def folder(self, *key: object) -> Iterator[Path]:
        """A folder for the part of the run that `key` names: under --work it is kept (the same key gives the same
        folder, so a rerun finds what it holds), else in the scratch folder the run's shards share (--workers),
        else a temporary one, removed after."""
        base = self.work or self.scratch
        if base is None:
            with tempfile.TemporaryDirectory(prefix=f"neumat-{self.suite.NAME}-") as tmp:
                yield Path(tmp)
            return
        digest = hashlib.sha1(json.dumps([self.suite.NAME, self.quick, *key], default=str).encode()).hexdigest()
        path = base / f"{self.suite.NAME}-{'quick' if self.quick else 'full'}-{digest[:12]}"
        path.mkdir(parents=True, exist_ok=True)
        yield path

    def job(self, what: str, key: dict, compute: Callable[[], dict], keep: Callable[[dict], bool]) -> dict | None:
        """The result of the job that `key` (JSON-able) names: the ledger's entry when it holds one, else
        compute()'s, added to the ledger when keep(result); None, in a shard, for a job another shard is running.
        Shards take jobs as they come (a lock per job, `_claim`), so one that draws the long fits does not leave the
        others idle. One job at a time goes through here, so a full run survives being cut off at any point."""
        digest = hashlib.sha256(json.dumps([self.suite.NAME, self.quick, key], sort_keys=True,
                                           default=str).encode()).hexdigest()
        if self.ledger is not None and (entry := self.ledger.get(digest)) is not None:
            self.reused.append(entry["commit"])
            self.job_times.append(job_seconds(entry))
            return entry["result"]
        with contextlib.ExitStack() as held:
            if self.shard[1] > 1:
                if not held.enter_context(self._claim(digest)):
                    self.progress(f"{what}: another shard is running it")
                    return None
                if (entry := self.ledger.get(digest)) is not None:   # finished while this shard looked
                    self.reused.append(entry["commit"])
                    self.job_times.append(job_seconds(entry))
                    return entry["result"]
            self.running = what
            self.progress(f"{what}: running")
            code_now = code()  # the code the job runs, read before it runs (a fit takes minutes to hours)
            wall, cpu = time.perf_counter(), cpu_seconds_now()
            result = compute()
            times = {"wall_seconds": round(time.perf_counter() - wall, 2),
                     "cpu_seconds": round(cpu_seconds_now() - cpu, 2)}
            self.job_times.append((times["wall_seconds"], times["cpu_seconds"]))
            self.running = None
            if self.ledger is not None and keep(result):
                self.ledger.add(digest, what, result, self.command, code_now, times)
            return result

    @contextlib.contextmanager
    def _claim(self, digest: str) -> Iterator[bool]:
        """Whether this shard holds the job `digest` of its ledger, for as long as the context lasts: an exclusive
        lock on a file per job in a folder of this machine's temporary directory named by the ledger's path; the
        lock goes with the process, so a killed shard leaves no stale claim."""
        folder = Path(tempfile.gettempdir()) / "neumat-bench-claims" / hashlib.sha1(
            str(self.ledger.path.resolve()).encode()).hexdigest()[:16]
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / digest, "w") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                yield False
                return
            yield True

    def skip(self, what: str, reason: str) -> None:
        """Record something the run could not measure here, and why."""
        self.skipped.append({"what": what, "reason": reason})
        self.progress(f"skipped {what}: {reason}")

    def execute(self) -> dict:
        """Pin threads, seed, run the suite and return its results document; `cut_off` is set when the run was
        interrupted (SIGINT or SIGTERM: a full run outlasts a sitting), and the document then holds the tables
        finished before it, with the rest named in "skipped"."""
        pin_threads(self.threads)
        seed_all(self.seed)
        self.started = started = time.perf_counter()
        cpu0 = time.process_time()
        code_now = code()  # the code that runs: read before it runs (a run takes minutes to hours)
        self.cut_off, self.running = None, None  # running: the job under way (`job`)
        with interrupted_by_sigterm():
            try:
                self.suite.run(self)
            except KeyboardInterrupt:
                self.cut_off = f"cut off after {time.perf_counter() - started:.0f} s"
                self.skip("the rest of the run", f"{self.cut_off} (interrupted" + (
                    f", in job '{self.running}'" if self.running else "") + "); the tables above are whole; the same "
                    "command goes on from there (--ledger keeps the finished jobs, --work what they made)")
        mode = "quick" if self.quick else "full"
        return {
            "schema": SCHEMA,
            "suite": self.suite.NAME,
            "mode": mode,
            "command": self.command,
            "description": self.suite.DESCRIPTION,
            "budget": self.suite.BUDGET[mode],
            "seed": self.seed,
            "machine": machine(code_now),
            "harness": {"timer": "best of N samples of process CPU seconds, each sample >= min_seconds of calls",
                        "repeats": self.repeats, "min_seconds": self.min_seconds,
                        "floor_seconds": timer_floor(self.repeats, self.min_seconds)},
            "protocol": self.protocol,
            **({"ledger": {"path": _relative(self.ledger.path), "entries_reused": len(self.reused),
                           "their_commits": sorted(set(self.reused))}} if self.ledger is not None else {}),
            **({"jobs": jobs_summary(self.job_times)} if self.job_times else {}),
            "tables": self.tables,
            "skipped": self.skipped,
            "wall_seconds": round(time.perf_counter() - started, 2),
            "cpu_seconds": round(time.process_time() - cpu0, 2),
        }


def cpu_seconds_now() -> float:
    """CPU seconds of this process and of its children that have ended (a job's subprocesses count)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def job_seconds(entry: dict) -> tuple[float | None, float | None]:
    """A ledger entry's (wall, CPU) seconds: those `Run.job` recorded, else the wall seconds of a fit-many row
    (entries from before the job was timed; their CPU unknown)."""
    if "wall_seconds" in entry:
        return entry["wall_seconds"], entry.get("cpu_seconds")
    result = entry.get("result")
    seconds = result.get("seconds") if isinstance(result, dict) else None
    cpu = result.get("cpu_seconds") if isinstance(result, dict) else None
    return (seconds if isinstance(seconds, (int, float)) else None), (cpu if isinstance(cpu, (int, float)) else None)


def jobs_summary(times: list[tuple[float | None, float | None]]) -> dict:
    """The run's jobs and their own times summed, in seconds: what a run one job after another on one thread takes
    (`--workers N`: about 1/N), measured, beside the budget's expected wall time. CPU time is not inflated by a
    paused or crowded job; each sum covers the jobs that recorded it."""
    walls = [w for w, _ in times if w is not None]
    cpus = [c for _, c in times if c is not None]
    return {"count": len(times), "timed_wall": len(walls), "wall_seconds": round(sum(walls), 1),
            "timed_cpu": len(cpus), "cpu_seconds": round(sum(cpus), 1)}


@contextlib.contextmanager
def interrupted_by_sigterm() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt inside the block (as SIGINT does), so a run stopped either way keeps its
    finished tables; the handler before is restored after. Main thread only (elsewhere the block does nothing)."""
    def interrupt(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)
    try:
        before = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


class Ledger:
    """A JSON-lines file of finished jobs (`Run.job`), one line each: its key's digest, what it was, the command,
    commit (and whether the tree was dirty) and date that made it, its wall and CPU seconds and its result. Shards
    append to one ledger at once (each line one locked write);
    committed between sittings, it carries a full run of many hours across machines. A line cut off by a killed
    run is ignored."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def get(self, digest: str) -> dict | None:
        """The newest entry of `digest` (read afresh: another shard may have added it), or None."""
        found = None
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(entry, dict) and entry.get("key") == digest:
                    found = entry
        return found

    def add(self, digest: str, what: str, result: dict, command: str, code_then: dict | None = None,
            times: dict | None = None) -> None:
        """Append one entry; its commit and dirtiness `code_then` (`code()` when the job started), else read now;
        `times`: the job's wall_seconds and cpu_seconds."""
        entry = {"key": digest, "what": what, "command": command, **(code_then or code()),
                 "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                 **(times or {}), "result": result}
        line = json.dumps(entry, default=str) + "\n"
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX)
            f.write(line)
            f.flush()
            fcntl.flock(f, fcntl.LOCK_UN)


def _relative(path: Path) -> str:
    """`path` relative to the root of the checkout it lies in (this one, or another one's ledger when the suite runs
    from a frozen worktree): results name no machine's folders."""
    path = path.resolve()
    top = _git("rev-parse", "--show-toplevel", cwd=path.parent if path.parent.is_dir() else None)
    for root in (ROOT, None if top == "unknown" else Path(top).resolve()):
        if root is not None and path.is_relative_to(root):
            return str(path.relative_to(root))
    return str(path)


def _plain(row: dict) -> dict:
    """JSON-safe values: finite floats rounded to 6 significant digits, non-finite ones as None."""
    out = {}
    for k, v in row.items():
        if isinstance(v, (np.floating, np.integer)) or (torch.is_tensor(v) and v.numel() == 1):
            v = v.item()
        if isinstance(v, float):
            v = float(f"{v:.6g}") if math.isfinite(v) else None
        out[str(k)] = v
    return out


def png_base64(image: np.ndarray) -> str:
    """A uint8 (H, W, 3) picture as base64 PNG text: how a figure travels in a ledger entry and a results document
    until `write` puts it in its file."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", optimize=True)
    return base64.b64encode(buffer.getvalue()).decode()


def write(doc: dict, out: Path) -> dict:
    """Write `doc` as JSON at `out`, each table's figure as the PNG file `STEM.TABLE.png` beside it (`full.images.png`,
    named in the JSON), and regenerate the folder's page (README.md: every results file in it, i.e. each JSON file
    there that names this harness's schema; other JSON beside `--out` is left out, not a crash at the end of a run of
    hours); returns the document as written."""
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = copy.deepcopy(doc)
    for table in doc["tables"]:
        figure = table.get("figure")
        if figure is not None and "png" in figure:
            file = out.with_name(f"{out.stem}.{table['name']}.png")
            file.write_bytes(base64.b64decode(figure["png"]))
            table["figure"] = {"caption": figure["caption"], "file": file.name}
    out.write_text(json.dumps(doc, indent=1) + "\n")
    page = out.parent / "README.md"
    page.write_text("\n".join(markdown(d) for d in map(_results_document, sorted(out.parent.glob("*.json")))
                              if d is not None))
    return doc


def _results_document(path: Path) -> dict | None:
    """The results document in `path`, or None when it holds something else (unreadable, not JSON, another
    schema)."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) and doc.get("schema") == SCHEMA else None


def _duration(seconds: float) -> str:
    """A duration for the page: hours to two decimals, or seconds below a tenth of an hour."""
    return f"{seconds / 3600:.2f} h" if seconds >= 360 else f"{seconds:.1f} s"


def markdown(doc: dict) -> str:
    """The Markdown page of one results document (generated: edit the suite, not the page)."""
    m = doc["machine"]
    budget = doc["budget"]
    lines = [f"# {doc['suite']} ({doc['mode']})", "", doc["description"], "",
             "<!-- generated by benchmarks/harness.py from the JSON beside this file; do not edit -->", "",
             f"    {doc['command']}", "",
             f"commit `{m['commit'][:12]}`{' (dirty)' if m['dirty'] else ''}, {m['date']}, {m['host']}: {m['cpu']}, "
             f"{m['threads']} thread(s) of {m['cores']} cores, device {m['device']}, load {m['load']}; "
             f"torch {m['versions']['torch']}"
             + (f", CPU kernels {m['cpu_kernels']}" if "cpu_kernels" in m else "")
             + f". Wall {doc['wall_seconds']} s, CPU {doc['cpu_seconds']} s.", "",
             f"Budget: {budget['ours']}. Paper: {budget['paper']}. Expected wall time on 2 cores: "
             f"{budget['expected_wall']}.", "",
             f"Timer: {doc['harness']['timer']} (N = {doc['harness']['repeats']}, min "
             f"{doc['harness']['min_seconds']} s); its floor: {doc['harness']['floor_seconds']:.3g} s per call."]
    for key, text in doc["protocol"].items():
        lines += ["", f"Protocol ({key}): {text}"]
    if "jobs" in doc:
        jobs = doc["jobs"]
        cpu = (f" and {_duration(jobs['cpu_seconds'])} CPU (the {jobs['timed_cpu']} that recorded it; a paused or "
               "crowded job's wall time overstates it)") if jobs["timed_cpu"] else ""
        lines += ["", f"Jobs: {jobs['count']}; their own times sum to {_duration(jobs['wall_seconds'])} wall (the "
                      f"{jobs['timed_wall']} that recorded it){cpu}."]
    if "ledger" in doc:
        ledger = doc["ledger"]
        lines += ["", f"Ledger `{ledger['path']}`: {ledger['entries_reused']} of the jobs taken from it, made at "
                      f"commit(s) {', '.join(f'`{c[:12]}`' for c in ledger['their_commits']) or '-'}."]
    for t in doc["tables"]:
        lines += ["", f"## {t['title']}", ""]
        if t["notes"]:
            lines += [t["notes"], ""]
        if not t["rows"]:
            lines.append("(no rows: see below)")
            continue
        lines += ["| " + " | ".join(t["columns"]) + " |", "|" + "---|" * len(t["columns"])]
        lines += ["| " + " | ".join(_cell(r.get(c)) for c in t["columns"]) + " |" for r in t["rows"]]
        if "figure" in t:
            figure = t["figure"]
            lines += ["", f"![{t['name']}]({figure['file']})", "", figure["caption"]] if "file" in figure else \
                ["", "(its figure: `--out` writes it as a PNG file)"]
    if doc["skipped"]:
        lines += ["", "## Not measured here", ""] + [f"- {s['what']}: {s['reason']}" for s in doc["skipped"]]
    return "\n".join(lines) + "\n"


def _cell(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
