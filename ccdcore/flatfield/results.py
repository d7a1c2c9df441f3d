"""The results of the flat-field correction of :mod:`ccdcore.flatfield.fit` (de Lasarte et al.
2007): the gain and offset maps G, O with what they were made from (:class:`FlatField`, one
:class:`FlatChannel` per channel) and the correction DL_c = O + G·DL they apply (eq. 2,
:func:`correct`); the frozen results of the base-image recommendation, the base-image study, the
zero-dark check, the comparison of offset settings and that of G/O with K̂; the defaults of the
flag rule and of the zero-dark warning (the rules are stated in the docstring of
:mod:`ccdcore.flatfield.fit`).

Every name here is re-exported by :mod:`ccdcore.flatfield.fit`.

Public objects
--------------
FlatChannel, FlatField
    Per-channel summary; the result with G, O, flags, DL_0/DL_B moments, ``correct()``, ``maps()``.
FlatChannelSummary, FlatFieldSummary
    The records ``calibration.json`` stores (``estimates["flat_field"]``): ``summary()`` of a
    :class:`FlatChannel` and a :class:`FlatField`, with ``rows()``.
correct(frame, G, O)
    DL_c = O + G·DL as float32 (for saved maps).
BaseRecommendation, BaseStudy, ZeroDark, SettingsComparison, KMapComparison
    The results of :func:`~ccdcore.flatfield.fit.recommend_base`,
    :func:`~ccdcore.flatfield.fit.base_image_study`, :func:`~ccdcore.flatfield.fit.zero_dark`,
    :func:`~ccdcore.flatfield.fit.compare_dark_settings` and
    :func:`~ccdcore.flatfield.fit.compare_with_k_map`.
NOISE_LIMIT, WINDOW, ZERO_LIMIT
    Defaults of the flag rule and of the zero-dark warning.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common import json_safe
from ..dark.model import DarkModelSummary
from ..errors import CcdError
from .check import HeldOutCheck
from ..map_names import MapName
from ..records import OMIT_NONE, Record, Row
from ..stats import MomentsResult
from .uniformity import Linearity

__all__ = ["FlatChannel", "FlatField", "FlatChannelSummary", "FlatFieldSummary", "correct",
           "BaseRecommendation", "BaseStudy", "ZeroDark", "SettingsComparison",
           "KMapComparison", "NOISE_LIMIT", "WINDOW", "ZERO_LIMIT", "group_words"]


def group_words(key: Any) -> str:
    """A flat group's key ``(level, exposure)`` in words: ``"level 3, exposure 0.04 s"``
    (``–`` for what the frames do not say; the exposure to 6 significant digits)."""
    level, t = key
    return (f"level {'–' if level is None else level}, exposure "
            + ("–" if t is None else f"{t:g} s"))

#: c of the flag rule Δ <= c·σ_Δ
NOISE_LIMIT = 5.0
#: side of the neighbourhood giving G at flagged pixels
WINDOW = 9
#: fraction of zero dark pixels above which the dark image counts as clipped at zero
ZERO_LIMIT = 0.01


# --------------------------------------------------------------------------------------------
# G and O
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlatChannelSummary(Record):
    """A :class:`FlatChannel` as ``calibration.json`` stores it (``flat_field.channels[i]``)."""

    #: the channel's name (``L``, ``R``, ``G``, ``B``, ``Gr`` ...)
    name: str
    #: k, the level the channel is corrected to (eq. 3: G = k / (DL_B − DL_0)), DN; ``None``:
    #: not finite
    k: float | None
    #: ⟨DL_0⟩ and ⟨DL_B⟩, the channel's mean dark and base levels, DN
    dark_level: float | None
    base_level: float | None
    #: pixels flagged by the flag rule (G from their neighbourhood) and pixels of the channel
    n_flagged: int
    n_pixels: int
    #: fraction of the dark pixel values equal to 0 (a zero-clipped dark image above
    #: :data:`ZERO_LIMIT`); ``None``: not counted
    dark_zero_fraction: float | None = None

    def rows(self) -> tuple[Row, ...]:
        """k, ⟨DL_0⟩, ⟨DL_B⟩, the flagged pixels and the dark pixels at 0."""
        zero = self.dark_zero_fraction
        return (Row("k", self.k, None, "DN", "the level the channel is corrected to "
                                             "(eq. 3: G = k / (DL_B − DL_0))"),
                Row("⟨DL_0⟩", self.dark_level, None, "DN", "mean level of the dark image"),
                Row("⟨DL_B⟩", self.base_level, None, "DN", "mean level of the base image"),
                Row("flagged", self.n_flagged, None, "pixels",
                    f"of {self.n_pixels}: DL_B − DL_0 not above the noise, G taken from the "
                    "neighbourhood"),
                Row("dark pixels at 0", None if zero is None else 100.0 * zero, None, "%",
                    "dark pixel values equal to 0: above "
                    f"{100 * ZERO_LIMIT:g} % the dark image is clipped at zero"))


@dataclass(frozen=True)
class FlatChannel:
    """One channel of a :class:`FlatField`: k, ⟨DL_0⟩, ⟨DL_B⟩ (DN), flags and zero-dark pixels."""

    name: str
    k: float
    dark_level: float
    base_level: float
    n_flagged: int
    n_pixels: int
    dark_zero_fraction: float | None = None

    def summary(self) -> FlatChannelSummary:
        """The record ``calibration.json`` stores (non-finite numbers as ``None``)."""
        return FlatChannelSummary(
            name=str(self.name), k=json_safe(self.k), dark_level=json_safe(self.dark_level),
            base_level=json_safe(self.base_level), n_flagged=int(self.n_flagged),
            n_pixels=int(self.n_pixels), dark_zero_fraction=json_safe(self.dark_zero_fraction))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


@dataclass(frozen=True)
class FlatFieldSummary(Record):
    """A :class:`FlatField` as ``calibration.json`` stores it (``estimates["flat_field"]``): what
    the maps G, O (eqs. 3–4 of de Lasarte et al. 2007) were made from, without the maps."""

    #: ``"mono"``, ``"rgb"`` or ``"bayer-rggb"`` ..., and the frames' shape ((H, W) or (H, W, 3))
    layout: str
    shape: tuple[int, ...]
    #: frames averaged into the dark image DL_0 and into the base image DL_B
    n_dark: int
    n_base: int
    #: the per-channel figures, in channel order
    channels: tuple[FlatChannelSummary, ...]
    #: pixels flagged by the flag rule, all channels
    n_flagged: int
    #: c of the flag rule Δ <= c·σ_Δ, the side of the neighbourhood giving G at flagged pixels
    #: (pixels), and the rule in words
    noise_limit: float
    window: int
    flag_rule: str
    #: the base flat group ``(level, exposure in s)`` (``None``: base frames given directly)
    base: tuple[int | None, float | None] | None
    #: the offset setting and the dark frames' exposure (s) when known
    setting: str | None
    dark_exposure: float | None
    #: decisions taken (setting chosen, base recommended, zero-clipped dark image ...)
    notes: tuple[str, ...]
    #: where DL_0 came from when not the average of dark frames at the flats' exposure:
    #: ``"model"`` (the dark model o + c·t at the base exposure, :mod:`ccdcore.dark.model`) or
    #: ``"zero"`` (no dark frames: de Lasarte's zero-dark form, DL_0 = 0); absent otherwise
    dark_source: str | None = field(default=None, metadata=OMIT_NONE)
    #: the dark model's summary when DL_0 came from it
    dark_model: DarkModelSummary | None = field(default=None, metadata=OMIT_NONE)
    #: the held-out check (:mod:`ccdcore.flatfield.check`) when made
    held_out: HeldOutCheck | None = field(default=None, metadata=OMIT_NONE)

    def base_text(self) -> str:
        """The base image as the report names it: ``"level 3, exposure 0.04 s"``."""
        if self.base is None:
            return "n/a"
        return group_words(self.base)

    def _dark_row(self) -> Row:
        """The dark image DL_0: frames averaged, the dark model at an exposure, or zero."""
        at = "" if self.dark_exposure is None else f", exposure {self.dark_exposure:g} s"
        if self.dark_source == "zero":
            return Row("dark image", 0, None, "frames", "no dark frames: de Lasarte's zero-dark "
                       "form, DL_0 = 0 (the black level stays in G and O)", "zero (DL_0 = 0)")
        if self.dark_source == "model":
            m = self.dark_model
            return Row("dark image", self.n_dark, None, "frames",
                       f"DL_0 = o + c·t from the dark model of {self.n_dark} biases and darks"
                       + ("" if m is None or m.temperature is None
                          else f" at {m.temperature:g} °C") + at,
                       f"dark model ({self.n_dark} frames)")
        return Row("dark image", self.n_dark, None, "frames", "frames averaged into DL_0" + at)

    def rows(self) -> tuple[Row, ...]:
        """The offset setting, the base and dark images, the flagged pixels, k per channel,
        the held-out check and the largest fraction of dark pixels at 0."""
        out = [Row("correction", None, None, "", "corrected = O + G·raw, pixel by pixel, which "
                   "removes the dark image, the PRNU and the vignetting", "DL_c = O + G·DL"),
               Row("offset setting", None, None, "", "the camera offset setting the maps are for",
                   self.setting or "none named"),
               Row("base image", self.n_base, None, "frames",
                   "the flat group averaged into DL_B",
                   f"{self.base_text()} ({self.n_base} frames)"),
               self._dark_row(),
               Row("flagged pixels", self.n_flagged, None, "pixels",
                   f"DL_B − DL_0 not above {self.noise_limit:g}·σ: G taken from the "
                   f"{self.window}×{self.window} neighbourhood")]
        out += [Row(f"k, {c.name}", c.k, None, "DN",
                    "target level k of the channel (eq. 3: G = k / (DL_B − DL_0))")
                for c in self.channels]
        if self.held_out is not None:
            out += list(self.held_out.rows())
        zeros = [c.dark_zero_fraction for c in self.channels if c.dark_zero_fraction is not None]
        if zeros:
            worst = max(zeros)
            out.append(Row("dark pixels at 0", 100.0 * worst, None, "%",
                           "largest fraction of dark pixel values equal to 0 (a channel's); "
                           f"above {100 * ZERO_LIMIT:g} % the dark image is clipped at zero",
                           f"{100.0 * worst:.3g} %: the dark image is clipped at zero"
                           if worst > ZERO_LIMIT else None))
        return tuple(out)


@dataclass(frozen=True, eq=False)
class FlatField:
    """Gain and offset maps G, O (eqs. 3–4) and what they were made from.

    Attributes
    ----------
    G, O
        float32 maps of the frames' shape ((H, W) or (H, W, 3); Bayer: the full mosaic).
    flags
        bool map: Δ = DL_B − DL_0 not positive or noise dominated (the flag rule of
        :mod:`ccdcore.flatfield.fit`).
    dark, base
        :class:`~ccdcore.stats.MomentsResult` of DL_0 and DL_B (per-pixel mean, variance, n).
    layout
        ``"mono"``, ``"rgb"`` or ``"bayer-rggb"`` ...
    channels
        :class:`FlatChannel` per channel.
    noise_limit, window
        c and the neighbourhood of the flag rule.
    base_key, setting, dark_exposure
        The base group ``(level, exposure)``, offset setting and dark exposure when known.
    notes
        Decisions taken (setting chosen, zero-clipped dark image ...).
    dark_source
        ``None`` (DL_0 the average of dark frames), ``"model"`` (the dark model o + c·t at the
        base exposure, :mod:`ccdcore.dark.model`) or ``"zero"`` (no dark frames: DL_0 = 0).
    dark_model
        The :class:`~ccdcore.dark.model.DarkModel` when DL_0 came from it.
    held_out
        The held-out check (:mod:`ccdcore.flatfield.check`), when made.
    base_frames, dark_frames
        Relative paths of the frames averaged into DL_B and into (or fitted for) DL_0.
    """

    G: NDArray[np.float32]
    O: NDArray[np.float32]
    flags: NDArray[np.bool_]
    dark: MomentsResult
    base: MomentsResult
    layout: str
    channels: tuple[FlatChannel, ...]
    noise_limit: float = NOISE_LIMIT
    window: int = WINDOW
    base_key: tuple | None = None
    setting: str | None = None
    dark_exposure: float | None = None
    notes: tuple[str, ...] = ()
    dark_source: str | None = None
    dark_model: Any = None
    held_out: HeldOutCheck | None = None
    base_frames: tuple[str, ...] = ()
    dark_frames: tuple[str, ...] = ()

    flag_rule = ("flagged where DL_B − DL_0 <= c·sqrt(s²_B/n_B + s²_0/n_0); there "
                 "G = k / (mean DL_B − DL_0 of the unflagged pixels of the channel in a "
                 "window x window neighbourhood), O = ⟨DL_0⟩ − G·DL_0")

    @property
    def shape(self) -> tuple[int, ...]:
        return self.G.shape

    def channel(self, name: str) -> FlatChannel:
        for c in self.channels:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def G_rel_err(self) -> NDArray[np.float64]:
        """Per-pixel relative standard error of G from the temporal noise of DL_B and DL_0:
        σ_G/G = σ_Δ/Δ (NaN where flagged or where one frame gives no variance)."""
        dvar = self.dark.var / self.dark.n if self.dark.n > 0 else 0.0
        sd = np.sqrt(self.base.var / self.base.n + dvar)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = sd / (self.base.mean - self.dark.mean)
        out[self.flags] = np.nan
        return out

    def correct(self, frame: ArrayLike, *, where: Any = "frame") -> NDArray[np.float32]:
        """DL_c = O + G·DL (eq. 2), float32."""
        return correct(frame, self.G, self.O, where=where)

    def maps(self) -> dict[str, NDArray[np.float32]]:
        """float32 maps for a calibration product: ``flat_G``, ``flat_O``, ``flat_flags`` (0/1),
        ``flat_dark`` (DL_0), ``flat_base`` (DL_B)."""
        return {MapName.FLAT_G: self.G, MapName.FLAT_O: self.O,
                MapName.FLAT_FLAGS: self.flags.astype(np.float32),
                MapName.FLAT_DARK: self.dark.mean.astype(np.float32),
                MapName.FLAT_BASE: self.base.mean.astype(np.float32)}

    def summary(self) -> FlatFieldSummary:
        """The record ``calibration.json`` stores (no maps; non-finite numbers as ``None``)."""
        base = None
        if self.base_key is not None:
            level, t = self.base_key
            base = (None if level is None else int(level), json_safe(t))
        return FlatFieldSummary(
            layout=str(self.layout), shape=tuple(int(n) for n in self.shape),
            n_dark=int(self.dark.n), n_base=int(self.base.n),
            channels=tuple(c.summary() for c in self.channels),
            n_flagged=int(self.flags.sum()), noise_limit=json_safe(self.noise_limit),
            window=int(self.window), flag_rule=self.flag_rule, base=base,
            setting=self.setting, dark_exposure=json_safe(self.dark_exposure),
            notes=tuple(str(n) for n in self.notes), dark_source=self.dark_source,
            dark_model=None if self.dark_model is None else self.dark_model.summary(),
            held_out=self.held_out)

    def to_dict(self) -> dict[str, Any]:
        """Summary (no maps), JSON-friendly: :meth:`summary` as a dict."""
        return self.summary().to_dict()


def correct(frame: ArrayLike, G: ArrayLike, O: ArrayLike, *,
            where: Any = "frame") -> NDArray[np.float32]:
    """DL_c = O + G·DL (eq. 2 of de Lasarte et al. 2007), computed in float64, returned float32.

    Raises
    ------
    CcdError
        The frame's shape differs from the maps' (``where`` names the frame), or it holds NaN.
    """
    D = np.asarray(frame)
    if D.shape != np.shape(G) or D.shape != np.shape(O):
        raise CcdError(where, f"frame shape {D.shape} differs from the flat-field maps' "
                              f"{np.shape(G)} (another camera mode or layout?)")
    out = np.multiply(G, D, dtype=np.float64)
    out += O
    return out.astype(np.float32)


# --------------------------------------------------------------------------------------------
# the studies (items 5-7)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BaseRecommendation:
    """The recommended base correction image and every candidate's numbers.

    ``candidates``: one dict per flat group: ``key``, ``n_frames``, ``mean_dn`` and
    ``p_high_dn`` per channel, ``in_linear_range``, ``distance`` (to the middle of the range,
    in range widths; None outside).
    """

    key: tuple[Any, Any]
    reason: str
    rule: str
    candidates: tuple[dict, ...]
    linearity: Linearity

    def to_dict(self) -> dict[str, Any]:
        return {"base": list(self.key), "reason": self.reason, "rule": self.rule,
                "candidates": [dict(c, key=list(c["key"])) for c in self.candidates]}


@dataclass(frozen=True)
class BaseStudy:
    """SNUP after correction of every image group with every candidate base (Fig. 3, Tables 3–5).

    ``rows``: dicts ``base`` (``(level, exposure)``, None = uncorrected), ``image``, ``channel``,
    ``snup_mean``, ``snup_std`` (over the group's frames), ``n``, ``image_mean_dn``,
    ``base_mean_dn``, ``self`` (the image group is the base: optimistic, its noise is in G).
    """

    rows: tuple[dict, ...]
    setting: str | None
    nearest: bool
    recommended: tuple[Any, Any] | None

    def table(self, channel: str) -> dict[tuple, dict[tuple, float]]:
        """``{base: {image: snup_mean}}`` for one channel."""
        out: dict[tuple, dict[tuple, float]] = {}
        for r in self.rows:
            if r["channel"] == channel:
                out.setdefault(r["base"], {})[r["image"]] = r["snup_mean"]
        return out

    def to_dict(self) -> dict[str, Any]:
        def k(v):
            return None if v is None else list(v)
        return {"setting": self.setting, "nearest": self.nearest,
                "recommended": k(self.recommended),
                "rows": [dict(r, base=k(r["base"]), image=k(r["image"])) for r in self.rows]}


@dataclass(frozen=True)
class ZeroDark:
    """Fraction of dark pixel values equal to zero, per channel; ``clipped`` above ``limit``."""

    fractions: dict[str, float]
    limit: float
    clipped: bool
    warning: str | None

    @staticmethod
    def warning_text(fraction: float) -> str:
        return (f"{100 * fraction:.1f} % of the dark pixel values are 0: the dark image is "
                "clipped at zero (a 'zero dark image' offset setting). The negative half of the "
                "dark noise and the true dark level are lost, so DL_0 is biased and the "
                "correction is worse (de Lasarte et al., Table 2); raise the camera offset "
                "until no dark pixel reads 0")

    def to_dict(self) -> dict[str, Any]:
        return {"fractions": dict(self.fractions), "limit": self.limit, "clipped": self.clipped,
                "warning": self.warning}


@dataclass(frozen=True)
class SettingsComparison:
    """Table 2: mean SNUP after correction of the images in the linear range, per setting.

    ``rows``: dicts ``setting``, ``channel``, ``snup_mean``, ``snup_std`` (over images), ``n``,
    ``zero_fraction``, ``base``; ``zero_dark``: :class:`ZeroDark` per setting.
    """

    rows: tuple[dict, ...]
    zero_dark: dict[str, ZeroDark]

    def to_dict(self) -> dict[str, Any]:
        return {"rows": [dict(r, base=list(r["base"])) for r in self.rows],
                "zero_dark": {s: z.to_dict() for s, z in self.zero_dark.items()}}


@dataclass(frozen=True)
class KMapComparison:
    """G/O against K̂ on the same held-out uniform-field frames (:mod:`ccdcore.flatfield.fit`).

    ``rows``: per channel ``snup_raw``, ``snup_G``, ``snup_K`` (mean over the held-out frames;
    the K̂-corrected frame (D − D̂_D)/K̂ gets the channel's mean dark level added back, as eq. 2
    keeps it, so that all three SNUPs divide by comparable means),
    ``snup_limit`` (the shot-noise limit of one frame, from its temporal variance: 100·σ_t/mean),
    and with a true flat field ``residual_G_pct`` / ``residual_K_pct`` (100·std of the estimated
    flat field divided by the truth, normalised) and ``residual_hf_G_pct`` / ``residual_hf_K_pct``
    (the same after dividing out the local mean in the K̂ window: the PRNU part).
    """

    rows: tuple[dict, ...]
    evaluate: tuple[Any, Any]
    base: tuple[Any, Any]
    configurations: tuple[tuple, ...]
    window: int
    conclusion: str

    def to_dict(self) -> dict[str, Any]:
        return {"rows": list(self.rows), "evaluate": list(self.evaluate), "base": list(self.base),
                "configurations": [list(c) for c in self.configurations], "window": self.window,
                "conclusion": self.conclusion}
