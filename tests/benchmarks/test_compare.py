"""`python -m benchmarks compare`: a rerun's quality numbers against the committed run's seed spread."""
from __future__ import annotations

import copy
import json

from benchmarks import compare
from benchmarks.__main__ import main


def _doc() -> dict:
    rows = [{"source": "a", "model": "m", "seed": 0, "log_err": 0.10, "bytes": 100, "fit s": 5.0, "fit CPU min": 0.1},
            {"source": "a", "model": "m", "seed": 1, "log_err": 0.12, "bytes": 100, "fit s": 6.0, "fit CPU min": 0.1},
            {"source": "b", "model": "m", "seed": 0, "log_err": 0.30, "bytes": 100, "fit s": 5.0, "fit CPU min": 0.1},
            {"source": "b", "model": "m", "seed": 1, "log_err": 0.30, "bytes": 100, "fit s": 5.0, "fit CPU min": 0.1}]
    summary = [{"model": "m", "seeds": 2, "log_err mean": 0.2, "log_err seed spread": 0.01}]
    return {"suite": "toy", "tables": [{"name": "fits", "rows": rows}, {"name": "summary", "rows": summary}]}


def test_a_rerun_within_the_seed_spread_agrees_and_one_outside_is_named():
    old = _doc()
    new = copy.deepcopy(old)
    new["tables"][0]["rows"][0]["log_err"] = 0.115      # within a's spread 0.02
    new["tables"][0]["rows"][0]["fit s"] = 50.0         # a time: not judged
    new["tables"][0]["rows"][0]["fit CPU min"] = 0.9    # nor a CPU budget
    new["tables"][1]["rows"][0]["log_err mean"] = 0.205  # within its own seed spread column
    result = compare.compare(old, new)
    assert result["outside"] == 0 and not result["missing"]
    assert result["checked"] == 4 * 2 + 2               # log_err and bytes of 4 rows; the summary's mean, seeds
    new["tables"][0]["rows"][0]["log_err"] = 0.125      # 0.025 > 0.02
    new["tables"][0]["rows"][2]["log_err"] = 0.30002    # b's seeds agree: 1e-4 of the value is the least tolerance
    new["tables"][0]["rows"][3]["bytes"] = 101          # a size must be equal
    new["tables"][1]["rows"][0]["log_err mean"] = 0.22
    result = compare.compare(old, new)
    assert sorted((f["row"], f["column"]) for f in result["failures"]) == [
        ("model m", "log_err mean"), ("model m, seed 0, source a", "log_err"), ("model m, seed 1, source b", "bytes")]


def test_rows_that_differ_only_in_size_are_matched_by_it():
    """The speed suite's rows of one model at three batch sizes: each is compared with its own size's row, not
    with whichever came last."""
    rows = [{"material": "m", "seed": 0, "queries": q, "flops/query": 10, "evals/cpu s": 1e6 * q}
            for q in (1024, 65536, 1048576)]
    old = {"suite": "speed", "tables": [{"name": "eval", "rows": rows}]}
    new = copy.deepcopy(old)
    new["tables"][0]["rows"].reverse()
    result = compare.compare(old, new)
    assert result["outside"] == 0 and not result["missing"] and result["checked"] == 3 * 2
    new["tables"][0]["rows"][0]["flops/query"] = 11     # the 2^20 row's count changed: its row is not reproduced
    result = compare.compare(old, new)
    assert result["missing"] == ["eval: material m, seed 0, flops/query 10, queries 1048576"]
    assert result["checked"] == 2 * 2


def test_the_command_reports_and_exits_by_the_result(tmp_path, capsys):
    old, new = tmp_path / "old.json", tmp_path / "new.json"
    old.write_text(json.dumps(_doc()))
    changed = _doc()
    del changed["tables"][0]["rows"][3]
    new.write_text(json.dumps(changed))
    assert main(["compare", str(old), str(old)]) == 0
    assert "0 outside it" in capsys.readouterr().out
    assert main(["compare", str(old), str(new)]) == 1
    assert "missing: fits: model m, seed 1, source b" in capsys.readouterr().out
    other = _doc() | {"suite": "other"}
    new.write_text(json.dumps(other))
    assert main(["compare", str(old), str(new)]) == 2
    assert "different suites" in capsys.readouterr().err
    assert main(["compare", str(old)]) == 2
