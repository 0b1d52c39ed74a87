"""The root of the package's error tree, and which errors a command reports as one line.

Every error a user can cause and fix (a bad bag, reader spec, checkpoint, config value, option,
detector setting, output directory, a full disk) derives from :class:`OMPNError`, through the
``errors.py`` of its sub-package (``data/errors.py``, ``model/errors.py``, ``detect/errors.py``,
``train/errors.py``, ``app/errors.py``; the sims' own in ``sim_nodes``).  Most also derive from the
builtin they stand for (``ValueError``, ``RuntimeError``, ``OSError``), as their second base, so a
library caller's ``except ValueError`` catches them too.

:data:`KNOWN_ERRORS` is what ``ompn_*`` commands print as one line and exit 2 on
(``cli/_common.py``), and what batch segmentation refuses a bag with (``app/batch.py``).  Any other
exception, a plain ``ValueError`` included, is a bug and keeps its traceback.
"""

from __future__ import annotations


class OMPNError(Exception):
    """Base class of every error of this package that names something a user can fix."""


KNOWN_ERRORS: tuple[type[BaseException], ...] = (
    OMPNError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
"""Errors a user fixes: the package's own (:class:`OMPNError`) and the ``OSError`` subclasses a path
given by the user raises (a missing or existing file, a file where a folder belongs or the other way
round, no permission).  Other ``OSError`` s (a full disk while writing) reach the user as a package
error naming the file (:class:`WriteFailure`) or, unexpected, with their traceback."""


def error_line(exc: BaseException) -> str:
    """The first line of an error's message (its type name when the message is empty): what a command
    prints after ``error:`` and what a batch run records as the reason a bag was refused."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class WriteFailure(OMPNError, OSError):
    """A file could not be written (full or read-only filesystem...): the message names it."""
