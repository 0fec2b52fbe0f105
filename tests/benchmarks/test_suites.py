"""The benchmark suites (`python -m benchmarks`): --list names every suite, every suite's --quick run writes results
that match benchmarks/schema.json with its command, commit and machine, every committed results file does, and the
benchmarks (suites and studies) hold no sys.path edit and no training loop of their own. Speed numbers are checked for
sanity only."""
from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import torch
from PIL import Image

from benchmarks import harness
from benchmarks.suites import SUITES, speed
from neumat.io.shared_data import shared_data_dir
from neumat.nn import cpu_kernels

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = json.loads(harness.SCHEMA_PATH.read_text())
#: suites whose quick run needs the shared data for any row
NEEDS_DATA = {"multiscale", "neural-appearance"}


def _bench(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "benchmarks", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def _main(capsys, *args: str) -> tuple[int, str, str]:
    """`python -m benchmarks ARGS` in this process: (exit status, stdout, stderr)."""
    from benchmarks.__main__ import main

    try:
        status = main(list(args))
    except SystemExit as e:  # argparse's refusals
        status = e.code
    out = capsys.readouterr()
    return status, out.out, out.err


def test_list_names_every_suite_with_its_budget(capsys):
    status, out, _ = _main(capsys, "--list")
    assert status == 0
    for name in SUITES:
        assert re.search(rf"^{re.escape(name)}\s", out, re.M), name
    assert out.count("on 2 cores") == len(SUITES)


def test_unknown_suite_and_bad_out_are_refused(capsys, tmp_path):
    assert "invalid choice: 'nope'" in _main(capsys, "nope")[2]
    status, _, err = _main(capsys, "speed", "--out", str(tmp_path / "x.txt"))
    assert status == 2 and "expected a .json path" in err


@pytest.mark.parametrize("suite", SUITES)
def test_quick_run_writes_schema_valid_results(suite, tmp_path):
    if suite in NEEDS_DATA and shared_data_dir() is None:
        pytest.skip("shared data absent: the suite's sources are the shared texture sets")
    out = tmp_path / suite / "quick.json"
    extra = ["--work", str(out.parent / "work")] if suite in ("sparsebtf", "neupress") else []  # kept, resumable
    if suite == "sparsebtf":  # two shards share the work folder: the BTF generated once, under a lock
        extra += ["--ledger", str(out.parent / "ledger.jsonl"), "--workers", "2"]
    extra += ["--repeats", "1"] if suite == "speed" else []  # the schema and the arithmetic, not the rates: one sample
    if suite == "neubrdf":  # two shard processes fill a ledger; then a rerun must take every job from it
        extra += ["--ledger", str(out.parent / "ledger.jsonl"), "--workers", "2"]
    if suite == "neupress":  # its fits and image rows are jobs, shared by two shards (one traces, the other waits)
        extra += ["--ledger", str(out.parent / "ledger.jsonl"), "--workers", "2"]
    run = _bench(suite, "--quick", "--json", "--out", str(out), *extra)
    assert run.returncode == 0, run.stderr[-3000:]
    doc = json.loads(run.stdout)
    jsonschema.validate(doc, SCHEMA)
    assert doc == json.loads(out.read_text())
    assert doc["suite"] == suite and doc["mode"] == "quick"
    assert doc["command"] == " ".join(["python -m benchmarks", suite, "--quick --json --out", str(out), *extra])
    assert re.fullmatch(r"[0-9a-f]{40}", doc["machine"]["commit"]) and doc["machine"]["threads"] == 1
    assert any(t["rows"] for t in doc["tables"]), doc["skipped"]
    for table in doc["tables"]:  # progress on stderr, a line per table, for runs that take hours
        assert re.search(rf"\[ *\d+:\d\d\] {suite}: table '{table['name']}' done", run.stderr), run.stderr[-2000:]
    page = (out.parent / "README.md").read_text()
    assert doc["command"] in page and f"# {suite} (quick)" in page
    if suite == "speed":
        _check_speed(doc)
    if suite in ("speed", "export-parity"):
        _check_drjit_rows(doc)
    if suite == "neubrdf":
        _check_sharing(doc)
        _check_ledger(out, doc, run.stderr)
    if suite in ("multiscale", "neural-appearance"):  # the set's figure: a row of 4 panels per model fitted
        figure = next(t for t in doc["tables"] if t["name"] == "fits")["figure"]
        picture = np.asarray(Image.open(out.parent / figure["file"]))
        assert picture.shape[1] == 4 * 160 + 5 * 4 and picture.shape[0] > 160 * len(doc["tables"][0]["rows"])
    if suite == "neupress":
        _check_neupress_images(doc, out.parent / "work")
        _check_neupress_ledger(out, doc)
    if suite == "sparsebtf":
        _check_resume(out, doc, run.stderr)
        _check_equal_bytes(doc)


def _check_neupress_images(doc: dict, work: Path) -> None:
    """The image table where Mitsuba runs: the floor row, then each model of the fitted seed, each scored (finite
    FLIP in [0, 1], object FLIP too, held-out errors), each kept fit beside the checkpoint of its last step (a fit
    cut off in a full run, hours long, resumes from there); without LLVM it is skipped with the reason."""
    from neumat.testing.drjit_parity import drjit_available
    if not drjit_available():
        assert any(s["what"] == "image table" for s in doc["skipped"])
        return
    fits = sorted(work.glob("neupress-quick-*/*.nmat"))
    assert [f.name.split("-")[0] for f in fits] == ["dipole", "neupress"], fits
    for nmat in fits:
        state = torch.load(nmat.with_suffix(".checkpoint"), weights_only=True)
        assert state["step"] == 20, (nmat, sorted(state))
    rows = next(t for t in doc["tables"] if t["name"] == "images")["rows"]
    assert [(r["model"], r["seed"]) for r in rows] == [("reference, another seed (floor)", None),
                                                       ("neupress", 0), ("dipole-bssrdf", 0)]
    for r in rows:
        assert 0 < r["FLIP"] < 1 and 0 < r["object FLIP"] < 1 and r["MSE"] > 0, r
    assert all(r["held-out mean"] > 0 and r["held-out median"] > 0 for r in rows[1:])
    figure = next(t for t in doc["tables"] if t["name"] == "images")["figure"]
    assert figure["file"] == "quick.images.png" and "FLIP error" in figure["caption"]
    picture = np.asarray(Image.open(work.parent / figure["file"]))  # three rows of three panels of 16^2, enlarged
    assert picture.ndim == 3 and picture.shape[0] > 3 * 160 and picture.shape[1] > 3 * 160, picture.shape
    image = np.load(fits[1].with_suffix(".image.npy"))  # the image its row scored, kept for the figure
    assert image.shape == (16, 16, 3) and np.isfinite(image).all()


def _check_neupress_ledger(out: Path, doc: dict) -> None:
    """Each synthetic fit and image row is in the ledger; a rerun with it and an empty --work takes every row from it
    and traces, renders and fits nothing (a full table takes hours: one sitting's table is not redone in the next)."""
    entries = [json.loads(line) for line in (out.parent / "ledger.jsonl").read_text().splitlines()]
    images = next((t for t in doc["tables"] if t["name"] == "images"), None)
    assert len(entries) == 2 + (len(images["rows"]) + 1 if images else 0)  # the rows and the figure
    assert sorted(e["result"]["model"] for e in entries[:2]) == ["dipole-bssrdf", "neupress"]
    work = out.parent / "work-again"
    run = _bench("neupress", "--quick", "--json", "--ledger", str(out.parent / "ledger.jsonl"), "--work", str(work))
    assert run.returncode == 0, run.stderr[-3000:]
    again = json.loads(run.stdout)
    assert again["ledger"]["entries_reused"] == len(entries) and "running" not in run.stderr, run.stderr[-2000:]
    assert [t["rows"] for t in again["tables"]] == [t["rows"] for t in doc["tables"]]
    if images:  # the figure too, from the ledger (as the written one's PNG)
        png = next(t for t in again["tables"] if t["name"] == "images")["figure"]["png"]
        assert base64.b64decode(png) == (out.parent / "quick.images.png").read_bytes()
    assert not list(work.glob("*"))  # nothing traced or fitted


def _check_sharing(doc: dict) -> None:
    """fit-clusters' members beside their own fits: every source once, in one cluster of all of them (-k 1), each
    member's bytes below its own fit's (the codebook and MLP are shared) and its errors finite."""
    rows = next(t for t in doc["tables"] if t["name"] == "sharing")["rows"]
    own = {r["source"] for r in next(t for t in doc["tables"] if t["name"] == "table3")["rows"]}
    assert {r["source"] for r in rows} == own and len(rows) == len(own) == 2
    for r in rows:
        assert r["cluster"] == 0 and r["cluster size"] == 2
        assert r["own log_err"] is not None and r["log_err"] is not None
        assert r["bytes"] < r["own bytes"]


def _check_ledger(out: Path, first: dict, stderr: str) -> None:
    """Both shards ran jobs (4 fits, the clusters and the first source's figure), each job once; the same command
    again without --workers runs none: every job from the ledger, the same tables, the ledger's commits named. The
    figure stacks the first source's pictures, one row per model (drawn by the shard that finished last, or the
    last pass)."""
    ledger = out.parent / "ledger.jsonl"
    entries = [json.loads(line) for line in ledger.read_text().splitlines()]
    assert len(entries) == len({e["key"] for e in entries}) == 6
    assert re.search(r"\[shard 0/2\]: .*: running", stderr) and re.search(r"\[shard 1/2\]: .*: running", stderr)
    assert first["ledger"]["entries_reused"] in (5, 6)
    assert first["ledger"]["their_commits"] == [first["machine"]["commit"]]
    figure = first["tables"][0]["figure"]
    assert figure["file"] == "quick.table3.png" and figure["caption"].startswith("ggx:roughness=0.2, seed 0, a row per")
    picture = np.asarray(Image.open(out.parent / figure["file"]))
    assert picture.shape[1] == 4 * 160 + 5 * 4 and picture.shape[0] > 2 * 160  # two models' rows of 4 panels
    again = _bench("neubrdf", "--quick", "--json", "--ledger", str(ledger))
    assert again.returncode == 0, again.stderr[-3000:]
    assert ": running" not in again.stderr
    tables = json.loads(again.stdout)["tables"]  # its figure as PNG text (no --out), the first run's in its file
    png = tables[0]["figure"].pop("png")
    assert base64.b64decode(png) == (out.parent / figure["file"]).read_bytes()
    assert tables == [{**t, "figure": {"caption": t["figure"]["caption"]}} if "figure" in t else t
                      for t in first["tables"]]


def _check_drjit_rows(doc: dict) -> None:
    """The Dr.Jit runtime's rows (quick mode: neubrdf) where Mitsuba's LLVM backend runs here."""
    from neumat.testing.drjit_parity import drjit_available
    if not drjit_available():
        return
    rows = [r for t in doc["tables"] for r in t["rows"] if str(r.get("target", "")).startswith("drjit")]
    assert [r.get("model", r.get("material")) for r in rows] == ["neubrdf"], doc["skipped"]
    if doc["suite"] == "export-parity":
        assert rows[0]["max"] < 1e-4
    else:
        assert rows[0]["evals/wall s"] > 0


def _check_speed(doc: dict) -> None:
    """Sanity, not speed: rates positive, % of sgemm and the GGX ratio consistent with the rates."""
    gflops = doc["tables"][0]["rows"][0]["GFLOP/s"]
    assert gflops > 0.1
    rows = {(r["material"], r["queries"]): r for r in next(t for t in doc["tables"] if t["name"] == "eval")["rows"]}
    assert {m for m, _ in rows} >= {"ggx:roughness=0.2", "ggx", "nbrdf", "neubrdf"}
    kernels = cpu_kernels.unavailable() is None
    for (material, n), r in rows.items():
        assert r["evals/cpu s"] > 0
        if material in ("ggx:roughness=0.2", "nbrdf", "neubrdf"):  # each has a fused kernel: the column must say so
            assert r["path"] == ("C kernel" if kernels else "torch"), (material, n)
        ggx = rows[("ggx:roughness=0.2", n)]["evals/cpu s"]
        assert r["x GGX"] == pytest.approx(ggx / r["evals/cpu s"], rel=1e-3)
        if r["flops/query"] is not None:
            assert r["% sgemm"] == pytest.approx(100 * r["flops/query"] * r["evals/cpu s"] / (gflops * 1e9), rel=1e-3)
    reads = next(t for t in doc["tables"] if t["name"] == "reads")["rows"]
    assert {(r["material"], r["read"]) for r in reads} >= {("multiscale", read) for read in speed.READS}
    assert all(r["evals/cpu s"] > 0 and r["path"] == rows[(r["material"], r["queries"])]["path"] for r in reads)
    for r in next(t for t in doc["tables"] if t["name"] == "fixed")["rows"]:  # the intercept of the two batches
        if r["us/call at 64"] is not None:
            one, many = r["us/call at 1"], r["us/call at 64"]
            assert r["fixed us"] == pytest.approx(min(max(one - (many - one) / 63, 0.0), one), rel=1e-3), r
    exports = next((t["rows"] for t in doc["tables"] if t["name"] == "exports"), [])
    mitsuba = [r for r in exports if r["target"] == "mitsuba measured (llvm)"]
    from neumat.testing.drjit_parity import drjit_available
    if drjit_available() and shared_data_dir() is not None:  # the RGL reader's reference: Mitsuba's plugin, same file
        assert [r["material"] for r in mitsuba] == ["rgl:paper_white"] and mitsuba[0]["evals/cpu s"] > 0
    if any(r["target"] == "glsl (llvmpipe)" for r in exports):  # NeuBRDF's table as an image, and as a sampler
        assert {r["precision"] for r in exports if r["target"] == "glsl 3.30 (llvmpipe)"} == {"fp32"}
    for target in {r["target"] for r in exports if r["target"].split()[0] in ("glsl", "slang")}:
        at = {r["material"]: r for r in exports if r["target"] == target}
        family = "glsl (llvmpipe)" if target.startswith("glsl") else target  # GGX and the floor: once a language
        timed = {r["material"]: r for r in exports if r["target"] == family}
        assert {"ggx:roughness=0.2", "harness floor (wi + wo)"} <= set(timed), target
        ggx = timed["ggx:roughness=0.2"]["evals/cpu s"]
        if target.startswith("glsl"):  # quick: Slang times GGX and the floor only (its NeuBRDF compile: ~20 s)
            assert at["neubrdf"]["x GGX"] == pytest.approx(ggx / at["neubrdf"]["evals/cpu s"], rel=1e-3), target
            if cpu_kernels.unavailable() is None:  # its runtime is a C kernel: its torch operations timed too
                assert at["neubrdf"]["x torch ops"] > 0, at["neubrdf"]
    training = next(t for t in doc["tables"] if t["name"] == "training")["rows"]
    assert {r["phase"] for r in training if r["model"] == "neubrdf"} == {"coarse", "dense", "vq"}
    written = next(t for t in doc["tables"] if t["name"] == "targets")["rows"]  # the last table, from the others
    expected = speed.targets({t["name"]: t["rows"] for t in doc["tables"] if t["name"] != "targets"}, 2 ** 16)
    assert [(r["target"], r["what"], r["met"]) for r in written] == [(r["target"], r["what"], r["met"])
                                                                     for r in expected]
    for w, e in zip(written, expected):
        assert (w["measured"] is None) == (e["measured"] is None), w
        assert w["measured"] is None or w["measured"] == pytest.approx(e["measured"], rel=1e-4), w
    assert any(r["met"] is not None for r in written)  # the fixed costs at least are measured in a quick run
    assert all(r["cpu s/step"] > 0 for r in training)
    if shared_data_dir() is not None:  # multiscale on two crops, the larger's step over the smaller's
        crop = {(r["batch"], r["phase"]): r["cpu s/step"] for r in training if r.get("texels") == "32^2"}
        larger = [r for r in training if r.get("texels") == "64^2"]
        assert crop and len(larger) == 1 and {r["model"] for r in larger} == {"multiscale"}
        r = larger[0]
        assert r["x 32^2"] == pytest.approx(r["cpu s/step"] / crop[(r["batch"], r["phase"])], rel=1e-3)


def test_targets_read_the_tables_and_say_what_is_not_measured():
    """Issue 49's targets from a run's tables: met, missed at the bound's far side, None where not measured."""
    n = 2 ** 16
    evals = [{"material": "neubrdf", "queries": n, "% sgemm": 50.0, "evals/cpu s": 1.0},
             {"material": "nbrdf", "queries": n, "% sgemm": 49.9, "evals/cpu s": 1.0},
             {"material": "multiscale", "queries": n, "% sgemm": 15.0, "evals/cpu s": 1.0},
             {"material": "ggx", "queries": n, "evals/cpu s": 3.0}, {"material": "ggx", "queries": 2 ** 20,
                                                                     "evals/cpu s": 1.99}]
    tables = {"eval": evals,
              "fixed": [{"what": "a.eval", "fixed us": 50.0}, {"what": "b.eval", "fixed us": 50.1},
                        {"what": "Query", "fixed us": None}],
              "exports": [{"material": "neubrdf", "target": "glsl (llvmpipe)", "precision": "fp32", "queries": n,
                           "evals/cpu s": 1.66e6, "x runtime": 2.5, "x torch ops": 1.5},
                          {"material": "neubrdf", "target": "glsl 3.30 (llvmpipe)", "precision": "fp32", "queries": n,
                           "evals/cpu s": 1.0e6, "x runtime": 4.2, "x torch ops": 2.5}],
              "training": [{"model": "multiscale", "texels": "1024^2", "phase": "fit", "x 64^2": 3.0},
                           {"model": "multiscale", "preset": "cpu", "texels": "1024^2", "phase": "fit",
                            "x 64^2": 3.5},  # the paper's recipe: reported, not a target
                           {"model": "multiscale", "texels": "64^2", "phase": "fit", "x 64^2": None},
                           {"model": "neumip", "texels": "1024^2", "phase": "fit", "x 64^2": 9.0}]}
    rows = {(r["target"].split(" ")[0], r["what"]): r for r in speed.targets(tables, n)}
    assert rows[("%", "neubrdf")]["met"] is True and rows[("%", "nbrdf")]["met"] is False
    assert rows[("%", "multiscale")]["met"] is True and rows[("%", "neumip")]["met"] is None
    assert {w for (t, w) in rows if t == "%"} == {"neubrdf", "nbrdf", *speed.LATENT_FAMILY}
    assert rows[("fixed", "a.eval")]["met"] is True and rows[("fixed", "b.eval")]["met"] is False
    assert ("fixed", "Query") not in rows
    assert rows[("per-query", "ggx")]["measured"] == pytest.approx(3.0 / 1.99)
    assert rows[("per-query", "ggx")]["met"] is False and rows[("per-query", "ggx:roughness=0.2")]["met"] is None
    glsl = [r for r in speed.targets(tables, n) if r["target"].startswith("GLSL")]
    assert [r["what"] for r in glsl] == (["neubrdf (fp32)"] * 3 + ["neubrdf (fp32, GLSL 3.30)"] * 3
                                         + ["neubrdf (fp16)"] * 3)  # no fp16 GLSL 3.30 row: none measured
    gain, slower, slower_than_torch = glsl[:3]
    assert gain["measured"] == pytest.approx(10.0) and gain["met"] is True
    assert slower["measured"] == 2.5 and slower["met"] is False
    assert slower_than_torch["measured"] == 1.5 and slower_than_torch["met"] is True
    assert glsl[5]["measured"] == 2.5 and glsl[5]["met"] is False  # the sampler's form, judged on its own
    assert all(r["measured"] is None and r["met"] is None for r in glsl[6:])  # no fp16 row in these tables
    assert rows[("1K-set", "multiscale (fit)")]["met"] is True and ("1K-set", "neumip (fit)") not in rows
    assert [r["measured"] for r in speed.targets(tables, n) if r["target"].startswith("1K-set")] == [3.0]


def test_the_latent_family_target_names_every_latent_texture_model():
    """A new latent-texture model is held to the 15 % target too: the family is every neural model of the
    latent_mlp folder (ggx-mipmap, its analytic baseline, aside) and neural-appearance."""
    from neumat.models.registry import load_all

    registry = load_all()
    family = {n for n in registry.names() if registry.get(n).__module__.startswith("neumat.methods.latent_mlp.")}
    assert set(speed.LATENT_FAMILY) == (family - {"ggx-mipmap"}) | {"neural-appearance"}


def test_raster_uv_walks_the_square_row_by_row():
    """The texture-read table's coherent uv: pixel centres of a side x rows image, u fastest, every one inside."""
    uv = speed.raster_uv(64)
    assert uv.shape == (64, 2) and ((uv > 0) & (uv < 1)).all()
    assert torch.equal(uv[:8, 0], (torch.arange(8) + 0.5) / 8) and (uv[:8, 1] == 1 / 16).all()
    assert (uv[8:16, 1] == 3 / 16).all() and len(set(map(tuple, uv.tolist()))) == 64
    assert speed.raster_uv(96)[-1].tolist() == pytest.approx([7.5 / 8, 11.5 / 12], rel=1e-7)  # 8 wide, 12 rows


def test_committed_results_match_the_schema_and_name_their_command():
    """Every results file validates and names its command, every ledger entry its command and commit; besides them
    the folders hold their pages and the figures the results files name (each one there)."""
    files = sorted((ROOT / "benchmarks" / "results").rglob("*.json"))
    figures = set()
    for path in files:
        doc = json.loads(path.read_text())
        jsonschema.validate(doc, SCHEMA)
        assert doc["command"].startswith(f"python -m benchmarks {doc['suite']}"), path
        figures |= {path.parent / t["figure"]["file"] for t in doc["tables"] if "figure" in t}
    assert all(f.is_file() for f in figures), figures
    for path in sorted((ROOT / "benchmarks" / "results").rglob("*.jsonl")):  # ledgers: every job with its command
        for line in path.read_text().splitlines():
            entry = json.loads(line)
            assert entry["command"].startswith(f"python -m benchmarks {path.parent.name}"), path
            assert re.fullmatch(r"[0-9a-f]{40}", entry["commit"]) and entry["result"], path
    assert not [p for p in (ROOT / "benchmarks" / "results").rglob("*") if p.is_file()
                and p.suffix not in (".json", ".jsonl", ".md") and p not in figures]


def test_no_sys_path_edit_and_no_training_loop_in_the_benchmarks():
    """Every script imports siblings as a package; the suites and the studies fit only through neumat.fit (no
    optimiser, no backward pass of their own)."""
    for path in (ROOT / "benchmarks").rglob("*.py"):
        assert "sys.path" not in path.read_text(), path
        _no_training_loop(path)


def _no_training_loop(path: Path) -> None:
    text = path.read_text()
    for pattern in (r"\.backward\(", r"torch\.optim\.\w+\(", r"\.step\(\)"):  # a call, a new optimiser, a step
        assert not re.search(pattern, text), (path, pattern)


def test_neumat_bench_runs_the_suite_entry_point(tmp_path, monkeypatch):
    """`neumat bench` is `python -m benchmarks` of the source repository: --list names every suite (run for real);
    a suite's options reach the entry point as its own (the quick runs above check what it writes); `compare` takes
    exactly two files."""
    from typer.testing import CliRunner

    from neumat.cli import bench
    from neumat.cli.main import app

    listed = subprocess.run([sys.executable, "-m", "neumat", "bench", "--list"], capture_output=True, text=True,
                            timeout=120)
    assert listed.returncode == 0, listed.stderr
    assert all(line.split()[0] in SUITES for line in listed.stdout.splitlines() if line and not line[0].isspace())
    calls = []
    monkeypatch.setattr(bench.subprocess, "run", lambda argv, **kw: calls.append((argv, kw)) or
                        subprocess.CompletedProcess(argv, 0))
    out = tmp_path / "e.json"
    result = CliRunner().invoke(app, ["bench", "sparsebtf", "--quick", "--out", str(out), "--seed", "3"])
    assert result.exit_code == 0, result.output
    (argv, kw), = calls
    assert argv == [sys.executable, "-m", "benchmarks", "sparsebtf", "--quick", "--out", str(out.resolve()),
                    "--seed", "3", "--threads", "1"]
    assert kw["cwd"] == ROOT
    calls.clear()
    result = CliRunner().invoke(app, ["bench", "neubrdf", "--work", str(tmp_path / "w"), "--ledger",
                                      str(tmp_path / "l.jsonl"), "--workers", "2"])
    assert result.exit_code == 0, result.output
    assert calls[0][0][-6:] == ["--work", str((tmp_path / "w").resolve()), "--ledger",
                                str((tmp_path / "l.jsonl").resolve()), "--workers", "2"]
    calls.clear()
    result = CliRunner().invoke(app, ["bench", "compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")])
    assert result.exit_code == 0, result.output
    assert calls[0][0][3:] == ["compare", str((tmp_path / "a.json").resolve()), str((tmp_path / "b.json").resolve())]
    for wrong in (["compare", str(tmp_path / "a.json")], ["sparsebtf", str(tmp_path / "a.json")]):
        result = CliRunner().invoke(app, ["bench", *wrong])
        assert result.exit_code == 2 and "two files are compared" in result.output, result.output


def _check_equal_bytes(doc: dict) -> None:
    """PCA is compared at equal storage: it keeps the most components that fit SparseBTF's per-BTF bytes (its codes
    at full capacity and its statistics) for the quick run's BTF (17 x 17 directions, 20 x 20 texels)."""
    from neumat.methods.sparse_btf.model import Config, storage_bytes

    rows = {r["model"]: r for r in next(t for t in doc["tables"] if t["name"] == "fits")["rows"]}
    per_btf = storage_bytes(Config(n_light=17, n_view=17, height=20, width=20))["per_btf"]
    component = 2 * (17 * 17 + 20 * 20)                   # one more principal component's bytes at fp16
    assert rows["pca-btf"]["bytes"] <= per_btf < rows["pca-btf"]["bytes"] + component, rows
    assert rows["sparse-btf"]["bytes"] > per_btf     # its total holds the dictionary ensemble too


def _check_resume(out: Path, first: dict, stderr: str) -> None:
    """The two shards generated the BTF once; the same command again with the --work folder it ran with refits
    nothing: the same rows, the generated BTF and fitted files untouched; with the ledger alone it runs no job and
    generates no BTF."""
    work = out.parent / "work"
    fitted = {p: p.stat().st_mtime_ns for p in work.rglob("*") if p.suffix in (".nmat", ".nbtf")}
    assert sorted(p.suffix for p in fitted) == [".nbtf", ".nmat", ".nmat"]
    again = _bench("sparsebtf", "--quick", "--json", "--work", str(work))
    assert again.returncode == 0, again.stderr[-3000:]
    assert "already done (kept), 0 to fit" in again.stderr
    assert {p: p.stat().st_mtime_ns for p in work.rglob("*") if p.suffix in (".nmat", ".nbtf")} == fitted
    assert json.loads(again.stdout)["tables"] == first["tables"]
    assert "a rerun resumes" in first["protocol"]["fits"]
    assert stderr.count(".partial.nbtf: ") == 1, stderr[-3000:]
    ledger_only = _bench("sparsebtf", "--quick", "--json", "--ledger", str(out.parent / "ledger.jsonl"))
    assert ledger_only.returncode == 0, ledger_only.stderr[-3000:]
    assert ": running" not in ledger_only.stderr and ".partial.nbtf" not in ledger_only.stderr
    assert json.loads(ledger_only.stdout)["tables"] == first["tables"]


def test_workers_below_one_are_refused(capsys):
    status, _, err = _main(capsys, "sparsebtf", "--workers", "0")
    assert status == 2 and "--workers 0: expected at least 1" in err


def test_shards_are_refused_where_they_cannot_work(capsys, tmp_path):
    """--shard needs a ledger and writes no --out; suites without independent fit jobs take neither option."""
    ledger = str(tmp_path / "l.jsonl")
    for args, message in ((["neubrdf", "--shard", "0/2"], "needs --ledger"),
                          (["neubrdf", "--shard", "0/2", "--ledger", ledger, "--out", str(tmp_path / "x.json")],
                           "takes neither --out"),
                          (["neubrdf", "--shard", "2/2", "--ledger", ledger], "expected 0 <= I < N"),
                          (["neubrdf", "--shard", "x", "--ledger", ledger], "expected I/N"),
                          (["speed", "--workers", "2"], "suite speed has no independent fit jobs")):
        status, _, err = _main(capsys, *args)
        assert status == 2 and message in err, (args, err)


def test_the_image_tables_folder_key_follows_the_trace_defaults(monkeypatch):
    """The suite keeps its trace of `neumat translucent trace`'s defaults under a folder keyed by them: a changed
    default (4000 -> 8000 views in session 60) must trace again, not reuse the old file."""
    import inspect

    from benchmarks.suites import neupress
    from neumat.cli import translucent
    from neumat.fit.translucent_observations import collect_observations

    option = inspect.signature(translucent.trace).parameters["images"].default
    before = neupress.trace_defaults()
    assert before["cli"]["images"] == option.default
    assert before["observations"]["resolution"] == inspect.signature(
        collect_observations).parameters["resolution"].default
    # how a trace is checkpointed or reported does not change it: a trace cut off resumes in the same folder
    assert not {"checkpoint", "resume", "quiet"} & set(before["cli"])
    assert not {"checkpoint", "resume", "checkpoint_every_s", "progress"} & set(before["observations"])
    monkeypatch.setattr(option, "default", option.default // 2)
    assert neupress.trace_defaults()["cli"]["images"] == option.default
    assert neupress.trace_defaults() != before


def test_a_run_cut_off_keeps_its_finished_tables_and_the_same_command_goes_on(tmp_path):
    """SIGTERM in the neupress quick run's first image job (a full run outlasts a sitting): --out holds the table
    before it, "skipped" names the rest and the job it stopped in, status 130; the same command then finishes,
    taking the finished jobs from the ledger."""
    import signal

    out = tmp_path / "quick.json"
    args = [sys.executable, "-m", "benchmarks", "neupress", "--quick", "--out", str(out), "--ledger",
            str(tmp_path / "ledger.jsonl"), "--work", str(tmp_path / "work")]
    run = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    for line in run.stderr:
        if "images: reference, another seed (floor): running" in line:  # after the first table, in a job
            run.send_signal(signal.SIGTERM)
            break
    err = run.stderr.read()
    assert run.wait(timeout=600) == 130, err[-3000:]
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    assert [t["name"] for t in doc["tables"]] == ["fits"]
    assert doc["skipped"][-1]["what"] == "the rest of the run" and "cut off after" in doc["skipped"][-1]["reason"]
    assert "in job 'images: reference, another seed (floor)'" in doc["skipped"][-1]["reason"]
    assert "the results hold the tables finished before it" in err
    again = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    doc = json.loads(out.read_text())
    assert doc["tables"][0]["name"] == "fits" and doc["ledger"]["entries_reused"] >= 2
    assert not any(s["what"] == "the rest of the run" for s in doc["skipped"])


def test_a_failed_or_interrupted_command_stops_the_suite_that_ran_it(tmp_path):
    """`cli` (a neumat command in the suite's process): a failed command raises SystemExit with its status, an
    interrupted one KeyboardInterrupt (the harness then writes the finished tables), a good one returns."""
    import os
    import signal
    import threading

    from benchmarks.suites.common import cli

    with pytest.raises(SystemExit) as failed:
        cli(["fit", str(tmp_path / "missing.bsdf"), "--model", "neubrdf", "-o", str(tmp_path / "a.nmat")])
    assert failed.value.code == 2
    # a good one first: it imports what a fit needs (an interrupt landing in an import, torch._dynamo's of sympy
    # under a loaded machine, leaves the module half made for every later test of the worker)
    cli(["fit", "plastic:roughness=0.2", "--model", "neubrdf", "--steps", "2", "-q", "-o", str(tmp_path / "c.nmat")])
    assert (tmp_path / "c.nmat").exists()
    # Python's own SIGINT handler: a process started in the background of a script inherits SIGINT ignored, and the
    # fit below would then run its million steps
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            cli(["fit", "plastic:roughness=0.2", "--model", "neubrdf", "--steps", "1000000", "-q", "-o",
                 str(tmp_path / "b.nmat")])
    finally:
        timer.join()
        signal.signal(signal.SIGINT, previous)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="looks for the shard processes with pgrep")
def test_a_run_with_workers_cut_off_stops_its_shards(tmp_path):
    """SIGTERM to a --workers 2 run while its shards work: it stops them (none left running), says the ledger keeps
    what they finished and exits 130."""
    import signal

    ledger = tmp_path / "ledger.jsonl"
    run = subprocess.Popen([sys.executable, "-m", "benchmarks", "neupress", "--quick", "--workers", "2", "--ledger",
                            str(ledger), "--work", str(tmp_path / "work")], cwd=ROOT, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    for line in run.stderr:
        if "[shard" in line and "running" in line:
            run.send_signal(signal.SIGTERM)
            break
    err = run.stderr.read()
    assert run.wait(timeout=600) == 130, err[-3000:]
    assert "cut off while its shards ran" in err
    left = subprocess.run(["pgrep", "-f", str(ledger)], capture_output=True, text=True).stdout.split()
    assert left == [], left


def test_results_name_a_ledger_relative_to_its_own_checkout(tmp_path):
    """A ledger in another checkout (a suite run from a frozen worktree writing main's ledger) is named relative to
    that checkout's root, one outside any checkout by its path."""
    subprocess.run(["git", "init", "-q", str(tmp_path / "repo")], check=True)
    (tmp_path / "repo" / "results").mkdir()
    assert harness._relative(tmp_path / "repo" / "results" / "l.jsonl") == "results/l.jsonl"
    assert harness._relative(tmp_path / "l.jsonl") == str((tmp_path / "l.jsonl").resolve())
    assert harness._relative(harness.ROOT / "benchmarks" / "x.json") == "benchmarks/x.json"
