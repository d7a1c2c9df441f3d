"""The report of a session or a calibration product, built and written: the inputs opened (a
session calibrated when no product is given), the sections in document order, the page.

Public objects
--------------
build_report(source, *, product=None, change=None, progress=None)
    The report's HTML text.
write_report(source, out_path, **kw)
    The same, written atomically to ``out_path`` (never over an input).
MAX_MAP_SIDE, MAX_HELD_OUT
    The longest side a map is drawn with; most flat frames corrected for the held-out table
    (from :mod:`ccdcore_report.figures` and :mod:`ccdcore_report.sections`).
"""
from __future__ import annotations

import datetime
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ccdcore import __version__
from ccdcore.errors import CcdError
from ccdcore.product.make import (PRODUCT_FILE, REQUIREMENTS, CalibrationProduct, calibrate,
                             estimate_all, load_product, missing_frames)
from ccdcore.product.records import ProductSteps, Provenance
from ccdcore.progress import Progress, silent, within
from ccdcore.session import Session, open_session

if TYPE_CHECKING:     # the change detector is imported where it runs
    from ccdcore.change.detector import ChangeInputs

from . import sections
from .figures import MAX_MAP_SIDE
from .html import Doc, esc, page
from .sections import MAX_HELD_OUT

__all__ = ["build_report", "write_report", "MAX_MAP_SIDE", "MAX_HELD_OUT"]



# ---------------------------------------------------------------------------------------------
# inputs
# ---------------------------------------------------------------------------------------------
def _is_product(path: Path) -> bool:
    return (path.is_dir() and (path / PRODUCT_FILE).is_file()) or (
        path.is_file() and path.name == PRODUCT_FILE)


def _has_change(session: Session) -> bool:
    roles = session.roles()
    return bool(roles.get("reference")) and bool(roles.get("target"))


def _skipped_product(session: Session) -> CalibrationProduct:
    """The product of a session that holds only brackets for change detection: no estimate,
    each listed skipped with its reason, and the provenance :func:`calibrate` records."""
    e = estimate_all(session)
    provenance = Provenance(
        ccdcore=__version__, session=session.label, source=session.source,
        n_frames=len(session.frames), session_hash=session.content_hash(),
        date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        steps=ProductSteps())
    return CalibrationProduct(maps={}, camera=session.camera, provenance=provenance,
                              skipped=e.skipped)


def _calibrate(session: Session, progress: Progress) -> tuple[CalibrationProduct, Any]:
    """The product of ``session`` and, with reference and target brackets, its change result
    (``(result, inputs)`` of :func:`ccdcore.change.session.session_change`)."""
    session.raise_if_invalid()
    with_change = _has_change(session)
    share = 0.6 if with_change else 0.95
    if with_change and len(missing_frames(session)) == len(REQUIREMENTS):
        product = _skipped_product(session)   # only brackets: every estimate skipped
    else:
        product = calibrate(session, progress=within(progress, 0.0, share,
                                                     prefix="calibrate: "))
    change = None
    if with_change:
        from ccdcore.change.session import session_change

        progress(share, "change detection")
        change = session_change(session, progress=within(progress, share, 0.95,
                                                          prefix="change detection: "))
    return product, change


@dataclass
class _Inputs:
    product: CalibrationProduct
    session: Session | None
    change: Any
    change_inputs: ChangeInputs | None
    origin: str


def _inputs(source: Any, product: CalibrationProduct | None, change: Any,
            progress: Progress) -> _Inputs:
    """What a report is made of: the product (made from the session when not given), the
    session when there is one, the change result and its inputs, and where it all came from."""
    session: Session | None = None
    if isinstance(source, CalibrationProduct):
        product = product or source
        origin = f"calibration product of {product.provenance.session or 'a session'}"
    elif isinstance(source, Session):
        session = source
        origin = session.label
    else:
        path = Path(source)
        if product is None and _is_product(path):
            product = load_product(path)
            origin = str(path)
        elif product is not None and _is_product(path):
            origin = str(path)
        else:
            session = open_session(path)
            origin = session.label
    if product is None:
        assert session is not None
        product, computed = _calibrate(session, progress)
        change = change if change is not None else computed
    inputs = None
    if isinstance(change, tuple):
        change, inputs = change
    return _Inputs(product, session, change, inputs, origin)


# ---------------------------------------------------------------------------------------------
# the document
# ---------------------------------------------------------------------------------------------
def _estimate_sections(doc: Doc, p: CalibrationProduct, session: Session | None) -> None:
    """A section per estimate the product holds, in document order."""
    est = p.estimates
    if est.noise is not None:
        sections.noise_section(doc, est.noise)
    if p.emva1288 is not None:                 # EMVA 1288 data-sheet figures, when made
        sections.emva_section(doc, p.emva1288)
    if est.dark is not None:
        sections.dark_section(doc, est.dark)
    if est.fixed_pattern is not None:
        sections.fixed_pattern_section(doc, est.fixed_pattern)
    if est.plan is not None:
        sections.plan_section(doc, est.plan)
    if est.correction_check is not None:
        sections.correction_section(doc, est.correction_check)
    if est.scene:
        sections.scene_section(doc, est.scene)
    if est.flat_field is not None:
        sections.flat_section(doc, p, session)
    if est.response is not None:
        sections.response_section(doc, est.response)


def _document(src: _Inputs, title: str, now: str) -> Doc:
    """The header, the summary, the estimates' sections, the maps, the change detection, the
    skipped estimates, the provenance and the footer."""
    p = src.product
    doc = Doc()
    doc.add('<header class="ccd-report-header">' f"<h1>{esc(title)}</h1>"
            f'<p class="subtitle">{esc(src.origin)} \u2014 made by ccdcore {esc(__version__)} '
            f"on {esc(now)}</p>")
    doc.add("</header>")
    sections.summary_section(doc, p, src.session, src.change)
    _estimate_sections(doc, p, src.session)
    sections.maps_section(doc, p)
    if src.change is not None:
        sections.change_section(doc, src.change, src.change_inputs)
    sections.skipped_section(doc, p)
    sections.provenance_section(doc, p, src.session, now)
    doc.add(f"<footer>Made by ccdcore {esc(__version__)}. Every figure's data and BokehJS "
            "are in this file; it needs no network.</footer>")
    return doc


# ---------------------------------------------------------------------------------------------
# public
# ---------------------------------------------------------------------------------------------
def build_report(source: Any, *, product: CalibrationProduct | None = None, change: Any = None,
                 progress: Progress | None = None) -> str:
    """The calibration report of ``source`` as one self-contained HTML text.

    Parameters
    ----------
    source
        A :class:`~ccdcore.session.Session`, a :class:`~ccdcore.product.make.CalibrationProduct`, or
        a path: a calibration product folder (or its ``calibration.json``), or a session (a
        folder, ``session.toml``, plain folder or EMVA1288 descriptor).
    product
        The session's calibration product when it is already made: nothing is then computed
        (a change result is drawn only when ``change`` is given). Without it, a session is
        calibrated (:func:`ccdcore.product.make.calibrate`) and, when it has ``reference`` and
        ``target`` brackets, change detection runs (:func:`ccdcore.change.session.session_change`,
        default options).
    change
        A :class:`ccdcore.change.detector.ChangeResult`, or the ``(result, inputs)`` pair
        :func:`~ccdcore.change.session.session_change` returns.
    progress
        A :class:`ccdcore.progress.Progress`, ``progress(fraction, message)``, called as the
        computation goes (fraction of the whole, 0 to 1).

    Returns
    -------
    str
        The HTML text: the estimates with their errors, the plots and maps (Bokeh, inline),
        the skipped estimates and the provenance; nothing is fetched when it is opened.

    Raises
    ------
    CcdError
        The source cannot be opened, the session has errors, or nothing could be calibrated
        (the message names the file and the problem).
    """
    report = progress or silent
    src = _inputs(source, product, change, report)
    report(0.95, "writing the report")
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    cam = src.product.camera
    title = "Calibration report" + (f": {cam.name}" if cam.name else "")
    out = page(_document(src, title, now), title)
    report(1.0, "done")
    return out


def _input_files(source: Any) -> tuple[list[Path], Any]:
    """The files (and the product folder) a report of ``source`` reads -- an output must not be
    one of them nor inside one -- and the opened source (a session is opened once)."""
    from ccdcore.product.make import session_inputs

    if isinstance(source, Session):
        return session_inputs(source), source
    if isinstance(source, CalibrationProduct):
        return [], source
    path = Path(source)
    if _is_product(path):
        return [path if path.is_dir() else path.parent], source
    session = open_session(path)
    return session_inputs(session), session


def write_report(source: Any, out_path: str | os.PathLike, **kw: Any) -> Path:
    """:func:`build_report` written to ``out_path`` atomically (a temporary folder beside it,
    :func:`ccdcore.io.frames.output_set`, renamed into place once complete: a failure or SIGTERM
    leaves an earlier report untouched and no temporary file); returns the path.

    Raises
    ------
    CcdError
        As :func:`build_report`; or ``out_path`` is a folder, a FIFO or a device (or a symlink
        to one), one of the files the report reads or inside the product folder (it is
        refused before anything is computed); or writing failed (naming ``out_path``).
    """
    from ccdcore.io.frames import atomic_write_text, check_output, check_outputs, output_set

    out = Path(out_path)
    if out.is_dir():
        raise CcdError(out, "is a folder; give the report's file name, e.g. report.html")
    check_output(out)
    inputs, source = _input_files(source)
    check_outputs(out.parent, [out.name], inputs)
    text = build_report(source, **kw)
    with output_set(out.parent, inputs=inputs) as tmp:
        atomic_write_text(tmp / out.name, text)
    return out
