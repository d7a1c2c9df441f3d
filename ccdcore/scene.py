"""Scene variation V_S of a surface patch and the variance budget of an image region.

Implements sec. VI and sec. VII-B/C (Figs. 3 and 4) of Healey & Kondepudy (1994).  An image of a
planar surface of one material, corrected with eq. 51, D_C = (D − D̂_D)/K̂, is (eq. 53)

    D_C(a, b) = S·A + E(a, b)·A + (N_I + N_C)/K̂,

so over a region of interest (ROI) its mean is μ_D = S·A (eq. 54) and its spatial variance
σ²_D = σ_E²·A² + σ²_KN (eq. 55), with σ²_KN = E[1/K̂²]·σ²_N (eq. 56).  Hence
σ²_D − σ²_KN = V_S·μ²_D (eq. 57), where V_S = σ_E²/S² is the *scene variation*: independent of the
illumination level, so one patch imaged through several neutral-density filters gives one V_S.

Black level
-----------
Eq. 58 estimates the noise of the corrected region as σ̂²_N = Â(μ̂_D + D̄_D) + σ̂²_C: the raw mean
of the region is μ = μ_D + D̄_D (K ≈ 1), and eq. 41 says σ²_N = A·μ + σ²_C.  The paper's model has
no electronic offset, so there D̄_D = A·Ē_DC is pure dark *signal* and carries shot noise.  A real
camera adds a black level b0 (DN) that is in the dark reference D̂_D but has no shot noise; eq. 41
becomes σ²_N = A·(μ − b0) + σ²_C (the project's convention, see ``ccdcore.noise``), and so we use

    σ̂²_N = Â·(μ̂_D + D̄_D − b0) + σ̂²_C          (eq. 58 with a black level),

with D̄_D the mean of the dark reference over the ROI.  With b0 = 0 this is eq. 58 exactly.  (When
b0 was itself taken as the dark mean — the EMVA 1288 convention of ``ccdcore.noise`` — the dark
shot noise is in σ̂²_C, and D̄_D − b0 ≈ 0 removes it from the first term: consistent either way.)

Uncertainty of V_S
------------------
V̂_S = (σ̂²_D − σ̂²_KN − σ̂²_cal)/μ̂²_D, σ̂²_cal = 0 in the paper (see ``dark_var``/``K_var``).
Its standard error combines, to first order,

* the sampling error of σ̂²_D.  The surface texture E(a, b) inside the ROI is one fixed pattern
  (the same at every ND level); only the sensor noise is drawn anew in each frame.  For a fixed
  texture of sample variance v_s = V_S·μ²_D and Gaussian noise of variance σ²_n (= σ²_KN + σ²_cal)
  the sample variance of the n pixels has
  var[σ̂²_D] = (4·v_s·σ²_n + 2·σ⁴_n)/(n − 1)   (the cross term plus eq. 39 for the noise alone);
* the error of μ̂_D (variance σ²_n/n), which enters both σ̂²_KN (through eq. 58) and μ̂²_D;
* the error of σ̂²_KN from the noise model: ∂σ̂²_KN/∂(Â, σ̂²_C) = E[1/K̂²]·(μ̂_D + D̄_D − b0, 1),
  propagated with the 2×2 covariance of (Â, σ̂²_C) (eq. 66) when it is given.

``V_S_err`` is therefore the error of V_S *of the imaged region* (the texture actually in the ROI),
which is what the simulator's truth is and what is comparable across light levels.  The error of
V_S as a property of the material (another region of the same surface would have another texture
sample) also contains the sampling variance of the texture's own variance; ``V_S_err_population``
adds it with the fourth-moment form var[s²] = (m₄ − s⁴(n − 3)/(n − 1))/n of the pixel values,
assuming spatially independent pixels (for a spatially correlated texture it is a lower bound).

Fit across levels (eq. 57, Fig. 3)
----------------------------------
y_i = σ̂²_D,i − σ̂²_KN,i − σ̂²_cal,i against x_i = μ̂²_D,i: a least-squares line through the
origin.  The per-level errors are independent except for the noise-model part, which is common to
all levels (the same Â, σ̂²_C), so the fit is generalised least squares with the covariance
Σ = diag(var_i) + G·C·Gᵀ (G: rows ∂y_i/∂(Â, σ̂²_C), C: eq. 66); without C it is the weighted fit
with weights 1/var_i.  V̂_S = xᵀΣ⁻¹y / xᵀΣ⁻¹x, var[V̂_S] = 1/xᵀΣ⁻¹x, χ² = rᵀΣ⁻¹r with L − 1
degrees of freedom and Q its upper tail probability (as eq. 67).  A single level gives V̂_S with its
error, ``dof`` = 0 and ``chi2`` = ``Q`` = NaN (no test of level independence is possible).

Variance budget (Fig. 4, sec. VII-C)
------------------------------------
For the *uncorrected* image D = A·K·I + D_D + N of a surface (eqs. 20–22, 17), over a region with
raw mean μ, dark mean D̄ and I = S(1 + e) (var[e] = V_S), K and e independent with mean 1 and 0:

* spatial variation of the dark reference D_D(a, b): its spatial variance, constant;
* σ²_C (eq. 27), constant;
* shot noise A²·(K·I + E_DC) averaged = A·(μ − b0) (eqs. 26, 41 with the black level), linear;
* K variation: var[A·K·I] = (A·S)²·(σ_K² + V_S + σ_K²·V_S); with A·S = μ − D̄ the K part is
  σ_K²·(1 + V_S)·(μ − D̄)² (the tiny product term σ_K²·V_S is counted here);
* scene: V_S·(μ − D̄)², quadratic.

These are independent, so they add up to the total variance of the region (cross terms vanish in
expectation).  ``fractions`` are each over the total.

Public objects
--------------
SceneMeasurement
    One ROI in one corrected scene image: μ̂_D, σ̂²_D, E[1/K̂²], σ̂²_N, σ̂²_KN, V_S and errors.
SceneVariation
    One patch across light levels: the eq. 57 fit, χ², dof, Q.
VarianceBudget
    Components and fractions of the variance of an uncorrected region against intensity (Fig. 4).
SceneMeasurementSummary, SceneSummary, CorrectionCheckSummary
    The records a calibration product stores of a measurement, of a patch
    (:meth:`SceneVariation.summary`) and of the correction check of sec. VII-A; defined in
    :mod:`ccdcore.scene_summary` and re-exported here.
scene_measurement(frame, dark_map, K, *, A, sigma_c2, roi, ...)
    Measure one frame (pure arrays and floats).
fit_scene_variation(measurements, *, noise_cov=None, name="")
    The eq. 57 fit over measurements.
scene_variation(frames_with_meta, dark, K, noise, *, name=None, ...)
    Measure and fit the frames of one patch (duck-typed calibration results accepted).
scene_variations(session, dark, K, noise, ...)
    Every patch of a session's ``scene`` frames (manifest key ``patch``, else the ROI).
variance_budget(mu, *, A, sigma_c2, dark_spatial_var, sigma_K2, V_S, black_level=0.0, ...)
    The Fig. 4 budget.

References
----------
.. [1] G. E. Healey, R. Kondepudy, "Radiometric CCD Camera Calibration and Noise Estimation",
   IEEE TPAMI 16(3), 267–276, 1994.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .channels import Layout
from .common import Roi, check_roi, json_safe
from .errors import CcdError
from .reduce import READ_AHEAD
from .scene_summary import CorrectionCheckSummary, SceneMeasurementSummary, SceneSummary

__all__ = ["SceneMeasurement", "SceneVariation", "VarianceBudget", "SceneMeasurementSummary",
           "SceneSummary", "CorrectionCheckSummary", "scene_measurement",
           "fit_scene_variation", "scene_variation", "scene_variations", "variance_budget",
           "BUDGET_COMPONENTS"]

#: names of the variance-budget components, in the order of Fig. 4's legend
BUDGET_COMPONENTS = ("dark spatial", "sigma_C^2", "shot noise", "K variation", "scene")



# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SceneMeasurement:
    """One region of interest in one corrected scene image (sec. VI).

    Attributes
    ----------
    path, level
        Source frame and its light-level id (``None`` when unknown).
    roi
        ``(x, y, w, h)`` in pixels (columns x..x+w−1, rows y..y+h−1).
    n_pixels
        Pixels in the ROI.
    mu_D
        μ̂_D, sample mean of D_C over the ROI (eq. 54), DN.
    var_D
        σ̂²_D, sample variance (ddof = 1) of D_C over the ROI (eq. 55), DN².
    E_invK2
        E[1/K̂²] over the ROI (eq. 56).
    dark_mean
        D̄_D, mean of the dark reference over the ROI (eq. 58), DN.
    black_level
        b0, the black level used in eq. 58 (DN; 0 in the paper's model).
    sigma_N2
        σ̂²_N = Â(μ̂_D + D̄_D − b0) + σ̂²_C (eq. 58 with the black level, see the module notes).
    sigma_KN2
        σ̂²_KN = E[1/K̂²]·σ̂²_N (eq. 56).
    sigma_cal2
        Extra variance from the calibration maps' own errors (0 unless ``dark_var``/``K_var`` are
        given; the paper assumes it negligible, eq. 52).
    V_S, V_S_err
        (σ̂²_D − σ̂²_KN − σ̂²_cal)/μ̂²_D (eq. 57) and its standard error for the imaged region.
    V_S_err_population
        Standard error including the sampling of the texture itself (fourth-moment form).
    var_y
        Variance of y = σ̂²_D − σ̂²_KN − σ̂²_cal not shared with other levels (DN⁴; excludes the
        noise-model part), used by the eq. 57 fit.
    dy_dnoise
        ∂y/∂(Â, σ̂²_C): the shared noise-model sensitivity, used by the fit.
    n_clipped
        ROI pixels at 0 or at the full scale (such a frame is left out of the fit).
    """

    path: str | None
    level: int | None
    roi: tuple
    n_pixels: int
    mu_D: float
    var_D: float
    E_invK2: float
    dark_mean: float
    black_level: float
    sigma_N2: float
    sigma_KN2: float
    sigma_cal2: float
    V_S: float
    V_S_err: float
    V_S_err_population: float
    var_y: float
    dy_dnoise: tuple[float, float]
    n_clipped: int = 0

    @property
    def y(self) -> float:
        """σ̂²_D − σ̂²_KN − σ̂²_cal, the left side of eq. 57 (DN²)."""
        return self.var_D - self.sigma_KN2 - self.sigma_cal2

    def summary(self, used: bool = True) -> SceneMeasurementSummary:
        """The measurement as the record a product stores, with ``used``: whether the eq. 57
        fit used it."""
        return SceneMeasurementSummary(
            path=self.path, level=self.level, roi=tuple(int(v) for v in self.roi),
            n_pixels=int(self.n_pixels), mu_D=json_safe(self.mu_D),
            var_D=json_safe(self.var_D), E_invK2=json_safe(self.E_invK2),
            dark_mean=json_safe(self.dark_mean), black_level=json_safe(self.black_level),
            sigma_N2=json_safe(self.sigma_N2), sigma_KN2=json_safe(self.sigma_KN2),
            sigma_cal2=json_safe(self.sigma_cal2), y=json_safe(self.y), V_S=json_safe(self.V_S),
            V_S_err=json_safe(self.V_S_err),
            V_S_err_population=json_safe(self.V_S_err_population),
            n_clipped=int(self.n_clipped), used=bool(used))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly values: :meth:`summary` as its JSON object, without ``used``."""
        out = self.summary().to_dict()
        del out["used"]
        return out


@dataclass(frozen=True)
class SceneVariation:
    """One surface patch across light levels: the fit of eq. 57 (Fig. 3).

    Attributes
    ----------
    name
        Patch name (``note = "patch=NAME"``) or ``"roi=x,y,w,h"``.
    measurements
        Every measured frame, in input order (including excluded ones).
    V_S, V_S_err
        Fitted scene variation and its standard error (generalised least squares through the
        origin; includes the shared noise-model error when its covariance is known).
    chi2, dof, Q
        Goodness of fit of eq. 57 across levels: χ², L − 1 degrees of freedom, upper-tail
        probability (eq. 67).  One level: ``dof`` = 0, ``chi2`` = ``Q`` = NaN.
    used
        Per measurement, whether it entered the fit.
    excluded
        Reasons for the measurements left out (``"path: reason"``).
    notes
        Assumptions worth knowing (calibration-error terms, noise covariance missing ...).
    """

    name: str
    measurements: tuple[SceneMeasurement, ...]
    V_S: float
    V_S_err: float
    chi2: float
    dof: int
    Q: float
    used: tuple[bool, ...] = ()
    excluded: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def summary(self) -> SceneSummary:
        """The patch as the record a product stores (one of ``estimates["scene"]``): plain
        numbers, NaN as ``None``, each measurement with whether the fit used it."""
        return SceneSummary(
            name=self.name, V_S=json_safe(self.V_S), V_S_err=json_safe(self.V_S_err),
            chi2=json_safe(self.chi2), dof=int(self.dof), Q=json_safe(self.Q),
            measurements=tuple(m.summary(bool(u)) for m, u in zip(self.measurements, self.used)),
            excluded=tuple(self.excluded), notes=tuple(self.notes))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly values: :meth:`summary` as its JSON object."""
        return self.summary().to_dict()


@dataclass(frozen=True)
class VarianceBudget:
    """Variance of an uncorrected image region of one surface against intensity (Fig. 4).

    Attributes
    ----------
    mu
        Raw region means μ (DN), 1-D.
    components
        Name (:data:`BUDGET_COMPONENTS`) -> absolute variance at each μ (DN²).
    fractions
        Name -> component / total at each μ (they sum to 1).
    parameters
        The inputs (A, σ²_C, dark spatial variance, σ_K², V_S, b0, D̄).
    """

    mu: np.ndarray
    components: dict[str, np.ndarray]
    fractions: dict[str, np.ndarray]
    parameters: dict[str, float] = field(default_factory=dict)

    @property
    def total(self) -> np.ndarray:
        """Total variance at each μ (DN²)."""
        return np.sum([self.components[k] for k in BUDGET_COMPONENTS], axis=0)

    def dominant(self) -> list[str]:
        """The largest component's name at each μ."""
        stack = np.array([self.fractions[k] for k in BUDGET_COMPONENTS])
        return [BUDGET_COMPONENTS[i] for i in np.argmax(stack, axis=0)]

    def to_dict(self) -> dict[str, Any]:
        return {"mu": [float(v) for v in self.mu], "total": [float(v) for v in self.total],
                "components": {k: [float(v) for v in a] for k, a in self.components.items()},
                "fractions": {k: [float(v) for v in a] for k, a in self.fractions.items()},
                "dominant": self.dominant(), "parameters": dict(self.parameters)}


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _mono(a: ArrayLike, where: str) -> NDArray[np.float64]:
    arr = np.asarray(a)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 3:
        raise CcdError(where, f"colour frames ({arr.shape[2]} channels) are not supported yet: "
                              "per channel support comes with the flat-field work")
    if arr.ndim != 2:
        raise CcdError(where, f"expected a 2-D image, got shape {arr.shape}")
    if arr.dtype.kind not in "uifb":
        raise CcdError(where, f"cannot use pixels of dtype {arr.dtype}")
    return arr


def _map(a: Any, shape: tuple[int, int], where: str) -> NDArray[np.float64]:
    """A calibration map as float64 of ``shape`` (a scalar is broadcast)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0:
        return np.broadcast_to(arr, shape)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.shape != shape:
        raise CcdError(where, f"map shape {arr.shape} differs from the frame's {shape}")
    return arr


def _roi_slices(roi: Any, shape: tuple[int, int], where: str) -> tuple[Roi, tuple]:
    """The checked ROI (the whole frame for ``None``) and its slices; at least 3 pixels."""
    box = check_roi(roi if roi is not None else (0, 0, shape[1], shape[0]), shape, where,
                    min_pixels=3)
    return box, box.slices


def _correct(frame: NDArray, dark: NDArray, K: NDArray) -> NDArray[np.float64]:
    """D_C = (D − D̂_D)/K̂, eq. 51 (local copy of ``ccdcore.fixedpattern.correct`` on a crop),
    float64, computed in one new array."""
    out = np.subtract(frame, dark, dtype=np.float64)
    out /= K
    return out


def _once(cache: dict | None, key: tuple, compute: Any) -> Any:
    """``compute()``, or its value from an earlier frame: the calibration maps' terms over one
    ROI are the same for every frame of a patch (:func:`scene_variation` passes a ``cache``).
    A failure is not kept, so a bad map fails at the same step of every frame."""
    if cache is None:
        return compute()
    if key not in cache:
        cache[key] = compute()
    return cache[key]


def _check_K(Kr: NDArray, roi_t: tuple) -> bool:
    if not np.all(np.isfinite(Kr)) or np.any(Kr <= 0):
        raise CcdError("K map", f"K must be finite and positive inside roi {list(roi_t)}")
    return True


def _check_dark(dk: NDArray, roi_t: tuple) -> bool:
    if not np.all(np.isfinite(dk)):
        raise CcdError("dark map", f"non-finite values inside roi {list(roi_t)}")
    return True


def _noise_params(noise: Any) -> tuple[float, float, NDArray | None, float | None]:
    """(A, σ²_C, cov or None, black level or None) from a PhotonTransfer-like object or mapping."""
    def get(key: str, default: Any = None) -> Any:
        if isinstance(noise, Mapping):
            return noise.get(key, default)
        return getattr(noise, key, default)

    A, c2 = get("A"), get("sigma_c2")
    if A is None or c2 is None:
        raise CcdError("noise", "the noise model needs A and sigma_c2 (a photon-transfer result "
                                "or a mapping with those keys)")
    cov = get("cov")
    b0 = get("black_level_dn", get("black_level"))
    return float(A), float(c2), None if cov is None else np.asarray(cov, dtype=float), \
        None if b0 is None else float(b0)


def _check_cov(cov: Any) -> NDArray[np.float64] | None:
    if cov is None:
        return None
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (2, 2) or not np.all(np.isfinite(c)):
        raise CcdError("noise_cov", f"expected a finite 2x2 covariance of (A, sigma_c2), got "
                                    f"shape {c.shape}")
    return c


# --------------------------------------------------------------------------------------------
# one frame
# --------------------------------------------------------------------------------------------
def scene_measurement(frame: ArrayLike, dark_map: ArrayLike, K: ArrayLike, *, A: float,
                      sigma_c2: float, roi: Any, black_level: float = 0.0,
                      noise_cov: ArrayLike | None = None, path: str | None = None,
                      level: int | None = None, full_scale: float | None = None,
                      dark_var: ArrayLike | float = 0.0, K_var: float = 0.0,
                      fp_level: float | None = None) -> SceneMeasurement:
    """Scene variation of one ROI of one scene image (eqs. 51, 54–58).

    Parameters
    ----------
    frame
        Raw image D(a, b), 2-D (DN).
    dark_map
        Dark reference D̂_D(a, b) (sec. V-A), same shape (or a scalar), DN, black level included.
    K
        Fixed-pattern map K̂(a, b) (eq. 49), same shape (or a scalar), positive in the ROI.
    A, sigma_c2
        Noise model Â (DN per electron) and σ̂²_C (DN²) of eq. 41.
    roi
        ``(x, y, w, h)``; ``None`` for the whole frame.
    black_level
        b0 (DN) in D̂_D that carries no shot noise; eq. 58 uses μ̂_D + D̄_D − b0.
    noise_cov
        2×2 covariance of (Â, σ̂²_C) (eq. 66), or ``None`` to ignore the noise-model error.
    path, level
        Recorded in the result.
    full_scale
        Largest ADC value (2^b − 1): ROI pixels at 0 or at it are counted as clipped.
    dark_var
        Variance of the dark reference's own estimation error (per pixel map or scalar; e.g.
        σ²_N,dark/s for s averaged dark frames, sec. V-A).  Adds E[dark_var/K̂²] to the noise.
    K_var
        Relative variance of K̂'s estimation error (≤ the bound of eq. 50 divided by K² ≈ 1);
        it multiplies the signal, so it adds K_var·μ̂²_D, which would otherwise look like V_S.
    fp_level
        When K̂ was estimated with the same D̂_D (eq. 46), the dark-reference error δ enters K̂
        too: K̂ ≈ K − δ/μ_fp with μ_fp the (harmonic) mean level e_i of the fixed-pattern
        configurations, so D_C ≈ μ − δ·(1 − μ/μ_fp) and the dark term is
        ``dark_var·(1 − μ̂_D/μ_fp)²`` — it vanishes for a scene at the calibration level.
        ``None`` treats the two errors as independent.

    Returns
    -------
    SceneMeasurement

    Raises
    ------
    CcdError
        Colour or non-2-D frames, mismatched map shapes, an ROI outside the frame, K̂ ≤ 0 or
        non-finite values in the ROI, a non-positive corrected mean, bad noise parameters.
    """
    return _scene_measurement(frame, dark_map, K, A=A, sigma_c2=sigma_c2, roi=roi,
                              black_level=black_level, noise_cov=noise_cov, path=path,
                              level=level, full_scale=full_scale, dark_var=dark_var,
                              K_var=K_var, fp_level=fp_level, cache=None)


def _scene_measurement(frame: ArrayLike, dark_map: ArrayLike, K: ArrayLike, *, A: float,
                       sigma_c2: float, roi: Any, black_level: float,
                       noise_cov: ArrayLike | None, path: str | None, level: int | None,
                       full_scale: float | None, dark_var: ArrayLike | float, K_var: float,
                       fp_level: float | None, cache: dict | None) -> SceneMeasurement:
    """:func:`scene_measurement`; with a ``cache`` shared by the frames of one patch (same maps),
    the maps' terms over an ROI (crops, checks, E[1/K̂²], D̄_D, the dark_var term) are computed
    once for all its frames."""
    where = path or "frame"
    D = _mono(frame, where)
    shape = D.shape
    roi_t, sl = _roi_slices(roi, shape, where)
    at = (roi_t, shape)
    dk = _once(cache, ("dark", at), lambda: _map(dark_map, shape, "dark map")[sl])
    Kr = _once(cache, ("K", at), lambda: _map(K, shape, "K map")[sl])
    # the raw crop: integer pixels are compared and converted exactly, as float64 would be
    Dr = D[sl] if D.dtype.kind in "uib" else D[sl].astype(np.float64)
    if not (math.isfinite(A) and A >= 0 and math.isfinite(sigma_c2) and sigma_c2 >= 0):
        raise CcdError("noise", f"need finite A >= 0 and sigma_c2 >= 0, got A={A}, "
                                f"sigma_c2={sigma_c2}")
    cov = _check_cov(noise_cov)
    _once(cache, ("K ok", at), lambda: _check_K(Kr, roi_t))
    _once(cache, ("dark ok", at), lambda: _check_dark(dk, roi_t))
    if Dr.dtype.kind == "f" and not np.all(np.isfinite(Dr)):
        raise CcdError(where, f"non-finite pixel values inside roi {list(roi_t)}")
    if K_var < 0:
        raise CcdError("K_var", f"must be >= 0, got {K_var}")
    n_clipped = 0
    if full_scale is not None:
        n_clipped = int(np.count_nonzero((Dr <= 0) | (Dr >= float(full_scale))))

    n = Dr.size
    DC = _correct(Dr, dk, Kr)                                    # eq. 51
    mu = float(DC.mean())                                        # eq. 54
    if not mu > 0:
        raise CcdError(where, f"the corrected mean over roi {list(roi_t)} is {mu:.4g} DN; "
                              "V_S = (σ²_D − σ²_KN)/μ²_D needs a lit region above the dark level")
    d2 = DC                                                      # one buffer, in place:
    d2 -= mu                                                     # the deviations D_C − μ̂_D,
    d2 *= d2                                                     # their squares
    m2 = float(np.mean(d2))
    var_D = m2 * n / (n - 1)                                     # eq. 55, sample variance
    d2 *= d2                                                     # fourth powers (not dev ** 4)
    m4 = float(np.mean(d2))
    del DC, d2
    E = _once(cache, ("E", at), lambda: float((1.0 / (Kr * Kr)).mean()))  # E[1/K̂²], eq. 56
    dbar = _once(cache, ("dbar", at), lambda: float(dk.mean()))
    b0 = float(black_level)
    g = np.array([mu + dbar - b0, 1.0])                          # ∂σ̂²_N/∂(Â, σ̂²_C)
    sigma_N2 = float(A * g[0] + sigma_c2)                        # eq. 58 with the black level
    sigma_KN2 = E * sigma_N2                                     # eq. 56
    if np.ndim(dark_var):                                        # E[dark_var/K̂²]
        dv = _once(cache, ("dark_var", at), lambda: float(np.mean(
            _map(np.asarray(dark_var, dtype=np.float64), shape, "dark_var")[sl]
            * (1.0 / (Kr * Kr)))))
    else:
        dv = float(np.asarray(dark_var, dtype=np.float64)) * E
    if dv < 0:
        raise CcdError("dark_var", "variance of the dark reference must be >= 0")
    if fp_level is not None:
        if not fp_level > 0:
            raise CcdError("fp_level", f"must be > 0 DN, got {fp_level}")
        dv *= (1.0 - mu / float(fp_level)) ** 2
    sigma_cal2 = dv + float(K_var) * mu * mu
    y = var_D - sigma_KN2 - sigma_cal2
    V = y / (mu * mu)                                            # eq. 57

    # ---- uncertainty (module notes) ----------------------------------------------------------
    s2n = sigma_KN2 + dv                                         # per-frame noise variance
    v_s = max(y, 0.0)
    var_varD = (4.0 * v_s * s2n + 2.0 * s2n * s2n) / (n - 1)     # fixed texture + Gaussian noise
    var_varD_pop = max((m4 - m2 * m2 * (n - 3) / (n - 1)) / n, var_varD)
    dy_dmu = -(E * A + 2.0 * float(K_var) * mu)                  # y depends on μ̂ via eq. 58
    var_mu = s2n / n
    # V = y/μ²: dV/dμ = dy_dmu/μ² − 2V/μ; y−V·x for the fit has the same μ-sensitivity
    var_y = var_varD + (dy_dmu - 2.0 * max(V, 0.0) * mu) ** 2 * var_mu
    var_y_pop = var_varD_pop + (dy_dmu - 2.0 * max(V, 0.0) * mu) ** 2 * var_mu
    dy_dnoise = -E * g
    var_model = float(dy_dnoise @ cov @ dy_dnoise) if cov is not None else 0.0
    mu4 = mu ** 4
    return SceneMeasurement(
        path=None if path is None else str(path), level=None if level is None else int(level),
        roi=roi_t, n_pixels=int(n), mu_D=mu, var_D=var_D, E_invK2=E, dark_mean=dbar,
        black_level=b0, sigma_N2=sigma_N2, sigma_KN2=sigma_KN2, sigma_cal2=sigma_cal2, V_S=V,
        V_S_err=math.sqrt((var_y + var_model) / mu4),
        V_S_err_population=math.sqrt((var_y_pop + var_model) / mu4),
        var_y=var_y, dy_dnoise=(float(dy_dnoise[0]), float(dy_dnoise[1])), n_clipped=n_clipped)


# --------------------------------------------------------------------------------------------
# across levels
# --------------------------------------------------------------------------------------------
def fit_scene_variation(measurements: Iterable[SceneMeasurement], *,
                        noise_cov: ArrayLike | None = None, name: str = "",
                        notes: Iterable[str] = ()) -> SceneVariation:
    """Fit σ̂²_D − σ̂²_KN = V_S·μ̂²_D (eq. 57) across light levels (Fig. 3).

    Generalised least squares through the origin with the covariance
    Σ = diag(var_y) + G·C·Gᵀ (independent per-level errors plus the noise-model error common to
    all levels, see the module notes).  Measurements with clipped ROI pixels are left out, with
    the reason in ``excluded``.

    Raises
    ------
    CcdError
        No usable measurement.
    """
    ms = tuple(measurements)
    cov = _check_cov(noise_cov)
    used = tuple(m.n_clipped == 0 for m in ms)
    excluded = tuple(f"{m.path or f'level {m.level}'}: {m.n_clipped} clipped pixel(s) in the roi"
                     for m, u in zip(ms, used) if not u)
    use = [m for m, u in zip(ms, used) if u]
    where = name or "scene patch"
    if not use:
        raise CcdError(where, "no usable scene measurement (none given, or all clipped)")
    x = np.array([m.mu_D ** 2 for m in use])
    y = np.array([m.y for m in use])
    S = np.diag([m.var_y for m in use])
    if cov is not None:
        G = np.array([m.dy_dnoise for m in use])
        S = S + G @ cov @ G.T
    Si = np.linalg.inv(S)
    F = float(x @ Si @ x)
    V = float(x @ Si @ y) / F
    err = math.sqrt(1.0 / F)
    L = len(use)
    notes = list(notes)
    if L >= 2:
        r = y - V * x
        chi2 = float(r @ Si @ r)
        dof = L - 1
        from scipy.stats import chi2 as _chi2  # here: scipy.stats is slow to import

        Q = float(_chi2.sf(chi2, dof))
    else:
        chi2, dof, Q = float("nan"), 0, float("nan")
        notes.append("one level only: V_S from that level; chi2 and Q undefined (dof = 0)")
    if cov is None:
        notes.append("noise-model covariance not given: the error of (A, sigma_c2) is not in "
                     "V_S_err")
    return SceneVariation(name=name, measurements=ms, V_S=V, V_S_err=err, chi2=chi2, dof=dof,
                          Q=Q, used=used, excluded=excluded, notes=tuple(notes))


def _frame_meta(item: Any) -> tuple[Any, NDArray, dict[str, Any]]:
    """(record, pixels, meta) from ``(record, array)``, ``(array, mapping)`` or an array."""
    if isinstance(item, tuple) and len(item) == 2:
        a, b = item
        if isinstance(b, Mapping):
            return None, np.asarray(a), dict(b)
        if isinstance(a, Mapping):
            return None, np.asarray(b), dict(a)
        rec = a
        meta = {"roi": getattr(rec, "roi", None), "level": getattr(rec, "level", None),
                "path": getattr(rec, "relpath", None) or getattr(rec, "path", None),
                "patch": getattr(rec, "patch", None)}
        return rec, np.asarray(b), meta
    return None, np.asarray(item), {}


def scene_variation(frames_with_meta: Iterable[Any], dark: Any, K: Any, noise: Any, *,
                    name: str | None = None, roi: Any = None,
                    black_level: float | None = None, full_scale: float | None = None,
                    dark_var: ArrayLike | float = 0.0, K_var: float = 0.0,
                    fp_level: float | None = None) -> SceneVariation:
    """Scene variation of one patch imaged at several light levels (sec. VI, VII-B).

    Parameters
    ----------
    frames_with_meta
        Items ``(record, pixels)`` as :meth:`ccdcore.session.Session.iter_frames` yields
        (``record.roi``, ``.level``, ``.relpath``), or ``(pixels, {"roi":, "level":, "path":})``,
        or bare arrays.  Consumed one frame at a time.
    dark
        Dark reference: an array, or an object with ``mean_map`` (``DarkReference``).
    K
        Fixed-pattern map: an array, or an object with ``K`` (``FixedPattern``).
    noise
        Photon-transfer result (``A``, ``sigma_c2``, optional ``cov`` of (A, σ²_C) and
        ``black_level_dn``) or a mapping with those keys.
    name
        Patch name (default: the first frame's ``patch``, else ``"roi=x,y,w,h"``).
    roi
        ROI for every frame, overriding the frames' own; frames without one use the whole frame.
    black_level
        b0 (DN); default: the noise model's ``black_level_dn``, else 0.
    full_scale, dark_var, K_var
        See :func:`scene_measurement`.
    """
    dark_map = getattr(dark, "mean_map", dark)
    K_map = getattr(K, "K", K)
    A, c2, cov, b0_noise = _noise_params(noise)
    b0 = black_level if black_level is not None else (b0_noise if b0_noise is not None else 0.0)
    ms = []
    cache: dict = {}          # the maps' terms per ROI, shared by the frames (same maps)
    for item in frames_with_meta:
        _, pixels, meta = _frame_meta(item)
        r = roi if roi is not None else meta.get("roi")
        m = _scene_measurement(pixels, dark_map, K_map, A=A, sigma_c2=c2, roi=r,
                               black_level=b0, noise_cov=cov,
                               path=meta.get("path") and str(meta.get("path")),
                               level=meta.get("level"), full_scale=full_scale,
                               dark_var=dark_var, K_var=K_var, fp_level=fp_level, cache=cache)
        if name is None:
            name = meta.get("patch") or "roi=" + ",".join(str(v) for v in m.roi)
        ms.append(m)
    notes = [f"eq. 58 with black level b0 = {b0:g} DN: sigma_N^2 = A(mu_D + mean dark - b0) "
             "+ sigma_C^2"]
    if not np.any(np.asarray(dark_var)) and K_var == 0:
        notes.append("errors of the dark and K maps assumed negligible (eq. 52); pass dark_var "
                     "/ K_var to include them")
    return fit_scene_variation(ms, noise_cov=cov, name=name or "scene patch", notes=notes)


def scene_variations(session: Any, dark: Any, K: Any, noise: Any, *,
                     black_level: float | None = None, dark_var: ArrayLike | float = 0.0,
                     K_var: float = 0.0,
                     fp_level: float | None = None) -> dict[str, SceneVariation]:
    """Scene variation of every patch among a session's ``scene`` frames.

    Frames are grouped by :meth:`ccdcore.session.Session.scene_patches`: by the manifest key
    ``patch`` (as the ``healey94`` simulator writes), else by their ROI (``"roi=x,y,w,h"``).  A
    patch frame without an ROI is measured over the whole frame.  Frames with neither (general
    scene images) and the ``max-intensity`` frame (sec. VII-A correction check) are skipped.
    Frames are read once, one at a time, the next few decoded ahead in worker threads.

    Parameters
    ----------
    session
        A :class:`~ccdcore.session.Session`.
    dark, K, noise
        As for :func:`scene_variation`.
    black_level
        b0 (DN); default: the noise model's ``black_level_dn``, else the session camera's
        ``black_level``, else 0.
    dark_var, K_var
        See :func:`scene_measurement`.

    Returns
    -------
    dict
        Patch name -> :class:`SceneVariation`, in the order the patches first appear.

    Raises
    ------
    CcdError
        No scene frame with a patch or ROI; colour sessions; any bad frame.
    """
    camera = getattr(session, "camera", None)
    layout = getattr(camera, "layout", "mono") or "mono"
    if layout != Layout.MONO:
        raise CcdError("camera.layout", f"colour frames ({layout}) are not supported yet: per "
                                        "channel support comes with the flat-field work")
    bits = getattr(camera, "bits", None)
    full_scale = None if bits is None else float(2 ** int(bits) - 1)
    if black_level is None:
        _, _, _, b0n = _noise_params(noise)
        black_level = b0n if b0n is not None else getattr(camera, "black_level", None)
    groups = session.scene_patches()
    if not groups:
        raise CcdError(session.label, "no scene frames with a 'patch' or an 'roi' to measure "
                                      "V_S on")
    stream = session.iter_frames([r for recs in groups.values() for r in recs],
                                 read_ahead=READ_AHEAD)
    return {name: scene_variation(itertools.islice(stream, len(recs)), dark, K, noise,
                                  name=name, black_level=black_level, full_scale=full_scale,
                                  dark_var=dark_var, K_var=K_var, fp_level=fp_level)
            for name, recs in groups.items()}


# --------------------------------------------------------------------------------------------
# variance budget
# --------------------------------------------------------------------------------------------
def variance_budget(mu: ArrayLike, *, A: float, sigma_c2: float, dark_spatial_var: float,
                    sigma_K2: float, V_S: float, black_level: float = 0.0,
                    dark_mean: float | None = None) -> VarianceBudget:
    """Parts of the variance of an uncorrected region of one surface versus intensity (Fig. 4).

    See the module notes for the derivation (sec. VII-C): dark spatial variance and σ²_C are
    constant, shot noise A·(μ − b0) is linear, K variation σ_K²(1 + V_S)(μ − D̄)² and scene
    V_S·(μ − D̄)² are quadratic in the signal μ − D̄.

    Parameters
    ----------
    mu
        Raw region means μ (DN), scalar or 1-D.
    A, sigma_c2
        Noise model (eq. 41).
    dark_spatial_var
        Spatial variance of the dark reference D̂_D over the region (DN²).
    sigma_K2
        Spatial variance σ_K² of K (sec. II-B).
    V_S
        Scene variation of the surface (eq. 57).
    black_level
        b0 (DN): no shot noise below it.
    dark_mean
        D̄, mean dark level (DN, black level included) where the signal starts; default
        ``black_level`` (no dark current).

    Raises
    ------
    CcdError
        Negative variances, non-finite or too-low intensities (μ below the dark level).
    """
    m = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    if m.ndim != 1 or m.size == 0 or not np.all(np.isfinite(m)):
        raise CcdError("mu", "give one or more finite intensities (1-D)")
    for key, val in (("A", A), ("sigma_c2", sigma_c2), ("dark_spatial_var", dark_spatial_var),
                     ("sigma_K2", sigma_K2), ("V_S", V_S)):
        if not (math.isfinite(val) and val >= 0):
            raise CcdError(key, f"must be finite and >= 0, got {val} (clamp an estimate "
                                "consistent with zero to 0)")
    b0 = float(black_level)
    dbar = b0 if dark_mean is None else float(dark_mean)
    if dbar < b0:
        raise CcdError("dark_mean", f"dark mean {dbar} is below the black level {b0}")
    if np.any(m < dbar):
        raise CcdError("mu", f"intensities must be >= the dark level {dbar:g} DN; got "
                             f"min {m.min():g}")
    sig2 = (m - dbar) ** 2
    comps = {
        "dark spatial": np.full(m.shape, float(dark_spatial_var)),
        "sigma_C^2": np.full(m.shape, float(sigma_c2)),
        "shot noise": float(A) * (m - b0),
        "K variation": float(sigma_K2) * (1.0 + float(V_S)) * sig2,
        "scene": float(V_S) * sig2,
    }
    total = np.sum(list(comps.values()), axis=0)
    if np.any(total <= 0):
        raise CcdError("variance_budget", "total variance is zero: nothing to apportion")
    fracs = {k: v / total for k, v in comps.items()}
    params = {"A": float(A), "sigma_c2": float(sigma_c2),
              "dark_spatial_var": float(dark_spatial_var), "sigma_K2": float(sigma_K2),
              "V_S": float(V_S), "black_level": b0, "dark_mean": dbar}
    return VarianceBudget(mu=m, components=comps, fractions=fracs, parameters=params)
