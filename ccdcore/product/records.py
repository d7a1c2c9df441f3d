"""What a calibration product holds besides its maps, as typed records: the estimates made
(:class:`ProductEstimates`), and where they came from (:class:`Provenance`, with the parameters
of each step in :class:`ProductSteps`).

Each estimate is the summary record of its result (:class:`ccdcore.records.Record`): the
estimator's result gives it (``PhotonTransfer.summary()``, ``DarkReference.summary()``, ...),
``calibration.json`` stores it (``to_dict``) and :func:`ccdcore.product.make.load_product` reads it
back, checked (``from_dict``). The report, the CLI's summary and the app read its attributes.

Public objects
--------------
ProductEstimates
    The estimates of a product, each ``None`` when it was not made.
Provenance, ProductSteps
    The version, session, date and scheduler of a product, and the method and parameters of
    each step.
NoiseStep, DarkStep, FixedPatternStep, FlatFieldStep, ResponseStep, SceneStep, EmvaStep
    The parameters of one step.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

from ..dark.map import DarkSummary
from ..flatfield.results import FlatFieldSummary
from ..kmap_kernels import FixedPatternSummary
from ..planning import PlanSummary
from ..ptc_fit import PhotonTransferSummary
from ..records import OMIT_NONE, Record
from ..response.methods import ResponseSummary
from ..scene import CorrectionCheckSummary, SceneSummary

__all__ = ["ProductEstimates", "Provenance", "ProductSteps", "NoiseStep", "DarkStep",
           "FixedPatternStep", "FlatFieldStep", "ResponseStep", "SceneStep", "EmvaStep"]


def _absent():
    """A field whose key is left out of the JSON when it is ``None``."""
    return field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True)
class ProductEstimates(Record):
    """The estimates of a calibration product (the ``estimates`` object of
    ``calibration.json``); each is ``None`` (its key absent) when it was not made, and
    :attr:`ccdcore.product.make.CalibrationProduct.skipped` says why.

    Attributes
    ----------
    noise
        Photon transfer: A, σ²_C and the fit (Healey & Kondepudy 1994, eqs. 37–42, 59–67).
    dark
        The dark reference D̂_D and its hot and dead pixels (sec. V-A).
    fixed_pattern
        K̂ (eqs. 45–50, sec. V-B).
    plan
        The acquisition plan n1, n2 (sec. V-B), with the session's shortfalls.
    correction_check
        The correction check on a max-intensity scene frame (sec. VII-A).
    flat_field
        The flat-field gain and offset maps (de Lasarte et al. 2007).
    response
        The inverse response g per channel with its band and noise terms (Tsin et al. 2001).
    scene
        Patch name -> scene variation V_S (eqs. 53–58, sec. VI).
    """

    noise: PhotonTransferSummary | None = _absent()
    dark: DarkSummary | None = _absent()
    fixed_pattern: FixedPatternSummary | None = _absent()
    plan: PlanSummary | None = _absent()
    correction_check: CorrectionCheckSummary | None = _absent()
    flat_field: FlatFieldSummary | None = _absent()
    response: ResponseSummary | None = _absent()
    scene: dict[str, SceneSummary] | None = _absent()

    def made(self) -> tuple[str, ...]:
        """The names of the estimates made (``"noise"``, ``"dark"``, ...), in the order of
        ``calibration.json``."""
        return tuple(f.name for f in fields(self) if getattr(self, f.name) is not None)


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NoiseStep(Record):
    """Photon transfer: the method and the region of interest ``(x, y, w, h)`` it used."""

    method: str
    roi: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class DarkStep(Record):
    """The dark reference: the method, the number of frames s and the hot/dead rules."""

    method: str
    s: int
    hot_rule: str
    dead_rule: str


@dataclass(frozen=True)
class FixedPatternStep(Record):
    """K̂: the method, the window of the local mean and p of the centre ± p·σ̂ rule."""

    method: str
    window: int
    p: float


@dataclass(frozen=True)
class FlatFieldStep(Record):
    """The flat field: the method, the base set (setting and exposure) and the flag rule."""

    method: str
    base: tuple[int | float | str | None, ...]
    flag_rule: str


@dataclass(frozen=True)
class ResponseStep(Record):
    """The response: the method, the bloom radius (pixels) and the bracket's files."""

    method: str
    bloom_radius: int
    files: tuple[str, ...]


@dataclass(frozen=True)
class SceneStep(Record):
    """The scene variation: the method."""

    method: str


@dataclass(frozen=True)
class EmvaStep(Record):
    """The EMVA 1288 figures: the method and the constants it used."""

    method: str
    sensitivity_fraction: float
    linearity_range: tuple[float, float]
    sigma2_y_dark_floor: float


@dataclass(frozen=True)
class ProductSteps(Record):
    """The method and parameters of each step of a product (``None``: not run)."""

    noise: NoiseStep | None = _absent()
    dark: DarkStep | None = _absent()
    fixed_pattern: FixedPatternStep | None = _absent()
    flat_field: FlatFieldStep | None = _absent()
    response: ResponseStep | None = _absent()
    scene: SceneStep | None = _absent()
    emva1288: EmvaStep | None = _absent()


@dataclass(frozen=True)
class Provenance(Record):
    """Where a product came from (the ``provenance`` object of ``calibration.json``).

    Attributes
    ----------
    ccdcore
        The version that made it.
    session, source, n_frames
        The session's label, how it was described (``"manifest"``, ...) and its frame count.
    session_hash
        SHA-256 of the session's content (:meth:`ccdcore.session.Session.content_hash`).
    date
        When it was made (UTC, ISO 8601).
    scheduler
        Where the reductions ran: ``"streamed (this process)"`` or a Dask scheduler.
    steps
        The method and parameters of each step.

    Products of earlier releases lack ``session_hash``, ``date`` and ``scheduler`` (``None``).
    """

    ccdcore: str | None = _absent()
    session: str | None = _absent()
    source: str | None = _absent()
    n_frames: int | None = _absent()
    session_hash: str | None = _absent()
    date: str | None = _absent()
    scheduler: str | None = _absent()
    steps: ProductSteps | None = _absent()
