"""`python -m neumat`: the `neumat` command line."""
from neumat.cli.main import app

app(prog_name="neumat")
