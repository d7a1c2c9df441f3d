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
    its compiled passes over the pools in :mod:`ccdcore.response.tsin.kernels`, the gauge of
    the white-balance fit and the band in :mod:`ccdcore.response.tsin.gauge`, eq. 17's fit in
    :mod:`ccdcore.response.tsin.noise`, its notes in :mod:`ccdcore.response.tsin.notes`.
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
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading):
# ``import ccdcore.response.names`` (the command line) loads no estimator
__getattr__, __dir__, __all__ = lazy.attach(__name__, submodules=[
    "agreement", "align", "bracket_fit", "brackets", "classic", "classic_common", "exposures",
    "hdr", "hdr_merge", "methods", "moving", "names", "scale", "tsin", "verdict"], submod_attrs={
    "brackets": ["BracketData", "bracket_data", "load_bracket", "preprocess"],
    "classic": ["ClassicFit", "debevec", "mitsunaga_nayar", "robertson"],
    "hdr": ["HdrResult", "ResponseModel", "merge"],
    "methods": ["METHODS", "ResponseResult", "response_of"],
    "bracket_fit": ["fit_bracket", "session_response"],
    "align": ["estimate_alignment", "apply_alignment"],
    "tsin": ["ChannelResponse", "TsinOptions", "estimate", "noise_terms"],
    "scale": ["normalize", "reference_codes", "rms_error"],
})
