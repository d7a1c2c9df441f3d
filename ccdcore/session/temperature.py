"""Sensor temperature as a grouping key: darks and biases matched to the frames they correct.

A CCD's dark current roughly doubles every 6 °C, so a dark frame corrects only frames taken at
its own sensor temperature.  Each frame's temperature comes from its header (FITS ``SET-TEMP``,
the regulated set point, when present, else the measured ``CCD-TEMP``; EXIF ``Temperature``
where a camera writes one) or the manifest key ``temperature``.  Two frames are at the same
temperature when they differ by at most :data:`TEMPERATURE_TOLERANCE` (°C).

Public objects
--------------
TEMPERATURE_TOLERANCE
    The tolerance, 1 °C.
CORRECTED_ROLES
    The roles whose frames the dark frames correct, in order of preference.
target_temperature(records, roles=CORRECTED_ROLES)
    The temperature the darks are wanted at, and the role it comes from.
match_temperature(records, target, tolerance)
    Split frames into those within the tolerance of ``target`` and the others.
temperatures_text(values)
    A set of temperatures in a few words.
temperature_problems(records)
    The ``temperature-mismatch`` warning of a session, if any.
"""
from __future__ import annotations

from typing import Any, Iterable, Sequence

import numpy as np

from .records import FrameRecord, Problem, ProblemCode

__all__ = ["TEMPERATURE_TOLERANCE", "CORRECTED_ROLES", "target_temperature", "match_temperature",
           "temperatures_text", "temperature_problems"]

#: two frames are at the same sensor temperature when they differ by at most this much (°C)
TEMPERATURE_TOLERANCE = 1.0
#: the roles whose frames dark frames correct, in the order their temperature is preferred
CORRECTED_ROLES = ("flat", "fixed_pattern", "ptc")


def temperatures_text(values: Iterable[float | None]) -> str:
    """Distinct temperatures in a few words: ``"−10 and −5 °C"`` (rounded to 0.1 °C; unknown
    ones counted)."""
    values = list(values)
    known = sorted({round(float(v), 1) for v in values if v is not None})
    unknown = sum(1 for v in values if v is None)
    txt = ("no known temperature" if not known else
           (", ".join(f"{v:g}" for v in known[:-1]) + " and " if len(known) > 1 else "")
           + f"{known[-1]:g} °C")
    return txt + (f" ({unknown} frames without a temperature)" if unknown and known else "")


def target_temperature(records: Sequence[FrameRecord],
                       roles: Sequence[str] = CORRECTED_ROLES) -> tuple[float | None, str | None]:
    """The temperature the dark frames are wanted at: the median temperature of the frames of
    the first of ``roles`` that have one, with that role; ``(None, None)`` when none has."""
    for role in roles:
        temps = [r.temperature for r in records if r.role == role and r.temperature is not None]
        if temps:
            return float(np.median(temps)), role
    return None, None


def match_temperature(records: Iterable[Any], target: float | None,
                      tolerance: float = TEMPERATURE_TOLERANCE) -> tuple[list, list]:
    """``(matched, other)``: records within ``tolerance`` of ``target`` and the rest.

    With no ``target`` every record matches; a record without a temperature matches (it cannot
    be checked; callers note it)."""
    matched, other = [], []
    for r in records:
        t = getattr(r, "temperature", None)
        if target is None or t is None or abs(t - target) <= tolerance:
            matched.append(r)
        else:
            other.append(r)
    return matched, other


def temperature_problems(records: Sequence[FrameRecord],
                         tolerance: float = TEMPERATURE_TOLERANCE) -> list[Problem]:
    """A ``temperature-mismatch`` warning when the session has dark frames with temperatures
    but none within ``tolerance`` of the temperature of the frames they correct
    (:func:`target_temperature`); nothing otherwise."""
    darks = [r for r in records if r.role == "dark"]
    target, role = target_temperature(records)
    if target is None or not darks or all(r.temperature is None for r in darks):
        return []
    matched, _ = match_temperature(darks, target, tolerance)
    if matched:
        return []
    return [Problem("dark", f"no dark frame within {tolerance:g} °C of the {role} frames' "
                            f"{target:g} °C (the dark frames are at "
                            f"{temperatures_text([r.temperature for r in darks])}): dark current "
                            "depends on temperature, so these darks cannot correct them",
                    "warning", code=ProblemCode.TEMPERATURE_MISMATCH, roles=("dark", role))]
