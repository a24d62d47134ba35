"""The console script ``rooftrace`` (and ``python -m rooftrace``).

The interrupt handlers go in before anything heavy is imported: importing
the commands (numpy, typer, ...) takes about a second, and a Ctrl-C then
would otherwise end in a KeyboardInterrupt traceback.
"""

from __future__ import annotations

import sys

__all__ = ["main"]


def main() -> None:
    from rooftrace.cli.interrupt import ignore_from_now, install_handlers

    install_handlers()
    from rooftrace.cli.main import main as run

    code = run(sys.argv[1:])
    ignore_from_now()
    sys.exit(code)
