"""Errors raised for bad input.

Every error the user can cause carries the file (or manifest entry) it concerns and one line saying
what is wrong, so the command line can print it as is (exit code 2) and the app can show it as an
alert.  They subclass :class:`ValueError` so generic callers still catch them.
"""
from __future__ import annotations

from os import PathLike

__all__ = ["CcdError", "ImageReadError", "ImageWriteError", "SessionError", "MethodNotAvailable",
           "MissingExtra", "require_extra"]


class CcdError(ValueError):
    """Bad input for ccdcore: ``str(err)`` is ``"<where>: <problem>"``.

    Parameters
    ----------
    where : str or PathLike or None
        The file, manifest entry or argument the problem concerns (may be ``None``).
    problem : str
        One line describing what is wrong and, where possible, what to do.

    Examples
    --------
    >>> from ccdcore import open_session
    >>> try:
    ...     open_session("no/such/folder")
    ... except CcdError as err:
    ...     print(err.where, "|", err.problem)
    no/such/folder | does not exist
    """

    def __init__(self, where: str | PathLike | None, problem: str):
        self.where = None if where is None else str(where)
        self.problem = problem
        super().__init__(problem if self.where is None else f"{self.where}: {problem}")


class ImageReadError(CcdError):
    """An image file cannot be read (missing, unreadable, truncated, empty, unsupported)."""


class ImageWriteError(CcdError):
    """An output file cannot be written."""


class SessionError(CcdError):
    """A capture session is invalid; ``problems`` lists every problem found."""

    def __init__(self, where, problem: str, problems: tuple = ()):
        super().__init__(where, problem)
        self.problems = tuple(problems)


class MethodNotAvailable(CcdError):
    """A requested method or verb is not built yet, or needs an optional extra."""


class MissingExtra(CcdError):
    """A part of ccdcore needs a package of an optional extra that is not installed."""


def require_extra(module: str, extra: str, purpose: str) -> None:
    """Raise :class:`MissingExtra` unless ``module`` can be imported: one line saying that
    ``purpose`` (e.g. "the report") needs it and the ``pip install`` that brings it. The
    library itself (``pip install ccdcore``) needs no extra; the app, the report and a Dask
    cluster do (``pyproject.toml``)."""
    import importlib

    try:
        importlib.import_module(module)
    except ImportError:
        raise MissingExtra(None, f"{purpose} needs {module}, which is not installed: "
                                 f"pip install 'ccdcore[{extra}]'") from None
