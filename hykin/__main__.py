"""``python -m hykin``: the command line, for environments without the console script."""

from .cli import main

main()
