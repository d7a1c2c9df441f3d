"""The ccdcore browser app (Panel): pages are thin views over ccdcore.

Public objects
--------------
create_app(session_path=None, *, allowed_roots=None)
    A fresh app (Bootstrap template) for one browser session.
serve(session_path=None, port=5006, show=False, threaded=False, address="127.0.0.1")
    Serve the app on 127.0.0.1 (``ccdcore app`` and ``python -m ccdcore_app`` call it).

Modules: :mod:`ccdcore_app.main` (shell, server), :mod:`ccdcore_app.state` (the shared state
object),
:mod:`ccdcore_app.plots.base` (pure plot-building functions), :mod:`ccdcore_app.pages` (the page
registry). Importing ``app`` is cheap; Panel and HoloViews load when ``create_app`` or ``serve`` is
used.
"""
from __future__ import annotations

from typing import Any

__all__ = ["create_app", "serve"]


def create_app(*args: Any, **kwargs: Any):
    """See :func:`ccdcore_app.main.create_app`."""
    from .main import create_app as _create_app

    return _create_app(*args, **kwargs)


def serve(*args: Any, **kwargs: Any):
    """See :func:`ccdcore_app.main.serve`."""
    from .main import serve as _serve

    return _serve(*args, **kwargs)
