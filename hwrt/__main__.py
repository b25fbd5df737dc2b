"""``python -m hwrt``: the hwrt command line, as the console script runs it."""
from hwrt.cli import run

run()
