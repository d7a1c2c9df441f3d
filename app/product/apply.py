"""Applying a calibration product to a session's frames: the frame before and after, the SNUP.

Public objects
--------------
AppliedFrame, apply_frame(product, session, record, mode)
    One frame corrected (or linearised) by the product, with the SNUP of both.
SnupPair, snup_pair(raw, corrected, layout, roi=None, where="frame")
    The SNUP before and after (each ``None`` with ccdcore's reason when undefined).
snup_table(pair)
    The SNUP table shown (per channel: mean and SNUP before and after).
save_corrected(product, paths, out_dir, linearise=False)
    :func:`ccdcore.product.make.apply_product` frame by frame, with progress and cancel.
view_roi(x_range, y_range, plane_shape, frame_shape)
    The frame pixels ``(x, y, w, h)`` a view shows (``None``: the whole frame).
CORRECT, LINEARISE
    The two modes.

Every number comes from ccdcore (``CalibrationProduct.correct`` and ``linearise``,
:func:`ccdcore.flatfield.uniformity.snup`, :func:`ccdcore.product.make.apply_product`); the
Calibration product tab (:class:`ccdcore_app.product.panel.ProductPanel`) shows them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from ccdcore.common import format_pm, format_size
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_header
from ccdcore.product.make import CalibrationProduct, apply_product
from ccdcore.progress import checkpoint
from ccdcore.session import FrameRecord, Session
from ccdcore.flatfield.uniformity import SnupResult, snup

from ..plots import base as plots

__all__ = ["AppliedFrame", "apply_frame", "SnupPair", "snup_pair", "snup_table",
           "save_corrected", "view_roi", "CORRECT", "LINEARISE"]

#: the modes: correct each frame (flat field or dark and K̂), or linearise it (inverse response)
CORRECT, LINEARISE = "correct", "linearise"


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
    """:func:`ccdcore.flatfield.uniformity.snup` of ``raw`` and ``corrected`` over ``roi`` (``(x, y, w, h)``
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
    """:func:`ccdcore.product.make.apply_product` of ``paths`` into ``out_dir``; the written files.

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
