"""The neubrdf suite's full run, its fits replaced by stubs: the paper's Table 3 on both data sets, its Table 4 from
the three grids of the paper's model (the codebook rows shared with Table 3), pruning (pruned and not, on
balanced and uniform draws) and sharing, each fit asked for with the options its ledger key holds."""
from __future__ import annotations

import types

from benchmarks import harness
from benchmarks.suites import neubrdf


def test_the_full_run_asks_for_each_table_s_fits_and_tabulates_tables_3_and_4(monkeypatch):
    calls = []

    def fit_many(run, sources, models, options, seeds):
        calls.append((tuple(sources), tuple(models), tuple(options), tuple(seeds)))
        return [{"name": s.split("/")[-1], "source": s, "model": m, "seed": seed, "status": "ok",
                 "metrics": {"log_err": 0.001, "rmse_hdr": 0.1, "img_mae": 0.01, "img_ssim": 0.9, "img_flip": 0.05},
                 "bytes_fp16": 100}
                for s in sources for m in models for seed in seeds]

    monkeypatch.setattr(neubrdf, "fit_many", fit_many)
    monkeypatch.setattr(neubrdf, "fits_figure", lambda *a: None)
    monkeypatch.setattr(neubrdf, "_clusters", lambda *a: None)
    run = harness.Run(types.SimpleNamespace(NAME="neubrdf"), False, 0, 1, 1, ["neubrdf"])
    rgl, merl = ["rgl/a.bsdf", "rgl/b.bsdf"], ["merl/x.h5", "merl/y.h5", "merl/z.h5"]
    neubrdf._full(run, rgl, merl, [0, 1])

    assert [t["name"] for t in run.tables] == ["table3", "table3_summary", "table3_merl", "table3_merl_summary",
                                               "pruning", "table4", "table4_summary", "sharing"]
    tables = {t["name"]: t for t in run.tables}
    assert {r["model"] for r in tables["table3"]["rows"]} == {"neubrdf", "nbrdf", "ggx", "neubrdf-paper"}
    assert {r["model"] for r in tables["table3_merl"]["rows"]} == {"neubrdf", "nbrdf", "neubrdf-paper"}
    assert [r["model"] for r in tables["table4_summary"]["rows"]] == ["neubrdf-dense", "neubrdf-lowbit4",
                                                                       "neubrdf-paper"]
    assert all(r["seeds"] == 2 and r["sources"] == 3 for r in tables["table4_summary"]["rows"])
    assert "rmse_hdr mean" in tables["table4_summary"]["columns"]
    # the paper's model is fitted once per data set (Table 4 takes the MERL-like rows of Table 3), with the options
    # the ledger keys of the committed run hold
    paper = (*neubrdf.PAPER_MODEL, *neubrdf.FULL_EVAL)
    assert calls.count((tuple(merl), ("neubrdf",), paper, (0, 1))) == 1
    assert calls.count((tuple(rgl), ("neubrdf",), paper, (0, 1))) == 1
    for options in neubrdf.QUANTISATION.values():
        assert (tuple(merl), ("neubrdf",), (*options, *neubrdf.FULL_EVAL), (0, 1)) in calls
    assert (tuple(rgl), ("neubrdf",), (*neubrdf.PRUNING, *neubrdf.FULL_EVAL), (0,)) in calls
    assert (tuple(rgl), ("neubrdf",), (*neubrdf.REPLAY, *neubrdf.FULL_EVAL), (0,)) in calls
    assert (tuple(rgl), ("neubrdf",), (*neubrdf.PRUNING_UNIFORM, *neubrdf.FULL_EVAL), (0,)) in calls
    assert (tuple(rgl), ("neubrdf",), (*neubrdf.REPLAY_UNIFORM, *neubrdf.FULL_EVAL), (0,)) in calls
    assert {r["model"] for r in tables["pruning"]["rows"]} == {"neubrdf-pruned", "neubrdf-unpruned",
                                                               "neubrdf-pruned-uniform", "neubrdf-unpruned-uniform"}
    assert len(calls) == 10
