"""``python -m rooftrace``: the command line, as the ``rooftrace`` console script runs it."""

from rooftrace.cli.entry import main

main()
