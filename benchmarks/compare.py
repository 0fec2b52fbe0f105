"""`python -m benchmarks compare COMMITTED.json RERUN.json`: does a rerun reproduce a suite's committed quality
numbers within their seed spread? Rows are matched by their text columns and seed (and their sizes and counts where
those alone repeat); each quality number of the rerun must lie within the committed run's spread over seeds of the
same row (max - min of that column over the seeds, or the row's own "<column> seed spread"; at least 1e-4 of the
value, for deterministic methods whose seeds agree and whose numbers still move with the machine's arithmetic);
sizes and counts (bytes, steps, ...) must be equal; times and rates are machine-dependent and not judged. Exit
status 0 when every judged number agrees, 1 otherwise, 2 for unusable files."""
from __future__ import annotations

import json
import re
import sys
from collections import Counter
from pathlib import Path

#: columns that measure the machine, not the method: never judged
MACHINE = re.compile(r"(^fit s$|second|/s\b|/cpu s|\bcpu min\b|/wall s|us/|wall|gflop|% sgemm|x ggx|x torch|x runtime|^time)",
                     re.I)
#: the least tolerance, relative to the committed value (module docstring)
FLOOR = 1e-4
#: columns that must be equal in a rerun (sizes and counts)
EXACT = {"bytes", "steps", "queries", "flops/query", "sources", "seeds", "failed", "members", "clusters"}


def compare(committed: dict, rerun: dict) -> dict:
    """{"checked", "outside", "unjudged", "missing": [...], "failures": [...]} of `rerun` against `committed`
    (results documents of one suite; module docstring)."""
    if committed.get("suite") != rerun.get("suite"):
        raise ValueError(f"the files are results of different suites ({committed.get('suite')!r}, "
                         f"{rerun.get('suite')!r})")
    out = {"checked": 0, "outside": 0, "unjudged": 0, "missing": [], "failures": []}
    new_tables = {t["name"]: t for t in rerun.get("tables", [])}
    for table in committed.get("tables", []):
        new = new_tables.get(table["name"])
        if new is None:
            out["missing"].append(f"table {table['name']!r}")
            continue
        repeated = _repeated(table["rows"])
        new_rows = {_key(r, repeated): r for r in new["rows"]}
        spreads = _spreads(table["rows"], repeated)
        for row in table["rows"]:
            key = _key(row, repeated)
            other = new_rows.get(key)
            if other is None:
                out["missing"].append(f"{table['name']}: {_label(key)}")
                continue
            for column, old in row.items():
                new_value = other.get(column)
                if not _number(old) or not _number(new_value) or MACHINE.search(column) or \
                        column == "seed" or column.endswith("seed spread"):
                    continue
                if column in EXACT:
                    tolerance = 0.0
                else:
                    own = row.get(f"{column.removesuffix(' mean')} seed spread")
                    tolerance = own if _number(own) else spreads.get((_group(key), column))
                if tolerance is None:
                    out["unjudged"] += 1
                    continue
                out["checked"] += 1
                if column not in EXACT:
                    tolerance = max(tolerance, FLOOR * abs(old))
                if abs(new_value - old) > tolerance + 1e-12:
                    out["outside"] += 1
                    out["failures"].append({"table": table["name"], "row": _label(key), "column": column,
                                            "committed": old, "rerun": new_value, "spread": tolerance})
    return out


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _key(row: dict, repeated: frozenset = frozenset()) -> tuple:
    """A row's identity: its text columns and its seed, and its sizes and counts (`EXACT`) where text and seed alone
    name several rows of the committed table (`_repeated`: the speed suite's rows of one model at three batch
    sizes)."""
    key = tuple(sorted((k, v) for k, v in row.items() if isinstance(v, str) or k == "seed"))
    return key + tuple(sorted((k, v) for k, v in row.items() if k in EXACT)) if key in repeated else key


def _repeated(rows: list[dict]) -> frozenset:
    """The text-and-seed keys that more than one of `rows` has."""
    counts = Counter(_key(r) for r in rows)
    return frozenset(k for k, c in counts.items() if c > 1)


def _group(key: tuple) -> tuple:
    return tuple(kv for kv in key if kv[0] != "seed")


def _label(key: tuple) -> str:
    return ", ".join(f"{k} {v}" for k, v in key)


def _spreads(rows: list[dict], repeated: frozenset) -> dict:
    """{(group, column): max - min over the group's seeds} for groups with two seeds or more."""
    values: dict = {}
    for row in rows:
        if row.get("seed") is None:
            continue
        for column, v in row.items():
            if _number(v) and column != "seed":
                values.setdefault((_group(_key(row, repeated)), column), {})[row["seed"]] = v
    return {k: max(v.values()) - min(v.values()) for k, v in values.items() if len(v) >= 2}


def main(argv: list[str]) -> int:
    """Print the comparison of two results files; the exit status (module docstring)."""
    if len(argv) != 2:
        print("usage: python -m benchmarks compare COMMITTED.json RERUN.json", file=sys.stderr)
        return 2
    try:
        committed, rerun = (json.loads(Path(p).read_text()) for p in argv)
        result = compare(committed, rerun)
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"compare: {e}", file=sys.stderr)
        return 2
    print(f"{committed['suite']}: {result['checked']} quality numbers judged against the committed seed spread, "
          f"{result['outside']} outside it; {result['unjudged']} without a spread (one seed) not judged; "
          f"{len(result['missing'])} committed rows or tables missing from the rerun")
    for f in result["failures"]:
        print(f"  outside: {f['table']}: {f['row']}: {f['column']} {f['committed']:.6g} -> {f['rerun']:.6g} "
              f"(|diff| {abs(f['rerun'] - f['committed']):.3g} > spread {f['spread']:.3g})")
    for m in result["missing"]:
        print(f"  missing: {m}")
    return 0 if not result["outside"] and not result["missing"] else 1
