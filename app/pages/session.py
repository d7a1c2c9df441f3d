"""The Session page: open a capture session, check it, preview its frames.

Public objects
--------------
SessionPage
    The page (a :class:`panel.viewable.Viewer`): choose a bundled demo or open a folder (typed
    path or file browser restricted to the allowed roots); camera, groups and per-frame metadata
    tables; every validation problem as an alert; what was inferred for plain folders and a
    button writing the manifest draft; a zoomable preview of any frame with its histogram, per
    channel (R, G, B or the luminance of colour frames; the CFA planes R, G1, G2, B of raw Bayer
    frames, by the camera's layout: :func:`ccdcore.channels.split_channels`). Its *Calibration
    product* tab opens a product and applies it to the session's frames
    (:class:`ccdcore_app.product.panel.ProductPanel`).
create_page(state)
    The registry entry point.
InView, StaticTable
    A marker telling the server when it first comes near the browser's viewport (the Frame
    preview, below the fold of the first view, is built then); a read-only HTML table.
groups_frame(session), frames_frame(session)
    The groups and frames tables of a session as DataFrames (display-ready): sizes width first
    (:func:`ccdcore.common.format_size`), ``mixed`` where a group's sizes or dtypes differ.
inferred_summary(session)
    Which metadata keys were inferred, from what, for how many frames.

Widgets call ccdcore (``open_session``, ``Session.read``, ``draft_manifest``); the plots come from
:mod:`ccdcore_app.plots.base`; the frame preview's figures, error alert and reading are
:class:`ccdcore_app.frame_preview.FramePreview` (shared with the Photon transfer page). A mono or
colour frame larger than :func:`ccdcore_app.tiles.tile_threshold` pixels is not read whole: it is
previewed from a pyramid of block means on disk (:mod:`ccdcore_app.tiles`, built once per file in
bands of rows), each zoom reading only the visible region of the level that fits it, and its
histogram and automatic colour range come from a level of about a megapixel. Long work (opening a
session, reading a frame) runs in a worker thread from async callbacks, so the page stays
responsive, with a progress bar or loading spinner meanwhile.
"""
from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import panel as pn
import param
from panel.custom import JSComponent

from ccdcore.common import format_size
from ccdcore.errors import CcdError
from ccdcore.session import DRAFT_NAME, FrameRecord, Session, draft_manifest

from ..plots import base as plots
from ..frame_preview import FramePreview
from ..image_view import HistogramView, ImageView
from ..tiles import FramePyramid, TiledPlane
from ..state import AppState, assets_dir, demo_sessions
from ..batch import batched
from ._choices import set_choices
from ._styles import KEY_VALUE_CSS, TABLE_CSS

if TYPE_CHECKING:
    from ..product.panel import ProductPanel

__all__ = ["SessionPage", "create_page", "groups_frame", "frames_frame", "inferred_summary",
           "MAX_ALERTS"]

log = logging.getLogger(__name__)

#: at most this many problem alerts are listed (one more alert counts the rest)
MAX_ALERTS = 200
#: frames table rows per page
PAGE_SIZE = 12
#: at most this many lines of the manifest draft are shown (the written file has all)
MAX_DRAFT_LINES = 400

_SOURCES = {"manifest": "manifest", "folder": "plain folder (no manifest)",
            "emva1288": "EMVA1288 descriptor"}
_FROM = {"role": "folder names", "level": "sub-folder names", "config": "sub-folder names",
         "exposure": "file headers", "gain": "file headers", "temperature": "file headers",
         "stack": "the bracket's folder (one stack per folder or repeated exposure sequence)"}
# frames-table columns always shown; the other metadata columns only when some frame sets them
_ALWAYS = ("relpath", "role", "exposure", "size (W×H)", "dtype", "bits")


def _code(text: Any) -> str:
    """``text`` as a Markdown code span (paths keep their underscores and asterisks)."""
    return "`" + str(text).replace("`", "'") + "`"


#: what the groups table says for a size or dtype that differs within a group
MIXED = "mixed"
#: ... and when no frame of the group has a readable header
UNREADABLE = "unreadable"


def _size(shape: Any) -> str:
    """A NumPy shape as ``"W × H"`` (:func:`ccdcore.common.format_size`), "" for none."""
    return "" if shape is None else format_size(shape)


def _group_value(row: dict[str, Any], key: str, text: str) -> str:
    """``text`` (the group's size or dtype), or why there is none: mixed, unreadable."""
    if row.get(key) is not None:
        return text
    return MIXED if key in row.get("mixed", ()) else UNREADABLE


def groups_frame(session: Session) -> pd.DataFrame:
    """One row per group of frames (role, key, count, size, dtype, exposures) for display;
    a size or dtype that differs within a group reads ``mixed``."""
    rows = []
    for row in session.groups_table():
        exposures = row.get("exposures") or []
        rows.append({"role": row["role"],
                     "key": "" if row.get("key") is None else str(row["key"]),
                     "count": int(row["count"]),
                     "size (W×H)": _group_value(row, "shape", _size(row.get("shape"))),
                     "dtype": _group_value(row, "dtype", str(row.get("dtype"))),
                     "exposure (s)": ", ".join(f"{e:g}" for e in exposures)})
    return pd.DataFrame(rows, columns=["role", "key", "count", "size (W×H)", "dtype",
                                       "exposure (s)"])


def frames_frame(session: Session) -> pd.DataFrame:
    """One row per frame: path, role, metadata set in any frame, header shape/dtype/bits."""
    rows = session.frames_table()
    if not rows:
        return pd.DataFrame(columns=list(_ALWAYS) + ["inferred"])
    for row in rows:  # the shape (a tuple) as the size people read
        row["shape"] = _size(row.get("shape"))
    df = pd.DataFrame(rows)
    for col in df.columns:
        if df[col].map(lambda v: isinstance(v, (list, tuple))).any():
            df[col] = df[col].map(lambda v: ", ".join(map(str, v))
                                  if isinstance(v, (list, tuple)) else v)
    for col in ("stack", "note", "shape", "dtype"):  # mixed int/str or None: show as text
        if col in df.columns:
            df[col] = df[col].map(lambda v: "" if v is None or v is np.nan
                                  or isinstance(v, float) and np.isnan(v) else str(v))
    df = df.rename(columns={"shape": "size (W×H)"})
    keep = [c for c in df.columns
            if c in _ALWAYS or c == "inferred" and (df[c] != "").any()
            or c not in _ALWAYS and c != "inferred" and df[c].notna().any()
            and (df[c] != "").any()]
    order = [c for c in _ALWAYS if c in keep] + [c for c in keep if c not in _ALWAYS]
    return df[order].reset_index(drop=True)


def inferred_summary(session: Session) -> list[tuple[str, int, str]]:
    """``(key, number of frames, where it came from)`` for every inferred metadata key.

    A plain folder's exposure brackets (frames with an inferred ``stack``) are found from their
    folder and the exposure times in their headers, which the ``role`` and ``stack`` lines say.
    """
    counts = Counter(k for rec in session.frames for k in rec.inferred)
    brackets = any("stack" in rec.inferred for rec in session.frames)
    origins = dict(_FROM, role="folder names and, for exposure brackets, the exposure times "
                               "in the file headers") if brackets else _FROM
    return [(k, n, origins.get(k, "file headers")) for k, n in counts.items()]


class StaticTable(pn.pane.DataFrame):
    """A read-only table drawn as HTML; ``value`` is its DataFrame (as a Tabulator's)."""

    @property
    def value(self) -> pd.DataFrame:
        return self.object

    @value.setter
    def value(self, df: pd.DataFrame) -> None:
        self.object = df


class InView(JSComponent):
    """An invisible marker whose ``seen`` becomes True once it comes within 200 px of the
    browser's viewport (an ``IntersectionObserver``): what lies below the fold of the first
    view is built when the user scrolls to it.

    The observer starts at the first scroll, or once the marker has stayed in place for a
    second (while the page is being laid out every element may sit at the top, in view).
    """

    seen = param.Boolean(default=False, doc="The marker came near the viewport.")

    _esm = """
    export function render({ model, el }) {
      if (model.seen) return;
      let io = null, last = null, still = 0;
      const start = () => {
        if (io || model.seen) return;
        clearInterval(timer);
        removeEventListener("scroll", start, true);
        io = new IntersectionObserver((entries) => {
          if (entries.some((e) => e.isIntersecting)) {
            io.disconnect();
            model.seen = true;
          }
        }, { rootMargin: "200px" });
        io.observe(el);
      };
      addEventListener("scroll", start, { capture: true, passive: true });
      const timer = setInterval(() => {
        const top = el.isConnected ? el.getBoundingClientRect().top : null;
        if (top !== null && top === last) { if (++still >= 4) start(); }
        else { still = 0; last = top; }
      }, 250);
      model.on("remove", () => {
        clearInterval(timer);
        removeEventListener("scroll", start, true);
        if (io) io.disconnect();
      });
    }
    """


def _problem_alert(problem: Any) -> pn.pane.Alert:
    kind = "danger" if problem.severity == "error" else "warning"
    label = "Error" if problem.severity == "error" else "Warning"
    return pn.pane.Alert(f"**{label}** in {_code(problem.where)}: {problem.message}",
                         alert_type=kind, sizing_mode="stretch_width", margin=(2, 5))


#: the role choices of a plain folder's images (label -> role; None: from the names)
ROLE_CHOICES: dict[str, str | None] = {
    "as their folder and file names say": None,
    **{f"all {name}": role for name, role in (
        ("flat fields", "flat"), ("dark frames", "dark"), ("one exposure bracket", "bracket"),
        ("scenes", "scene"))}}


#: the channel choices of a colour frame (label -> channel)
_COLOUR_CHANNELS = {"R": "R", "G": "G", "B": "B", "Luminance": plots.LUMINANCE}


def _channel_choices(names: list[str]) -> dict[str, str]:
    """label -> channel for the preview's channel buttons (``L`` reads *Luminance*)."""
    return {("Luminance" if n == plots.LUMINANCE else n): n for n in names}


class SessionPage(pn.viewable.Viewer):
    """Open, check and preview a capture session (the app's first page)."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    frame = param.Selector(default=None, objects=[], allow_None=True,
                           doc="relpath of the previewed frame (None for none).")
    channel = param.Selector(default=plots.LUMINANCE, objects=_COLOUR_CHANNELS, doc=(
        "Channel shown: R, G, B or L (luminance) for colour frames, the CFA plane R, G1, G2 "
        "or B for raw Bayer frames (the choices follow the previewed frame)."))

    def __init__(self, state: AppState | None = None, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self._records: dict[str, FrameRecord] = {}
        self._array: np.ndarray | None = None     # the previewed frame, as stored
        self._shown: FrameRecord | None = None    # its record
        self._planes: dict[str, np.ndarray] = {}  # its channel choices (none when mono)
        self._plane: np.ndarray | TiledPlane | None = None   # its shown channel (2-D)
        #: the previewed frame, when large (ccdcore_app.tiles)
        self._tiled: FramePyramid | None = None
        self._layout: pn.Column | None = None
        self._preview_holder: pn.Column | None = None   # the preview card's body (deferred)
        self._build_open_widgets()
        self._build_session_widgets()
        self._build_preview_widgets()
        self._product_panel: ProductPanel | None = None   # built on the tab's first visit
        self.state.param.watch(self._on_session, "session")
        self.state.param.watch(self._on_state_message, ["error", "status", "busy", "progress"])
        if self.state.session is not None:
            self._on_session()
        self._on_state_message()

    # ================================================================ building the widgets ====
    def _build_open_widgets(self) -> None:
        demos = demo_sessions()
        self.demo_select = pn.widgets.Select(
            label="Bundled demo session", options=list(demos), width=220,
            value="healey94" if "healey94" in demos else next(iter(demos), None),
            disabled=not demos, css_classes=["ccd-demo"])
        self.open_demo_button = pn.widgets.Button(
            label="Open demo", color="primary", disabled=not demos, align="end",
            width=140)
        self.path_input = pn.widgets.TextInput(
            label="Session folder, session.toml, folder of images or EMVA1288 descriptor",
            placeholder="/path/to/session", sizing_mode="stretch_width", min_width=300)
        self.open_path_button = pn.widgets.Button(label="Open", color="primary",
                                                  align="end", width=140)
        # a plain folder's roles come from its folder and file names; a camera folder of flats
        # (or darks, or a bracket) is declared here without writing a manifest
        self.role_select = pn.widgets.Select(
            label="Images of a plain folder are", options=ROLE_CHOICES, value=None,
            width=260, align="end", css_classes=["ccd-role-choice"],
            description="A folder without session.toml: its roles come from folder and file "
                        "names, or every image takes the role chosen here (e.g. flats)")
        roots = {self._root_label(r): str(r) for r in self.state.allowed_roots if r.is_dir()}
        self.root_select = pn.widgets.Select(label="Browse in", options=roots, width=320)
        # the file browser is built when its card is first expanded (it is collapsed on the
        # first view, and a FileSelector is some twenty Bokeh models)
        self._file_selector_widget: pn.widgets.FileSelector | None = None
        self.browse_holder = pn.Column(sizing_mode="stretch_width", min_height=0)
        self.open_selected_button = pn.widgets.Button(label="Open selected", color="primary",
                                                      width=140)
        self.progress = pn.indicators.Progress(active=False, visible=False,
                                               value=-1, bar_color="primary",
                                               sizing_mode="stretch_width", height=12)
        self.status_pane = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(0, 10))
        self.error_alert = pn.pane.Alert("", alert_type="danger", visible=False,
                                         sizing_mode="stretch_width",
                                         css_classes=["ccd-open-error"])
        self.notice_alert = pn.pane.Alert("", alert_type="success", visible=False,
                                          sizing_mode="stretch_width")

        self.open_demo_button.on_click(self._on_open_demo)
        self.open_path_button.on_click(self._on_open_path)
        self.path_input.param.watch(self._on_open_path, "enter_pressed")
        self.open_selected_button.on_click(self._on_open_selected)
        self.root_select.param.watch(self._on_root, "value")

    @staticmethod
    def _root_label(root: Path) -> str:
        if root == assets_dir().resolve():
            return f"Demo assets ({root})"
        if root == Path.home().resolve():
            return f"Home ({root})"
        if root == Path.cwd().resolve():
            return f"Working folder ({root})"
        return str(root)

    @property
    def file_selector(self) -> pn.widgets.FileSelector:
        """The file browser over the chosen root (built on first use)."""
        if self._file_selector_widget is None:
            self._file_selector_widget = self._file_selector(self.root_select.value)
        return self._file_selector_widget

    def _show_browser(self, event: Any = None) -> None:
        """Put the file browser into its card (on the card's first expansion)."""
        if not self.browse_holder.objects:
            self.browse_holder.objects = [self.file_selector]

    @staticmethod
    def _file_selector(root: str | None) -> pn.widgets.FileSelector:
        root = root or str(Path.cwd())
        return pn.widgets.FileSelector(directory=root, root_directory=root, height=300,
                                       sizing_mode="stretch_width")

    def _build_session_widgets(self) -> None:
        self.camera_pane = pn.pane.Markdown("No session loaded.", sizing_mode="stretch_width",
                                            stylesheets=[KEY_VALUE_CSS])
        self.problems_column = pn.Column(sizing_mode="stretch_width", max_height=420,
                                         scroll=True, css_classes=["ccd-problems"])
        # a plain HTML table: read-only and a few rows (a Tabulator costs the browser some
        # 0.3 s of layout on the first view)
        self.groups_table = StaticTable(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                                        stylesheets=[TABLE_CSS], css_classes=["ccd-groups"])
        self.frames_table = pn.widgets.Tabulator(
            pd.DataFrame(), disabled=True, show_index=False, pagination="remote",
            page_size=PAGE_SIZE, selectable=1, sizing_mode="stretch_width",
            layout="fit_data_stretch", header_filters=False)
        self.frames_table.param.watch(self._on_table_selection, "selection")
        self.inferred_pane = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.draft_button = pn.widgets.Button(
            label=f"Write manifest draft ({DRAFT_NAME})", color="success", width=300)
        self.draft_button.on_click(self._on_draft)
        self.draft_pane = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.draft_card = pn.Card(
            self.inferred_pane, self.draft_button,
            pn.Card(self.draft_pane, title="Manifest draft (preview)", collapsed=True,
                    sizing_mode="stretch_width"),
            title="Inferred metadata and manifest draft", visible=False,
            sizing_mode="stretch_width")
        # the card goes into the page when a session first needs it (a manifest session with
        # nothing inferred never does)
        self._draft_holder = pn.Column(sizing_mode="stretch_width", margin=0)

    def _build_preview_widgets(self) -> None:
        self.frame_select = pn.widgets.Select.from_param(
            self.param.frame, label="Frame", sizing_mode="stretch_width")
        self.param.watch(self._on_frame, "frame")
        self.channel_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.channel, label="Channel", visible=False, color="primary",
            css_classes=["ccd-channel"])
        self.param.watch(self._on_channel, "channel")
        self.clim_slider = pn.widgets.EditableRangeSlider(
            label="Colour range (DN)", start=0, end=1, value=(0, 1), step=1,
            sizing_mode="stretch_width", css_classes=["ccd-clim"])
        self.auto_button = pn.widgets.Button(label="Auto (0.5\u201399.5 %)", align="end",
                                             width=150)
        self.auto_button.on_click(self._on_auto)
        self.frame_info = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.readout = pn.pane.Markdown("Move the cursor over the image to read pixel values.",
                                        css_classes=["ccd-readout"], sizing_mode="stretch_width")
        self.clim_slider.param.watch(self._on_clim, "value")
        # the figures (image and histogram, built once: another frame or channel replaces
        # their data), the error alert and the reading (ccdcore_app.frame_preview); the figures
        # and the preview's layout are built when first needed (the first frame shown, after
        # the first view's HTML went out), then kept
        self.preview = FramePreview(
            frame_width=760, max_frame_height=640, css_class="ccd-image",
            histogram="ccd-histogram", error_css_classes=["ccd-preview-error"],
            on_pointer=lambda x, y: self._on_pointer(x=x, y=y), lazy=True)
        self.preview_alert = self.preview.alert
        self._body: pn.Column | None = None

    @property
    def image_view(self) -> ImageView:
        """The previewed frame's figure (built on first use)."""
        return self.preview.view

    @property
    def hist_view(self) -> HistogramView:
        """The previewed frame's histogram (built on first use)."""
        return self.preview.hist_view  # type: ignore[return-value]

    @property
    def image_pane(self) -> pn.Column:
        return self.preview.image_pane

    @property
    def hist_pane(self) -> pn.Column:
        return self.preview.hist_pane  # type: ignore[return-value]

    @property
    def preview_body(self) -> pn.Column:
        """The Frame preview card's content (built on first use)."""
        if self._body is None:
            self._body = pn.Column(
                self.frame_select, self.channel_select,
                pn.Row(self.clim_slider, self.auto_button, sizing_mode="stretch_width"),
                self.preview_alert, self.frame_info, self.preview.image_pane, self.readout,
                self.preview.hist_pane, sizing_mode="stretch_width")
        return self._body

    # ================================================================== layout =============
    def __panel__(self) -> pn.viewable.Viewable:
        """The page layout (built once, so leaving and revisiting the page keeps it as is)."""
        if self._layout is None:
            self._layout = self._build_layout()
            # the preview is below the fold: what it shows waits until it is built
            self.preview.deferred = True
        return self._layout

    def _build_layout(self) -> pn.Column:
        browse_card = pn.Card(self.root_select, self.browse_holder, self.open_selected_button,
                              title="Browse folders", collapsed=True,
                              sizing_mode="stretch_width")
        browse_card.param.watch(lambda event: event.new or self._show_browser(), "collapsed")
        open_card = pn.Card(
            pn.Row(self.demo_select, self.open_demo_button),
            pn.Row(self.path_input, self.role_select, self.open_path_button,
                   sizing_mode="stretch_width"),
            browse_card,
            title="Open a session", sizing_mode="stretch_width", collapsible=False)
        # the Calibration product tab gets its panel on its first visit (the first page draws
        # nothing for it), then keeps it
        product_holder = pn.Column(sizing_mode="stretch_width", margin=0)
        self.open_tabs = pn.Tabs(("Open a session", open_card),
                                 ("Calibration product", product_holder),
                                 sizing_mode="stretch_width", css_classes=["ccd-open-tabs"])

        def show_product(event: Any) -> None:
            if event.new == 1 and not product_holder.objects:
                product_holder.objects = [self.product_panel.panel()]

        self.open_tabs.param.watch(show_product, "active")
        return pn.Column(
            pn.pane.Markdown("## Session", css_classes=["ccd-page-title"]),
            self.open_tabs, self.progress, self.status_pane, self.error_alert, self.notice_alert,
            pn.Row(
                pn.Card(self.camera_pane, title="Camera and source", width=380,
                        collapsible=False),
                pn.Card(self.groups_table, title="Groups", sizing_mode="stretch_width",
                        collapsible=False),
                sizing_mode="stretch_width"),
            pn.Card(self.problems_column, title="Validation", sizing_mode="stretch_width"),
            pn.Card(self._frames_holder(), title="Frames (select a row to preview it)",
                    sizing_mode="stretch_width"),
            self._draft_holder,
            self._preview_card(),
            sizing_mode="stretch_width", name="Session")

    @staticmethod
    def _deferred(text: str, css_class: str, show: Any) -> pn.Column:
        """A holder showing ``text`` and an :class:`InView` marker; ``show()`` (which replaces
        them) is called when the marker first comes near the browser's viewport."""
        placeholder = pn.pane.Markdown(text, css_classes=[f"{css_class}-placeholder"],
                                       sizing_mode="stretch_width")
        sentinel = InView(height=1, sizing_mode="stretch_width", margin=0)
        sentinel.param.watch(lambda event: event.new and show(), "seen")
        return pn.Column(placeholder, sentinel, sizing_mode="stretch_width", margin=0,
                         css_classes=[css_class])

    def _frames_holder(self) -> pn.Column:
        """The frames table's place. Below the groups table (one row per group), it is usually
        below the fold of the first view, where a Tabulator cost about 0.4 s of the first view:
        it goes into the page when scrolled near (:meth:`_deferred`)."""
        def show() -> None:
            if holder.objects and holder.objects[0] is not self.frames_table:
                holder.objects = [self.frames_table]

        holder = self._deferred("Scroll here to list the frames.", "ccd-frames", show)
        return holder

    def _preview_card(self) -> pn.Card:
        """The Frame preview card. It sits below the fold of the first view: its body (two
        Bokeh figures, the colour range, the channel buttons ...) goes into the page when the
        card first comes near the browser's viewport (:class:`InView`), or when a frame is
        chosen in the table; the frame itself is read and prepared meanwhile."""
        self._preview_holder = self._deferred("Scroll here to preview the frame.",
                                              "ccd-preview", self.show_preview)
        return pn.Card(self._preview_holder, title="Frame preview",
                       sizing_mode="stretch_width")

    def show_preview(self) -> None:
        """Put the preview's body into the page (once; it stays)."""
        holder = self._preview_holder
        if holder is not None and holder.objects and holder.objects[0] is not self.preview_body:
            holder.objects = [self.preview_body]

    # ============================================================ opening sessions =========
    async def _open(self, path: str | Path, role: str | None = None) -> None:
        self.notice_alert.visible = False
        await self.state.load_async(path, role)

    async def _on_open_demo(self, event: Any = None) -> None:
        name = self.demo_select.value
        if not name:
            self.state.error = "No bundled demo session found in " + str(assets_dir())
            return
        await self._open(demo_sessions()[name])

    async def _on_open_path(self, event: Any = None) -> None:
        await self._open(self.path_input.value_input or self.path_input.value,
                         self.role_select.value)

    async def _on_open_selected(self, event: Any = None) -> None:
        chosen = self.file_selector.value
        if not chosen:
            self.state.error = ("Nothing selected: select a session folder, a session.toml or "
                                "a descriptor in the browser, then press Open selected.")
            return
        await self._open(chosen[0])

    def _on_root(self, event: Any) -> None:
        self._file_selector_widget = self._file_selector(event.new)
        if self.browse_holder.objects:
            self.browse_holder.objects = [self._file_selector_widget]

    def _on_state_message(self, *events: Any) -> None:
        st = self.state
        self.error_alert.object = f"**Error:** {st.error}" if st.error else ""
        self.error_alert.visible = bool(st.error)
        self.status_pane.object = st.status
        self.progress.value = st.progress
        self.progress.active = st.busy and st.progress < 0
        self.progress.visible = st.busy

    # ============================================================ showing a session ========
    def _on_session(self, *events: Any) -> None:
        session = self.state.session
        if session is None:
            return
        self._records = {rec.relpath: rec for rec in session.frames}
        self.camera_pane.object = self._camera_markdown(session)
        self.groups_table.value = groups_frame(session)
        self.frames_table.param.update(value=frames_frame(session), selection=[], page=1)
        self._show_problems(session)
        self._show_inferred(session)
        first = session.frames[0].relpath if session.frames else None
        self.param.frame.objects = list(self._records)
        if first is None:
            self.frame = None
            self._clear_preview("This session has no frames to preview.")
        elif self.frame == first:
            self.param.trigger("frame")
        else:
            self.frame = first

    @staticmethod
    def _camera_markdown(session: Session) -> str:
        cam = session.camera
        roles = ", ".join(f"{n} {role}" for role, n in session.roles().items()) or "none"
        manifest = _code(session.manifest_path) if session.manifest_path else "none"
        rows = [("Camera", cam.name or "(unnamed)"),
                ("ADC bits", "unknown" if cam.bits is None else str(cam.bits)),
                ("Layout", cam.layout),
                ("Source", _SOURCES.get(session.source, session.source)),
                ("Folder", _code(session.root)),
                ("Manifest", manifest),
                ("Frames", f"{len(session.frames)} ({roles})"),
                ("Status", "valid" if session.ok else "**has errors**")]
        return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)

    def _show_problems(self, session: Session) -> None:
        problems = sorted(session.problems, key=lambda p: p.severity != "error")
        if not problems:
            alerts = [pn.pane.Alert("No problems found: the session is valid.",
                                    alert_type="success", sizing_mode="stretch_width")]
        else:
            alerts = [_problem_alert(p) for p in problems[:MAX_ALERTS]]
            rest = problems[MAX_ALERTS:]
            if rest:
                n_err = sum(p.severity == "error" for p in rest)
                alerts.append(pn.pane.Alert(
                    f"... and {len(rest)} more problems ({n_err} errors) not listed.",
                    alert_type="danger" if n_err else "warning", sizing_mode="stretch_width"))
        self.problems_column.objects = alerts

    def _show_inferred(self, session: Session) -> None:
        summary = inferred_summary(session)
        relevant = session.source != "manifest" or bool(summary)
        self.draft_card.visible = relevant
        if not relevant:
            return
        if not self._draft_holder.objects:   # (a manifest session never draws the card)
            self._draft_holder.objects = [self.draft_card]
        if summary:
            lines = [f"- **{key}** for {n} of {len(session.frames)} frames, from {origin}"
                     for key, n, origin in summary]
            text = "Inferred (not given by a manifest):\n\n" + "\n".join(lines)
        else:
            text = "Nothing was inferred: every frame's metadata comes from the manifest."
        self.inferred_pane.object = text
        self.draft_button.visible = session.source != "manifest"
        draft = session.to_toml().splitlines()
        more = len(draft) - MAX_DRAFT_LINES
        shown = "\n".join(draft[:MAX_DRAFT_LINES]) + (f"\n# ... {more} more lines" if more > 0
                                                      else "")
        self.draft_pane.object = f"```toml\n{shown}\n```"

    def _on_draft(self, event: Any = None) -> None:
        session = self.state.session
        if session is None:
            return
        try:
            path = draft_manifest(session)
        except CcdError as err:
            self.state.error = str(err)
            return
        except OSError as err:
            self.state.error = f"{session.root / DRAFT_NAME}: cannot write: {err}"
            return
        self.notice_alert.object = (f"Manifest draft written to {_code(path)}. Check it, then "
                                    "rename it to `session.toml`.")
        self.notice_alert.visible = True

    def _on_table_selection(self, event: Any) -> None:
        df = self.frames_table.value
        if not event.new or df is None or df.empty:
            return
        index = event.new[0]
        if 0 <= index < len(df):
            self.show_preview()
            self.frame = str(df.iloc[index]["relpath"])

    # ============================================================ frame preview ============
    def _clear_preview(self, message: str = "") -> None:
        self._array = self._plane = self._shown = self._tiled = None
        self._planes = {}
        self.preview.clear()
        self.frame_info.object = message
        self.channel_select.visible = False

    async def _on_frame(self, event: Any = None) -> None:
        session, rec = self.state.session, self._records.get(self.frame)
        if session is None or rec is None:
            self._clear_preview()
            return
        read = await self.preview.fetch(
            session, rec, spinner=self.preview_body if self.preview.built else None)
        if read is None:  # a newer frame was chosen meanwhile
            return
        array, error = read
        if array is None:
            self._clear_preview()
            self.preview.fail(error)
            return
        self.preview.hide_error()
        if isinstance(array, FramePyramid):
            self._show_pyramid(array, rec)
            return
        try:
            planes = plots.channel_planes(array, session.camera.layout)
        except ValueError as err:
            self._clear_preview()
            self.preview.fail(f"{rec.relpath}: {err}")
            return
        if planes:
            channel = self.channel if self.channel in planes else \
                plots.LUMINANCE if plots.LUMINANCE in planes else next(iter(planes))
            # shown below
            set_choices(self, {"channel": (self.channel_select, _channel_choices(list(planes)),
                                           channel)}, trigger=False)
        self._array, self._shown, self._planes, self._tiled = array, rec, planes, None
        self.channel_select.visible = bool(planes)
        self._show_plane(rec)

    def _show_pyramid(self, pyramid: FramePyramid, rec: FrameRecord) -> None:
        planes = {c: pyramid.plane(c) for c in pyramid.channels if c is not None}
        if planes:
            channel = self.channel if self.channel in planes else plots.LUMINANCE
            set_choices(self, {"channel": (self.channel_select, _channel_choices(list(planes)),
                                           channel)}, trigger=False)
        self._array, self._shown, self._planes, self._tiled = None, rec, planes, pyramid
        self.channel_select.visible = bool(planes)
        self._show_plane(rec)

    def _on_channel(self, event: Any = None) -> None:
        if (self._array is not None or self._tiled is not None) and self._shown is not None:
            self._show_plane(self._shown)

    @batched
    def _show_plane(self, rec: FrameRecord) -> None:
        """Show the current channel of the current frame: image, histogram, range, info."""
        if self._tiled is not None:
            self._show_tiled(rec, self._tiled)
            return
        array = self._array
        plane = self._planes.get(self.channel, array) if self._planes else \
            plots.channel_data(array)
        self._plane = plane
        finite = plane[np.isfinite(plane)] if plane.dtype.kind == "f" else plane
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        if not hi > lo:
            hi = lo + 1.0
        integer = plane.dtype.kind in "iu"
        clim = plots.auto_clim(plane)
        self.clim_slider.param.update(start=lo, end=hi, step=1 if integer else (hi - lo) / 1000)
        self._set_clim((max(lo, clim[0]), min(hi, clim[1])))
        channel = f", channel {self.channel}" if self._planes else ""
        if plane.shape[:2] != array.shape[:2]:  # a CFA plane: every other row and column
            channel += f" ({_size(plane.shape)} px plane)"
        self.frame_info.object = (
            f"{_code(rec.relpath)} \u2014 {rec.role}"
            + ("" if rec.exposure is None else f", exposure {rec.exposure:g} s")
            + f", {_size(array.shape)} px {array.dtype}{channel}; "
            f"min {lo:g}, max {hi:g}, mean {float(np.mean(finite)) if finite.size else 0:g} DN")
        clim = self.clim_slider.value
        self.preview.show(plane, clim, Path(rec.relpath).name, plane, "Histogram")
        self.readout.object = "Move the cursor over the image to read pixel values."

    def _show_tiled(self, rec: FrameRecord, pyramid: FramePyramid) -> None:
        """:meth:`_show_plane` for a large frame: the view reads its pyramid by the region; the
        range and the mean are exact (gathered while building), the histogram and the
        automatic colour range come from a coarse level (block means)."""
        plane = self._planes.get(self.channel) if self._planes else pyramid.plane()
        self._plane = plane
        lo, hi, mean = plane.stats
        if not (np.isfinite(lo) and np.isfinite(hi)):
            lo, hi, mean = 0.0, 1.0, 0.0
        if not hi > lo:
            hi = lo + 1.0
        level = plane.coarse_level()
        coarse = np.asarray(plane.level(level))
        clim = plots.auto_clim(coarse)
        integer = plane.dtype.kind in "iu"
        self.clim_slider.param.update(start=lo, end=hi, step=1 if integer else (hi - lo) / 1000)
        self._set_clim((max(lo, clim[0]), min(hi, clim[1])))
        channel = f", channel {self.channel}" if self._planes else ""
        f = plane.factors[level]
        shape = (*pyramid.shape, 3) if self._planes else pyramid.shape
        self.frame_info.object = (
            f"{_code(rec.relpath)} — {rec.role}"
            + ("" if rec.exposure is None else f", exposure {rec.exposure:g} s")
            + f", {_size(shape)} px {pyramid.dtype}{channel}; "
            f"min {lo:g}, max {hi:g}, mean {mean:g} DN. Large frame: previewed from a pyramid "
            f"of block means (2×2 to {plane.factors[-1]}×{plane.factors[-1]} px), "
            f"each zoom reading only what it shows; histogram and automatic range of the "
            f"{f}×{f} px block means.")
        clim = self.clim_slider.value
        self.preview.show(plane, clim, Path(rec.relpath).name, coarse,
                          f"Histogram of {f}×{f} px block means")
        self.readout.object = "Move the cursor over the image to read pixel values."

    def _on_pointer(self, x: float | None = None, y: float | None = None) -> None:
        plane = self._plane
        if plane is None or x is None or y is None:
            return
        col, row = int(round(x)), int(round(y))
        if 0 <= row < plane.shape[0] and 0 <= col < plane.shape[1]:
            value = plane.value(row, col) if isinstance(plane, TiledPlane) else plane[row, col]
            text = f"{value:g}" if plane.dtype.kind == "f" else str(value)
            self.readout.object = f"x = {col}, y = {row}: **{text} DN**"

    def _on_auto(self, event: Any = None) -> None:
        if self._plane is None:
            return
        plane = self._plane
        lo, hi = plots.auto_clim(plane.coarse() if isinstance(plane, TiledPlane) else plane)
        start, end = self.clim_slider.start, self.clim_slider.end
        self._set_clim((max(start, lo), min(end, hi)))

    def release(self) -> None:
        """The browser session ended: drop the frame shown (no redraw)."""
        self.preview.release()
        self._array = self._plane = self._shown = self._tiled = None
        self._planes = {}
        if self._product_panel is not None:
            self._product_panel.release()

    def _on_clim(self, event: Any) -> None:
        self.preview.set_clim(event.new)   # (not built: the first show draws with this range)

    def _set_clim(self, clim: tuple[float, float]) -> None:
        """Set the colour range in two steps, widening first.

        The editable slider's browser side clamps a new lower value to the *current* upper value
        (and vice versa), so going straight from (0, 1) to (8, 14) would arrive as (1, 14).
        """
        old_lo, old_hi = self.clim_slider.value
        wide = (min(old_lo, clim[0]), max(old_hi, clim[1]))
        if wide != tuple(clim):
            self.clim_slider.value = wide
        self.clim_slider.value = tuple(clim)

    @property
    def product_panel(self) -> ProductPanel:
        """The *Calibration product* tab: open a product, apply it to this session's frames
        (:class:`ccdcore_app.product.panel.ProductPanel`, built on first use)."""
        if self._product_panel is None:
            from ..product.panel import ProductPanel

            self._product_panel = ProductPanel(self.state)
        return self._product_panel

    # ============================================================ helpers for tests ========
    @property
    def problem_alerts(self) -> list[pn.pane.Alert]:
        """The alerts listing the session's problems (a success alert when there are none)."""
        return list(self.problems_column.objects)


def create_page(state: AppState) -> SessionPage:
    """Registry entry point: the Session page bound to ``state``."""
    return SessionPage(state)
