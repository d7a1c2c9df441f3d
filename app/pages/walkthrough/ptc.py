"""Step 4, ptc: photon transfer with its band and residuals, levels left out, the robust mode
and the fit range; the EMVA 1288 datasheet, the deviation from linearity and the spatial
nonuniformity plots when the session carries photon counts.

The fit range is the step's choice (:attr:`PtcStep.fit_range`): EMVA 1288's 0–70 % of the
saturation signal (release 3.1 sec. 6.6, :data:`ccdcore.noise.EMVA_FIT_FRACTION`), the default
for a session whose ptc frames carry photon counts (an EMVA 1288 set), or every level below
saturation (Healey & Kondepudy's range), the default otherwise. The fit, its plots and the gate
(:func:`ccdcore.guide.ptc_gate`, whose reasons name the range) follow it.

The spatial nonuniformity plots (sec. 8: spectrograms, histograms, profiles) are drawn here
rather than in the dark step: they explain the datasheet's DSNU1288 and PRNU1288 rows and their
row, column and pixel parts listed beside them, PRNU comes from the bright spatial set (ptc
frames) and both need the gain K of the same sensitivity fit.
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import pandas as pd
import panel as pn
import param

from ccdcore import guide
from ccdcore.common import format_pm
from ccdcore.emva.results import EmvaSummary
from ccdcore.emva.sheet import datasheet_rows
from ccdcore.guide import Gate
from ccdcore.noise import EMVA_FIT_FRACTION
from ccdcore.session import Session
from ccdcore_report.ptc import PtcFigures

from ...batch import in_document
from .._styles import MUTED
from ._common import Step, skip_missing, table

if TYPE_CHECKING:
    from ccdcore.noise import PhotonTransfer

#: the fit range's choices (label -> value of :attr:`PtcStep.fit_range`)
FIT_RANGES = {"EMVA 1288 range: 0–70 % of saturation": "emva",
              "every level below saturation": "paper"}
#: the fit range -> ``fit_fraction`` of :func:`ccdcore.noise.photon_transfer`
FIT_FRACTIONS: dict[str, float | None] = {"emva": EMVA_FIT_FRACTION, "paper": None}


@dataclass(frozen=True, eq=False)
class PtcResult:
    """The photon transfer with the page's choices; ``noise`` is ``None`` when the session lacks
    the frames (the step is skipped)."""

    noise: PhotonTransfer | None


def is_emva_set(session: Session | None) -> bool:
    """The session's ptc frames carry photon counts (an EMVA 1288 set)."""
    return session is not None and any(r.photons for r in session.by_role("ptc"))


def default_fit_range(session: Session | None) -> str:
    """The fit range a session starts with: ``"emva"`` for an EMVA 1288 set, else
    ``"paper"``."""
    return "emva" if is_emva_set(session) else "paper"


def compute_ptc(session: Session, exclude: list[int], robust: bool,
                fit_fraction: float | None = None) -> Any:
    from ccdcore.noise import photon_transfer

    return photon_transfer(session, exclude_levels=exclude, robust=robust,
                           fit_fraction=fit_fraction)


def emva_of_frames(session: Session) -> Any:
    """The EMVA 1288 figures of the session's frames, without photon transfer: what a refit of
    the photon transfer does not change (:func:`ccdcore.emva.datasheet.with_photon_transfer` adds
    it)."""
    from ccdcore.emva.datasheet import emva_figures

    return emva_figures(session, with_ptc=False)


#: the text of a figure the session does not determine
NOT_DETERMINED = "not determined"


def emva_table(figures: EmvaSummary) -> pd.DataFrame:
    """The datasheet (:func:`ccdcore.emva.sheet.datasheet_rows`): every figure in the
    standard's order, one row each: ``section`` (on its first row only), ``figure``,
    ``symbol``, ``value`` (value ± error and unit, or "not determined") and ``note`` (why it
    is not determined)."""
    rows, last = [], None
    for r in datasheet_rows(figures):
        value = (NOT_DETERMINED if r.value is None
                 else format_pm(r.value, r.error, unit=r.unit))
        rows.append({"section": r.section if r.section != last else "", "figure": r.name,
                     "symbol": r.symbol, "value": value, "note": r.note or ""})
        last = r.section
    return pd.DataFrame(rows, columns=["section", "figure", "symbol", "value", "note"])


def _linearity_data(figures: EmvaSummary) -> tuple:
    """What the deviation-from-linearity plot draws (it is rebuilt only when this changes)."""
    return (figures.points, figures.linearity_slope, figures.linearity_offset, figures.LE_min,
            figures.LE_max, figures.LE_min_err, figures.LE_max_err)


class PtcStep(Step, param.Parameterized):
    """The photon-transfer step; its result is :class:`PtcResult` (``results.ptc``), and the
    EMVA 1288 figures of an EMVA set (``results.emva``)."""

    slug = "ptc"

    fit_range = param.Selector(default="paper", objects=FIT_RANGES, doc=(
        "The levels the gain is fitted over: 'emva' (0–70 % of the saturation signal, EMVA "
        "1288 release 3.1 sec. 6.6) or 'paper' (every level below saturation). A session "
        "starts with 'emva' when its ptc frames carry photon counts, else 'paper'."))

    def __init__(self, page: Any) -> None:
        param.Parameterized.__init__(self)
        Step.__init__(self, page)
        self._resetting = False
        #: (session, its EMVA 1288 figures without photon transfer): read once per session
        self._emva_frames: tuple[Session, Any] | None = None
        #: what the EMVA plots show: the data they were built from
        self._linearity_shown: tuple | None = None
        self._spatial_shown: Any = None

    def build(self) -> list[pn.viewable.Viewable]:
        self.figs = PtcFigures(height=320)
        self.exclude_select = pn.widgets.MultiChoice(label="Leave out levels", options=[],
                                                     width=300, css_classes=["ccd-wt-exclude"])
        self.exclude_select.param.watch(self._on_exclude, "value")
        self.robust_box = pn.widgets.Checkbox.from_param(
            self.page.param.robust, name="Robust mode (drop levels beyond 3σ)")
        self.range_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.fit_range, color="default", variant="outline",
            css_classes=["ccd-wt-fit-range"], margin=(0, 10), width=540,
            description="EMVA 1288 fits the gain over 0–70 % of the saturation signal (release "
                        "3.1 sec. 6.6); Healey & Kondepudy fit every level below saturation")
        self.reset_fit_range()
        self.emva_table = table("ccd-wt-emva")
        self.emva_table.stylesheets = [*self.emva_table.stylesheets,
                                       "td:nth-child(4) { white-space: nowrap; }"]
        # (Bokeh panes are never hidden: Panel takes their visibility from the Bokeh model)
        self.linearity_pane = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                            css_classes=["ccd-wt-linearity"])
        # the section's twelve plots are sent to the browser when the card is first opened
        self.spatial_pane = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                          css_classes=["ccd-wt-spatial"])
        self.spatial_card = pn.Card(
            self.spatial_pane, title="Spatial nonuniformity (sec. 8): spectrograms, histograms, "
                                     "profiles", collapsed=True, visible=False,
            sizing_mode="stretch_width", css_classes=["ccd-wt-spatial-card"])
        self.spatial_card.param.watch(self._on_spatial_card, "collapsed")
        self.emva_holder = pn.Column(
            pn.pane.Markdown("**EMVA 1288 datasheet** (the session carries photon counts): "
                             "every figure in the standard's order, with its standard error or "
                             "why it is not determined. Definitions of release 3.1 (release "
                             "4.0's row, column and pixel parts of DSNU and PRNU), as the "
                             "emva1288 package computes them: docs/emva.md. K and η come from "
                             "the standard's own fit over 0–70 % of saturation, whatever the "
                             "fit range above."),
            self.emva_table, self.linearity_pane, self.spatial_card, visible=False,
            sizing_mode="stretch_width")
        fit_range = pn.Row(pn.pane.Markdown("Fit the gain over", width=130, margin=(6, 10),
                                            styles={"color": MUTED}),
                           self.range_select)
        return [fit_range, pn.Row(self.exclude_select, self.robust_box),
                pn.pane.Bokeh(self.figs.transfer, sizing_mode="stretch_width"),
                pn.pane.Bokeh(self.figs.residual, sizing_mode="stretch_width"),
                self.emva_holder]

    # ------------------------------------------------------------------ the fit range -----
    def reset_fit_range(self) -> None:
        """The loaded session's default range (:func:`default_fit_range`), without a refit."""
        self._resetting = True
        try:
            self.fit_range = default_fit_range(self.page.state.session)
        finally:
            self._resetting = False

    @param.depends("fit_range", watch=True)
    def _on_fit_range(self) -> None:
        if not self._resetting:
            self.page.refit_ptc()             # as the levels left out and the robust mode

    def dropped(self, names: Any) -> None:
        if "session" in names:                # another session: its own figures and range
            self._emva_frames = None
            self.reset_fit_range()

    @property
    def fit_fraction(self) -> float | None:
        """The chosen range as the ``fit_fraction`` of :func:`ccdcore.noise.photon_transfer`."""
        return FIT_FRACTIONS[self.fit_range]

    # ------------------------------------------------------------------ computing ---------
    async def ensure(self) -> PhotonTransfer | None:
        """The photon-transfer result (``None`` when skipped or failed; the gate says why)."""
        found = await self.once(self._compute)
        return found.noise if found is not None else None

    async def _compute(self) -> PtcResult | None:
        """The photon transfer and its gate (a skip without the frames)."""
        page, session = self.page, self.page.state.session
        skip = skip_missing(session, "noise")
        if skip is not None:
            self.set_gate(skip)
            return PtcResult(None)
        noise = await self.compute(compute_ptc, session, list(page.exclude), bool(page.robust),
                                   self.fit_fraction, label="photon transfer")
        if noise is None:
            return None
        self.results.ptc = found = PtcResult(noise)      # stored before the EMVA figures
        gate = guide.ptc_gate(noise)
        if is_emva_set(session):
            gate = await self._with_emva(session, noise, gate)
        self.set_gate(gate)
        return found

    async def _with_emva(self, session: Session, noise: Any, gate: Gate) -> Gate:
        """The EMVA 1288 figures (``results.emva``), and the gate judged with their linearity
        error (:func:`ccdcore.guide.ptc_gate` with ``emva``) and their notes. The frames
        are read once per session; a refit (levels left out, robust mode, fit range) changes
        only σ_d from the photon-transfer intercept."""
        from ccdcore.emva.datasheet import with_photon_transfer

        state = self.page.state
        if self._emva_frames is None or self._emva_frames[0] is not session:
            base = await state.compute(emva_of_frames, session, label="the EMVA 1288 figures")
            self._emva_frames = None if base is None else (session, base)
        figures = (None if self._emva_frames is None
                   else with_photon_transfer(self._emva_frames[1], noise).summary())
        self.results.emva = figures
        if figures is None:
            notes: tuple[str, ...] = (
                f"the EMVA 1288 figures could not be made: {state.error}",)
        else:
            gate = guide.ptc_gate(noise, emva=figures)      # judged with the datasheet's LE
            notes = tuple(f"EMVA 1288: {n}" for n in figures.notes)
        return Gate(gate.status, gate.summary, gate.reasons + notes, gate.next)

    # ------------------------------------------------------------------ drawing -----------
    def draw(self, found: PtcResult) -> None:
        noise = found.noise
        if noise is None:
            return
        self.figs.update(noise.points, noise)
        figures = self.results.emva
        if figures is not None:
            self.emva_table.object = emva_table(figures)
            self._draw_linearity(figures)
            self.spatial_card.visible = figures.spatial_plots is not None
            if not self.spatial_card.collapsed:
                pn.state.execute(self._draw_spatial)
        self.emva_holder.visible = figures is not None
        self.exclude_select.options = [int(p.level) for p in noise.points]
        self.page.steps["plan"].use_session.disabled = False

    def _draw_linearity(self, figures: EmvaSummary) -> None:
        """The deviation from linearity, built again only when its data changed (a new fit
        range or levels left out change the photon transfer, not the EMVA points)."""
        from ccdcore_report.emva_figures import linearity_deviation_figure

        data = _linearity_data(figures)
        if data != self._linearity_shown:
            self._linearity_shown = data
            self.linearity_pane.object = linearity_deviation_figure(figures)

    async def _draw_spatial(self) -> None:
        """The spatial plots of the EMVA figures, built again only when they changed, in a
        worker thread (twelve figures: some 0.3 s that would hold up every browser session)."""
        from ..maps.page import emva_spatial_layout

        figures = self.results.emva
        plots = figures.spatial_plots if figures is not None else None
        if plots is None or plots == self._spatial_shown:
            return
        self._spatial_shown = plots
        layout = await asyncio.to_thread(emva_spatial_layout, figures)
        if self.results.emva is not figures:        # dropped meanwhile: drawn when shown
            self._spatial_shown = None
            return
        in_document(self.page.doc, lambda: setattr(self.spatial_pane, "object", layout))

    def _on_spatial_card(self, event: Any) -> None:
        if not event.new:
            pn.state.execute(self._draw_spatial)

    def _on_exclude(self, event: Any) -> None:
        value = sorted(int(v) for v in event.new)
        if value != sorted(self.page.exclude):
            self.page.exclude = value

    def show_exclude(self) -> None:
        """The levels left out, as the page holds them (set from the address or a test)."""
        if self.exclude_select.value != list(self.page.exclude):
            self.exclude_select.value = list(self.page.exclude)
