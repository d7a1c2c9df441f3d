"""Illumination-invariant change detection with shadows and a calibrated false-alarm rate:
Tsin, Ramesh & Kanade (2001), sec. 5.

A static camera sees a static scene twice, hours apart. Each time an exposure bracket gives the
HDR radiance Ê(x) with its per-pixel sigma (eqs. 9, 18, 19; :mod:`ccdcore.response.hdr`).
Under a change of light, every pixel of one surface lit by one source obeys one colour transform
(eq. 20, row vectors)::

    E'(x) = E(x) M,     M a 3 x 3 matrix (1 x 1 for a mono camera)

so the background obeys one M, each shade of shadow another, and the changed pixels (new
objects) none. The steps:

1. **The dominant cluster** (:func:`fit_cluster`): least trimmed squares on a subsample -- a
   FAST-LTS random-subset search with C-steps, the cost being the sum of the h smallest d² --
   then an M-estimator (iteratively reweighted generalised least squares with Tukey's biweight
   on d) on every candidate pixel. M carries its covariance.
2. **The prediction error** e(x) = Ê(x) M - Ê'(x) and its covariance by first-order propagation,
   Σ_e = Mᵀ Σ_E M + Σ_E' + J Σ_M Jᵀ (J = ∂e/∂vec M: M's own uncertainty), and
   d² = eᵀ Σ_e⁻¹ e, χ² with C degrees of freedom (3 for RGB, 1 for mono) at the truth.
3. **The threshold** for a requested false-alarm probability P. Σ_e is evaluated at the
   estimates, so d̂² is only approximately χ² (sec. 5): the mapping from threshold to false-alarm
   rate is calibrated on the background cluster. Its d̂² values within a wide gate (the χ²
   quantile 1 - 1e-6 times the scale s that matches their median to χ²'s) are the background's
   sample; the threshold is its empirical 1 - P quantile (the scaled χ² quantile when the sample
   holds fewer than 20 / P values). Both the threshold and the χ² one are reported, with the
   false-alarm rate each gives on that sample.
4. **Further clusters** (shadows of other shades): the pixels the clusters so far do not explain
   are searched again, with a smaller LTS coverage; a cluster is kept when it has at least
   ``min_pixels`` members and its members' median d² is that of the noise (at most
   ``consistency`` times the background's); the search stops at the first one that is not.
5. **Shades of the background's light** (RGB): a pixel no cluster explains whose target is the
   background's prediction times one factor k, E' = k Ê M₀ with k in ``ChangeOptions.shade``
   (0.5-2 by default), is a shade -- a soft shadow or penumbra, a wall nearer the lamp --
   when that model's d² (C - 1 degrees of freedom) is under the scaled χ² threshold
   (:func:`ccdcore.change.kernels.shade_d2`).
6. **Labels**: 0 unchanged (the dominant cluster), 1..n the further clusters (shadows), 253
   shade of the background's light, 255 change, 254 undetermined (no radiance: saturated or
   dark in every exposure of either bracket, which the merge flags). A pixel takes the first
   cluster whose d² is under the threshold, else the shade when it passes.
   :meth:`ChangeResult.at` re-thresholds for another P without refitting M.

Departures from the paper, each for a stated reason (docs/change.md): the threshold's calibration
on the background (the paper only says an empirical step is needed); the consistency test for
further clusters (the paper stops when the statistic exceeds the χ² threshold, which an LTS fit
to a handful of changed pixels can pass); the shades of step 5 (the paper's shades are
clusters of one M each, which a soft shadow's continuum of shades does not form); the labels
253 and 254, which the paper does not need.

Public objects
--------------
ChangeOptions
    The detector's settings.
Cluster
    One cluster: its label, M, M's covariance, member count, median d².
ChangeResult
    Clusters, per-cluster d² maps, labels, threshold and false-alarm figures, predicted target.
detect(E_ref, sigma_ref, E_tgt, sigma_tgt, options)
    Sec. 5 on two radiance maps with their sigmas.
prediction_d2(E_ref, sigma_ref, E_tgt, sigma_tgt, M, M_cov)
    d² of every pixel under one transform.
ChangeInputs
    What :func:`ccdcore.change.session.session_change` gave :func:`detect` (both roles of a
    session as radiance with sigma, the response's and the noise's sources).
small_regions(mask, min_region)
    The changed regions smaller than ``min_region`` pixels.

The numerical kernels (d² and its compiled RGB pass, generalised least squares, the FAST-LTS
search) are in :mod:`ccdcore.change.kernels`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from .kernels import design_normal, error_d2, gls, lts, shade_d2
from ..errors import CcdError
from ..progress import Progress, silent

__all__ = ["ChangeOptions", "Cluster", "ChangeResult", "ChangeInputs", "detect", "prediction_d2",
           "LABEL_CHANGE", "LABEL_UNDETERMINED", "LABEL_SHADE", "SHADE_LOOSEST_P",
           "small_regions"]

LABEL_CHANGE = 255
LABEL_UNDETERMINED = 254
#: a shade of the background's light (step 5): E' = k Ê M₀
LABEL_SHADE = 253
#: the loosest false-alarm probability the shade test is prepared for (the app's slider's end):
#: pixels under the threshold at this P are not tested, so at a looser P they stay change
SHADE_LOOSEST_P = 0.2
#: the wide gate that defines the background's sample: χ² quantile 1 - GATE_P (times the scale)
GATE_P = 1e-6
#: candidates of the LTS search refined by C-steps (the best by their trimmed cost)
LTS_REFINED = 5
#: pixels the M-estimator refines each transform on (an even sample of the candidates)
REFINE = 20_000


@dataclass(frozen=True)
class ChangeOptions:
    """Settings of :func:`detect` (frozen: equal settings are one key of a cache of results).

    pfa
        Requested false-alarm probability per background pixel.
    max_clusters
        Most clusters (background and shadows) searched for.
    min_pixels
        Smallest cluster kept, as a fraction of the valid pixels (0.5 %) or, when >= 1, a count.
    coverage
        LTS coverage h / n of the dominant cluster's search (the background is at least half of
        the frame); further clusters use ``coverage / 2`` of the remaining pixels.
    subsample
        Pixels the LTS search works on (an even sample of the candidates).
    trials
        Random elemental subsets tried by the LTS search.
    consistency
        A further cluster is kept when its members' median d² is at most this many times the
        background's.
    max_condition
        A further cluster's M must have a condition number at most this: a change of light maps
        colours one to one, while a nearly singular M, collapsing every colour onto one hue, can
        "explain" a new object of one colour and texture.
    seed
        Seed of the LTS search's random subsets.
    min_region
        Smallest changed region kept (pixels, 8-connected); smaller ones are labelled
        unchanged (0) with a note. 1 keeps every pixel (the paper's per-pixel test, the default
        for brackets); frame sets default to a 3 x 3 block
        (:data:`ccdcore.change.frames.FRAME_MIN_REGION`).
    shade
        (k_min, k_max): a pixel no cluster explains whose target is the background's prediction
        times one factor k in this range, with that model's d² under the threshold, is a shade
        of the background's light (label 253), not change. RGB only; ``None``: off (every such
        pixel change, as in the paper).
    """

    pfa: float = 0.01
    max_clusters: int = 4
    min_pixels: float = 0.005
    coverage: float = 0.5
    subsample: int = 4000
    trials: int = 1000
    consistency: float = 1.5
    max_condition: float = 30.0
    seed: int = 0
    min_region: int = 1
    shade: tuple[float, float] | None = (0.5, 2.0)

    def check(self) -> None:
        if not 0.0 < float(self.pfa) < 0.5:
            raise CcdError("pfa", f"the false-alarm probability must lie in (0, 0.5), got "
                                  f"{self.pfa}")
        if int(self.max_clusters) < 1:
            raise CcdError("max_clusters", "at least one cluster (the background)")
        if not 0.1 <= float(self.coverage) <= 0.9:
            raise CcdError("coverage", f"LTS coverage must lie in [0.1, 0.9], got {self.coverage}")
        if float(self.min_pixels) <= 0:
            raise CcdError("min_pixels", "must be positive")
        if int(self.min_region) < 1:
            raise CcdError("min_region", f"the smallest changed region is at least 1 pixel, got "
                                         f"{self.min_region}")
        if self.shade is not None:
            lo, hi = (float(v) for v in self.shade)
            if not 0.0 < lo < 1.0 < hi < math.inf:
                raise CcdError("shade", f"the shade's factors must satisfy 0 < k_min < 1 < k_max, "
                                        f"got {lo:g}, {hi:g}")


@dataclass(frozen=True)
class Cluster:
    """One set of pixels obeying one transform: ``label`` (0 the background), ``M`` (C x C, row
    vectors: E' = E M), ``M_cov`` (C² x C², over ``M.ravel()``), ``pixels`` (members at the
    result's threshold), ``d2_median`` (members' median d²)."""

    label: int
    M: NDArray[np.float64]
    M_cov: NDArray[np.float64]
    pixels: int
    d2_median: float

    def to_dict(self) -> dict[str, Any]:
        return {"label": int(self.label), "pixels": int(self.pixels),
                "M": self.M.tolist(), "M_err": np.sqrt(np.diag(self.M_cov)).reshape(
                    self.M.shape).tolist(), "M_cov": self.M_cov.tolist(),
                "d2_median": float(self.d2_median)}


@dataclass(frozen=True, eq=False)
class ChangeInputs:
    """What :func:`session_change` gave :func:`detect`: both brackets' radiance maps E and
    their sigma (eqs. 9, 19; H×W×channels, float64), the ``channels``, where the response came
    from (``source``) and the frames of both brackets (``files``, reference first); where the
    noise (sigma) came from (``noise``) and each role's kind, ``"bracket"`` or ``"frames"``
    (``kinds``; :mod:`ccdcore.change.frames`)."""

    E_ref: NDArray[np.float64]
    sigma_ref: NDArray[np.float64]
    E_tgt: NDArray[np.float64]
    sigma_tgt: NDArray[np.float64]
    channels: tuple[str, ...]
    source: str
    files: tuple[str, ...]
    #: the response estimated from the reference bracket, with its verdict (``None`` with a
    #: calibration product)
    response: Any = None
    #: per role, the bracket's own exposures as estimated (``None``: the listed ones taken)
    exposures: dict[str, Any] = field(default_factory=dict)
    noise: str = ""
    kinds: dict[str, str] = field(default_factory=dict)


@dataclass
class ChangeResult:
    """What :func:`detect` found.

    ``d2`` holds one d² map per cluster (H, W, n), ``valid`` the pixels with a radiance in both
    maps; ``background`` the sorted d² sample of the background that calibrates the threshold;
    ``scale`` s (median d² of that sample over χ²'s median); ``dof`` the degrees of freedom.
    """

    clusters: list[Cluster]
    d2: NDArray[np.float64]
    valid: NDArray[np.bool_]
    background: NDArray[np.float64]
    scale: float
    dof: int
    pfa: float
    predicted: NDArray[np.float64]
    notes: tuple[str, ...] = ()
    #: where the response and the noise came from, in words (``"response"``, ``"noise"``)
    sources: dict[str, str] = field(default_factory=dict)
    #: smallest changed region kept (``ChangeOptions.min_region``)
    min_region: int = 1
    #: the shade's factor range (``ChangeOptions.shade``), its factor k and d² per pixel (NaN
    #: where not tested: under the threshold at :data:`SHADE_LOOSEST_P`); ``None``: no test
    shade: tuple[float, float] | None = None
    shade_k: NDArray[np.float64] | None = None
    shade_d2: NDArray[np.float64] | None = None
    labels: NDArray[np.uint8] = field(init=False)
    threshold: float = field(init=False)

    def __post_init__(self) -> None:
        self.labels, self.threshold = self._label(self.pfa)
        counts = [int(np.count_nonzero(self.labels == c.label)) for c in self.clusters]
        self.clusters = [Cluster(c.label, c.M, c.M_cov, n, c.d2_median)
                         for c, n in zip(self.clusters, counts)]
        if self.min_region > 1:
            n = int(np.count_nonzero(self.d2_best > self.threshold)) - int(
                np.count_nonzero(self.labels == LABEL_CHANGE)) - int(
                np.count_nonzero(self.labels == LABEL_SHADE))
            self.notes = tuple(self.notes) + ((
                f"{n} changed pixels in regions under {self.min_region} pixels labelled "
                "unchanged (min_region)",) if n else ())

    # -- the threshold ------------------------------------------------------------------------
    def threshold_for(self, pfa: float) -> float:
        """The calibrated threshold for false-alarm probability ``pfa`` (see the module)."""
        return _threshold(self.background, self.scale, self.dof, pfa)

    def chi2_threshold(self, pfa: float | None = None) -> float:
        """The χ² quantile 1 - P, without the calibration."""
        return float(stats.chi2.isf(self.pfa if pfa is None else pfa, self.dof))

    def shade_threshold(self, pfa: float | None = None) -> float:
        """The shade test's threshold: s times the χ² quantile 1 - P with C - 1 degrees of
        freedom (one factor k fitted per pixel)."""
        p = self.pfa if pfa is None else pfa
        return float(self.scale * stats.chi2.isf(p, max(self.dof - 1, 1)))

    def observed_pfa(self, threshold: float) -> float:
        """The fraction of the background's sample above ``threshold``."""
        n = self.background.size
        if n == 0:
            return float("nan")
        return float(n - np.searchsorted(self.background, threshold, side="right")) / n

    def _label(self, pfa: float) -> tuple[NDArray[np.uint8], float]:
        thr = self.threshold_for(pfa)
        labels = np.full(self.valid.shape, LABEL_CHANGE, np.uint8)
        open_ = self.valid.copy()
        for k, c in enumerate(self.clusters):
            hit = open_ & (self.d2[..., k] <= thr)
            labels[hit] = c.label
            open_ &= ~hit
        if self.shade is not None and self.shade_d2 is not None and self.shade_k is not None:
            lo, hi = self.shade
            with np.errstate(invalid="ignore"):
                hit = open_ & (self.shade_d2 <= self.shade_threshold(pfa)) & (
                    self.shade_k > lo) & (self.shade_k < hi)
            labels[hit] = LABEL_SHADE
        labels[~self.valid] = LABEL_UNDETERMINED
        if self.min_region > 1:
            small = small_regions(labels == LABEL_CHANGE, self.min_region)
            labels[small] = 0
        return labels, thr

    def at(self, pfa: float) -> tuple[NDArray[np.uint8], float]:
        """Labels and threshold for another false-alarm probability (M kept)."""
        return self._label(pfa)

    # -- summaries ----------------------------------------------------------------------------
    @property
    def d2_best(self) -> NDArray[np.float64]:
        """d² of every pixel under the cluster that explains it best (NaN where undetermined)."""
        out = self.d2.min(axis=-1)
        return np.where(self.valid, out, np.nan)

    def counts(self, labels: NDArray[np.uint8] | None = None) -> dict[int, int]:
        lab = self.labels if labels is None else labels
        values, n = np.unique(lab, return_counts=True)
        return {int(v): int(c) for v, c in zip(values, n)}

    def to_dict(self) -> dict[str, Any]:
        bg = self.d2[..., 0][self.labels == 0]
        return {
            "M": [c.M.tolist() for c in self.clusters],
            "M_cov": [c.M_cov.tolist() for c in self.clusters],
            "clusters": [c.to_dict() for c in self.clusters],
            "threshold": self.threshold,
            "threshold_chi2": self.chi2_threshold(),
            "dof": self.dof,
            "d2_scale": self.scale,
            "pfa_requested": self.pfa,
            "pfa_observed": self.observed_pfa(self.threshold),
            "pfa_observed_at_chi2_threshold": self.observed_pfa(self.chi2_threshold()),
            "background_sample": int(self.background.size),
            "background_d2_mean": float(np.mean(bg)) if bg.size else None,
            "background_d2_mean_all": float(np.mean(self.background))
            if self.background.size else None,
            "changed_pixels": int(np.count_nonzero(self.labels == LABEL_CHANGE)),
            "shade_pixels": int(np.count_nonzero(self.labels == LABEL_SHADE)),
            "shade": list(self.shade) if self.shade is not None else None,
            "shade_threshold": self.shade_threshold() if self.shade is not None else None,
            "undetermined_pixels": int(np.count_nonzero(self.labels == LABEL_UNDETERMINED)),
            "labels": {str(k): v for k, v in self.counts().items()},
            "notes": list(self.notes),
            "min_region": int(self.min_region),
            **({"response_source": self.sources.get("response"),
                "noise_source": self.sources.get("noise")} if self.sources else {}),
        }


# -- the model of eq. 20, its error and the fit of M (kernels: :mod:`ccdcore.change.kernels`) -
def prediction_d2(E_ref: ArrayLike, sigma_ref: ArrayLike, E_tgt: ArrayLike, sigma_tgt: ArrayLike,
                  M: ArrayLike, M_cov: ArrayLike | None = None) -> NDArray[np.float64]:
    """d² of every pixel of (H, W, C) radiance maps under E' = E M (NaN where a sigma is not
    finite)."""
    E, s, Et, st = (np.asarray(x, np.float64) for x in (E_ref, sigma_ref, E_tgt, sigma_tgt))
    if E.ndim == 2:
        E, s, Et, st = (x[..., None] for x in (E, s, Et, st))
    H, W, C = E.shape
    ok = np.all(np.isfinite(s) & np.isfinite(st) & np.isfinite(E) & np.isfinite(Et), axis=-1)
    out = np.full((H, W), np.nan)
    rows = ok.ravel()
    M = np.asarray(M, np.float64).reshape(C, C)
    Mc = None if M_cov is None else np.asarray(M_cov, np.float64)
    d2, _ = error_d2(E.reshape(-1, C)[rows], Et.reshape(-1, C)[rows],
                     s.reshape(-1, C)[rows] ** 2, st.reshape(-1, C)[rows] ** 2, M, Mc)
    out.reshape(-1)[rows] = d2
    return out


def _biweight(E, Et, var, var_t, M, c2: float, iters: int = 10) -> tuple[NDArray, NDArray, NDArray]:
    """The M-estimator: IRLS with Tukey's biweight on d (cut-off d² = ``c2``); returns M, the
    inverse normal matrix of the final weights and the weights."""
    w = np.ones(E.shape[0])
    Ninv = np.zeros((M.size, M.size))
    for _ in range(iters):
        d2, _ = error_d2(E, Et, var, var_t, M, want_p=False)
        w = biweight_weights(d2, c2)
        if np.count_nonzero(w) <= M.size:
            break
        M_new, Ninv = gls(E, Et, var, var_t, w, M, iters=1, corrected=True)
        step = float(np.max(np.abs(M_new - M)))
        M = M_new
        if step < 1e-7 * max(1.0, float(np.max(np.abs(M)))):
            break
    return M, Ninv, w


def _scores(E, Et, var, M, w, P) -> NDArray:
    """Per pixel, the corrected GLS estimating function of vec M (n, C²):
    ψ_i[k, j] = w_i (E_ik (P_i e_i)_j - var_ik (M P_i)_kj) (:func:`design_normal`), with
    P_i = Σ_e⁻¹ at M (:func:`error_d2`)."""
    C = E.shape[1]
    e = E @ M - Et
    Pe = np.einsum("ijm,im->ij", P, e, optimize=True)
    MP = np.matmul(M, P)                                  # (n, C, C): (M P_i)_kj
    return (w[:, None, None] * (E[:, :, None] * Pe[:, None, :] - var[:, :, None] * MP)
            ).reshape(-1, C * C)


def biweight_weights(d2: NDArray, c2: float) -> NDArray:
    """Tukey's biweight on d (cut-off d² = ``c2``): w = (1 - d²/c2)² inside, 0 beyond."""
    u = d2 / c2
    return np.where(u < 1.0, (1.0 - u) ** 2, 0.0)


def _m_covariance(E, Et, var, var_t, M, w, c2: float | None = None) -> NDArray:
    """Covariance of vec M from the biweight fit: the sandwich of the M-estimator,
    B⁻¹ (Σ ψ_i ψ_iᵀ) B⁻ᵀ with ψ the corrected estimating function (:func:`_scores`).

    With ``c2`` the weights are the biweight's of the pixels' d² and move with M: the bread
    B = ∂(Σ ψ_i)/∂ vec M is then taken by forward differences, weights and Σ_e⁻¹ recomputed
    at each M (Huber's Σψ' rather than Σw: holding the weights fixed in the bread reported
    standard errors 25-40 % below the Monte Carlo spread of M, since ψ'(d) = (1 - d²/c2)
    (1 - 5 d²/c2) is well below w(d) = (1 - d²/c2)² at the typical d² of 3). Without ``c2``
    the weights ``w`` are fixed and B is the normal matrix of the weighted GLS."""
    C = E.shape[1]
    member = w > 0
    if np.count_nonzero(member) <= C * C:
        return np.full((C * C, C * C), np.nan)
    if c2 is None:
        Em, Etm, vm, vtm, wm = E[member], Et[member], var[member], var_t[member], w[member]
        _, P = error_d2(Em, Etm, vm, vtm, M)
        bread, _ = design_normal(Em, Etm, P, wm, vm)
        g = _scores(Em, Etm, vm, M, wm, P)
    else:
        def scores(Mp: NDArray) -> NDArray:
            d2, P = error_d2(E, Et, var, var_t, Mp)
            return _scores(E, Et, var, Mp, biweight_weights(d2, c2), P)

        g = scores(M)
        base = g.sum(axis=0)
        bread = np.empty((C * C, C * C))
        h = 1e-6 * max(1.0, float(np.max(np.abs(M))))
        for q in range(C * C):               # forward differences: an error of order h (1e-6)
            step = np.zeros(C * C)
            step[q] = h
            bread[:, q] = (scores(M + step.reshape(C, C)).sum(axis=0) - base) / h
    meat = g.T @ g
    try:
        Bi = np.linalg.inv(bread)
    except np.linalg.LinAlgError:
        Bi = np.linalg.pinv(bread)
    return Bi @ meat @ Bi.T


def fit_cluster(E: NDArray, Et: NDArray, var: NDArray, var_t: NDArray, coverage: float,
                options: ChangeOptions, rng: np.random.Generator, c2: float
                ) -> tuple[NDArray, NDArray]:
    """The transform obeyed by the largest group of these pixels (rows (n, C)): LTS on a
    subsample, then the biweight M-estimator (cut-off d² = ``c2``) on a larger even sample
    (``REFINE`` pixels); returns M and its covariance."""
    n, C = E.shape

    def even(m: int) -> NDArray[np.int64]:
        return np.unique(np.linspace(0, n - 1, min(n, m)).astype(np.int64))

    sub = even(int(options.subsample))
    M0, _ = lts(E[sub], Et[sub], var[sub], var_t[sub], coverage, options.trials, rng,
                LTS_REFINED)
    ref = even(REFINE)
    M, _, w = _biweight(E[ref], Et[ref], var[ref], var_t[ref], M0, c2)
    return M, _m_covariance(E[ref], Et[ref], var[ref], var_t[ref], M, w, c2)


# -- the detector -----------------------------------------------------------------------------
def _as_rows(x: ArrayLike, name: str) -> NDArray[np.float64]:
    a = np.asarray(x, np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise CcdError(name, f"expected an (H, W) or (H, W, C) radiance map, got shape {a.shape}")
    return a


def small_regions(mask: NDArray[np.bool_], min_region: int) -> NDArray[np.bool_]:
    """The pixels of ``mask`` in 8-connected regions of fewer than ``min_region`` pixels."""
    from scipy import ndimage

    lab, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return np.zeros_like(mask)
    small = np.bincount(lab.ravel()) < int(min_region)
    small[0] = False
    return small[lab]


def _threshold(background: NDArray, scale: float, dof: int, pfa: float) -> float:
    """The background sample's 1 - P quantile (the scaled χ² one when the sample holds fewer
    than 20 / P values)."""
    pfa = float(pfa)
    if not 0.0 < pfa < 1.0:
        raise CcdError("pfa", f"the false-alarm probability must lie in (0, 1), got {pfa}")
    if background.size >= 20.0 / pfa:
        return float(np.quantile(background, 1.0 - pfa))
    return scale * float(stats.chi2.isf(pfa, dof))


def _background_scale(d2: NDArray, dof: int) -> tuple[float, NDArray]:
    """s and the background's sample: the d² within the gate s·χ²(1 - GATE_P), s matching
    their median to the gate-truncated χ²'s (fixed point from s = 1)."""
    q_gate = float(stats.chi2.isf(GATE_P, dof))
    med = float(stats.chi2.ppf(0.5 * (1.0 - GATE_P), dof))
    s = 1.0
    for _ in range(50):
        inside = d2[d2 <= s * q_gate]
        if inside.size == 0:
            s *= 4.0
            continue
        s_new = float(np.median(inside)) / med
        if abs(s_new - s) <= 1e-6 * s:
            s = s_new
            break
        s = s_new
    return s, np.sort(d2[d2 <= s * q_gate])


@dataclass(frozen=True, eq=False)
class _Rows:
    """The pixels with a radiance in both maps, as rows (n, C): the radiances ``E``, ``Et`` and
    their variances ``var``, ``var_t``."""

    E: NDArray[np.float64]
    Et: NDArray[np.float64]
    var: NDArray[np.float64]
    var_t: NDArray[np.float64]

    def take(self, idx: NDArray[np.int64]) -> _Rows:
        return _Rows(self.E[idx], self.Et[idx], self.var[idx], self.var_t[idx])

    def fit(self, coverage: float, options: ChangeOptions, rng: np.random.Generator,
            c2: float) -> tuple[NDArray, NDArray]:
        """:func:`fit_cluster` on these rows."""
        return fit_cluster(self.E, self.Et, self.var, self.var_t, coverage, options, rng, c2)

    def d2(self, M: NDArray, M_cov: NDArray) -> NDArray:
        """d² of every row under the transform M (with its covariance)."""
        return error_d2(self.E, self.Et, self.var, self.var_t, M, M_cov, want_p=False)[0]


@dataclass(frozen=True, eq=False)
class _Fit:
    """One cluster's transform M, its covariance and the d² of every row under it."""

    M: NDArray[np.float64]
    M_cov: NDArray[np.float64]
    d2: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class _Background:
    """The dominant cluster (step 1) and the threshold calibrated on it (step 3): the scale s,
    the sorted sample, the threshold for the requested P and the sample's median d²."""

    fit: _Fit
    scale: float
    sample: NDArray[np.float64]
    threshold: float
    median: float


def _checked_maps(E_ref: ArrayLike, sigma_ref: ArrayLike, E_tgt: ArrayLike,
                  sigma_tgt: ArrayLike, names: tuple[str, str]) -> tuple[NDArray, ...]:
    """The four maps as (H, W, C) float64, of one shape, the radiances without NaN."""
    E, s, Et, st = (_as_rows(x, n) for x, n in ((E_ref, names[0]), (sigma_ref, names[0]),
                                                (E_tgt, names[1]), (sigma_tgt, names[1])))
    if E.shape != s.shape:
        raise CcdError(names[0], f"radiance {E.shape} and sigma {s.shape} differ in shape")
    if Et.shape != st.shape:
        raise CcdError(names[1], f"radiance {Et.shape} and sigma {st.shape} differ in shape")
    if E.shape != Et.shape:
        raise CcdError(names[1], f"shape {Et.shape} (height, width, channels) differs from the "
                                 f"{names[0]}'s {E.shape}: the same camera and framing are needed")
    for arr, nm in ((E, names[0]), (Et, names[1])):
        if np.any(np.isnan(arr)):
            raise CcdError(nm, "the radiance holds NaN values")
    return E, s, Et, st


def _valid_pixels(s: NDArray, st: NDArray, opts: ChangeOptions, name: str
                  ) -> tuple[NDArray[np.bool_], int, list[str]]:
    """The pixels with a radiance in both maps (finite sigma > 0), the smallest cluster in
    pixels, and the note on the undetermined ones; too few valid pixels is an error."""
    H, W, C = s.shape
    valid = np.all(np.isfinite(s) & np.isfinite(st) & (s > 0) & (st > 0), axis=-1)
    n_valid = int(np.count_nonzero(valid))
    min_px = int(opts.min_pixels) if opts.min_pixels >= 1 else int(
        math.ceil(opts.min_pixels * max(n_valid, 1)))
    min_px = max(min_px, 10 * C * C)
    if n_valid < max(10 * C * C, 2 * min_px):
        raise CcdError(name, f"only {n_valid} of {H * W} pixels have a radiance in both "
                             "brackets (the rest is saturated or dark in every exposure): "
                             "nothing to compare")
    notes: list[str] = []
    if n_valid < 0.95 * H * W:
        notes.append(f"{H * W - n_valid} pixels are saturated or dark in every exposure of a "
                     "bracket: undetermined (label 254)")
    return valid, min_px, notes


def _pixel_rows(E: NDArray, s: NDArray, Et: NDArray, st: NDArray,
                valid: NDArray[np.bool_]) -> _Rows:
    """The valid pixels of both maps as rows, sigmas squared into variances."""
    C = E.shape[-1]
    rows = valid.ravel()
    return _Rows(E.reshape(-1, C)[rows], Et.reshape(-1, C)[rows],
                 s.reshape(-1, C)[rows] ** 2, st.reshape(-1, C)[rows] ** 2)


def _background(rows: _Rows, opts: ChangeOptions, rng: np.random.Generator, c2: float,
                dof: int) -> _Background:
    """Steps 1 and 3: the dominant cluster's M over every row, and the threshold calibrated
    on its d²."""
    M, M_cov = rows.fit(opts.coverage, opts, rng, c2)
    d2 = rows.d2(M, M_cov)
    scale, sample = _background_scale(d2, dof)
    thr = _threshold(sample, scale, dof, opts.pfa)
    median = float(np.median(sample)) if sample.size else float("nan")
    return _Background(_Fit(M, M_cov, d2), scale, sample, thr, median)


def _further_clusters(rows: _Rows, bg: _Background, min_px: int, opts: ChangeOptions,
                      rng: np.random.Generator, c2: float, report: Progress) -> list[_Fit]:
    """Step 4: the clusters (shadows) of the rows the clusters so far leave above the
    threshold, while one has ``min_px`` members, a median d² of the noise (``consistency``)
    and a well-conditioned M."""
    fits: list[_Fit] = []
    open_ = bg.fit.d2 > bg.threshold
    for k in range(1, int(opts.max_clusters)):
        n_open = int(np.count_nonzero(open_))
        if n_open < 2 * min_px:
            break
        report(0.1 + 0.6 * k / opts.max_clusters, f"searching the remaining {n_open} pixels for "
                                                   f"cluster {k + 1}")
        cov_k = max(0.5 * opts.coverage, min_px / n_open)
        try:
            Mk, Mk_cov = rows.take(np.flatnonzero(open_)).fit(min(cov_k, 0.9), opts, rng,
                                                              c2 * bg.scale)
        except (CcdError, np.linalg.LinAlgError):
            break
        d2k = rows.d2(Mk, Mk_cov)
        members = open_ & (d2k <= bg.threshold)
        if int(np.count_nonzero(members)) < min_px:
            break
        if not float(np.median(d2k[members])) <= opts.consistency * bg.median:
            break
        if not np.linalg.cond(Mk) <= opts.max_condition:
            break
        fits.append(_Fit(Mk, Mk_cov, d2k))
        open_ &= ~members
    return fits


def _shades(rows: _Rows, fits: list[_Fit], bg: _Background, valid: NDArray[np.bool_],
            opts: ChangeOptions, dof: int) -> tuple[NDArray | None, NDArray | None]:
    """Step 5: the shade's factor k and d² (maps) of the pixels no cluster explains at
    :data:`SHADE_LOOSEST_P` (or the requested P, if looser); ``(None, None)`` when the test is
    off or the frames are not RGB."""
    if opts.shade is None or dof != 3:
        return None, None
    best = np.min(np.stack([f.d2 for f in fits], axis=1), axis=1)
    thr = _threshold(bg.sample, bg.scale, dof, max(float(opts.pfa), SHADE_LOOSEST_P))
    idx = np.flatnonzero(best > thr)
    k_rows = np.full(best.size, np.nan)
    d2_rows = np.full(best.size, np.nan)
    if idx.size:
        sub = rows.take(idx)
        f0 = fits[0]
        k_rows[idx], d2_rows[idx] = shade_d2(sub.E, sub.Et, sub.var, sub.var_t, f0.M, f0.M_cov)
    maps = []
    for v in (k_rows, d2_rows):
        out = np.full(valid.shape, np.nan)
        out[valid] = v
        maps.append(out)
    return maps[0], maps[1]


def _change_result(E: NDArray, valid: NDArray[np.bool_], fits: list[_Fit], bg: _Background,
                   dof: int, opts: ChangeOptions, notes: list[str],
                   shades: tuple[NDArray | None, NDArray | None] = (None, None)
                   ) -> ChangeResult:
    """Step 6: every cluster's d² as maps, the clusters with their medians, the predicted
    target, and the labels (made by :class:`ChangeResult`)."""
    H, W, C = E.shape
    d2 = np.full((H * W, len(fits)), np.inf)
    d2[valid.ravel()] = np.stack([f.d2 for f in fits], axis=1)
    predicted = E.reshape(-1, C) @ fits[0].M
    clusters = []
    for k, f in enumerate(fits):
        inside = f.d2[f.d2 <= bg.threshold]
        clusters.append(Cluster(k, f.M, f.M_cov, 0, float(np.median(inside)) if inside.size
                                else float("nan")))
    if abs(bg.scale - 1.0) > 0.25:
        notes.append(f"the background's d² is {bg.scale:.2f} times χ²'s ({dof} degrees of "
                     "freedom): the threshold is calibrated on the background, not taken from χ²")
    return ChangeResult(clusters, d2.reshape(H, W, len(fits)), valid, bg.sample, bg.scale, dof,
                        float(opts.pfa), predicted.reshape(H, W, C), tuple(notes),
                        min_region=int(opts.min_region),
                        shade=None if shades[0] is None or opts.shade is None
                        else (float(opts.shade[0]), float(opts.shade[1])),
                        shade_k=shades[0], shade_d2=shades[1])


def detect(E_ref: ArrayLike, sigma_ref: ArrayLike, E_tgt: ArrayLike, sigma_tgt: ArrayLike,
           options: ChangeOptions | None = None, *, names: tuple[str, str] = ("reference",
                                                                             "target"),
           progress: Progress | None = None) -> ChangeResult:
    """Sec. 5 on two radiance maps (H, W, C) or (H, W) with their per-pixel sigmas.

    Pixels whose sigma is not finite in either map (the merge's bounds) are undetermined.

    The steps of the module docstring, each a function: the inputs checked
    (:func:`_checked_maps`, :func:`_valid_pixels`), the dominant cluster and the calibrated
    threshold (steps 1-3, :func:`_background`), the further clusters (step 4,
    :func:`_further_clusters`), the shades of the background's light (step 5,
    :func:`_shades`) and the result with its labels (step 6, :func:`_change_result`).

    Parameters
    ----------
    E_ref : array_like
        The reference's radiance map, (H, W, C) or (H, W).
    sigma_ref : array_like
        Its per-pixel sigma, of the same shape.
    E_tgt : array_like
        The target's radiance map, of the reference's shape.
    sigma_tgt : array_like
        Its per-pixel sigma, of the same shape.
    options : ChangeOptions or None, optional
        The settings (:class:`ChangeOptions`); default ``ChangeOptions()``.
    names : tuple of str, optional
        The names of the two inputs in messages.
    progress : Progress or None, optional
        A :class:`ccdcore.progress.Progress` that follows the steps.

    Returns
    -------
    ChangeResult
        The clusters (the background first, each with its transform M), one d² map per
        cluster, the valid pixels, the background's d² sample that calibrates the threshold and
        its scale s, the degrees of freedom, the labels with the threshold, the predicted
        target, the shades of the background's light and notes.

    Raises
    ------
    CcdError
        Mismatched shapes, NaN radiance, or too few pixels with a radiance in both maps;
        ``options`` outside their ranges.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> E = rng.uniform(10.0, 100.0, (40, 50, 3))          # the reference's radiance, RGB
    >>> M = np.diag([0.5, 0.6, 0.7])                        # a change of light (eq. 20)
    >>> target = E @ M
    >>> target[10:20, 10:20] = 30.0                         # an object appears
    >>> sigma = np.full(E.shape, 0.5)
    >>> result = detect(E, sigma, target + rng.normal(0, 0.5, E.shape), sigma)
    >>> found = result.labels[10:20, 10:20] == 255
    >>> bool(found.mean() > 0.9), bool((result.labels == 255).mean() < 0.1)
    (True, True)
    """
    opts = options or ChangeOptions()
    opts.check()
    report = progress if progress is not None else silent
    E, s, Et, st = _checked_maps(E_ref, sigma_ref, E_tgt, sigma_tgt, names)
    valid, min_px, notes = _valid_pixels(s, st, opts, names[0])
    rows = _pixel_rows(E, s, Et, st, valid)
    rng = np.random.default_rng(int(opts.seed))
    dof = E.shape[-1]
    # the M-estimator's cut-off: a generous χ² quantile (Tukey's biweight weights 0 beyond)
    c2 = float(stats.chi2.isf(1e-4, dof))
    report(0.05, "fitting the background's transform (LTS)")
    bg = _background(rows, opts, rng, c2, dof)
    fits = [bg.fit] + _further_clusters(rows, bg, min_px, opts, rng, c2, report)
    report(0.85, "testing the unexplained pixels for shades of the background's light")
    shades = _shades(rows, fits, bg, valid, opts, dof)
    report(0.9, "labels and the predicted target")
    res = _change_result(E, valid, fits, bg, dof, opts, notes, shades)
    report(1.0, "done")
    return res
