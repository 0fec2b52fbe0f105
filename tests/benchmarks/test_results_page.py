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
    assert harness.write(doc, tmp_path / "full.json") == doc
    assert json.loads((tmp_path / "full.json").read_text()) == doc
    text = (tmp_path / "README.md").read_text()
    assert text.count("# sparsebtf (full)") == 2
    assert doc["command"] in text and earlier["command"] in text
    assert text.index(earlier["command"]) < text.index(doc["command"])  # the folder's files in name order


def test_a_figure_goes_to_its_png_file_named_in_the_json_and_shown_on_the_page(tmp_path):
    """A table's figure travels as base64 PNG (in a ledger entry, in the document) and is written as its own file
    beside the results, which the JSON names (valid against the schema) and the page shows under its table."""
    import jsonschema
    import numpy as np
    from PIL import Image

    doc = json.loads(COMMITTED.read_text())
    picture = np.zeros((5, 7, 3), np.uint8)
    picture[1, 2] = (255, 128, 3)
    doc["tables"][0]["figure"] = {"caption": "reference | model | error", "png": harness.png_base64(picture)}
    written = harness.write(doc, tmp_path / "full.json")
    name = doc["tables"][0]["name"]
    assert written["tables"][0]["figure"] == {"caption": "reference | model | error", "file": f"full.{name}.png"}
    assert "png" in doc["tables"][0]["figure"]  # the run's own document is left as it was
    assert np.array_equal(np.asarray(Image.open(tmp_path / f"full.{name}.png")), picture)
    assert json.loads((tmp_path / "full.json").read_text()) == written
    jsonschema.validate(written, json.loads(harness.SCHEMA_PATH.read_text()))
    page = (tmp_path / "README.md").read_text()
    last_row = "| " + " | ".join(harness._cell(doc["tables"][0]["rows"][-1].get(c))
                                 for c in doc["tables"][0]["columns"]) + " |"
    assert f"{last_row}\n\n![{name}](full.{name}.png)\n\nreference | model | error\n" in page  # under its table
    assert "(its figure: `--out` writes it as a PNG file)" in harness.markdown(doc)
