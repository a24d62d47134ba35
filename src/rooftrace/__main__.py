"""``python -m rooftrace``: the command line."""

from rooftrace.cli.entry import main

main()
