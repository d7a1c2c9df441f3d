"""Fixed-pattern map K̂(a, b) and the correction D_C = (D − D̂_D)/K̂ (sec. V-B, VII-A of
Healey & Kondepudy 1994).

Method (eqs. 45–51)
-------------------
For each of the n1 imaging configurations (card and lamp moved), the n2 frames are stream-averaged
(:class:`ccdcore.stats.PixelMoments`), an estimate of (K·I_i + E_DC)·A (eq. 45), and the dark
reference D̂_D is subtracted: e_i(a, b) ≈ K(a, b)·I_i(a, b)·A (eq. 46).  The local mean ē_i(a, b)
over an m×m window (default 9×9) estimates I_i(a, b)·A; the slopes are m_i = e_i/ē_i (eq. 47) and
their mean m̄ (eq. 48).  σ̂ is the per-pixel sample standard deviation (ddof = 1) of the m_i over
the configurations, averaged over all locations (the paper's "averaging the sample standard deviation
in m_i over many different locations").  Slopes outside centre ± p·σ̂ (default p = 1.5) are
rejected and the rest averaged into K̂ (eq. 49); n'_1(a, b) counts them, and the bound of eq. 50
is var[K̂] ≤ (p·σ̂)²/n̂_1 with n̂_1 = min n'_1.

The centre of the rejection interval: the paper uses the mean m̄ (eq. 48, ``center="mean"``).  One
spot of relative contrast c among n1 configurations pulls m̄ by c/n1; once that exceeds p·σ̂
(c = 0.25, n1 = 12: 0.021 against p·σ̂ ≈ 0.01 on the simulator) *every* slope of that pixel falls
outside m̄ ± p·σ̂ and nothing is left to average.  The default ``center="median"`` uses the
per-pixel median of the slopes instead, which a minority of outliers cannot move; on spot-free
pixels median and mean agree to within the noise, so K̂ is the paper's estimate there.  m̄ is
reported either way.

Border rule: ē_i is ``scipy.ndimage.uniform_filter(e_i, window, mode="reflect")``: near the edge
the window is completed by mirroring the image about its edge (``d c b a | a b c d``), so every
pixel has a full m×m mean, edge pixels' neighbours counting twice.  It is computed by
:func:`local_mean`, a compiled copy of scipy's running sums (the same bits with scipy 1.17).

Where no slope survives the rejection (possible with n1 = 2, when the two slopes are more than
2·p·σ̂ apart), K̂ falls back to the median of the slopes; those pixels are counted in ``notes`` and
have n'_1 = 0.  Pixels with ē_i ≤ 0 give no slope for configuration i (rejected).

Memory: the n1 slope maps are kept as one (n1, H, W) float32 array (n1·H·W·4 bytes; 80 MB for 20
configurations of 1024²) plus the (n1, H, W) boolean rejection array (n1·H·W bytes) and a few
float64 (H, W) maps (the running average of one configuration, ē_i, m̄, K̂, its variance); nothing
grows with n2.  Eqs. 48 and 49 (m̄, σ̂, the median, the rejection, K̂ and its variance) are compiled
passes over the slopes pixel by pixel (numba, as :mod:`ccdcore.stats`), with no full-size
temporaries; they sum in the same order as the array formulas they replace, so the results are
the same to the bit.  The frames of the next configuration are decoded ahead in worker threads
(``Session.iter_frames(read_ahead=...)``).

The streamed estimate is :meth:`ccdcore.reduce.Reducer.fixed_pattern`. With a Dask reducer
(``reducer=DaskReducer(client)``), eqs. 45–50 run band by band of rows on the workers
(:func:`ccdcore.distributed.client.fixed_pattern_bands`): each band's averages e_i are read with a
halo of m//2 + 1 rows above and m//2 below; ē_i's column running sums are handed from band to band
(:func:`box_mean_band`), and the whole-frame means (the levels, the noise, σ̂) are rebuilt from
the bands' shares of numpy's pairwise sums (:func:`pw_pieces`, :func:`pw_total`), so the result
is the streamed one to the bit, with no process holding the n1 full-frame averages.

Public objects
--------------
FixedPattern
    Frozen result: K̂, n'_1 map, rejections, m̄, σ̂, the eq. 50 bound, summary statistics
    (defined in :mod:`ccdcore.kmap_kernels`, re-exported here).
fixed_pattern_map(session_or_configs, dark, ...)
    Estimate K̂ from a Session or from per-configuration frame iterables.
fixed_pattern_of(K, used, rejected, m_bar, K_var, ...)
    The :class:`FixedPattern` of the maps of eqs. 48–49, as the streamed and the cluster paths
    assemble it (defined in :mod:`ccdcore.kmap_kernels`, re-exported here).
correct(frame, dark, K)
    D_C = (D − D̂_D)/K̂ (eq. 51), float32.
CorrectionCheck, correction_check(frame, dark, K, q)
    How much the correction modifies a maximum-intensity image (sec. VII-A: 27 %, 3 %, 5 steps).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .dark.frame import DarkReference, as_dark_map, dark_reference
from .errors import CcdError
from .kmap_kernels import FixedPattern, fixed_pattern_of
from .reduce import STREAMED, Reducer
from .scene_summary import CorrectionCheckSummary

__all__ = ["FixedPattern", "fixed_pattern_map", "fixed_pattern_of", "correct", "CorrectionCheck",
           "correction_check"]


# --------------------------------------------------------------------------------------------
def fixed_pattern_map(session_or_configs: Any, dark: DarkReference | np.ndarray | None = None,
                      *, window: int = 9, p: float = 1.5,
                      center: str = "median", reducer: Reducer | None = None) -> FixedPattern:
    """Estimate the fixed-pattern map K̂(a, b) (eqs. 45–50 of Healey & Kondepudy 1994).

    Parameters
    ----------
    session_or_configs : Session, mapping, sequence or numpy.ndarray
        A :class:`~ccdcore.session.Session` (its ``fixed_pattern`` frames grouped by ``config``);
        a mapping ``config id -> iterable of frames`` (arrays or ``(record, array)`` pairs); a
        sequence of such iterables; or an ``(n1, n2, H, W)`` array.  Frames are streamed.
    dark : DarkReference or numpy.ndarray or None, optional
        The dark reference D̂_D (:class:`~ccdcore.dark.frame.DarkReference` or an array).  With a
        session it may be omitted: it is then computed from the session's dark frames.
    window : int, optional
        m, the side of the local window whose mean ē_i estimates I_i·A (odd, ≥ 3; default 9).
    p : float, optional
        Rejection half-width in units of σ̂ (default 1.5, the paper's value).
    center : str, optional
        Centre of the rejection interval: ``"median"`` (default) of the n1 slopes, or ``"mean"``,
        the paper's m̄ of eq. 48 (see the module docstring for why the median is the default).
    reducer : Reducer or None, optional
        Runs eqs. 45–50 over the frames (:mod:`ccdcore.reduce`; default streamed here). On a
        Dask cluster (:class:`ccdcore.distributed.client.DaskReducer`) they run band by band of
        rows, so that no process holds the n1 full-frame averages; the result equals the streamed
        one (every map ``np.array_equal``, the summary statistics ``==``).  ``session_or_configs``
        is then a session or a mapping ``config id -> records or file paths``; a dark
        reference computed here uses the same reducer.

    Returns
    -------
    FixedPattern
        K̂ (``K``, eq. 49) and its per-pixel variance, the slopes kept per pixel, the rejected
        ones, m̄ (eq. 48), σ̂, the variance bound of eq. 50, the mean and spatial standard
        deviation of K̂, the configurations' ids and levels, and notes.

    Raises
    ------
    CcdError
        Fewer than 2 configurations; frames of different shapes (naming the file); no dark
        reference (no ``dark`` and no session dark frames), or one that is not a 2-D map; colour
        frames; a configuration without frames or not above the dark level; no pixel with two
        usable slopes (σ̂ unknown); an array that is not ``(n1, n2, H, W)``; a bad window or p;
        a ``center`` other than ``"median"`` or ``"mean"``.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.session import open_session
    >>> from ccdcore.dark import dark_reference
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> session = open_session(tmp.name)
    >>> kmap = fixed_pattern_map(session, dark_reference(session))
    >>> kmap.K.shape, bool(abs(float(kmap.K.mean()) - 1) < 0.01)     # K̂ averages to 1
    ((48, 64), True)
    >>> tmp.cleanup()
    """
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise CcdError("window", f"the local window m must be odd and at least 3, got {window}")
    if center not in ("median", "mean"):
        raise CcdError("center", f"choose 'median' or 'mean', got {center!r}")
    if not (p > 0):
        raise CcdError("p", f"the rejection width p must be positive, got {p}")
    red = reducer or STREAMED

    def dark_of(session: Any) -> np.ndarray:
        if dark is not None:
            return as_dark_map(dark)
        if session is None:
            raise CcdError("dark", "no dark reference D̂_D: K̂ needs e_i = average − D̂_D "
                                   "(eq. 46); pass dark= (see dark_reference())")
        if not session.dark_frames():
            raise CcdError(str(session.root), "no dark frames (role = 'dark'): K̂ needs the dark "
                                              "reference D̂_D (eq. 46); capture lens-capped "
                                              "frames or pass dark=")
        # darks at several exposures: use those at the fixed-pattern frames' exposure
        fp_exp = {r.exposure for cfg in session.fixed_pattern_configs().values() for r in cfg}
        dark_exp = {r.exposure for r in session.dark_frames()}
        pick = next(iter(fp_exp)) if len(dark_exp) > 1 and len(fp_exp) == 1 else None
        return as_dark_map(dark_reference(session, exposure=pick, reducer=red))

    return red.fixed_pattern(session_or_configs, dark_of=dark_of, window=window, p=p,
                             center=center)


# --------------------------------------------------------------------------------------------
def _k_map(K: FixedPattern | np.ndarray) -> np.ndarray:
    return K.K if isinstance(K, FixedPattern) else np.asarray(K, dtype=np.float64)


def _operands(frame: Any, dark: Any, K: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    D = np.asarray(frame)
    if D.ndim != 2:
        raise CcdError("frame", f"expected a 2-D mono frame, got shape {D.shape}")
    dmap, kmap = as_dark_map(dark), _k_map(K)
    for name, a in (("dark", dmap), ("K", kmap)):
        if a.ndim and a.shape != D.shape:
            raise CcdError(name, f"map shape {a.shape} differs from the frame's {D.shape}")
    return D.astype(np.float64), dmap, kmap


def correct(frame: np.ndarray, dark: DarkReference | np.ndarray,
            K: FixedPattern | np.ndarray) -> np.ndarray:
    """The corrected image D_C(a, b) = (D(a, b) − D̂_D(a, b)) / K̂(a, b) (eq. 51).

    Computed in float64 and returned as float32.
    """
    D, dmap, kmap = _operands(frame, dark, K)
    return ((D - dmap) / kmap).astype(np.float32)


@dataclass(frozen=True)
class CorrectionCheck:
    """How much dividing by K̂ changes a (maximum-intensity) image, in quantisation steps q.

    The *modification* of a pixel is what eq. 51's division by K̂ changes beyond the dark
    subtraction: ``c = D_C − (D − D̂_D) = (D − D̂_D)(1/K̂ − 1)``.

    Attributes
    ----------
    frac_gt_1q
        Fraction of all pixels with |c| > q (paper: 27 %).
    frac_gt_2q
        Fraction of *all* pixels with |c| > 2q (paper: "3 % of these modifications"; for the
        paper's σ_K = 3.72e-3 at about 244 DN above dark, a Gaussian K gives 27 % above 1q and
        2.8 % of all pixels above 2q, i.e. 10 % of the 27 %; so the 3 % is read as a fraction of
        all pixels).
    frac_gt_2q_of_gt_1q
        The other reading: the fraction of the > 1q pixels that exceed 2q.
    max_change_q
        max |c| / q (paper: five steps).
    mean_level
        Mean of D − D̂_D over the image (DN).
    n_pixels
        Pixels considered (finite values).
    """

    frac_gt_1q: float
    frac_gt_2q: float
    frac_gt_2q_of_gt_1q: float
    max_change_q: float
    mean_level: float
    n_pixels: int
    q: float = 1.0

    def summary(self) -> CorrectionCheckSummary:
        """The figures as the calibration product stores them."""
        return CorrectionCheckSummary.of(self)

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def correction_check(frame: np.ndarray, dark: DarkReference | np.ndarray,
                     K: FixedPattern | np.ndarray, q: float = 1.0) -> CorrectionCheck:
    """The paper's check of K̂ (sec. VII-A): how much eq. 51 modifies a maximum-intensity image.

    Parameters
    ----------
    frame
        An image D of a uniform card at maximum intensity (not clipped).
    dark, K
        D̂_D and K̂.
    q
        Quantisation step in DN (1 for integer DN).

    Returns
    -------
    CorrectionCheck
        Fractions of pixels whose modification ``(D − D̂_D)(1/K̂ − 1)`` exceeds q and 2q, and the
        largest modification in units of q.
    """
    if not q > 0:
        raise CcdError("q", f"the quantisation step must be positive, got {q}")
    D, dmap, kmap = _operands(frame, dark, K)
    level = D - dmap
    change = np.abs(level * (1.0 / kmap - 1.0)) / q
    ok = np.isfinite(change)
    c = change[ok]
    n = int(c.size)
    if n == 0:
        raise CcdError("frame", "no finite pixel to check")
    n1, n2 = int(np.count_nonzero(c > 1.0)), int(np.count_nonzero(c > 2.0))
    return CorrectionCheck(frac_gt_1q=n1 / n, frac_gt_2q=n2 / n,
                           frac_gt_2q_of_gt_1q=n2 / n1 if n1 else 0.0,
                           max_change_q=float(c.max()), mean_level=float(level[ok].mean()),
                           n_pixels=n, q=float(q))
