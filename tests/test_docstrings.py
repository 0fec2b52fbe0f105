"""Prose where it belongs (issue 54, item 5): docstrings say what and, in a line, why, with a link; design
decisions and their measurements live in docs/notes/, format and interface specs in docs/formats/.

Two checks over every module under src/neumat (nothing exempt):

- module docstrings (`ast.get_docstring`) are at most MAX_MODULE_LINES (15) lines;
- no docstring (module, class, function, or the string statement after an attribute) holds more than
  MAX_MEASUREMENT_LINES (2) measurement lines. A measurement line contains a `benchmarks/` path, or the word
  "measured" together with a digit, or a numeric change "a -> b" between two numbers (e.g. "SSIM 0.85 -> 0.94").
  Measurements beyond that belong in the notes file next to the evidence, with one line of why and a pointer
  left in the docstring.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "neumat"
MAX_MODULE_LINES = 15
MAX_MEASUREMENT_LINES = 2

_MEASURED = re.compile(r"\bmeasured\b", re.IGNORECASE)
_DIGIT = re.compile(r"\d")
_CHANGE = re.compile(r"\d\s*->\s*\d")
_FILES = sorted(SRC.rglob("*.py"))


def _rel(path: Path) -> str:
    return path.relative_to(SRC).as_posix()


def is_measurement_line(line: str) -> bool:
    """A line of measurement narrative: a `benchmarks/` path, "measured" with a number, or "a -> b" numbers."""
    return ("benchmarks/" in line or bool(_MEASURED.search(line) and _DIGIT.search(line))
            or bool(_CHANGE.search(line)))


def docstrings(tree: ast.AST):
    """(line number, text) of every string statement in a body: module, class and function docstrings and
    attribute docstrings (the string after an assignment)."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(body, list):
            continue
        for statement in body:
            if (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)
                    and isinstance(statement.value.value, str)):
                yield statement.lineno, statement.value.value


@pytest.mark.parametrize("path", _FILES, ids=_rel)
def test_module_docstring_short(path):
    doc = ast.get_docstring(ast.parse(path.read_text(), str(path))) or ""
    n = len(doc.splitlines())
    assert n <= MAX_MODULE_LINES, (
        f"{_rel(path)}: module docstring of {n} lines (at most {MAX_MODULE_LINES}): keep what the module is, "
        "its interface in brief and a link; move the rest to docs/formats/ or docs/notes/")


@pytest.mark.parametrize("path", _FILES, ids=_rel)
def test_no_measurement_narrative(path):
    long = [(lineno, n) for lineno, text in docstrings(ast.parse(path.read_text(), str(path)))
            if (n := sum(map(is_measurement_line, text.splitlines()))) > MAX_MEASUREMENT_LINES]
    assert not long, (
        f"{_rel(path)}: docstrings at lines {[lineno for lineno, _ in long]} hold "
        f"{[n for _, n in long]} measurement lines (at most {MAX_MEASUREMENT_LINES}): move the measurements "
        "to docs/notes/<method>.md and leave one line of why with a pointer")


def test_rule_catches_narrative():
    """The measurement rule flags a docstring like the old `NeuBRDF.Config.direction_inputs` one."""
    text = """sharp highlights: MERL-like steel image MAE 0.0089 -> 0.0021, SSIM 0.971 -> 0.997 (CPU recipe,
    queries, log_cos_eps; benchmarks/studies/neubrdf/results/neubrdf_table3_hd_warp.md), where a log loss
    weighs a peak like its tails. Measured once on MERL-like chrome: 0.0029 and 0.0027."""
    assert sum(map(is_measurement_line, text.splitlines())) == 3
    assert not is_measurement_line("Corner weights of the runtime form (src/neumat/methods/neubrdf/NOTES.md).")
