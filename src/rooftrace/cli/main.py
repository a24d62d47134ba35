"""Entry point: registers the commands and maps exceptions to exit codes.

Exit 0 on success; 2 on bad input or usage, with one ``error:`` line on
stderr and no traceback; 1 on an internal failure (traceback with ``-v``).
"""

from __future__ import annotations

import logging
import os
import sys
import traceback

import click
import typer

from rooftrace.cli.app import STATE, app
from rooftrace.errors import InputError

# command modules register themselves on ``app`` when imported (one line each)
from rooftrace.cli import cmd_info  # noqa: F401,E402

__all__ = ["main"]


@app.callback()
def _global(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logs, and tracebacks of internal errors."),
    version: bool = typer.Option(False, "--version", help="Print the version and exit."),
) -> None:
    """3D building roof outlines and ridges from airborne LiDAR (and an aerial image)."""
    STATE["verbose"] = verbose
    if version:
        from rooftrace import __version__

        typer.echo(__version__)
        raise typer.Exit(0)


def _error(message: str) -> None:
    message = " ".join(str(message).split())
    sys.stderr.write(f"error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (also used as the console script)."""
    logging.captureWarnings(True)
    try:
        rv = app(args=argv, standalone_mode=False, prog_name="rooftrace")
        code = rv if isinstance(rv, int) else 0
    except click.exceptions.Exit as exc:
        code = exc.exit_code
    except click.exceptions.Abort:
        _error("aborted")
        code = 130
    except click.exceptions.UsageError as exc:
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        _error(exc.format_message() + hint)
        code = 2
    except click.exceptions.ClickException as exc:
        _error(exc.format_message())
        code = 2
    except InputError as exc:
        _error(str(exc))
        code = 2
    except KeyboardInterrupt:
        _error("interrupted")
        code = 130
    except MemoryError:
        _error("out of memory; use --tile-size to process the cloud in tiles")
        code = 1
    except Exception as exc:  # an internal failure: our bug, not the user's
        if STATE["verbose"] or os.environ.get("ROOFTRACE_DEBUG"):
            traceback.print_exc()
        _error(f"internal failure ({type(exc).__name__}: {exc}); rerun with -v for the traceback and report it")
        code = 1
    if __name__ == "__main__" or argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
