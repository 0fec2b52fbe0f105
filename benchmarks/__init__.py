"""neumat's benchmark suites: `python -m benchmarks --list`, `python -m benchmarks SUITE [--quick] [--json]
[--out FILE.json]`; results and their generated pages in benchmarks/results/<suite>/."""
