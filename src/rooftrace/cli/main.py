"""Entry point: registers the commands and maps exceptions to exit codes.

Exit 0 on success; 2 on bad input or usage, with one ``error:`` line on
stderr and no traceback; 1 on an internal failure (traceback with ``-v``).
"""

from __future__ import annotations

import logging
import os
import sys
import traceback

import typer

try:  # typer >= 0.20 vendors click; older releases use the click package
    from typer._click import exceptions as click_exc
except ImportError:  # pragma: no cover
    from click import exceptions as click_exc

# command modules register themselves on ``app`` when imported (one line each)
from rooftrace.cli import (
    cmd_demo,  # noqa: F401
    cmd_detect,  # noqa: F401
    cmd_evaluate,  # noqa: F401
    cmd_info,  # noqa: F401
    cmd_outline,  # noqa: F401
    cmd_refine,  # noqa: F401
    cmd_resect,  # noqa: F401
    cmd_run,  # noqa: F401
    cmd_simulate,  # noqa: F401
    cmd_snake,  # noqa: F401
)
from rooftrace.cli.app import STATE, app
from rooftrace.cli.interrupt import ignore_from_now, interrupt_handlers
from rooftrace.cli.options import flag_for
from rooftrace.errors import InputError, OptionError

__all__ = ["main"]


def _print_version(value: bool) -> None:
    if value:
        from rooftrace import __version__

        typer.echo(__version__)
        raise typer.Exit(0)


@app.callback()
def _global(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logs, and tracebacks of internal errors."),
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """3D building roof outlines and ridges from airborne LiDAR (and an aerial image)."""
    STATE["verbose"] = verbose


def _error(message: str) -> None:
    message = " ".join(str(message).split())
    sys.stderr.write(f"error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (also used as the console script)."""
    logging.captureWarnings(True)
    try:
        with interrupt_handlers():
            rv = app(args=argv, standalone_mode=False, prog_name="rooftrace")
        code = rv if isinstance(rv, int) else 0
    except typer.Exit as exc:
        code = exc.exit_code
    except typer.Abort:  # click's name for a KeyboardInterrupt (no handler installed, e.g. a thread)
        _error("interrupted")
        code = 130
    except click_exc.UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError" and exc.ctx is not None:
            typer.echo(exc.ctx.get_help())
            return _exit(2, argv)
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        _error(exc.format_message() + hint)
        code = 2
    except click_exc.ClickException as exc:
        _error(exc.format_message())
        code = 2
    except InputError as exc:
        _error(exc.render(flag_for) if isinstance(exc, OptionError) else str(exc))
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
    finally:
        atomic = sys.modules.get("rooftrace.io.atomic")
        if atomic is not None:  # a command that failed leaves no temporary file (a demo's unfinished folder)
            atomic.remove_temporary()
    return _exit(code, argv)


def _exit(code: int, argv: list[str] | None) -> int:
    if argv is None:  # console script
        ignore_from_now()
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
