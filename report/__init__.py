"""ccdcore_report: one self-contained HTML calibration report, with Bokeh only.

Every estimate with its uncertainty, every plot and map as a Bokeh figure, the skipped estimates
and the provenance, in a file that opens offline (docs/report.md).

The report is built from a :class:`ccdcore.product.make.CalibrationProduct` (its JSON summaries and
float32 maps) and, when given, a change-detection result; nothing in it is estimated here. From a
session, the product is made first (:func:`ccdcore.product.make.calibrate`) and, when the session
has ``reference`` and ``target`` brackets, the change masks
(:func:`ccdcore.change.session.session_change`). BokehJS (Bokeh's own code only) and every figure's
data are inlined: no script, style sheet, font or image is fetched from anywhere.

It is a package of its own, beside ``ccdcore`` and ``ccdcore_app``, because both use it:
``ccdcore report`` (the CLI, which must not load the app) and the app's report download and
Walkthrough (which pass the product they already hold). It imports ccdcore, NumPy, pandas and
Bokeh (Bokeh only when a report is built), never Panel, HoloViews or ``ccdcore_app``; ccdcore
never imports it, except the CLI's ``report`` verb, lazily (docs/architecture.md).

Modules: :mod:`~ccdcore_report.build` (the inputs, the orchestration, writing the file),
:mod:`~ccdcore_report.sections` (one function per section), :mod:`~ccdcore_report.figures`
(the Bokeh figures), :mod:`~ccdcore_report.html` (escaping, tables, the page and its CSS),
:mod:`~ccdcore_report.ptc` (the photon-transfer figures the app's page draws too),
:mod:`~ccdcore_report.emva_figures` (the EMVA 1288 datasheet's plots, which the app draws too),
:mod:`~ccdcore_report.agreement` (the response's prediction agreement as table rows, also the
app's), :mod:`~ccdcore_report.scales` (colour ranges, also the app's).

Public objects
--------------
build_report(source, *, product=None, change=None, progress=None)
    The report's HTML text.
write_report(source, out_path, **kw)
    The same, written atomically to ``out_path`` (never over an input).
MAX_MAP_SIDE
    The longest side, in pixels, a map is drawn with (larger maps are reduced by block means).
MAX_HELD_OUT
    Most flat frames (one per flat group) corrected for the held-out SNUP table.
"""
from __future__ import annotations

from .build import MAX_HELD_OUT, MAX_MAP_SIDE, build_report, write_report

__all__ = ["build_report", "write_report", "MAX_MAP_SIDE", "MAX_HELD_OUT"]
