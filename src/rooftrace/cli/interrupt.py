"""SIGINT and SIGTERM: one ``error: interrupted`` line, no temporary files, exit 130 or 143.

Python's own SIGINT handling raises KeyboardInterrupt wherever the
interpreter happens to be, which may be inside numba's dispatcher (a
``SystemError: ... returned a result with an exception set``) or while
numba's worker threads still run a parallel kernel (a segmentation fault
as the interpreter shuts down around them).  So the handler raises nothing:
it runs, as every Python signal handler does, in the main thread between
two bytecodes, removes the temporary files of the writes under way
(:func:`rooftrace.io.atomic.remove_temporary`), writes the message and ends
the process with ``os._exit``.  No output is ever half written: outputs are
only renamed into place, inside an :func:`~rooftrace.io.atomic.uninterrupted`
section that a signal waits for (and a command's several outputs together,
:func:`~rooftrace.io.atomic.commit_together`); the worker processes of a
local Dask cluster are killed first.  Once the command is over the signals
are ignored (:func:`ignore_from_now`): the outputs are complete.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Iterator

__all__ = ["EXIT_CODES", "ignore_from_now", "install_handlers", "interrupt_handlers"]

#: the shell's convention, 128 + the signal number
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


def _on_signal(signum: int, frame) -> None:
    # installed before anything else is imported (rooftrace.cli.entry): until
    # rooftrace.io.atomic is loaded there is no temporary file and no section to wait for
    atomic = sys.modules.get("rooftrace.io.atomic")
    if atomic is not None and atomic.hold_signal(signum):
        return
    # the workers of a local Dask cluster first, before they notice their scheduler has gone and log it
    # (they would exit with their parent anyway: distributed.process watches it)
    mp = sys.modules.get("multiprocessing")
    if mp is not None:
        try:
            for child in mp.active_children():
                child.kill()
        except Exception:
            pass
        _unlink_semaphores()
    if atomic is not None:
        atomic.remove_temporary()
    # nothing here may raise or wait for a lock another frame of this thread holds
    # (a logging handler, sys.stderr's buffer): write to the file descriptor
    message = b"error: interrupted\n"
    try:
        if os.isatty(2):
            message = b"\x1b[?25h\n" + message  # a progress bar hid the cursor and holds the line
        os.write(2, message)
    except OSError:
        pass
    os._exit(EXIT_CODES.get(signum, 128 + signum))


def _unlink_semaphores() -> None:
    """Unlink the named semaphores of multiprocessing (Dask's nanny queues), as an orderly exit would.

    Left to it, multiprocessing's resource tracker (a process that outlives
    this one) removes them and warns "There appear to be 12 leaked semaphore
    objects" on stderr.  Each semaphore registered a finaliser that unlinks
    it; only those run here (the other finalisers may wait for threads).
    """
    util, synchronize = sys.modules.get("multiprocessing.util"), sys.modules.get("multiprocessing.synchronize")
    if util is None or synchronize is None:
        return
    try:
        cleanup = synchronize.SemLock._cleanup
        for finalizer in list(util._finalizer_registry.values()):
            if getattr(finalizer, "_callback", None) is cleanup:
                finalizer()
    except Exception:
        pass


def ignore_from_now() -> None:
    """The command is over: SIGINT and SIGTERM are ignored while the interpreter shuts down.

    Python gives the signals their default action back during its
    finalisation, so a Ctrl-C in the last moments (freeing the arrays, the
    threads of numba and Dask) would kill the process (exit -2, no message)
    after its outputs were complete.
    """
    import threading

    if threading.current_thread() is threading.main_thread():
        for s in EXIT_CODES:
            signal.signal(s, signal.SIG_IGN)


def install_handlers() -> dict:
    """Install the handlers for SIGINT and SIGTERM (main thread); returns the previous ones."""
    return {s: signal.signal(s, _on_signal) for s in EXIT_CODES}


@contextlib.contextmanager
def interrupt_handlers() -> Iterator[None]:
    """Install the handlers for SIGINT and SIGTERM while the block runs (main thread only)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = install_handlers()
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
