"""The one fact of :mod:`ccdcore.reduce` that the command line needs before a verb runs, kept
here so that loading the command line does not load the reductions' compiled kernels (numba):
this module imports nothing. ``tests/test_cli_startup.py`` checks that
:data:`ccdcore.reduce.STREAMED_NAME` is the same string.
"""
from __future__ import annotations

__all__ = ["STREAMED_NAME"]

#: what a product's provenance records of a streamed run (no Dask scheduler)
STREAMED_NAME = "streamed (this process)"
