"""Calibration products in the app: open one, see what it holds, apply it to the session's frames.

A calibration product is the folder :meth:`ccdcore.product.CalibrationProduct.save` writes
(``calibration.json`` + ``maps/*.exr``). The panel opens one (:func:`ccdcore.product.load_product`,
inside the app's allowed roots) and lists its camera, every estimate with its headline numbers
(the EMVA 1288 figures too, when the product has them), its maps with their sizes, the estimates
it skipped and why, and its provenance. It applies the product to any frame of the loaded
session -- :meth:`~ccdcore.product.CalibrationProduct.correct` (the flat field O + G·DL of
de Lasarte et al. 2007, or (D − D̂_D)/K̂, eq. 51 of Healey & Kondepudy 1994) or
:meth:`~ccdcore.product.CalibrationProduct.linearise` (the inverse response g of Tsin et al.
2001) -- and shows the frame before and after in two linked views, with a pixel readout of both
and the SNUP (eq. 5 of de Lasarte et al., :func:`ccdcore.uniformity.snup`) of both over the
whole frame or the part in view. It writes corrected frames as float32 files
(:func:`ccdcore.product.apply_product`). The product may also be made from the loaded session
in the app (:func:`ccdcore.product.calibrate`, unsaved).

Every number comes from ccdcore; this module only reads, arranges and shows them.

Public objects
--------------
ProductPanel(state)
    The panel (a :class:`param.Parameterized`; :meth:`ProductPanel.panel` is its layout), which
    the Session page shows in its *Calibration product* tab.
AppliedFrame, apply_frame(product, session, record, mode)
    One frame corrected (or linearised) by the product, with the SNUP of both.
SnupPair, snup_pair(raw, corrected, layout, roi=None, where="frame")
    The SNUP before and after (each ``None`` with ccdcore's reason when undefined).
save_corrected(product, paths, out_dir, linearise=False)
    :func:`ccdcore.product.apply_product` frame by frame, with progress and cancel.
view_roi(x_range, y_range, plane_shape, frame_shape)
    The frame pixels ``(x, y, w, h)`` a view shows (``None``: the whole frame).
camera_markdown(product, folder), estimates_frame(product), estimate_headline(name, summary),
maps_frame(product), skipped_frame(product), provenance_markdown(product), snup_table(pair)
    What the summary and the SNUP table show (pure functions of ccdcore's results).
CORRECT, LINEARISE
    The two modes.
"""
from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
import param

from ccdcore.common import format_pm, format_size
from ccdcore.errors import CcdError
from ccdcore.io import read_header
from ccdcore.product import (ESTIMATE_STEPS, CalibrationProduct, MapName, apply_product,
                             calibrate, load_product, requirement)
from ccdcore.progress import checkpoint
from ccdcore.session import FrameRecord, Session
from ccdcore.uniformity import SnupResult, snup

from . import plots
from .batch import batched, in_document
from .image_view import ImageView, view_pane
from .latest import Latest
from .state import AppState
from .pages._choices import set_choices
from .pages._styles import KEY_VALUE_CSS, MUTED, TABLE_CSS

__all__ = ["ProductPanel", "AppliedFrame", "apply_frame", "SnupPair", "snup_pair",
           "save_corrected", "view_roi", "camera_markdown", "estimates_frame",
           "estimate_headline", "maps_frame", "skipped_frame", "provenance_markdown",
           "snup_table", "CORRECT", "LINEARISE", "MAX_LISTED"]

#: the modes: correct each frame (flat field or dark and K̂), or linearise it (inverse response)
CORRECT, LINEARISE = "correct", "linearise"
#: SNUP over the whole frame or over the part in view
WHOLE, IN_VIEW = "frame", "view"
#: save the chosen frame or every frame of its role
ONE, ROLE = "frame", "role"
#: at most this many written paths are listed (the rest are counted)
MAX_LISTED = 20
#: frame width of the before and after views (px; two fit side by side in a 1400 px window);
#: the height follows, pixels are square
IMAGE_WIDTH = 360
#: roles offered first (frames a correction is meant for), then the session's other roles
_ROLE_ORDER = ("scene", "flat", "bracket", "fixed_pattern", "ptc", "dark")

#: what each map of a product is (CalibrationProduct.maps)
MAP_MEANINGS: dict[str, str] = {
    MapName.DARK: "dark reference D\u0302_D (DN)",
    MapName.DARK_VAR: "temporal variance of the dark frames (DN\u00b2)",
    MapName.HOT: "hot pixels (1 = flagged)", MapName.DEAD: "dead pixels (1 = flagged)",
    MapName.K: "fixed-pattern map K\u0302 (eq. 49)", MapName.K_VAR: "error variance of K\u0302",
    MapName.N1_USED: "configurations used per pixel n'_1", MapName.FLAT_G: "flat-field gain G",
    MapName.FLAT_O: "flat-field offset O (DN)",
    MapName.FLAT_FLAGS: "flagged pixels of the flat field",
    MapName.FLAT_DARK: "dark image DL_0 (DN)", MapName.FLAT_BASE: "base image DL_B (DN)"}

_METHODS = {"flat_field": "the flat field: DL_c = O + G\u00b7DL (de Lasarte et al. 2007)",
            "fixed_pattern": "D_C = (D \u2212 D\u0302_D)/K\u0302 (eq. 51)",
            "dark": "D \u2212 D\u0302_D (no K\u0302 in the product)"}
_MODE_LABELS = {"flat_field": "Correct (O + G\u00b7DL)",
                "fixed_pattern": "Correct ((D \u2212 D\u0302_D)/K\u0302)",
                "dark": "Correct (D \u2212 D\u0302_D)"}
_LINEARISE_LABEL = "Linearise (inverse response g)"


def _code(text: Any) -> str:
    """``text`` as a Markdown code span."""
    return "`" + str(text).replace("`", "'") + "`"


def _num(value: Any, fmt: str = ".4g") -> str:
    """A JSON number for people (``?`` when missing or not finite)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "?"
    return format(value, fmt)


# ----------------------------------------------------------------------------- summary -------
def camera_markdown(product: CalibrationProduct, folder: str | Path | None = None) -> str:
    """The product's camera, frame size, correction and source as a two-column table."""
    cam = product.camera
    rows = [("Camera", cam.name or "(unnamed)"),
            ("ADC bits", "unknown" if cam.bits is None else str(cam.bits)),
            ("Layout", cam.layout),
            ("Black level", "not given" if cam.black_level is None else
             f"{cam.black_level:g} DN"),
            ("Frame size", "no frame maps" if product.shape is None else
             f"{format_size(product.shape)} px"),
            ("Corrects with", _METHODS[product.method] if product.shape is not None else
             "nothing (no dark reference nor flat field)"),
            ("Linearises", "yes (inverse response g)" if "response" in product.estimates
             else "no (no response curve)")]
    rows.append(("Folder", "not saved (calibrated in the app)" if folder is None
                 else _code(folder)))
    return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)


def _noise(e: Mapping[str, Any]) -> str:
    chi = f"\u03c7\u00b2 = {_num(e.get('chi2'), '.3g')} for {e.get('dof', '?')} dof"
    return (f"A = {format_pm(e.get('A'), e.get('A_err'))} DN/e\u207b, "
            f"\u03c3\u00b2_C = {format_pm(e.get('sigma_c2'), e.get('sigma_c2_err'))} DN\u00b2; "
            f"{chi} (Q = {_num(e.get('Q'), '.2g')}, {e.get('verdict', '?')})")


def _dark(e: Mapping[str, Any]) -> str:
    return (f"D\u0302_D mean {format_pm(e.get('mean'), e.get('mean_sem'))} DN from "
            f"s = {e.get('s', '?')} frames, spatial \u03c3 {_num(e.get('spatial_std'))} DN; "
            f"{e.get('n_hot', '?')} hot, {e.get('n_dead', '?')} dead pixels")


def _fixed_pattern(e: Mapping[str, Any]) -> str:
    return (f"K\u0302 mean {_num(e.get('mean'), '.5g')}, spatial \u03c3 "
            f"{_num(e.get('spatial_std'), '.3g')} from n1 = {e.get('n1', '?')} configurations "
            f"\u00d7 n2 = {e.get('n2', '?')} frames (window {e.get('window', '?')}, "
            f"p = {e.get('p', '?')})")


def _plan(e: Mapping[str, Any]) -> str:
    return (f"n1 = {e.get('n1_required', '?')} configurations \u00d7 n2 = "
            f"{e.get('n2_required', '?')} frames (n\u0302_1 = {e.get('n1_hat', '?')}); "
            f"{len(e.get('warnings') or [])} warning(s)")


def _percent(fraction: Any) -> str:
    return "?" if _num(fraction) == "?" else f"{100 * fraction:.1f} %"


def _check(e: Mapping[str, Any]) -> str:
    return (f"{_percent(e.get('frac_gt_1q'))} of the pixels changed by more than 1 q, "
            f"{_percent(e.get('frac_gt_2q'))} by more than 2 q (largest "
            f"{_num(e.get('max_change_q'), '.3g')} q) at mean level "
            f"{_num(e.get('mean_level'), '.4g')} DN")


def _scene(e: Mapping[str, Any]) -> str:
    parts = [f"{name} {format_pm(v.get('V_S'), v.get('V_S_err'))}" for name, v in e.items()
             if isinstance(v, Mapping)]
    return "V_S: " + ("; ".join(parts) if parts else "no patches")


def _flat_field(e: Mapping[str, Any]) -> str:
    base = e.get("base")
    base_text = "?" if not isinstance(base, list) or len(base) != 2 else \
        f"level {base[0]}, {_num(base[1], 'g')} s"
    ks = ", ".join(f"{c.get('name', '?')} {_num(c.get('k'), '.4g')}"
                   for c in e.get("channels") or [] if isinstance(c, Mapping))
    setting = f", setting {e['setting']}" if e.get("setting") else ""
    return (f"base image {base_text} ({e.get('n_base', '?')} frames), {e.get('n_dark', '?')} "
            f"dark frames{setting}; k per channel: {ks or '?'}; {e.get('n_flagged', '?')} "
            "flagged pixels")


def _response(e: Mapping[str, Any]) -> str:
    channels = [str(c) for c in e.get("channels") or []]
    sig = []
    for key, label in (("sigma_s", "\u03c3_s"), ("sigma_c1", "\u03c3_c1"),
                       ("sigma_c2", "\u03c3_c2")):
        vals, errs = e.get(key) or [], e.get(f"{key}_err") or []
        sig.append(f"{label} " + "/".join(
            format_pm(v, errs[i] if i < len(errs) else None) for i, v in enumerate(vals)))
    converged = e.get("converged") or []
    return (f"{e.get('method', '?')} inverse response of channel{'s' if len(channels) != 1 else ''}"
            f" {', '.join(channels) or '?'} over {e.get('levels', '?')} codes; "
            + ", ".join(sig)
            + ("" if all(converged) else "; **not converged**"))


#: the EMVA 1288 figures in a product's headline (keys of :data:`ccdcore.emva_sheet.DATASHEET`)
_EMVA_HEADLINE = ("K", "QE", "sigma_d", "u_e_sat", "DR_dB", "u_I_mean", "DSNU1288", "PRNU1288")


def _emva(e: Mapping[str, Any]) -> str:
    """The headline figures of the datasheet's rows (:func:`ccdcore.emva_sheet.datasheet_rows`),
    those the product has."""
    from ccdcore.emva_sheet import datasheet_rows

    return ", ".join(f"{r.symbol} = {format_pm(r.value, r.error, unit=r.unit)}"
                     for r in datasheet_rows(e)
                     if r.key in _EMVA_HEADLINE and r.value is not None)


#: the EMVA 1288 figures of a product (``CalibrationProduct.emva1288``), listed as an estimate
EMVA = "emva1288"

_HEADLINES = {"noise": _noise, "dark": _dark, "fixed_pattern": _fixed_pattern, "plan": _plan,
              "correction_check": _check, "scene": _scene, "flat_field": _flat_field,
              "response": _response, EMVA: _emva}


def estimate_headline(name: str, summary: Mapping[str, Any]) -> str:
    """One line of the headline numbers of an estimate's JSON summary (``value ± error``,
    :func:`ccdcore.common.format_pm`); an estimate this app does not know lists its keys."""
    func = _HEADLINES.get(name)
    if func is None:
        return "keys: " + ", ".join(sorted(map(str, summary))[:12])
    try:
        return func(summary)
    except (TypeError, ValueError, AttributeError, KeyError, IndexError) as err:
        return f"(cannot summarise: {type(err).__name__}: {err})"


def _purpose(name: str) -> str:
    if name == EMVA:
        return "the EMVA 1288 figures (photon counts of the ptc levels)"
    try:
        return requirement(name).purpose
    except KeyError:
        return ""


def estimates_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per estimate made: its name, what it is, its headline numbers (and the EMVA 1288
    figures when the product has them)."""
    summaries = dict(product.estimates)
    emva = getattr(product, EMVA, None)
    if isinstance(emva, Mapping):
        summaries[EMVA] = emva
    rows = [{"estimate": name, "what": _purpose(name),
             "headline": estimate_headline(name, summary)}
            for name, summary in summaries.items()]
    return pd.DataFrame(rows, columns=["estimate", "what", "headline"])


def maps_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per map: name, what it is, size (width first), dtype and value range."""
    rows = []
    for name in sorted(product.maps):
        m = product.maps[name]
        finite = m[np.isfinite(m)] if m.dtype.kind == "f" else m
        rng = f"{float(finite.min()):.5g} \u2026 {float(finite.max()):.5g}" if finite.size \
            else "no finite values"
        rows.append({"map": name, "what": MAP_MEANINGS.get(name, ""),
                     "size (W\u00d7H)": format_size(m.shape), "dtype": str(m.dtype),
                     "range": rng})
    return pd.DataFrame(rows, columns=["map", "what", "size (W\u00d7H)", "dtype", "range"])


def skipped_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per skipped estimate: name, code and reason."""
    rows = [{"estimate": s.estimate, "code": s.code, "reason": s.reason}
            for s in product.skipped]
    return pd.DataFrame(rows, columns=["estimate", "code", "reason"])


def _params(step: Mapping[str, Any]) -> str:
    parts = []
    for key, value in step.items():
        if key == "method":
            continue
        if isinstance(value, list) and len(value) > 4:
            value = f"{len(value)} items"
        parts.append(f"{key} = {value}")
    return "; ".join(parts)


def provenance_markdown(product: CalibrationProduct) -> str:
    """Which ccdcore, which session, and per step its method and parameters; the product's
    warnings and notes."""
    prov = product.provenance
    lines = [f"Made by ccdcore {prov.get('ccdcore', '?')} from {_code(prov.get('session', '?'))}"
             f" ({prov.get('source', '?')}, {prov.get('n_frames', '?')} frames)."]
    known = ("ccdcore", "session", "source", "n_frames", "steps")
    lines += [f"- {key}: {_code(value)}" for key, value in prov.items()
              if key not in known and isinstance(value, (str, int, float))]
    steps = prov.get("steps")
    if isinstance(steps, Mapping):
        for name, step in steps.items():
            if isinstance(step, Mapping):
                extra = _params(step)
                lines.append(f"- **{name}**: {step.get('method', '?')}"
                             + (f" ({extra})" if extra else ""))
    if product.warnings:
        lines.append("\n**Warnings:**")
        lines += [f"- {w}" for w in product.warnings]
    if product.notes:
        lines.append("\n**Notes:**")
        lines += [f"- {n}" for n in product.notes]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- applying ------
@dataclass(frozen=True)
class SnupPair:
    """SNUP (eq. 5) of a frame before and after; each ``None`` with ccdcore's reason when it is
    undefined (a dark-subtracted frame has mean ≈ 0)."""

    before: SnupResult | None
    after: SnupResult | None
    before_error: str = ""
    after_error: str = ""
    roi: tuple[int, int, int, int] | None = None


def _snup_or_reason(image: np.ndarray, layout: str, roi: Sequence[int] | None,
                    where: str) -> tuple[SnupResult | None, str]:
    try:
        return snup(image, roi=roi, layout=layout, where=where), ""
    except CcdError as err:
        return None, err.problem


def snup_pair(raw: np.ndarray, corrected: np.ndarray, layout: str,
              roi: Sequence[int] | None = None, where: str = "frame") -> SnupPair:
    """:func:`ccdcore.uniformity.snup` of ``raw`` and ``corrected`` over ``roi`` (``(x, y, w, h)``
    in frame pixels; ``None``: the whole frame)."""
    before, berr = _snup_or_reason(raw, layout, roi, where)
    after, aerr = _snup_or_reason(corrected, layout, roi, where)
    box = None if roi is None else tuple(int(v) for v in roi)
    return SnupPair(before, after, berr, aerr, box)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class AppliedFrame:
    """One frame of the session before and after the product, with the SNUP of both over the
    whole frame."""

    relpath: str
    role: str
    mode: str
    layout: str
    raw: np.ndarray
    corrected: np.ndarray
    snup: SnupPair


def _check_size(product: CalibrationProduct, shape: tuple[int, ...], where: Any) -> None:
    """A clear error when a frame of ``shape`` is not the size the product corrects."""
    if product.shape is not None and tuple(shape) != product.shape:
        raise CcdError(where, f"the frame is {format_size(shape)} px, the product corrects "
                              f"{format_size(product.shape)} px frames (another camera, "
                              "binning or layout?)")


def apply_frame(product: CalibrationProduct, session: Session, record: FrameRecord,
                mode: str = CORRECT) -> AppliedFrame:
    """Read ``record`` and apply ``product`` to it: ``product.correct`` or, with
    ``mode="linearise"``, ``product.linearise`` (float32); the SNUP before and after.

    Raises
    ------
    CcdError
        The frame cannot be read, its size differs from the product's maps (correcting), or
        the product refuses it (no response, codes beyond the response's levels ...).
    """
    if mode not in (CORRECT, LINEARISE):
        raise CcdError("mode", f"expected {CORRECT!r} or {LINEARISE!r}, got {mode!r}")
    raw = session.read(record)
    if mode == CORRECT:
        _check_size(product, raw.shape, record.relpath)
    fix = product.linearise if mode == LINEARISE else product.correct
    corrected = fix(raw, name=record.relpath)
    try:
        layout = plots.frame_layout(raw.shape, session.camera.layout)
    except ValueError as err:
        raise CcdError(record.relpath, str(err)) from None
    return AppliedFrame(relpath=record.relpath, role=record.role, mode=mode, layout=layout,
                        raw=raw, corrected=corrected,
                        snup=snup_pair(raw, corrected, layout, where=record.relpath))


def save_corrected(product: CalibrationProduct, paths: Sequence[str | Path],
                   out_dir: str | Path, *, linearise: bool = False) -> list[Path]:
    """:func:`ccdcore.product.apply_product` of ``paths`` into ``out_dir``; the written files.

    When the inputs' base names differ (so their outputs do), each frame is written by its own
    call, with :func:`ccdcore.progress.checkpoint` between them (the app shows progress and can
    cancel between two frames); otherwise one call checks them all and says which collide.
    """
    paths = [Path(p) for p in paths]
    stems = [p.stem for p in paths]
    if len(paths) < 2 or len(set(stems)) != len(stems):
        return apply_product(product, paths, out_dir, linearise=linearise)
    if not linearise:               # every header first: a frame of another size writes nothing
        for p in paths:
            _check_size(product, read_header(p).shape, p)
    written: list[Path] = []
    for i, p in enumerate(paths):
        checkpoint(i, len(paths))
        written += apply_product(product, [p], out_dir, linearise=linearise)
    return written


def view_roi(x_range: tuple[float, float], y_range: tuple[float, float],
             plane_shape: tuple[int, ...], frame_shape: tuple[int, ...]
             ) -> tuple[int, int, int, int] | None:
    """The frame pixels ``(x, y, w, h)`` shown by a view of ``x_range``, ``y_range`` (plot
    coordinates: pixel ``(row, col)`` centred on ``(col, row)``) over a plane of
    ``plane_shape``; a CFA plane (half the frame's size) maps to even frame pixels. ``None``
    when the whole frame is in view; a view outside the plane keeps one pixel."""
    h, w = int(plane_shape[0]), int(plane_shape[1])
    f = max(1, int(frame_shape[0]) // max(h, 1))

    def span(lo: float, hi: float, n: int) -> tuple[int, int]:
        a = min(max(int(math.floor(min(lo, hi) + 0.5)), 0), n - 1)
        b = max(min(int(math.ceil(max(lo, hi) + 0.5)), n), a + 1)
        return a, b

    x0, x1 = span(*x_range, w)
    y0, y1 = span(*y_range, h)
    if (x0, y0, x1, y1) == (0, 0, w, h):
        return None
    return (x0 * f, y0 * f, (x1 - x0) * f, (y1 - y0) * f)


def snup_table(pair: SnupPair) -> pd.DataFrame:
    """Per channel: mean and SNUP (± standard error) before and after; blank where undefined."""
    names: list[str] = []
    for result in (pair.before, pair.after):
        if result is not None:
            names += [n for n in result.names if n not in names]
    rows = []
    for name in names:
        b = pair.before[name] if pair.before is not None else None
        a = pair.after[name] if pair.after is not None else None
        rows.append({"channel": name,
                     "mean before": "" if b is None else f"{b.mean:.4g}",
                     "SNUP before (%)": "" if b is None else format_pm(b.snup, b.snup_err),
                     "mean after": "" if a is None else f"{a.mean:.4g}",
                     "SNUP after (%)": "" if a is None else format_pm(a.snup, a.snup_err),
                     "pixels": (b or a).n})
    return pd.DataFrame(rows, columns=["channel", "mean before", "SNUP before (%)",
                                       "mean after", "SNUP after (%)", "pixels"])


def _table(css_class: str) -> Any:
    import panel as pn

    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css_class], stylesheets=[TABLE_CSS])


def _alert(kind: str, css_class: str) -> Any:
    import panel as pn

    return pn.pane.Alert("", alert_type=kind, visible=False, sizing_mode="stretch_width",
                         css_classes=[css_class])


def _frame_label(rec: FrameRecord) -> str:
    extra = [] if rec.exposure is None else [f"{rec.exposure:g} s"]
    if rec.level is not None:
        extra.append(f"level {rec.level}")
    return rec.relpath + (f" ({', '.join(extra)})" if extra else "")


# ----------------------------------------------------------------------------- the panel -----
class ProductPanel(param.Parameterized):
    """Open a calibration product, show what it holds, apply it to the session's frames and save
    the corrected frames (see the module docstring).

    Parameters
    ----------
    state
        The app state: the loaded session, the allowed roots, :meth:`AppState.compute`.
    auto
        Apply when the product, the frame or the mode changes, and recompute the SNUP when the
        view zooms (scheduled on the server's event loop); tests pass ``False`` and await
        :meth:`open_product`, :meth:`apply`, :meth:`update_snup` and :meth:`save`.
    """

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    product_path = param.String(default="", doc=(
        "The folder of the product shown (resolved; '' for none)."))
    product = param.ClassSelector(class_=CalibrationProduct, default=None, allow_None=True,
                                  precedence=-1, doc=(
        "The product shown (ccdcore.product.load_product), or None."))
    role = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "The role whose frames the frame choice lists."))
    frame = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "relpath of the frame the product is applied to."))
    mode = param.Selector(default=CORRECT, objects={_MODE_LABELS["fixed_pattern"]: CORRECT},
                          doc=("correct: product.correct (flat field or (D − D̂_D)/K̂); "
                               "linearise: product.linearise (inverse response g)."))
    channel = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "Channel (or CFA plane) of the before and after views; None for mono frames."))
    view = param.Selector(default=WHOLE, objects={"Whole frame": WHOLE, "Current view": IN_VIEW},
                          doc="SNUP over the whole frame or over the part in view.")
    out_dir = param.String(default="", doc="The folder corrected frames are written into.")
    scope = param.Selector(default=ONE, objects={"This frame": ONE,
                                                 "Every frame of the role": ROLE},
                           doc="Save the chosen frame or every frame of its role.")

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        import panel as pn

        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self._doc = pn.state.curdoc
        self._records: dict[str, FrameRecord] = {}
        #: what is shown: the applied frame and the SNUP of the region chosen
        self.applied: AppliedFrame | None = None
        self.shown_snup: SnupPair | None = None
        self.written: list[Path] = []
        self.error = ""
        self._applies = Latest()        # apply requests (newest wins)
        self._snups = Latest()          # SNUP-in-view requests
        self._layout: Any = None
        self._build_widgets()
        self.state.param.watch(self._on_session, "session")
        self._fill_frames()

    # ================================================================ building the widgets ====
    def _build_widgets(self) -> None:
        import panel as pn
        from bokeh.events import RangesUpdate

        self.path_input = pn.widgets.TextInput(
            label="Calibration product folder (holding calibration.json)",
            placeholder="/path/to/product", sizing_mode="stretch_width", min_width=300)
        self.open_button = pn.widgets.Button(label="Open product", color="primary",
                                             align="end", width=140)
        self.open_button.on_click(self._on_open)
        self.calibrate_button = pn.widgets.Button(
            label="Calibrate the loaded session", color="light", align="end", width=240,
            description="Make a product from the loaded session (ccdcore.product.calibrate, "
                        "every estimate its frames allow, with the Photon transfer page's fit "
                        "when made) without saving it")
        self.calibrate_button.on_click(self._on_calibrate)
        self.path_input.param.watch(self._on_open, "enter_pressed")
        self.error_alert = _alert("danger", "ccd-product-error")
        self.camera_pane = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            stylesheets=[KEY_VALUE_CSS],
                                            css_classes=["ccd-product-camera"])
        self.estimates_table = _table("ccd-product-estimates")
        self.maps_table = _table("ccd-product-maps")
        self.skipped_table = _table("ccd-product-skipped")
        self.skipped_note = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.provenance_pane = pn.pane.Markdown("", sizing_mode="stretch_width",
                                                css_classes=["ccd-product-provenance"])
        self.summary = pn.Column(
            pn.Row(pn.Column(pn.pane.Markdown("#### Camera"), self.camera_pane, width=420),
                   pn.Column(pn.pane.Markdown("#### Estimates"), self.estimates_table,
                             sizing_mode="stretch_width"),
                   sizing_mode="stretch_width"),
            pn.pane.Markdown("#### Maps"), self.maps_table,
            pn.pane.Markdown("#### Skipped estimates"), self.skipped_note, self.skipped_table,
            pn.pane.Markdown("#### Provenance"), self.provenance_pane,
            sizing_mode="stretch_width", visible=False)

        # apply
        self.role_select = pn.widgets.Select.from_param(self.param.role, label="Role", width=180)
        self.frame_select = pn.widgets.Select.from_param(self.param.frame, label="Frame",
                                                         sizing_mode="stretch_width")
        self.mode_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.mode, label="Mode", color="primary", align="end",
            css_classes=["ccd-product-mode"])
        self.channel_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.channel, label="Channel", visible=False, align="end",
            css_classes=["ccd-product-channel"])
        self.view_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.view, label="SNUP over", align="end", css_classes=["ccd-product-view"])
        self.apply_info = pn.pane.Alert("Open a calibration product, then a session: the "
                                        "product is applied to the frame you choose.",
                                        alert_type="info", sizing_mode="stretch_width",
                                        css_classes=["ccd-product-info"])
        self.apply_alert = _alert("danger", "ccd-product-apply-error")
        self.snup_title = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.snup_table = _table("ccd-product-snup")
        self.snup_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                          styles={"color": MUTED})
        # two views sharing their ranges (linked zoom), the pointer read in both
        self.before_view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                                     css_classes=["ccd-product-before"])
        self.after_view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                                    link=self.before_view, symbol="after",
                                    css_classes=["ccd-product-after"])
        for v in (self.before_view, self.after_view):
            v.on_pointer = lambda x, y: self._on_pointer(x=x, y=y)
            v.figure.on_event(RangesUpdate, self._on_ranges)
        self.before_pane = view_pane(self.before_view)
        self.after_pane = view_pane(self.after_view)
        self.pair_pane = pn.FlexBox(self.before_pane, self.after_pane,
                                    sizing_mode="stretch_width", css_classes=["ccd-product-pair"])
        self.readout = pn.pane.Markdown("", sizing_mode="stretch_width",
                                        css_classes=["ccd-product-readout"])
        self.apply_body = pn.Column(
            pn.Row(self.role_select, self.frame_select, sizing_mode="stretch_width"),
            pn.Row(self.mode_select, self.channel_select, sizing_mode="stretch_width"),
            self.apply_alert, self.snup_title,
            pn.Row(self.view_select, sizing_mode="stretch_width"),
            self.snup_table, self.snup_note, self.pair_pane, self.readout,
            sizing_mode="stretch_width", visible=False)

        # save
        self.out_input = pn.widgets.TextInput(
            label="Output folder (inside the allowed folders; never a folder of the session's "
                 "frames)", placeholder="/path/to/output", sizing_mode="stretch_width",
            min_width=300)
        self.scope_select = pn.widgets.RadioButtonGroup.from_param(self.param.scope,
                                                                   label="Save", align="end")
        self.save_button = pn.widgets.Button(label="Save corrected frames",
                                             color="success", align="end", width=200)
        self.save_button.on_click(self._on_save)
        self.save_alert = _alert("danger", "ccd-product-save-error")
        self.saved_alert = _alert("success", "ccd-product-saved")
        self.save_body = pn.Column(
            pn.Row(self.out_input, self.scope_select, self.save_button,
                   sizing_mode="stretch_width"),
            pn.pane.Markdown("Each frame is written as float32 with its base name (TIFF, EXR "
                             "and FITS keep their format, others become TIFF) by "
                             "`ccdcore.product.apply_product`, atomically; the inputs are "
                             "never changed.", styles={"color": MUTED},
                             sizing_mode="stretch_width"),
            self.save_alert, self.saved_alert, sizing_mode="stretch_width", visible=False)

    def panel(self) -> Any:
        """The panel's layout (built once: revisiting keeps it as is)."""
        import panel as pn

        if self._layout is None:
            intro = ("A calibration product is the folder `ccdcore calibrate` writes "
                     "(`calibration.json` and `maps/`). Open one to see what it holds, apply "
                     "it to any frame of the loaded session, and save corrected frames.")
            self._layout = pn.Column(
                pn.pane.Markdown(intro, styles={"color": MUTED}, sizing_mode="stretch_width"),
                pn.Row(self.path_input, self.open_button, self.calibrate_button,
                       sizing_mode="stretch_width"),
                self.error_alert, self.summary,
                pn.Card(self.apply_info, self.apply_body, title="Apply to frames",
                        sizing_mode="stretch_width", collapsible=False),
                pn.Card(self.save_body, title="Save corrected frames",
                        sizing_mode="stretch_width", collapsible=False),
                sizing_mode="stretch_width", css_classes=["ccd-product"],
                name="Calibration product")
        return self._layout

    # ============================================================ helpers ==================
    def _schedule(self, step: Any) -> None:
        if self.auto:
            import panel as pn

            pn.state.execute(step)

    def _render(self, render: Any) -> None:
        """Run ``render`` holding the browser session's document (after a worker thread)."""
        in_document(self._doc, render)

    async def _compute(self, func: Any, *args: Any, label: str, **kwargs: Any
                       ) -> tuple[Any, str]:
        """``func(*args, **kwargs)`` through :meth:`AppState.compute` (off the UI thread, with
        progress); the result and the error, which this panel shows itself (the app-wide error
        is left as it was)."""
        before = self.state.error
        result = await self.state.compute(func, *args, label=label, **kwargs)
        error = ""
        if result is None:
            error = self.state.error or f"{label} did not finish (cancelled, or another " \
                                        "session was opened meanwhile)"
            self.state.error = before
        return result, error

    # ============================================================ opening a product ========
    async def _on_open(self, event: Any = None) -> None:
        await self.open_product(self.path_input.value_input or self.path_input.value)

    async def open_product(self, path: str | Path) -> bool:
        """Open the product in ``path`` (inside the allowed roots); True on success. A bad
        folder, a folder that is no product, a damaged ``calibration.json`` or maps of the wrong
        shape become an alert naming the folder and the problem; the product shown stays."""
        text = str(path).strip()
        if not text:
            self._open_failed(text, "no folder given: type the folder of a calibration product "
                                    "(it holds calibration.json)")
            return False
        try:
            folder = self.state.check_allowed(text)
        except CcdError as err:
            self._open_failed(text, err.problem)
            return False
        product, error = await self._compute(load_product, folder, label="calibration product")
        if product is None:
            self._open_failed(str(folder), error)
            return False
        self.error = ""
        self.error_alert.visible = False
        self.param.update(product_path=str(folder), product=product)
        return True

    def _open_failed(self, folder: str, message: str) -> None:
        """The alert naming ``folder`` and the problem (ccdcore's message names the file)."""
        message = message.removeprefix(f"{folder}: ").rstrip(".")
        still = f" Still showing {self._source()}." if self.product is not None else ""
        self.error = f"{folder}: {message}"
        self.error_alert.param.update(
            object=f"**Cannot open the calibration product** {_code(folder or '(none)')}: "
                   f"{message}.{still}", visible=True)

    async def _on_calibrate(self, event: Any = None) -> None:
        await self.calibrate_session()

    async def calibrate_session(self) -> bool:
        """Make a product from the loaded session (:func:`ccdcore.product.calibrate`, off the
        UI thread with progress and cancel) and show it, unsaved; True on success. The
        photon-transfer fit the app already made (``state.results.ptc``: the Photon transfer
        page's, with the user's excluded levels, robust mode and ROI) is used as it is."""
        session = self.state.session
        if session is None:
            self._open_failed("", "no session loaded: open one first")
            return False
        product, error = await self._compute(calibrate, session, label="calibration product",
                                             steps=ESTIMATE_STEPS, pass_progress=True,
                                             noise=self.state.results.ptc)
        if product is None:
            self._open_failed(str(session.label), error)
            return False
        if self.state.session is not session:
            return False
        self.error = ""
        self.error_alert.visible = False
        self.param.update(product_path="", product=product)
        return True

    def _source(self) -> str:
        """Where the product shown comes from (its folder, or the session calibrated)."""
        if self.product_path:
            return _code(self.product_path)
        if self.product is None:
            return "nothing"
        return (f"the product calibrated from {_code(self.product.provenance.get('session', '?'))}"
                " (not saved)")

    @param.depends("product", watch=True)
    def _on_product(self) -> None:
        product = self.product
        if product is None:
            self.summary.visible = False
            return
        self.camera_pane.object = camera_markdown(product, self.product_path or None)
        self.estimates_table.object = estimates_frame(product)
        self.maps_table.object = maps_frame(product)
        skipped = skipped_frame(product)
        self.skipped_table.object = skipped
        self.skipped_table.visible = not skipped.empty
        self.skipped_note.object = "" if not skipped.empty else "None: every estimate was made."
        self.provenance_pane.object = provenance_markdown(product)
        self.summary.visible = True
        modes = {}
        if product.shape is not None:
            modes[_MODE_LABELS[product.method]] = CORRECT
        if "response" in product.estimates:
            modes[_LINEARISE_LABEL] = LINEARISE
        mode = self.mode if self.mode in modes.values() else next(iter(modes.values()), CORRECT)
        self._set_choices("mode", modes or {_MODE_LABELS["dark"]: CORRECT}, mode)
        self.mode_select.visible = bool(modes)
        self._update_visibility()
        self._schedule(self.apply)

    # ============================================================ choosing a frame =========
    def _set_choices(self, name: str, objects: Any, value: Any) -> None:
        widget = {"role": self.role_select, "frame": self.frame_select,
                  "mode": self.mode_select, "channel": self.channel_select}[name]
        # a copy: param adds None to a list of objects of a selector that allows None
        objects = dict(objects) if isinstance(objects, Mapping) else list(objects)
        set_choices(self, {name: (widget, objects, value)}, trigger=False)

    def _on_session(self, *events: Any) -> None:
        self._fill_frames()
        if self.applied is not None:
            self._clear_applied()
        if self.product is not None:
            self._schedule(self.apply)

    def _fill_frames(self) -> None:
        """The role and frame choices of the loaded session."""
        session = self.state.session
        self._records = {} if session is None else {r.relpath: r for r in session.frames}
        roles = [] if session is None else list(session.roles())
        ordered = [r for r in _ROLE_ORDER if r in roles] + [r for r in roles
                                                           if r not in _ROLE_ORDER]
        role = self.role if self.role in ordered else next(iter(ordered), None)
        self._set_choices("role", roles, role)
        self._fill_role_frames()
        self._update_visibility()

    def _fill_role_frames(self) -> None:
        session = self.state.session
        recs = [] if session is None or self.role is None else session.by_role(self.role)
        options = {_frame_label(r): r.relpath for r in recs}
        frame = self.frame if self.frame in options.values() else \
            next(iter(options.values()), None)
        self._set_choices("frame", options, frame)

    @param.depends("role", watch=True)
    def _on_role(self) -> None:
        self._fill_role_frames()
        if self.product is not None:
            self._schedule(self.apply)

    @param.depends("frame", "mode", watch=True)
    def _on_frame(self) -> None:
        if self.product is not None:
            self._schedule(self.apply)

    @param.depends("channel", watch=True)
    def _on_channel(self) -> None:
        self._render_pair(reset=False)
        if self.view == IN_VIEW:
            self._schedule(self.update_snup)

    @param.depends("view", watch=True)
    def _on_view(self) -> None:
        if self.applied is not None:
            self._schedule(self.update_snup)

    def _update_visibility(self) -> None:
        session, product = self.state.session, self.product
        if product is None and session is None:
            text = "Open a calibration product and a session: the product is applied to the " \
                   "frame you choose."
        elif product is None:
            text = "Open a calibration product to apply it to the session's frames."
        elif session is None:
            text = "Open a session (the *Open a session* tab) to apply the product to its frames."
        elif not self._records:
            text = "The session has no frames."
        elif product.shape is None and "response" not in product.estimates:
            text = ("This product holds no maps to correct frames with (no dark reference, no "
                    "flat field) and no response curve to linearise them.")
        else:
            text = ""
        self.apply_info.param.update(object=text, visible=bool(text))
        self.apply_body.visible = self.save_body.visible = not text

    # ============================================================ applying =================
    async def apply(self) -> None:
        """Apply the product to the chosen frame (off the UI thread) and show both."""
        product, session = self.product, self.state.session
        rec = self._records.get(self.frame) if self.frame is not None else None
        if product is None or session is None or rec is None:
            return
        request, mode = self._applies.next(), self.mode
        self.pair_pane.loading = True
        try:
            applied, error = await self._compute(apply_frame, product, session, rec, mode,
                                                 label=f"{rec.relpath} with the product")
        finally:
            if self._applies.is_current(request):
                self.pair_pane.loading = False
        if not self._applies.is_current(request) or product is not self.product \
                or session is not self.state.session:
            return
        if applied is None:
            self.applied = self.shown_snup = None
            self.apply_alert.param.update(
                object=f"**Cannot apply the product to** {_code(rec.relpath)}: {error}",
                visible=True)
            self._render(self._clear_applied)
            return
        self.apply_alert.visible = False
        self.applied = applied
        self.shown_snup = applied.snup
        self._render(self._render_applied)
        if self.view == IN_VIEW:
            await self.update_snup()

    @batched
    def _clear_applied(self) -> None:
        self.applied = self.shown_snup = None
        for v in (self.before_view, self.after_view):
            v.show(None)
        self.before_pane.visible = self.after_pane.visible = False
        self.snup_title.object = self.snup_note.object = self.readout.object = ""
        self.snup_table.object = pd.DataFrame()

    @batched
    def _render_applied(self) -> None:
        applied = self.applied
        if applied is None:
            return
        planes = plots.channel_planes(applied.raw, applied.layout)
        names = list(planes)
        channel = self.channel if self.channel in names else \
            (plots.LUMINANCE if plots.LUMINANCE in names else next(iter(names), None))
        self._set_choices("channel", names, channel)
        self.channel_select.visible = bool(names)
        self._render_pair(reset=True)
        self._render_snup()

    def _planes(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The shown channel of the frame before and after (2-D)."""
        applied = self.applied
        if applied is None:
            return None
        return (plots.channel_data(applied.raw, self.channel, applied.layout),
                plots.channel_data(applied.corrected, self.channel, applied.layout))

    @batched
    def _render_pair(self, reset: bool = True) -> None:
        pair = self._planes()
        applied = self.applied
        if pair is None or applied is None:
            return
        raw, cor = pair
        name = Path(applied.relpath).name
        ch = f" \u2014 {self.channel}" if self.channel else ""
        self.before_view.show(raw, clim=plots.auto_clim(raw), title=f"Before: {name}{ch}",
                              how="mean", reset=reset)
        unit = "linear" if applied.mode == LINEARISE else "corrected"
        self.after_view.color_bar.title = "g (linear)" if applied.mode == LINEARISE else "DN"
        self.after_view.show(cor, clim=plots.auto_clim(cor), title=f"After ({unit}){ch}",
                             how="mean", reset=reset)
        self.before_pane.visible = self.after_pane.visible = True
        self.readout.object = ("Move the cursor over either image to read the pixel before and "
                               "after.")

    def _render_snup(self) -> None:
        pair, applied = self.shown_snup, self.applied
        if pair is None or applied is None:
            self.snup_title.object = ""
            self.snup_table.object = pd.DataFrame()
            self.snup_note.object = ""
            return
        what = "linearised" if applied.mode == LINEARISE else "corrected"
        where = "the whole frame" if pair.roi is None else \
            "the pixels in view (x {0}\u2013{1}, y {2}\u2013{3})".format(
                pair.roi[0], pair.roi[0] + pair.roi[2] - 1, pair.roi[1],
                pair.roi[1] + pair.roi[3] - 1)
        self.snup_title.object = (
            f"**SNUP of {_code(applied.relpath)}** ({applied.role}) before and {what}, over "
            f"{where} (100\u00b7\u03c3/mean \u00b1 standard error, eq. 5 of de Lasarte et al. "
            "2007):")
        self.snup_table.object = snup_table(pair)
        notes = []
        if pair.before is None:
            notes.append(f"Before: SNUP undefined: {pair.before_error}")
        if pair.after is None:
            notes.append(f"After: SNUP undefined: {pair.after_error}")
        self.snup_note.object = "\n\n".join(notes)

    # ============================================================ SNUP of the view =========
    def _on_ranges(self, event: Any) -> None:
        if self.view == IN_VIEW and self.applied is not None:
            self._schedule(self.update_snup)

    def current_roi(self) -> tuple[int, int, int, int] | None:
        """The frame pixels in view (``None``: the whole frame, or nothing shown)."""
        applied, pair = self.applied, self._planes()
        if applied is None or pair is None:
            return None
        x_range, y_range = self.before_view.visible_ranges()
        return view_roi(x_range, y_range, pair[0].shape, applied.raw.shape)

    async def update_snup(self) -> None:
        """Show the SNUP over the region chosen: the whole frame (computed with the frame) or
        the pixels in view (computed now, off the UI thread)."""
        applied = self.applied
        if applied is None:
            return
        roi = self.current_roi() if self.view == IN_VIEW else None
        if roi is None:
            pair = applied.snup
        else:
            request = self._snups.next()
            pair = await asyncio.to_thread(snup_pair, applied.raw, applied.corrected,
                                           applied.layout, roi, applied.relpath)
            if not self._snups.is_current(request) or applied is not self.applied:
                return
        self.shown_snup = pair
        self._render(self._render_snup)

    # ============================================================ pixel readout ============
    def _on_pointer(self, x: float | None = None, y: float | None = None) -> None:
        pair, applied = self._planes(), self.applied
        if pair is None or applied is None or x is None or y is None:
            return
        raw, cor = pair
        col, row = int(round(x)), int(round(y))
        if not (0 <= row < raw.shape[0] and 0 <= col < raw.shape[1]):
            return
        before = raw[row, col]
        btext = f"{before:g}" if raw.dtype.kind == "f" else str(before)
        unit = "" if applied.mode == LINEARISE else " DN"
        ch = f" ({self.channel})" if self.channel else ""
        self.readout.object = (f"x = {col}, y = {row}{ch}: before **{btext} DN**, after "
                               f"**{float(cor[row, col]):.6g}{unit}**")

    # ============================================================ saving ===================
    async def _on_save(self, event: Any = None) -> None:
        await self.save(self.out_input.value_input or self.out_input.value)

    def _save_failed(self, message: str) -> None:
        self.saved_alert.visible = False
        self.save_alert.param.update(object=f"**Nothing written:** {message}", visible=True)

    async def save(self, out_dir: str | Path) -> list[Path]:
        """Write the chosen frame, or every frame of its role, corrected (or linearised) as
        float32 into ``out_dir`` (inside the allowed roots, holding no frame of the session);
        the written files, listed in a success alert (an alert says why nothing was written)."""
        product, session = self.product, self.state.session
        rec = self._records.get(self.frame) if self.frame is not None else None
        self.written = []
        if product is None or session is None or rec is None:
            self._save_failed("open a calibration product and a session, and choose a frame")
            return []
        text = str(out_dir).strip()
        if not text:
            self._save_failed("type the output folder first")
            return []
        try:
            folder = self.state.check_allowed(text)
        except CcdError as err:
            self._save_failed(str(err))
            return []
        inputs = {r.path.resolve().parent for r in session.frames}
        if folder in inputs:
            self._save_failed(f"{_code(folder)} holds frames of the session; choose another "
                              "folder so that no input can be overwritten")
            return []
        if self.product_path and folder in (Path(self.product_path),
                                            Path(self.product_path) / "maps"):
            self._save_failed(f"{_code(folder)} is the product's own folder; choose another")
            return []
        recs = session.by_role(rec.role) if self.scope == ROLE else (rec,)
        what = f"{len(recs)} corrected frame{'s' if len(recs) != 1 else ''}"
        written, error = await self._compute(
            save_corrected, product, [r.path for r in recs], folder,
            linearise=self.mode == LINEARISE, label=what)
        if written is None:
            self._save_failed(error)
            return []
        self.written = list(written)
        listed = "\n".join(f"- {_code(p)}" for p in self.written[:MAX_LISTED])
        more = len(self.written) - MAX_LISTED
        self.save_alert.visible = False
        self.saved_alert.param.update(
            object=f"**Wrote {len(self.written)} file{'s' if len(self.written) != 1 else ''}** "
                   f"({'linearised' if self.mode == LINEARISE else 'corrected'}, float32) into "
                   f"{_code(folder)}:\n\n{listed}" + (f"\n- ... and {more} more" if more > 0
                                                       else ""),
            visible=True)
        return self.written

    # ============================================================ memory ===================
    def release(self) -> None:
        """The browser session ended: drop the product and the frames shown (nothing is sent)."""
        for v in (self.before_view, self.after_view):
            v.release()
        self.applied = self.shown_snup = None
        with param.parameterized.discard_events(self):
            self.product = None

    # ============================================================ helpers for tests ========
    def shown_table(self) -> pd.DataFrame:
        """The SNUP table shown."""
        df = self.snup_table.object
        return pd.DataFrame() if df is None else df

