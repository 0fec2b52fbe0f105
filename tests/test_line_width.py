"""House style: no line of the package or its tests is longer than MAX_WIDTH characters (pyproject has no linter
that checks it; this does, so a long line fails CI where it is written)."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_WIDTH = 120


def test_no_line_is_wider_than_the_house_width():
    long = [f"{path.relative_to(ROOT)}:{number} ({len(line)} characters)"
            for folder in ("src", "tests") for path in sorted((ROOT / folder).rglob("*.py"))
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if len(line) > MAX_WIDTH]
    assert not long, f"lines wider than {MAX_WIDTH} characters:\n" + "\n".join(long)
