"""Small helpers every layer shares: JSON-safe numbers, "value ± error" text, sort keys, ROIs.

Each lives here once; estimators, the product, the command line and the app call these instead of
keeping their own copies (see ``docs/architecture.md``, "One home for each concept").

Public objects
--------------
json_safe(obj)
    Numbers, arrays and containers as strict-JSON values (NaN and infinities become ``None``).
float_or_nan(v)
    A stored number back as a float: ``None`` (written for NaN) is NaN again.
format_pm(value, error, digits=2)
    ``"value ± error"`` with the error to ``digits`` significant digits.
format_size(shape)
    A frame size as people read it, width first: ``(H, W)`` -> ``"W × H"``.
sort_key(value), group_by(items, key)
    A key that sorts ``None`` last and never compares numbers with strings; grouping by it.
named_frames(frames, what)
    ``(name, array)`` from arrays or ``(record, array)`` pairs, refusing NaN and infinities.
Roi, check_roi(roi, shape, where), crop(array, roi)
    A region of interest ``(x, y, w, h)``: validated once against a frame shape, then applied.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, NamedTuple, Sequence, TypeVar

import numpy as np

from .errors import CcdError

__all__ = ["json_safe", "float_or_nan", "format_pm", "format_size", "sort_key", "group_by", "named_frames", "Roi", "check_roi", "crop"]


# --------------------------------------------------------------------------------------------
# numbers for JSON
# --------------------------------------------------------------------------------------------
def json_safe(obj: Any) -> Any:
    """``obj`` with every number a plain Python ``bool``/``int``/``float`` and NaN/inf -> ``None``.

    Dicts, lists and tuples are converted recursively (tuples become lists, dict keys strings),
    NumPy arrays become nested lists, paths become POSIX strings; other objects are returned
    unchanged.  The result passes ``json.dumps(..., allow_nan=False)``.
    """
    if isinstance(obj, dict):
        return {k if isinstance(k, str) else str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return obj.as_posix()
    return obj


def float_or_nan(v: float | None) -> float:
    """A number as :func:`json_safe` stored it, back as a float: ``None`` (written for NaN or an
    infinity) is NaN."""
    return math.nan if v is None else float(v)


# --------------------------------------------------------------------------------------------
# text
# --------------------------------------------------------------------------------------------
def _finite(x: Any) -> bool:
    return (isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)
            and math.isfinite(x))


def format_pm(value: Any, error: Any = None, digits: int = 2, *, unit: str = "") -> str:
    """``"value ± error"``: the error to ``digits`` significant digits, the value to the same
    decimal place (``"1.0963 ± 0.0057"``, ``"1234 ± 56"``).

    Without a finite positive error the value alone, to 5 significant digits; ``"n/a"`` for a
    missing or non-finite value.  ``unit`` is appended after a space when given.
    """
    if not _finite(value):
        return "n/a"
    tail = f" {unit}" if unit else ""
    if not _finite(error) or error <= 0:
        return f"{value:.5g}{tail}"
    decimals = digits - 1 - int(math.floor(math.log10(error)))
    if decimals > 0:
        return f"{value:.{decimals}f} \u00b1 {error:.{decimals}f}{tail}"
    return f"{round(value, decimals):.0f} \u00b1 {round(error, decimals):.0f}{tail}"


def format_size(shape: Sequence[int] | None, sep: str = " \u00d7 ") -> str:
    """A frame size width first: ``(H, W)`` -> ``"W × H"``, ``(H, W, C)`` -> ``"W × H × C"``;
    ``"?"`` for ``None``."""
    if shape is None:
        return "?"
    dims = [int(n) for n in shape]
    return sep.join(map(str, dims[1::-1] + dims[2:]))


def sort_key(value: Any) -> tuple:
    """Sort ``None`` last and keep numbers and strings apart (numbers first).

    Tuples are keyed element by element, so ``(level, exposure)`` keys with ``None`` parts sort.
    """
    if isinstance(value, tuple):
        return tuple(sort_key(v) for v in value)
    if value is None:
        return (2, 0, "")
    if isinstance(value, str):
        return (1, 0, value)
    return (0, value, "")


T = TypeVar("T")


def group_by(items: Iterable[T], key: Callable[[T], Any]) -> dict[Any, tuple[T, ...]]:
    """Items grouped by ``key(item)``: keys sorted with :func:`sort_key`, items in input order."""
    groups: dict[Any, list[T]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    return {k: tuple(groups[k]) for k in sorted(groups, key=sort_key)}


def named_frames(frames: Iterable[Any], what: str) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(name, array)`` from arrays or ``(record, array)`` pairs.

    The name is the record's ``relpath`` (or ``str(record)``), else ``"<what> frame <i>"``.

    Raises
    ------
    CcdError
        A floating-point frame holds NaN or infinite values (named, with their count).
    """
    for i, item in enumerate(frames):
        rec, arr = item if isinstance(item, tuple) else (None, item)
        name = getattr(rec, "relpath", None) or (str(rec) if rec is not None
                                                 else f"{what} frame {i}")
        arr = np.asarray(arr)
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise CcdError(name, f"{int((~np.isfinite(arr)).sum())} NaN or infinite pixel values")
        yield name, arr


# --------------------------------------------------------------------------------------------
# regions of interest
# --------------------------------------------------------------------------------------------
class Roi(NamedTuple):
    """A region of interest in pixels: left ``x``, top ``y``, width ``w``, height ``h``."""

    x: int
    y: int
    w: int
    h: int

    def __str__(self) -> str:
        return f"{self.x},{self.y},{self.w},{self.h}"

    @property
    def slices(self) -> tuple[slice, slice]:
        """``(rows, columns)`` slices selecting the region of a ``(H, W, ...)`` array."""
        return slice(self.y, self.y + self.h), slice(self.x, self.x + self.w)


def check_roi(roi: Sequence[Any] | None, shape: Sequence[int], where: Any = "roi", *,
              min_pixels: int = 1, even: bool = False) -> Roi | None:
    """Validate ``roi = (x, y, w, h)`` against frames of ``shape = (H, W, ...)``.

    Parameters
    ----------
    roi
        Four integers, or ``None`` (the whole frame: ``None`` is returned).
    shape
        The frame shape, NumPy order.
    where
        Named in the error: the file or session the frames come from.
    min_pixels
        The fewest pixels the method needs inside the region.
    even
        Require even x, y, w, h (whole 2×2 cells of a Bayer mosaic).

    Raises
    ------
    CcdError
        Not four integers, empty, outside the frame, too small, or odd on a mosaic.
    """
    if roi is None:
        return None
    try:
        values = list(roi)
        ok = len(values) == 4 and all(float(v) == int(v) and not isinstance(v, bool)
                                      for v in values)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise CcdError(where, f"ROI must be four integers X,Y,W,H, got {roi!r}")
    x, y, w, h = (int(v) for v in values)
    H, W = int(shape[0]), int(shape[1])
    if w < 1 or h < 1:
        raise CcdError(where, f"ROI {x},{y},{w},{h} (X,Y,W,H) is empty (W and H must be >= 1)")
    if x < 0 or y < 0 or x + w > W or y + h > H:
        raise CcdError(where, f"ROI {x},{y},{w},{h} (X,Y,W,H) lies outside the {W}x{H} frame "
                              f"(need X, Y >= 0, X + W <= {W}, Y + H <= {H})")
    if w * h < min_pixels:
        raise CcdError(where, f"ROI {x},{y},{w},{h} has {w * h} pixel{'s' if w * h > 1 else ''}; "
                              f"the method needs at least {min_pixels}")
    if even and (x % 2 or y % 2 or w % 2 or h % 2):
        raise CcdError(where, f"on Bayer data the ROI must have even X, Y, W, H (whole 2x2 "
                              f"cells), got {x},{y},{w},{h}")
    return Roi(x, y, w, h)


def crop(array: np.ndarray, roi: Sequence[int] | None) -> np.ndarray:
    """The region ``roi = (x, y, w, h)`` of a ``(H, W, ...)`` array as a view (``array`` itself
    for ``None``).  Validate the ROI with :func:`check_roi` first."""
    if roi is None:
        return array
    x, y, w, h = roi
    return array[y:y + h, x:x + w]
