"""The report's flat-field section (de Lasarte et al. 2007): the flat field's inputs and
per-channel figures, the base image's SNUP and the SNUP of held-out frames before and after
correction.  Nothing is estimated here but that SNUP (:func:`ccdcore.flatfield.uniformity.snup`). 
Part of
:mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
MAX_HELD_OUT
    Most flat frames (one per flat group) corrected for the held-out SNUP table.
flat_section
    The section.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ccdcore.common import format_pm, sort_key
from ccdcore.errors import CcdError
from ccdcore.flatfield.results import FlatFieldSummary
from ccdcore.product.make import CalibrationProduct, MapName
from ccdcore.session import Session

from ..html import Doc, bullets, esc, facts, finite, num, para, table, value_text

__all__ = ["MAX_HELD_OUT", "flat_section"]

#: most flat groups whose first frame is corrected for the held-out SNUP table (one frame
#: read and corrected per group)
MAX_HELD_OUT = 24


# ---------------------------------------------------------------------------------------------
# flat field
# ---------------------------------------------------------------------------------------------
def _snup_rows(result: Any) -> dict[str, str]:
    return {c.name: format_pm(c.snup, c.snup_err, unit="%") for c in result.channels}


def _flat_facts(ff: FlatFieldSummary) -> str:
    """The offset setting, the base and dark images and the flagged pixels."""
    return facts([
        ("offset setting", ff.setting or "none named", ""),
        ("base image", "level {}, exposure {} s".format(*ff.base) if ff.base is not None
         else "n/a", f"{ff.n_base} frames averaged"),
        ("dark image", f"{ff.n_dark} frames",
         f"exposure {num(ff.dark_exposure, '.4g', 's')}"),
        ("flagged pixels", ff.n_flagged, ff.flag_rule),
    ])


def _flat_channels_table(ff: FlatFieldSummary) -> str:
    """Per channel k, ⟨DL_0⟩, ⟨DL_B⟩, the flagged pixels and the dark pixels at 0."""
    rows = [(c.name, num(c.k, ".5g"), num(c.dark_level, ".4g"), num(c.base_level, ".4g"),
             c.n_flagged,
             num(100 * c.dark_zero_fraction, ".3g", "%")
             if finite(c.dark_zero_fraction) else "n/a")
            for c in ff.channels]
    return table(rows, ("channel", "k (DN)", "\u27e8DL_0\u27e9 (DN)", "\u27e8DL_B\u27e9 (DN)",
                        "flagged", "dark pixels at 0"),
                 cls="ccd-report-flat-channels", numeric=(1, 2, 3, 4, 5))


def _base_snup(doc: Doc, product: CalibrationProduct, layout: str) -> None:
    """SNUP of the base image DL_B and of DL_B − DL_0 per channel, from the maps."""
    from ccdcore.flatfield.uniformity import snup

    if MapName.FLAT_BASE not in product.maps or MapName.FLAT_DARK not in product.maps:
        return
    dlb, dl0 = product.maps[MapName.FLAT_BASE], product.maps[MapName.FLAT_DARK]
    try:
        raw = _snup_rows(snup(dlb, layout=layout, where=MapName.FLAT_BASE))
        sub = _snup_rows(snup(dlb.astype(np.float64) - dl0, layout=layout,
                              where="flat_base - flat_dark"))
    except CcdError as err:
        doc.add(para(f"SNUP of the base image: {err}", "warning"))
        return
    doc.add("<h3>SNUP of the base image, before correction</h3>")
    doc.add(table([(ch, raw[ch], sub.get(ch, "n/a")) for ch in raw],
                  ("channel", "SNUP of DL_B", "SNUP of DL_B \u2212 DL_0"),
                  cls="ccd-report-snup ccd-report-snup-base", numeric=(1, 2)))
    doc.add(para("After correction the base image is flat by construction (G is made from "
                 "it); the held-out frames below measure the correction.", "note"))


def flat_section(doc: Doc, product: CalibrationProduct, session: Session | None) -> None:
    """The flat field's inputs and per-channel figures, the base image's SNUP and the SNUP of
    held-out frames before and after correction.

    Parameters
    ----------
    doc
        The report being assembled.
    product
        A product whose ``estimates.flat_field`` is made (the maps G, O, DL_0, DL_B with it).
    session
        The session, to correct held-out flat frames; ``None``: the table says it needs it.

    Raises
    ------
    ValueError
        The product holds no flat field.
    """
    ff = product.estimates.flat_field
    if ff is None:
        raise ValueError("flat_section: the product holds no flat field")
    layout = ff.layout or product.camera.layout
    with doc.section("flat-field", "Flat field"):
        doc.add(para("De Lasarte et al. 2007: DL_c = O + G\u00b7DL (eqs. 1\u20134) per channel, "
                     "from the dark image DL_0 and the base image DL_B (maps under Maps). "
                     "SNUP = 100\u00b7\u03c3/mean (eq. 5) measures the nonuniformity."))
        doc.add(_flat_facts(ff))
        doc.add(_flat_channels_table(ff))
        doc.add(bullets(ff.notes))
        _base_snup(doc, product, layout)
        _held_out(doc, product, session, ff, layout)


def _held_out_keys(session: Session, ff: FlatFieldSummary) -> tuple[list[Any], Any]:
    """The flat groups other than the base, those at the base's exposure first, and the groups
    themselves."""
    base = tuple(ff.base or ())
    groups = session.flat_groups(setting=ff.setting)
    base_t = base[1] if len(base) == 2 else None
    keys = sorted((k for k in groups if tuple(k) != base),
                  key=lambda k: (tuple(k)[1:2] != (base_t,), sort_key(tuple(k))))
    return keys, groups


def _held_out_rows(rec: Any, key: Any, before: Any, after: Any) -> list[str]:
    """One row per channel of a held-out frame; the frame, level, exposure and mean span them."""
    level, exposure = (tuple(key) + (None, None))[:2]
    mean = float(np.mean([c.mean for c in before.channels]))
    b, a = _snup_rows(before), _snup_rows(after)
    n = len(b)
    rows = []
    for i, ch in enumerate(b):
        lead = "".join(f'<td rowspan="{n}"{cls}>{esc(v)}</td>' for v, cls in (
            (rec.relpath, ""), (value_text(level), ' class="num"'),
            (num(exposure, ".4g"), ' class="num"'), (num(mean, ".4g"), ' class="num"'))
                       ) if i == 0 else ""
        first = ' class="first"' if i == 0 else ""
        rows.append(f'<tr{first}>{lead}<td>{esc(ch)}</td>'
                    f'<td class="num">{esc(b[ch])}</td>'
                    f'<td class="num">{esc(a.get(ch, "n/a"))}</td></tr>')
    return rows


def _held_out(doc: Doc, product: CalibrationProduct, session: Session | None,
              ff: FlatFieldSummary, layout: str) -> None:
    """SNUP before and after correction of the first frame of each flat group other than the
    base (the groups at the base's exposure first; at most :data:`MAX_HELD_OUT`), when the
    session is at hand."""
    from ccdcore.flatfield.fit import correct
    from ccdcore.flatfield.uniformity import snup

    doc.add("<h3>SNUP of held-out flat frames, before and after correction</h3>")
    if session is None or MapName.FLAT_G not in product.maps:
        doc.add(para("Not measured: the report was made from the calibration product alone. "
                     "Make it from the session (ccdcore report SESSION) to correct one frame of "
                     "each flat group that G was not made from.", "note"))
        return
    keys, groups = _held_out_keys(session, ff)
    if not keys:
        doc.add(para("None: every flat frame belongs to the base group.", "note"))
        return
    G, O = product.maps[MapName.FLAT_G], product.maps[MapName.FLAT_O]
    body, problems = [], []
    for key in keys[:MAX_HELD_OUT]:
        rec = groups[key][0]
        try:
            frame = session.read(rec)
            before = snup(frame, layout=layout, where=rec.relpath)
            after = snup(correct(frame, G, O, where=rec.relpath), layout=layout,
                         where=rec.relpath)
        except CcdError as err:
            problems.append(str(err))
            continue
        body += _held_out_rows(rec, key, before, after)
    if body:
        head = "".join(f"<th>{esc(h)}</th>" for h in (
            "frame", "level", "exposure (s)", "mean (DN)", "channel", "SNUP before",
            "SNUP after"))
        doc.add(f'<table class="ccd-report-snup ccd-report-snup-held-out"><thead><tr>{head}'
                f'</tr></thead><tbody>{"".join(body)}</tbody></table>')
    more = len(keys) - MAX_HELD_OUT
    doc.add(para("The first frame of each flat group but the base (those at the base's "
                 "exposure first), corrected with the product's G and O; SNUP \u00b1 its "
                 "standard error per channel, the mean before correction."
                 + (f" {more} more group{'s' if more > 1 else ''} not shown." if more > 0
                    else ""), "note"))
    doc.add(bullets(problems, "warnings"))
