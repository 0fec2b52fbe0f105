"""The harness's job ledger (`benchmarks.harness.Run.job`, `Ledger`): a job it holds is not run again, shards split
the jobs so that each runs on exactly one, failed results are not kept, a cut-off line is ignored, and two
processes appending at once lose nothing."""
from __future__ import annotations

import json
import multiprocessing
import types

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


def test_shards_split_the_jobs_and_the_last_pass_takes_all(tmp_path):
    ledger = tmp_path / "l.jsonl"
    keys = [{"i": i} for i in range(40)]
    ran = {0: [], 1: [], 2: []}
    for s in range(3):  # one after another: a later shard finds the earlier ones' jobs in the ledger
        for k in keys:
            _run(ledger, (s, 3)).job(str(k), k, lambda k=k, s=s: ran[s].append(k["i"]) or {"i": k["i"]},
                                     keep=lambda r: True)
    assert sorted(i for v in ran.values() for i in v) == list(range(40)) and all(ran.values())
    final = _run(ledger)
    assert [final.job(str(k), k, lambda: {"i": -1}, keep=lambda r: True)["i"] for k in keys] == list(range(40))
    assert len(final.reused) == 40


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

    from benchmarks.suites.common import content_sha256

    a = tmp_path / "here" / "Set"
    a.mkdir(parents=True)
    (a / "col.jpg").write_bytes(b"\x01\x02")
    (a / "rgh.jpg").write_bytes(b"\x03")
    b = tmp_path / "there" / "Set"
    shutil.copytree(a, b)
    assert content_sha256(str(a)) == content_sha256(str(b))
    (b / "rgh.jpg").write_bytes(b"\x04")
    assert content_sha256(str(a)) != content_sha256(str(b))
    assert content_sha256("ggx:roughness=0.2") == content_sha256("ggx:roughness=0.2")


def test_a_fit_job_runs_again_when_its_recipe_changes(tmp_path, monkeypatch):
    """fit_many's ledger key holds the model's recipe content: the same options after a changed
    default are a new job, the unchanged ones are not (the fit itself replaced by a stub)."""
    import dataclasses

    from benchmarks.suites import common
    from neumat.fit.method import recipe_for

    fits = []
    monkeypatch.setattr(common, "_fit_one", lambda run, source, model, options, seed, after:
                        fits.append(model) or {"name": source, "model": model, "status": "ok"})
    run = lambda: _run(tmp_path / "l.jsonl")  # noqa: E731
    common.fit_many(run(), ["ggx:roughness=0.2"], ["nbrdf"], ["--preset", "cpu"], [0])
    common.fit_many(run(), ["ggx:roughness=0.2"], ["nbrdf"], ["--preset", "cpu"], [0])
    assert fits == ["nbrdf"]
    changed = dataclasses.replace(recipe_for("nbrdf", "cpu"), steps=7)
    monkeypatch.setattr(common, "recipe_for", lambda model, name: changed if name == "cpu" else recipe_for(model, name))
    common.fit_many(run(), ["ggx:roughness=0.2"], ["nbrdf"], ["--preset", "cpu"], [0])
    assert fits == ["nbrdf", "nbrdf"]
