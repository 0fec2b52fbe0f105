"""The harness's job ledger (`benchmarks.harness.Run.job`, `Ledger`): a job it holds is not run again, shards split
the jobs so that each runs on exactly one, failed results are not kept, a cut-off line is ignored, and two
processes appending at once lose nothing."""
from __future__ import annotations

import hashlib
import json
import multiprocessing
import time
import types
from pathlib import Path

import pytest

from benchmarks import harness

SUITE = types.SimpleNamespace(NAME="toy")


def _run(ledger=None, shard=(0, 1)) -> harness.Run:
    return harness.Run(SUITE, False, 0, 1, 1, ["toy"], ledger=ledger, shard=shard)


def test_a_job_in_the_ledger_is_not_run_again(tmp_path):
    ledger = tmp_path / "l.jsonl"
    calls = []
    first = _run(ledger).job("a", {"x": 1}, lambda: calls.append(1) or {"v": 2.5}, keep=lambda r: True)
    again = _run(ledger)
    assert again.job("a", {"x": 1}, lambda: calls.append(1) or {"v": 9}, keep=lambda r: True) == first == {"v": 2.5}
    assert calls == [1] and len(again.reused) == 1
    entry = json.loads(ledger.read_text())
    assert entry["what"] == "a" and entry["command"] == "python -m benchmarks toy" and len(entry["commit"]) >= 7
    assert _run(ledger).job("a", {"x": 2}, lambda: {"v": 3}, keep=lambda r: True) == {"v": 3}  # another key


def test_results_not_kept_are_run_again(tmp_path):
    ledger = tmp_path / "l.jsonl"
    assert _run(ledger).job("a", {}, lambda: {"status": "error"}, keep=lambda r: r["status"] == "ok")
    assert not ledger.exists() or ledger.read_text() == ""


def _digest(key: dict) -> int:
    return int(hashlib.sha256(json.dumps(["toy", False, key], sort_keys=True).encode()).hexdigest(), 16)


def _shard_loop(ledger, index, ran, jobs):
    run = _run(ledger, (index, 2))
    for i in jobs:
        run.job(str(i), {"i": i}, lambda i=i: time.sleep(0.2) or ran.put((index, i)) or {"i": i}, keep=lambda r: True)


def test_shards_take_jobs_as_they_come_each_once_and_the_last_pass_takes_all(tmp_path):
    """Two shard processes at once: every job runs exactly once and both run a share, also of jobs whose keys all
    hash alike (a job is claimed, not assigned by its key's hash, which left one shard 8 of a full run's 10 missing
    fits and the other idle)."""
    ledger = tmp_path / "l.jsonl"
    jobs = [i for i in range(200) if _digest({"i": i}) % 2][:16]
    ctx = multiprocessing.get_context("fork")
    ran = ctx.Queue()
    shards = [ctx.Process(target=_shard_loop, args=(ledger, i, ran, jobs)) for i in range(2)]
    for p in shards:
        p.start()
    for p in shards:
        p.join(60)
    done = [ran.get(timeout=5) for _ in range(16)]
    assert sorted(i for _, i in done) == jobs and ran.empty()
    per_shard = [sum(s == k for s, _ in done) for k in range(2)]
    assert min(per_shard) >= 4, per_shard
    final = _run(ledger)
    assert [final.job(str(i), {"i": i}, lambda: {"i": -1}, keep=lambda r: True)["i"] for i in jobs] == jobs
    assert len(final.reused) == 16


def test_a_job_another_shard_holds_is_left_to_it(tmp_path):
    ledger = tmp_path / "l.jsonl"
    holder, other = _run(ledger, (0, 2)), _run(ledger, (1, 2))
    with holder._claim(f"{_digest({'x': 1}):064x}") as held:
        assert held
        assert other.job("a", {"x": 1}, lambda: {"v": 1}, keep=lambda r: True) is None
    assert other.job("a", {"x": 1}, lambda: {"v": 2}, keep=lambda r: True) == {"v": 2}   # released: runs it


def test_a_line_cut_off_is_ignored(tmp_path):
    ledger = tmp_path / "l.jsonl"
    _run(ledger).job("a", {"x": 1}, lambda: {"v": 1}, keep=lambda r: True)
    with open(ledger, "a") as f:
        f.write('{"key": "')  # a run killed in the middle of its line
    assert _run(ledger).job("a", {"x": 1}, lambda: {"v": 2}, keep=lambda r: True) == {"v": 1}
    assert _run(ledger).job("b", {"x": 3}, lambda: {"v": 3}, keep=lambda r: True) == {"v": 3}


def _append(path, start):
    ledger = harness.Ledger(path)
    for i in range(start, start + 200):
        ledger.add(f"k{i}", "w", {"pad": "x" * 5000, "i": i}, "c")


def test_two_processes_appending_at_once_lose_nothing(tmp_path):
    path = tmp_path / "l.jsonl"
    procs = [multiprocessing.get_context("fork").Process(target=_append, args=(path, s)) for s in (0, 200)]
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert sorted(r["result"]["i"] for r in rows) == list(range(400))


def test_a_source_folder_keys_by_its_content_not_its_path(tmp_path):
    """A texture set copied elsewhere (another machine's shared data) keys the same; a changed byte does not."""
    import shutil

    from neumat.cli.fit_job import source_sha256  # what fit_many's ledger keys hold

    a = tmp_path / "here" / "Set"
    a.mkdir(parents=True)
    (a / "col.jpg").write_bytes(b"\x01\x02")
    (a / "rgh.jpg").write_bytes(b"\x03")
    b = tmp_path / "there" / "Set"
    shutil.copytree(a, b)
    assert source_sha256(str(a)) == source_sha256(str(b))
    (b / "rgh.jpg").write_bytes(b"\x04")
    assert source_sha256(str(a)) != source_sha256(str(b))
    assert source_sha256("ggx:roughness=0.2") == source_sha256("ggx:roughness=0.2")


def _stub_fit_many(tmp_path, monkeypatch):
    """fit-many replaced by a stub that records each folder it is run in; returns (folders, fit), fit() running
    `common.fit_many` of nbrdf at preset cpu on one analytic source with one ledger and work folder."""
    from benchmarks.suites import common

    folders = []

    def fit_many_cli(args):
        out = Path(args[args.index("-o") + 1])
        folders.append(out)
        (out / "results.json").write_text(json.dumps({"rows": [{"name": "s", "model": args[3], "status": "ok"}]}))

    monkeypatch.setattr(common, "cli", fit_many_cli)

    def fit():
        run = harness.Run(SUITE, False, 0, 1, 1, ["toy"], work=tmp_path / "work", ledger=tmp_path / "l.jsonl")
        common.fit_many(run, ["ggx:roughness=0.2"], ["nbrdf"], ["--preset", "cpu"], [0])
    return folders, fit


def test_a_fit_job_runs_again_when_its_recipe_changes(tmp_path, monkeypatch):
    """fit_many's ledger key and its kept fit-many folder (--work) hold the model's recipe content: the same options
    after a changed default are a new job fitted in a new folder (fit-many would keep the old folder's fit, whose
    preset name and overrides match), the unchanged ones are not (fit-many itself replaced by a stub)."""
    import dataclasses

    from benchmarks.suites import common
    from neumat.fit.method import recipe_for

    folders, fit = _stub_fit_many(tmp_path, monkeypatch)
    fit()
    fit()
    assert len(folders) == 1
    changed = dataclasses.replace(recipe_for("nbrdf", "cpu"), steps=7)
    monkeypatch.setattr(common, "recipe_for", lambda model, name: changed if name == "cpu" else recipe_for(model, name))
    fit()
    assert len(folders) == 2 and folders[1] != folders[0] and folders[0].parent == folders[1].parent


@pytest.mark.parametrize("change", ["config", "preset"])
def test_a_fit_job_runs_again_when_its_model_defaults_or_preset_change(tmp_path, monkeypatch, change):
    """The same for a changed config default (the gated model's output_bound, session 77) and a changed override of
    a "paper" or "cpu" preset, which FitJob.fit_sha256 names only."""
    import dataclasses

    from neumat.fit import preset as presets
    from neumat.fit.preset import Preset
    from neumat.methods.baselines.nbrdf import NBRDF

    folders, fit = _stub_fit_many(tmp_path, monkeypatch)
    fit()
    fit()
    assert len(folders) == 1
    if change == "config":
        @dataclasses.dataclass
        class Config(NBRDF.Config):
            hidden: int = NBRDF.Config().hidden + 1
        monkeypatch.setattr(NBRDF, "Config", Config)
    else:
        named = presets.preset_named
        monkeypatch.setattr(presets, "preset_named", lambda model, name: Preset(
            "changed", recipe="cpu", overrides={"model.hidden": 3}) if name == "cpu" else named(model, name))
    fit()
    assert len(folders) == 2 and folders[1] != folders[0]


def test_a_changed_ledger_or_result_does_not_make_the_code_dirty(tmp_path, monkeypatch):
    """A ledger the run appends to (committed under benchmarks/results) is not a change of the code: entries and
    results made with an unchanged tree say dirty false; a changed source file says true."""
    import subprocess

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=tmp_path, check=True,
                       capture_output=True)

    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "benchmarks" / "results" / "full.jsonl").write_text("{}\n")
    study = tmp_path / "benchmarks" / "studies" / "topic"
    (study / "results").mkdir(parents=True)
    (study / "results" / "jobs.jsonl").write_text("{}\n")
    (study / "study.py").write_text("x = 1\n")
    (tmp_path / "code.py").write_text("x = 1\n")
    git("init", "-q")
    git("add", "-A")
    git("commit", "-qm", "c")
    monkeypatch.setattr(harness, "ROOT", tmp_path)
    assert harness._dirty() is False
    (tmp_path / "benchmarks" / "results" / "full.jsonl").write_text("{}\n{}\n")
    (study / "results" / "jobs.jsonl").write_text("{}\n{}\n")  # a study's ledger
    assert harness._dirty() is False
    (study / "study.py").write_text("x = 2\n")  # a study's code
    assert harness._dirty() is True
    (study / "study.py").write_text("x = 1\n")
    assert harness._dirty() is False
    (tmp_path / "code.py").write_text("x = 2\n")
    assert harness._dirty() is True


def test_results_name_the_code_as_it_was_when_the_run_started(tmp_path, monkeypatch):
    """A run takes minutes to hours: a commit or an edit made while it runs is not the code that made its numbers,
    so the commit and dirtiness are read when it starts, and a ledger entry's when its job starts."""
    import subprocess

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=tmp_path, check=True,
                       capture_output=True)

    (tmp_path / "code.py").write_text("x = 1\n")
    git("init", "-q")
    git("add", "-A")
    git("commit", "-qm", "c")
    monkeypatch.setattr(harness, "ROOT", tmp_path)
    started = harness._git("rev-parse", "HEAD")

    def change() -> dict:  # the code changes, then is committed, while a job runs
        (tmp_path / "code.py").write_text("x = 2\n")
        git("commit", "-qam", "d")
        return {"v": 1}

    def run(r):
        r.job("a", {"x": 1}, change, keep=lambda result: True)
        r.table("t", "t", [{"a": 1}])

    doc = harness.Run(types.SimpleNamespace(NAME="toy", run=run, BUDGET={"full": {}}, DESCRIPTION=""), False, 0, 1,
                      1, ["toy"], ledger=tmp_path / "l.jsonl").execute()
    assert doc["machine"]["commit"] == started != harness._git("rev-parse", "HEAD")
    assert doc["machine"]["dirty"] is False
    entry = json.loads((tmp_path / "l.jsonl").read_text())  # the job's ledger entry: the code it ran, too
    assert entry["commit"] == started and entry["dirty"] is False


def _busy(seconds: float) -> dict:
    """Spin on the CPU for about `seconds`, then sleep as long (wall time without CPU time)."""
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass
    time.sleep(seconds)
    return {"status": "ok"}


def test_jobs_record_their_wall_and_cpu_seconds_and_the_run_sums_them(tmp_path):
    """Each job's own wall and CPU seconds go into its ledger entry (a sleeping job: wall about twice its CPU), a
    run that takes it from the ledger sums them as one that ran it does, and an entry from before jobs were timed
    counts its fit-many row's wall seconds with its CPU unknown."""
    ledger = tmp_path / "l.jsonl"
    run = _run(ledger)
    run.job("a", {"x": 1}, lambda: _busy(0.2), keep=lambda r: True)
    entry = json.loads(ledger.read_text())
    assert 0.18 <= entry["cpu_seconds"] <= 0.3 and entry["wall_seconds"] >= entry["cpu_seconds"] + 0.19, entry
    old = {"key": "old", "what": "b", "command": "c", "commit": "0" * 40, "dirty": False, "date": "d",
           "result": {"seconds": 7200.0, "status": "ok"}}
    assert harness.job_seconds(old) == (7200.0, None)
    again = _run(ledger)
    again.job("a", {"x": 1}, lambda: _busy(5), keep=lambda r: True)  # taken from the ledger, not run
    summary = harness.jobs_summary(again.job_times + [harness.job_seconds(old)])
    assert summary["count"] == 2 and summary["timed_wall"] == 2 and summary["timed_cpu"] == 1
    assert summary["wall_seconds"] == round(entry["wall_seconds"] + 7200, 1)
    assert summary["cpu_seconds"] == round(entry["cpu_seconds"], 1)
    assert harness.jobs_summary(run.job_times) == harness.jobs_summary(again.job_times)
