"""Camera response from exposure brackets (Tsin, Ramesh & Kanade 2001, sec. 2-4, and the classic
methods beside it).

Modules
-------
:mod:`ccdcore.response.brackets`
    A session's bracket frames as pixel traces per channel, with the preprocessing of sec. 3.2
    step 1 (boundary, blooming and clipped codes out).
:mod:`ccdcore.response.scale`
    The one scale every response curve is reported on, and the RMS comparison of curves.
:mod:`ccdcore.response.classic`
    Debevec & Malik (1997), Robertson, Borman & Stevenson (2003), Mitsunaga & Nayar (1999);
    their shared input checks and curve finishing in :mod:`ccdcore.response.classic_common`.
:mod:`ccdcore.response.tsin`
    The iterative estimator of sec. 3.2 (instrumented pools), its band and the noise terms;
    its compiled passes over the pools in :mod:`ccdcore.response.tsin_kernels`, the gauge of
    the white-balance fit and the band in :mod:`ccdcore.response.tsin_gauge`, eq. 17's fit in
    :mod:`ccdcore.response.tsin_noise`, its notes in :mod:`ccdcore.response.tsin_notes`.
:mod:`ccdcore.response.exposures`
    The bracket's own exposures, estimated from its images against the listed ones.
:mod:`ccdcore.response.methods`
    The registry of methods (``METHODS``), the default ``auto`` with its challenger, and the
    response of a session's bracket.
:mod:`ccdcore.response.verdict`
    The one verdict of every response result (trusted, doubtful, failed).
:mod:`ccdcore.response.hdr`
    HDR radiance with per-pixel sigma from a calibrated camera (eqs. 9, 18, 19), with bounds and
    flags where no code is usable, of a bracket's files (streamed or on a Dask cluster).
:mod:`ccdcore.response.hdr_merge`
    The merge itself on frames in memory, the kernel both paths run (its names are re-exported by
    :mod:`ccdcore.response.hdr`).
:mod:`ccdcore.response.align`
    Handheld brackets: each frame registered to the middle one across exposures (a sub-pixel
    shift and a small rotation, with errors), resampled only where it moved.
:mod:`ccdcore.response.moving`
    Moving objects: pixels whose exposures disagree beyond the noise model, merged from one
    exposure; the suspects left out of the fit.
:mod:`ccdcore.response.bracket_fit`
    A session's bracket registered, its suspects left out, fitted, its moving pixels found:
    what every verb and page that fits a bracket runs.
:mod:`ccdcore.response.names`
    The methods' names, the exposure modes and the blooming limits, for the command line's
    parser: it imports nothing, and this package loads each public name from its submodule on
    first use.

See docs/response.md.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what a type checker sees; at run time the names load on first use
    from .brackets import BracketData, bracket_data, load_bracket, preprocess
    from .classic import ClassicFit, debevec, mitsunaga_nayar, robertson
    from .hdr import HdrResult, ResponseModel, merge
    from .methods import METHODS, ResponseResult, response_of
    from .bracket_fit import fit_bracket, session_response
    from .align import apply_alignment, estimate_alignment
    from .tsin import ChannelResponse, TsinOptions, estimate, noise_terms
    from .scale import normalize, reference_codes, rms_error

__all__ = ["BracketData", "bracket_data", "load_bracket", "preprocess", "ClassicFit",
           "debevec", "robertson", "mitsunaga_nayar", "HdrResult", "ResponseModel", "merge",
           "normalize", "reference_codes", "rms_error", "METHODS", "ResponseResult",
           "response_of", "session_response", "ChannelResponse", "TsinOptions", "estimate",
           "noise_terms", "fit_bracket", "estimate_alignment", "apply_alignment"]

#: each public name -> the submodule that defines it, imported on first use (SPEC 1's lazy
#: loading): ``import ccdcore.response.names`` (the command line) loads no estimator
_HOMES = {name: module for module, names in {
    "brackets": ("BracketData", "bracket_data", "load_bracket", "preprocess"),
    "classic": ("ClassicFit", "debevec", "mitsunaga_nayar", "robertson"),
    "hdr": ("HdrResult", "ResponseModel", "merge"),
    "methods": ("METHODS", "ResponseResult", "response_of"),
    "bracket_fit": ("fit_bracket", "session_response"),
    "align": ("estimate_alignment", "apply_alignment"),
    "tsin": ("ChannelResponse", "TsinOptions", "estimate", "noise_terms"),
    "scale": ("normalize", "reference_codes", "rms_error"),
}.items() for name in names}

#: the submodules, which ``ccdcore.response.<name>`` also loads on first use
_SUBMODULES = ("agreement", "align", "bracket_fit", "brackets", "classic", "classic_common",
               "exposures", "hdr", "hdr_merge", "methods", "moving", "names", "scale", "tsin",
               "tsin_gauge", "tsin_kernels", "tsin_noise", "tsin_notes", "verdict")


def __getattr__(name: str) -> Any:
    """A public name from its submodule (or a submodule), imported on first use and kept."""
    if name in _HOMES:
        value = getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__) | set(_SUBMODULES))
