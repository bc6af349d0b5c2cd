"""``python -m qkf``: the command line."""

from qkf.cli import app

app(prog_name="qkf")
