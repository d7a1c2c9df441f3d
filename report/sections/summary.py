"""The report's first and last sections: camera and session (the summary), skipped estimates
and provenance; and the titles the report gives the estimates (:data:`ESTIMATE_TITLES`).
Part of :mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
ESTIMATE_TITLES
    Estimate key -> the title the report gives it.
summary_section, skipped_section, provenance_section
    One section each.
"""
from __future__ import annotations

from typing import Any

from ccdcore import __version__
from ccdcore.common import format_size
from ccdcore.product.make import CalibrationProduct
from ccdcore.records import Record
from ccdcore.session import Session

from ..html import Doc, Html, bullets, esc, facts, num, para, table, value_text

__all__ = ["ESTIMATE_TITLES", "summary_section", "skipped_section", "provenance_section"]

ESTIMATE_TITLES = {"noise": "Photon transfer", "dark": "Dark reference",
                   "fixed_pattern": "Fixed pattern", "plan": "Acquisition plan",
                   "correction_check": "Correction check", "scene": "Scene variation",
                   "flat_field": "Flat field", "response": "Response curves",
                   "emva1288": "EMVA 1288 datasheet"}


# ---------------------------------------------------------------------------------------------
# camera and session
# ---------------------------------------------------------------------------------------------
def _frame_shape(product: CalibrationProduct | None, session: Session | None
                 ) -> tuple[int, ...] | None:
    if session is not None:
        shapes = {tuple(r["shape"]) for r in session.groups_table() if r["shape"] is not None}
        if len(shapes) == 1:
            return shapes.pop()
    if product is not None:
        if product.shape is not None:
            return tuple(product.shape)
        for _, est in product.estimates.items():
            shape = getattr(est, "shape", None)
            if shape is not None:
                return tuple(int(n) for n in shape)
    return None


def _camera_facts(product: CalibrationProduct, session: Session | None) -> str:
    """The camera and where the session came from (the session's, else the product's record)."""
    cam = product.camera
    prov = product.provenance
    shape = _frame_shape(product, session)
    return facts([
        ("camera", cam.name or "unnamed"),
        ("bit depth", f"{cam.bits} bits" if cam.bits else "unknown"),
        ("colour layout", cam.layout),
        ("frame size (W \u00d7 H)", format_size(shape) if shape else "unknown"),
        ("black level (manifest)", num(cam.black_level, ".6g", "DN")
         if cam.black_level is not None else "not given"),
        ("session", session.label if session is not None else _known(prov.session)),
        ("session source", session.source if session is not None
         else _known(prov.source)),
        ("frames", len(session.frames) if session is not None else _known(prov.n_frames)),
    ])


def _known(value: Any) -> Any:
    """A field of the provenance, ``"unknown"`` when the product does not record it."""
    return "unknown" if value is None else value


def _roles_table(session: Session) -> str:
    """Every role and group of the session: frames, size, type, the first exposures."""
    rows = []
    for row in session.groups_table():
        key = "" if row["key"] is None else f"{row['key_name']} {value_text(row['key'])}"
        exps = row["exposures"]
        rows.append((row["role"], key, row["count"],
                     format_size(row["shape"]) if row["shape"] else "mixed",
                     row["dtype"] or "mixed",
                     ", ".join(f"{t:g}" for t in exps[:4]) + (" \u2026" if len(exps) > 4
                                                                else "")))
    return table(rows, ("role", "group", "frames", "size", "type", "exposure (s)"),
                 cls="ccd-report-roles", numeric=(2,))


def _made_text(product: CalibrationProduct, change: Any) -> str:
    """Which estimates were made and which skipped, in one sentence."""
    made = [ESTIMATE_TITLES.get(k, k) for k in product.estimates.made()]
    if product.emva1288 is not None:
        made.append(ESTIMATE_TITLES["emva1288"])
    if change is not None:
        made.append("Change detection")
    return ("Estimates made: " + (", ".join(made) if made else "none") + ". Skipped: "
            + (", ".join(ESTIMATE_TITLES.get(s.estimate, s.estimate) for s in product.skipped)
               or "none")
            + " (see Skipped estimates).")


def summary_section(doc: Doc, product: CalibrationProduct, session: Session | None,
                    change: Any) -> None:
    """The camera, the frames by role and group (from a session), what was made and skipped,
    then the product's warnings (those of the plan are in its own section) and notes."""
    with doc.section("summary", "Camera and session"):
        doc.add(_camera_facts(product, session))
        if session is not None:
            doc.add("<h3>Frames by role and group</h3>")
            doc.add(_roles_table(session))
        else:
            doc.add(para("This report was made from a calibration product: the frames' roles "
                         "are not stored in it (the estimates below say what they used).",
                         "note"))
        doc.add(para(_made_text(product, change)))
        plan = product.estimates.plan
        plan_warnings = set(plan.warnings if plan is not None else ())
        other = [w for w in product.warnings if w not in plan_warnings]
        if other:
            doc.add("<h3>Warnings</h3>" + bullets(other, "warnings"))
        if product.notes:
            doc.add("<h3>Notes</h3>" + bullets(product.notes))


# ---------------------------------------------------------------------------------------------
# skipped, provenance
# ---------------------------------------------------------------------------------------------
def skipped_section(doc: Doc, product: CalibrationProduct) -> None:
    with doc.section("skipped", "Skipped estimates"):
        if not product.skipped:
            doc.add(para("None: every estimate was made."))
            return
        doc.add(table([(ESTIMATE_TITLES.get(s.estimate, s.estimate), s.code, s.reason,
                        ", ".join(s.roles)) for s in product.skipped],
                      ("estimate", "code", "reason", "roles missing"),
                      cls="ccd-report-skipped"))


def provenance_section(doc: Doc, product: CalibrationProduct, session: Session | None,
                       now: str) -> None:
    """The versions of the product and of the report, the session, its hash and the product's
    date (each said when the product does not record it), then every step's parameters."""
    prov = product.provenance
    digest = prov.session_hash
    date = prov.date
    with doc.section("provenance", "Provenance"):
        doc.add(facts([
            ("product made by", f"ccdcore {prov.ccdcore or 'unknown version'}", ""),
            ("report made by", f"ccdcore {__version__}", now),
            ("session", session.label if session is not None else _known(prov.session),
             prov.source or ""),
            ("session hash", digest if digest else "unavailable",
             "" if digest else "this product records no hash of its session"),
            ("date of the product", date if date else now,
             "" if date else "the product records no date: this is the report's date"),
        ]))
        steps = list(prov.steps.items()) if prov.steps is not None else []
        if steps:
            doc.add("<h3>Parameters per step</h3>")
            doc.add(table([(ESTIMATE_TITLES.get(k, k), _parameters(v))
                           for k, v in steps],
                          ("step", "parameters"), cls="ccd-report-steps"))


def _parameters(step: Record) -> Html:
    """A step's parameters, one ``key: value`` per line."""
    return Html("<br>".join(f"<b>{esc(k)}</b>: {esc(value_text(v))}" for k, v in step.items()))
