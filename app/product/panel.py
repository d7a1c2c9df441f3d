"""Calibration products in the app: open one, see what it holds, apply it to the session's frames.

A calibration product is the folder :meth:`ccdcore.product.make.CalibrationProduct.save` writes
(``calibration.json`` + ``maps/*.exr``). The panel opens one
(:func:`ccdcore.product.make.load_product`, inside the app's allowed roots) and lists its camera,
every estimate with its headline numbers (the EMVA 1288 figures too, when the product has them),
its maps with their sizes, the estimates it skipped and why, and its provenance. It applies the
product to any frame of the loaded session --
:meth:`~ccdcore.product.make.CalibrationProduct.correct` (the flat field O + G·DL of de Lasarte et
al. 2007, or (D − D̂_D)/K̂, eq. 51 of Healey & Kondepudy 1994) or
:meth:`~ccdcore.product.make.CalibrationProduct.linearise` (the inverse response g of Tsin et al.
2001) -- and shows the frame before and after in two linked views, with a pixel readout of both
and the SNUP (eq. 5 of de Lasarte et al., :func:`ccdcore.flatfield.uniformity.snup`) of both over
the whole frame or the part in view. It writes corrected frames as float32 files
(:func:`ccdcore.product.make.apply_product`). The product may also be made from the loaded session
in the app (:func:`ccdcore.product.make.calibrate`, unsaved).

Every number comes from ccdcore; this module only reads, arranges and shows them. The summary
tables come from :mod:`ccdcore_app.product.summary`, applying and saving from
:mod:`ccdcore_app.product.apply`, the Save card from :mod:`ccdcore_app.product.save` (their
public names are importable from here too).

Public objects
--------------
ProductPanel(state)
    The panel (a :class:`param.Parameterized`; :meth:`ProductPanel.panel` is its layout), which
    the Session page shows in its *Calibration product* tab.
AppliedFrame, apply_frame, SnupPair, snup_pair, save_corrected, view_roi, snup_table, CORRECT,
LINEARISE
    Applying a product to a frame, the SNUP, saving (:mod:`ccdcore_app.product.apply`).
camera_markdown, estimates_frame, estimate_headline, maps_frame, skipped_frame,
provenance_markdown
    What the summary shows (:mod:`ccdcore_app.product.summary`).
"""
from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
import param

from ccdcore.errors import CcdError
from ccdcore.product.make import ESTIMATE_STEPS, CalibrationProduct, calibrate, load_product
from ccdcore.session import FrameRecord

from ..plots import base as plots
from ..batch import batched, in_document
from ..image_view import ImageView, view_pane
from ..latest import Latest
from .apply import (CORRECT, LINEARISE, AppliedFrame, SnupPair, apply_frame,
                            save_corrected, snup_pair, snup_table, view_roi)
from .save import MAX_LISTED, ONE, ROLE, SaveCard, hidden_alert
from .summary import (camera_markdown, code_span, estimate_headline, estimates_frame,
                              maps_frame, provenance_markdown, skipped_frame)
from ..state import AppState
from ..pages._choices import set_choices
from ..pages._styles import KEY_VALUE_CSS, MUTED, TABLE_CSS

__all__ = ["ProductPanel", "AppliedFrame", "apply_frame", "SnupPair", "snup_pair",
           "save_corrected", "view_roi", "camera_markdown", "estimates_frame",
           "estimate_headline", "maps_frame", "skipped_frame", "provenance_markdown",
           "snup_table", "CORRECT", "LINEARISE", "MAX_LISTED", "ONE", "ROLE"]

#: SNUP over the whole frame or over the part in view
WHOLE, IN_VIEW = "frame", "view"
#: frame width of the before and after views (px; two fit side by side in a 1400 px window);
#: the height follows, pixels are square
IMAGE_WIDTH = 360
#: roles offered first (frames a correction is meant for), then the session's other roles
_ROLE_ORDER = ("scene", "flat", "bracket", "fixed_pattern", "ptc", "dark")

_MODE_LABELS = {"flat_field": "Correct (O + G\u00b7DL)",
                "fixed_pattern": "Correct ((D \u2212 D\u0302_D)/K\u0302)",
                "dark": "Correct (D \u2212 D\u0302_D)"}
_LINEARISE_LABEL = "Linearise (inverse response g)"


def _table(css_class: str) -> Any:
    import panel as pn

    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css_class], stylesheets=[TABLE_CSS])


def _frame_label(rec: FrameRecord) -> str:
    extra = [] if rec.exposure is None else [f"{rec.exposure:g} s"]
    if rec.level is not None:
        extra.append(f"level {rec.level}")
    return rec.relpath + (f" ({', '.join(extra)})" if extra else "")


# ----------------------------------------------------------------------------- the panel -----
class ProductPanel(SaveCard, param.Parameterized):
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
        "The product shown (ccdcore.product.make.load_product), or None."))
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
        self._build_summary_widgets()
        self._build_apply_widgets()
        self._build_save_widgets()

    def _build_summary_widgets(self) -> None:
        """Opening a product (or calibrating the session) and what the product holds."""
        import panel as pn

        self.path_input = pn.widgets.TextInput(
            label="Calibration product folder (holding calibration.json)",
            placeholder="/path/to/product", sizing_mode="stretch_width", min_width=300)
        self.open_button = pn.widgets.Button(label="Open product", color="primary",
                                             align="end", width=140)
        self.open_button.on_click(self._on_open)
        self.calibrate_button = pn.widgets.Button(
            label="Calibrate the loaded session", color="light", align="end", width=240,
            description="Make a product from the loaded session (ccdcore.product.make.calibrate, "
                        "every estimate its frames allow, with the Photon transfer page's fit "
                        "when made) without saving it")
        self.calibrate_button.on_click(self._on_calibrate)
        self.path_input.param.watch(self._on_open, "enter_pressed")
        self.error_alert = hidden_alert("danger", "ccd-product-error")
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

    def _build_apply_widgets(self) -> None:
        """The frame choice, the mode, the before and after views, the SNUP and the readout."""
        import panel as pn
        from bokeh.events import RangesUpdate

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
        self.apply_alert = hidden_alert("danger", "ccd-product-apply-error")
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
            object=f"**Cannot open the calibration product** {code_span(folder or '(none)')}: "
                   f"{message}.{still}", visible=True)

    async def _on_calibrate(self, event: Any = None) -> None:
        await self.calibrate_session()

    async def calibrate_session(self) -> bool:
        """Make a product from the loaded session (:func:`ccdcore.product.make.calibrate`, off the
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
            return code_span(self.product_path)
        if self.product is None:
            return "nothing"
        return (f"the product calibrated from {code_span(self.product.provenance.session or '?')}"
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
        if product.estimates.response is not None:
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
        elif product.shape is None and product.estimates.response is None:
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
                object=f"**Cannot apply the product to** {code_span(rec.relpath)}: {error}",
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
            f"**SNUP of {code_span(applied.relpath)}** ({applied.role}) before and {what}, over "
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
