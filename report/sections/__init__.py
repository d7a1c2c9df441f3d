"""The report's sections, one function each, in document order: camera and session, photon
transfer, EMVA 1288 datasheet, dark reference, fixed pattern, acquisition plan, correction check,
scene variation, flat field, response curves, maps, change detection, skipped estimates and
provenance (docs/report.md lists what each holds).

Every section writes into a :class:`ccdcore_report.html.Doc`: its text and tables from the
product's JSON summaries and maps, its plots from :mod:`ccdcore_report.figures` (the EMVA 1288
datasheet's from :mod:`ccdcore_report.emva_figures`). Nothing is estimated here but the SNUP of
the flat-field section's images (:func:`ccdcore.flatfield.uniformity.snup`).

The sections live in modules by report section; this module gathers them (import them from
here):

* :mod:`ccdcore_report.sections.summary`: :data:`ESTIMATE_TITLES`, camera and session,
  skipped estimates, provenance;
* :mod:`ccdcore_report.sections.healey`: photon transfer, dark reference, fixed pattern,
  acquisition plan, correction check, scene variation;
* :mod:`ccdcore_report.sections.emva`: the EMVA 1288 datasheet;
* :mod:`ccdcore_report.sections.flat`: :data:`MAX_HELD_OUT`, the flat field;
* :mod:`ccdcore_report.sections.response`: the response curves;
* :mod:`ccdcore_report.sections.maps`: the maps and change detection.

Public objects
--------------
MAX_HELD_OUT
    Most flat frames (one per flat group) corrected for the held-out SNUP table.
ESTIMATE_TITLES
    Estimate key -> the title the report gives it.
summary_section, noise_section, emva_section, dark_section, fixed_pattern_section,
plan_section, correction_section, scene_section, flat_section, response_section, maps_section,
change_section, skipped_section, provenance_section
    One section each.
"""
from __future__ import annotations

from .emva import emva_section
from .flat import MAX_HELD_OUT, flat_section
from .healey import (correction_section, dark_section, fixed_pattern_section,
                              noise_section, plan_section, scene_section)
from .maps import change_section, maps_section
from .response import response_section
from .summary import (ESTIMATE_TITLES, provenance_section, skipped_section,
                               summary_section)

__all__ = ["MAX_HELD_OUT", "ESTIMATE_TITLES", "summary_section", "noise_section",
           "emva_section", "dark_section", "fixed_pattern_section", "plan_section",
           "correction_section", "scene_section", "flat_section", "response_section",
           "maps_section", "change_section", "skipped_section", "provenance_section"]
