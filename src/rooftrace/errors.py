"""Exceptions raised by rooftrace.

Every error a user can cause derives from :class:`InputError`; the command
line turns it into one ``error:`` line and exit code 2.  Anything else that
escapes is a bug and exits with code 1.
"""

__all__ = ["RooftraceError", "InputError", "OutputExistsError", "GeometryError"]


class RooftraceError(Exception):
    """Root of all rooftrace exceptions."""


class InputError(RooftraceError, ValueError):
    """Bad input data, file or option: the user can fix it.

    The message says what is wrong, in which file, and what to do.
    """


class OutputExistsError(InputError):
    """The output exists and ``--overwrite`` was not given."""


class GeometryError(RooftraceError):
    """A stage cannot build geometry from degenerate input.

    Raised inside stages (collinear points, too few points); the pipeline
    catches it per building and records a ``status`` instead of aborting.
    """
