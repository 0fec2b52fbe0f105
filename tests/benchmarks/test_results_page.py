"""`harness.write`: the results folder's page is built from its results documents only."""
from __future__ import annotations

import json
from pathlib import Path

from benchmarks import harness

COMMITTED = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "sparsebtf" / "full.json"


def test_the_page_leaves_out_other_json_beside_the_results(tmp_path):
    """A run told `--out /tmp/x.json` meets whatever else is there: the page lists the results documents (two runs
    here), skips a list, another schema and a broken file, and the run still ends with its file written."""
    doc = json.loads(COMMITTED.read_text())
    (tmp_path / "crops.json").write_text("[[1, 2], [3, 4]]")
    (tmp_path / "other.json").write_text(json.dumps({"schema": "someone-else/1", "machine": []}))
    (tmp_path / "broken.json").write_text('{"schema": "neumat-bench/1", "suite"')
    earlier = dict(doc, command="python -m benchmarks sparsebtf --out earlier.json")
    (tmp_path / "a_earlier.json").write_text(json.dumps(earlier))
    out, page = harness.write(doc, tmp_path / "full.json")
    assert json.loads(out.read_text()) == doc
    text = page.read_text()
    assert text.count("# sparsebtf (full)") == 2
    assert doc["command"] in text and earlier["command"] in text
    assert text.index(earlier["command"]) < text.index(doc["command"])  # the folder's files in name order
