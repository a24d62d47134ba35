"""Exceptions raised by rooftrace.

Every error a user can cause derives from :class:`InputError`; the command
line turns it into one ``error:`` line and exit code 2.  Anything else that
escapes is a bug and exits with code 1.
"""

import re
from collections.abc import Callable

__all__ = ["RooftraceError", "InputError", "OptionError", "OutputExistsError", "GeometryError"]


class RooftraceError(Exception):
    """Root of all rooftrace exceptions."""


class InputError(RooftraceError, ValueError):
    """Bad input data, file or option: the user can fix it.

    The message says what is wrong, in which file, and what to do.
    """


class OptionError(InputError):
    """Bad or missing option value: the message names options by their field name.

    The library does not know how its caller spells an option (a keyword
    argument, a ``--flag``, a config key), so a message holds ``{name}``
    for each option it names, and :meth:`render` spells them: ``str()``
    gives the field names, the command line its flags.

    Parameters
    ----------
    template : str
        The message, with ``{name}`` where option ``name`` is meant.
    options : str
        The option names the template refers to (other braces stay as they are).

    Examples
    --------
    >>> exc = OptionError("{camera} needs {image}: give the image the camera file describes", "camera", "image")
    >>> str(exc)
    'camera needs image: give the image the camera file describes'
    >>> exc.render(lambda name: "--" + name)
    '--camera needs --image: give the image the camera file describes'
    """

    def __init__(self, template: str, *options: str) -> None:
        self.template = template
        self.options = options
        super().__init__(self.render(str))

    def render(self, spell: Callable[[str], str]) -> str:
        """The message with every option named as ``spell(name)`` says."""
        return re.sub(r"\{(\w+)\}", lambda m: spell(m[1]) if m[1] in self.options else m[0], self.template)


class OutputExistsError(OptionError):
    """The output exists and ``overwrite`` was not given."""


class GeometryError(RooftraceError):
    """A stage cannot build geometry from degenerate input.

    Raised inside stages (collinear points, too few points); the pipeline
    catches it per building and records a ``status`` instead of aborting.
    """
