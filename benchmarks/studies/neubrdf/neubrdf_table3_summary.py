"""NeuBRDF's Table 3 on our data from `neumat fit-many` results (issue 32): per source the models' image and
reflectance errors with the lowest image MAE in bold, then per model the mean image MAE / RMSE / SSIM, and how
many sources NeuBRDF wins in image MAE against each other model, with the sources it loses.

    python benchmarks/studies/neubrdf/neubrdf_table3_summary.py OUT/results.json [MORE/results.json ...] [--label "dense path"]
    python benchmarks/studies/neubrdf/neubrdf_table3_summary.py NEW/results.json --from-table benchmarks/studies/neubrdf/results/neubrdf_table3_merl.md
    python benchmarks/studies/neubrdf/neubrdf_table3_summary.py CODEBOOK/results.json --from-table benchmarks/studies/neubrdf/results/neubrdf_table3_merl.md \
        --table-models nbrdf,ggx --label codebook

`--from-table` reads the per-source rows of an earlier output of this script (for runs whose results.json is
gone); its values carry the printed rounding (image MAE to 4 decimals), so a comparison with a table row is made at
that rounding, and one equal there is listed as undecided (neither a win nor a loss). Results files
override table rows for the same source and model; `--table-models` takes only the listed models from the tables
(e.g. the baselines, when NEW holds another NeuBRDF recipe fitted to some of the sources). Sources fitted by fewer
than all the models seen are listed as incomplete and left out of the means.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

MODEL = "neubrdf"


def load_rows(paths: list[str]) -> dict[str, dict[str, dict]]:
    """source name -> model -> row (status ok), later files overriding earlier ones."""
    table: dict[str, dict[str, dict]] = {}
    for path in paths:
        for row in json.loads(Path(path).read_text())["rows"]:
            if row.get("status") == "ok":
                table.setdefault(row["name"], {})[row["model"]] = row
    return table


HEADER = ("| source | model | log_err | image MAE | image RMSE | SSIM | FLIP | floor MAE | floor SSIM | bytes (fp16) "
          "| fit s |")
TABLE_COLUMNS = ("log_err", "img_mae", "img_rmse", "img_ssim", "img_flip", "img_floor_mae", "img_floor_ssim")


def load_table_rows(path: str) -> dict[str, dict[str, dict]]:
    """source name -> model -> row, from the per-source markdown table this script prints (first such table in
    the file; bold marks dropped, the model is the label's first word)."""
    table: dict[str, dict[str, dict]] = {}
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as e:
        raise SystemExit(f"{path}: cannot read it ({e.strerror})") from None
    try:
        start = lines.index(HEADER) + 2
    except ValueError:
        raise SystemExit(f"{path}: no per-source table (a line {HEADER!r})") from None
    for line in lines[start:]:
        cells = [c.strip().replace("*", "").replace(",", "") for c in line.strip().strip("|").split("|")]
        if len(cells) != 11:
            break
        try:
            values = [float(c) for c in cells[2:]]
        except ValueError:
            raise SystemExit(f"{path}: cannot read the row {line!r}") from None
        table.setdefault(cells[0], {})[cells[1].split()[0]] = {
            "metrics": dict(zip(TABLE_COLUMNS, values[:7])), "bytes_fp16": int(values[7]), "fit_seconds": values[8],
            "rounded": True}
    if not table:
        raise SystemExit(f"{path}: the per-source table has no rows")
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="*", help="fit-many results.json files")
    ap.add_argument("--from-table", action="append", default=[], metavar="MD",
                    help="also read the per-source rows of an earlier output of this script (repeatable)")
    ap.add_argument("--table-models", metavar="M1,M2", help="take only these models' rows from the --from-table files")
    ap.add_argument("--label", default="", help="shown after 'neubrdf' in the rows (e.g. the recipe)")
    a = ap.parse_args()
    if not a.results and not a.from_table:
        ap.error("give fit-many results.json files and/or --from-table")
    keep = set(a.table_models.split(",")) if a.table_models else None
    earlier = [{name: {m: row for m, row in per.items() if keep is None or m in keep} for name, per in rows.items()}
               for rows in map(load_table_rows, a.from_table)]
    table: dict[str, dict[str, dict]] = {}
    for rows in [*earlier, load_rows(a.results)]:  # later sources override earlier ones
        for name, per in rows.items():
            table.setdefault(name, {}).update(per)
    models = sorted({m for per in table.values() for m in per}, key=lambda m: (m != MODEL, m))
    complete = {name: per for name, per in table.items() if set(per) == set(models)}
    print(f"{HEADER}\n|---|---|---|---|---|---|---|---|---|---|---|")
    for name, per in complete.items():
        best = min(per, key=lambda m: per[m]["metrics"]["img_mae"])
        for model in models:
            row, m = per[model], per[model]["metrics"]
            mae = f"**{m['img_mae']:.4f}**" if model == best else f"{m['img_mae']:.4f}"
            label = f"{model} {a.label}".strip() if model == MODEL else model
            print(f"| {name} | {label} | {m['log_err']:.5f} | {mae} | {m['img_rmse']:.4f} | {m['img_ssim']:.4f} | "
                  f"{m['img_flip']:.4f} | {m['img_floor_mae']:.5f} | {m['img_floor_ssim']:.4f} | "
                  f"{row['bytes_fp16']:,} | {row['fit_seconds']:.0f} |")
    n = len(complete)
    print(f"\n{n} sources with all of {', '.join(models)}"
          + (f"; incomplete: {', '.join(sorted(set(table) - set(complete)))}" if len(complete) < len(table) else ""))
    if not n:
        return
    print("\n| model | mean image MAE | mean image RMSE | mean SSIM | min SSIM |\n|---|---|---|---|---|")
    for model in models:
        ms = [per[model]["metrics"] for per in complete.values()]
        print(f"| {model} | {sum(m['img_mae'] for m in ms) / n:.4f} | {sum(m['img_rmse'] for m in ms) / n:.4f} | "
              f"{sum(m['img_ssim'] for m in ms) / n:.4f} | {min(m['img_ssim'] for m in ms):.4f} |")
    if MODEL not in models:
        return
    print()
    for other in (m for m in models if m != MODEL):
        verdicts = {name: compare_mae(per[MODEL], per[other]) for name, per in complete.items()}
        lost = [name for name, v in verdicts.items() if v == "loss"]
        undecided = [name for name, v in verdicts.items() if v == "undecided"]
        print(f"{MODEL} lower image MAE than {other}: {n - len(lost) - len(undecided)} of {n}"
              + (f" (not on {', '.join(lost)})" if lost else "")
              + (f"; equal at the table's 4-decimal rounding, undecided: {', '.join(undecided)}" if undecided else ""))


def compare_mae(ours: dict, other: dict) -> str:
    """'win' / 'loss' in image MAE; 'undecided' when either row comes from a table (`--from-table`) and the two
    are equal at its printed rounding (4 decimals)."""
    a, b = ours["metrics"]["img_mae"], other["metrics"]["img_mae"]
    if ours.get("rounded") or other.get("rounded"):
        a, b = round(a, 4), round(b, 4)
        if a == b:
            return "undecided"
    return "win" if a < b else "loss"


if __name__ == "__main__":
    main()
