"""No file of the repository carries merge-conflict markers (a merge once committed them into two docs)."""
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHECKED = ("src", "tests", "docs", "benchmarks", "examples", ".ci")
SUFFIXES = {".py", ".md", ".txt", ".toml", ".cfg", ".yml", ".yaml", ".json", ".glsl", ".slang", ".js", ".html", ""}
MARKERS = ("<<<<<<< ", ">>>>>>> ")


def test_no_merge_conflict_markers():
    files = [ROOT / name for name in ("README.md", "Makefile", "pyproject.toml")]
    for folder in CHECKED:
        files += [p for p in (ROOT / folder).rglob("*") if p.is_file() and p.suffix in SUFFIXES]
    found = []
    for path in files:
        if not path.is_file():
            continue
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}:{i + 1}" for i, line in enumerate(lines)
                  if line.startswith(MARKERS) or line == "======="]
    assert len(files) > 50 and not found, found
