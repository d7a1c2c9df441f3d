"""The Maps page's Maps tab: the grid of maps, their colour range, histograms, profiles, export.

Public objects
--------------
MapsTab
    The part of :class:`ccdcore_app.pages.maps.page.MapsPage` (a ``param`` mixin: the tab's state
    and its watchers) that shows the dark reference's and K̂'s maps (:mod:`ccdcore_app.plots.maps`)
    with linked zoom, the values of every map under the cursor, a histogram per shown map, row
    and column profiles, the colour range of the selected map and its export, and the summary
    tables beside them.
DEFAULT_SHOWN
    The maps shown in the grid when they exist.

The page owns ``state``, ``clims``, ``map_views`` and the other per-map dictionaries (its
``__init__``); this module only arranges and shows what ccdcore computed.
"""
from __future__ import annotations

import html
import io
from typing import Any

import numpy as np
import panel as pn
import param

from ccdcore.errors import CcdError
from ccdcore.product.make import MapName, requirement
from ccdcore.session import Session

from ...plots import maps as map_plots
from ...plots import base as plots
from ...batch import batched
from ...image_view import HistogramView, ImageView
from ...plots.maps import MapLayer
from .._choices import set_choices
from .tables import (EXPORT_FORMATS, MAPS_CSS, correction_summary, dark_summary,
                           export_bytes, fixed_pattern_summary, stats_pane)

__all__ = ["MapsTab", "DEFAULT_SHOWN"]

#: maps shown in the grid when they exist
DEFAULT_SHOWN = (MapName.K, MapName.DARK)


class MapsTab(param.Parameterized):
    """Mixin of the Maps page: the Maps tab (see the module docstring)."""

    state: Any
    clims: dict[str, tuple[float, float]]
    map_views: dict[str, ImageView]
    hist_views: dict[str, HistogramView]

    layers = param.Dict(default={}, precedence=-1, doc=(
        "The maps on the page: key -> ccdcore_app.plots.maps.MapLayer, from the dark reference "
        "and K̂."))
    shown = param.ListSelector(default=[], objects=[], doc=(
        "Keys of the maps shown in the grid (linked zoom), in display order."))
    active = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "Key of the selected map: its colour range, profiles and export."))
    overview = param.Selector(default="extreme", objects=list(plots.OVERVIEWS)[:2], doc=(
        "What a screen pixel of a zoomed-out value map shows: the value of its block farthest "
        "from the map's centre (a single deviating pixel stays visible) or the block mean."))

    # ====================================================================== building ========
    def _build_maps_tab(self) -> None:
        self._build_map_controls()
        self._build_map_figures()

    def _build_map_controls(self) -> None:
        """The map choices, the colour range, the overview, the profile sliders, export."""
        self.shown_select = pn.widgets.MultiChoice.from_param(
            self.param.shown, label="Maps shown (linked zoom)", sizing_mode="stretch_width",
            min_width=320)
        self.active_select = pn.widgets.Select.from_param(self.param.active,
                                                          label="Selected map", width=280)
        # one slider, reconfigured in place for the selected map (a widget swapped into the
        # page is built again in the browser: 0.5 s per choice)
        self.clim_slider = pn.widgets.EditableRangeSlider(
            label="Colour range", start=0.0, end=1.0, value=(0.0, 1.0), step=0.001,
            sizing_mode="stretch_width", format="0.[00000]", visible=False)
        self.clim_slider.param.watch(self._on_clim, "value")
        # the zoomed-out views follow the choice in place
        self.overview_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.overview, options={"extreme pixel": "extreme", "mean": "mean"},
            color="default", width=220,
            description="When a map has more pixels than the screen shows, each screen pixel "
                        "shows its block's pixel farthest from the centre (1 for K̂, the "
                        "median otherwise) or the block's mean; counts and flags show the "
                        "largest. The map's title says which.")
        self.param.watch(self._on_overview, "overview")
        self.auto_button = pn.widgets.Button(label="Auto (0.5–99.5 %)", align="end", width=150)
        self.auto_button.on_click(self._on_auto)
        self.row_slider = pn.widgets.IntSlider(label="Profile row y", start=0, end=1, value=0,
                                               sizing_mode="stretch_width")
        self.col_slider = pn.widgets.IntSlider(label="Profile column x", start=0, end=1,
                                               value=0, sizing_mode="stretch_width")
        self.row_slider.param.watch(self._update_profiles, "value")
        self.col_slider.param.watch(self._update_profiles, "value")
        self.download_exr = pn.widgets.FileDownload(
            callback=lambda: self._download("exr"), filename="map.exr", label="EXR",
            color="default", embed=False, width=90,
            description="The selected map as float32 OpenEXR (values, bit-exact)")
        self.download_fits = pn.widgets.FileDownload(
            callback=lambda: self._download("fits"), filename="map.fits", label="FITS",
            color="default", embed=False, width=90,
            description="The selected map as float32 FITS (values, bit-exact)")
        self.download_png = pn.widgets.FileDownload(
            callback=lambda: self._download("png"), filename="map.png", label="PNG",
            color="default", embed=False, width=90,
            description="A 16-bit greyscale picture of the selected map scaled to the current "
                        "colour range (low end 0, high end 65535) — not the values")

    def _build_map_figures(self) -> None:
        """The grid, the readout, the histograms, the profiles and the summary cards."""
        # the shown maps' views side by side, wrapping (fixed-size figures; a GridBox whose
        # children and column count change in one batch fails in BokehJS 3.9)
        self.grid_pane = pn.FlexBox(flex_wrap="wrap", sizing_mode="stretch_width",
                                    css_classes=["ccd-maps"])
        self.readout = pn.pane.Markdown(
            "Move the cursor over a map to read the values of every map; tap to set the "
            "profile row and column.", css_classes=["ccd-readout"], stylesheets=[MAPS_CSS],
            sizing_mode="stretch_width")
        self.hist_row = pn.FlexBox(sizing_mode="stretch_width", css_classes=["ccd-histograms"])
        # side by side in a FlexBox: a Row of stretching plots nested this deep makes Bokeh
        # lay the map grid out at zero size
        # built once (plain Bokeh): the sliders and the selected map replace their data
        self.profiles = map_plots.ProfileFigures()
        self.row_profile_pane = pn.pane.Bokeh(
            self.profiles.row, sizing_mode="stretch_width", height=240, min_width=300,
            styles={"flex": "1 1 45%"})
        self.col_profile_pane = pn.pane.Bokeh(
            self.profiles.col, sizing_mode="stretch_width", height=240, min_width=300,
            styles={"flex": "1 1 45%"})
        self.profiles.row.css_classes = self.profiles.col.css_classes = ["ccd-profile"]
        self.map_note = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(0, 10),
                                         styles={"color": "#6c757d", "font-size": "0.9em"})
        self.dark_table = stats_pane()
        self.fp_table = stats_pane()
        self.check_table = stats_pane()
        self.rules_pane = pn.pane.Markdown("", sizing_mode="stretch_width",
                                           styles={"font-size": "0.85em", "color": "#495057"})
        self.check_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                           styles={"font-size": "0.85em", "color": "#495057"})
        self.dark_card = pn.Card(self.dark_table, self.rules_pane,
                                 title="Dark reference D̂_D (sec. V-A)", collapsible=False,
                                 width=355, visible=False, margin=5)
        self.fp_card = pn.Card(self.fp_table, title="Fixed pattern K̂ (eqs. 45–50)",
                               collapsible=False, width=355, visible=False, margin=5)
        self.check_card = pn.Card(self.check_table, self.check_note,
                                  title="Correction check (sec. VII-A)", collapsible=False,
                                  width=355, visible=False, margin=5)
        self.maps_empty = pn.pane.Markdown("No maps yet.", sizing_mode="stretch_width")

    def _maps_tab_layout(self) -> pn.Column:
        """The Maps tab: the controls, the grid, the summaries, histograms, profiles, export."""
        controls = pn.Column(
            pn.FlexBox(self.shown_select, self.active_select, sizing_mode="stretch_width"),
            pn.Row(pn.Column(self.clim_slider, sizing_mode="stretch_width", min_width=300),
                   self.auto_button, sizing_mode="stretch_width"),
            pn.Row(pn.pane.Markdown("**Zoomed out**, a screen pixel of a map shows:",
                                    margin=(12, 10, 0, 10)),
                   self.overview_select, sizing_mode="stretch_width"),
            sizing_mode="stretch_width")
        export = pn.Row(pn.pane.Markdown("**Export the selected map:**", margin=(12, 10)),
                        self.download_exr, self.download_fits, self.download_png)
        stats = pn.FlexBox(self.dark_card, self.fp_card, self.check_card,
                           sizing_mode="stretch_width", css_classes=["ccd-map-stats"])
        maps_body = pn.Column(
            controls, self.map_note, self.grid_pane, self.readout, stats,
            pn.Card(self.hist_row, title="Histograms (the band is the colour range)",
                    sizing_mode="stretch_width"),
            pn.Card(pn.Row(self.row_slider, self.col_slider, sizing_mode="stretch_width"),
                    pn.FlexBox(self.row_profile_pane, self.col_profile_pane,
                               sizing_mode="stretch_width"),
                    title="Profiles through the selected map (tap a map to move them)",
                    sizing_mode="stretch_width"),
            export, sizing_mode="stretch_width")
        self.maps_body = maps_body
        return pn.Column(self.maps_empty, maps_body, sizing_mode="stretch_width", name="Maps")

    def _update_stats(self, session: Session | None, results: Any) -> None:
        dark, fp, check = results.dark, results.fixed_pattern, results.correction_check
        self.dark_card.visible = dark is not None
        if dark is not None:
            self.dark_table.object = dark_summary(dark)
            self.rules_pane.object = (f"Rules — {html.escape(dark.hot_rule)}; "
                                      f"{html.escape(dark.dead_rule)}.")
        self.fp_card.visible = fp is not None
        if fp is not None:
            self.fp_table.object = fixed_pattern_summary(fp)
        rec = session.max_intensity_frame() if session is not None else None
        self.check_card.visible = fp is not None
        if check is not None and fp is not None:
            self.check_table.object = correction_summary(check)
            self.check_table.visible = True
            self.check_note.object = (f"How much dividing by K̂ (eq. 51) changes "
                                      f"`{rec.relpath if rec else 'the max-intensity frame'}`.")
        elif fp is not None:
            self.check_table.visible = False
            self.check_note.object = (
                f"No maximum-intensity scene frame: capture "
                f"{requirement('correction_check').capture}, just below saturation, to check "
                "how much K̂ changes it." if rec is None
                else "Not computed yet: press **Compute maps**.")

    # ========================================================================= maps =========
    def _set_layers(self, layers: dict[str, MapLayer]) -> None:
        """Show ``layers``: new colour-range sliders, the choices, then (one batch of events)
        the grid and the selected map once each."""
        clims, specs = {}, {}
        for key, layer in layers.items():
            lo, hi = map_plots.default_clim(layer)
            finite = layer.data[np.isfinite(layer.data)]
            start = min(lo, float(finite.min())) if finite.size else lo
            end = max(hi, float(finite.max())) if finite.size else hi
            if layer.kind == "diverging":
                half = max(layer.centre - start, end - layer.centre)
                start, end = layer.centre - half, layer.centre + half
            if not end > start:
                end = start + 1.0
            step = 0.5 if layer.integer else (end - start) / 1000
            clims[key] = (lo, hi)
            specs[key] = dict(
                label=f"Colour range of {layer.symbol}" + (f" ({layer.unit})" if layer.unit
                                                         else ""),
                start=start, end=end, step=step, disabled=layer.kind == "flags")
        self.clims, self._clim_specs = clims, specs
        options = {l.title: k for k, l in layers.items()}
        shown = [k for k in self.shown if k in layers] or \
            [k for k in DEFAULT_SHOWN if k in layers]
        active = self.active if self.active in layers else next(iter(shown), None)
        self.maps_empty.visible = not layers
        if hasattr(self, "maps_body"):
            self.maps_body.visible = bool(layers)
        if layers:
            h, w = next(iter(layers.values())).data.shape
            self.row_slider.param.update(end=max(h - 1, 1), value=h // 2)
            self.col_slider.param.update(end=max(w - 1, 1), value=w // 2)
        set_choices(self, {"shown": (self.shown_select, options, shown),
                           "active": (self.active_select, options, active)}, layers=layers)

    @property
    def active_layer(self) -> MapLayer | None:
        """The selected map (colour range, profiles and export apply to it)."""
        return self.layers.get(self.active)

    @param.depends("layers", "shown", watch=True)
    @batched
    def _build_grid(self) -> None:
        """Show the chosen maps: their views (built on a map's first showing, then fed the new
        data in place) in the grid, and their histograms."""
        for key, view in self.map_views.items():   # maps gone: their data goes too
            if key not in self.layers and view.plane is not None:
                view.show(None)
                self.hist_views[key].show(None)
        keys = [k for k in self.shown if k in self.layers]
        frame_width = 640 if len(keys) == 1 else 380
        maps, hists = [], []
        for key in keys:
            layer, clim = self.layers[key], self.clims[key]
            view = self.map_views.get(key)
            if view is None:
                link = next(iter(self.map_views.values()), None)
                view = self.map_views[key] = map_plots.layer_view(
                    layer, frame_width=frame_width, link=link)
                view.on_pointer, view.on_tap = self._on_pointer, self._on_tap
                self._map_panes[key] = pn.pane.Bokeh(view.figure)
                self.hist_views[key] = HistogramView(height=200,
                                                     title=f"Histogram of {layer.symbol}",
                                                     label=layer.label, symbol=layer.symbol)
                self._hist_panes[key] = pn.pane.Bokeh(
                    self.hist_views[key].figure, height=220, min_width=260,
                    sizing_mode="stretch_width", styles={"flex": "1 1 45%"})
            else:
                view.resize(frame_width)
            if view.plane is not layer.data:
                map_plots.show_layer(view, layer, clim, self.overview)
                values, bins = map_plots.histogram_input(layer)
                self.hist_views[key].show(values, clim, bins=bins)
            view.set_crosshair(self.row_slider.value, self.col_slider.value)
            maps.append(self._map_panes[key])
            hists.append(self._hist_panes[key])
        self.grid_pane.objects = maps
        self.hist_row.objects = hists

    @property
    def grid_views(self) -> list[ImageView]:
        """The views of the shown maps, in display order."""
        return [self.map_views[k] for k in self.shown if k in self.layers and k in self.map_views]

    def _on_clim(self, event: Any) -> None:
        """The slider moved: the selected map's colour range, its view and histogram band."""
        key = self.active
        if self._syncing_clim or key not in self.clims:
            return
        self.clims[key] = tuple(event.new)
        if key in self.map_views:
            self.map_views[key].set_clim(event.new)
            self.hist_views[key].set_band(event.new)

    @batched
    def _on_overview(self, event: Any = None) -> None:
        for key, view in self.map_views.items():
            layer = self.layers.get(key)
            if layer is not None and view.plane is layer.data:
                how = map_plots.overview_how(layer, self.overview)
                view.set_how(how, centre=map_plots.overview_centre(layer)
                             if how == "extreme" else None)

    @param.depends("layers", "active", watch=True)
    @batched
    def _on_active(self) -> None:
        layer = self.active_layer
        if layer is None:
            self.clim_slider.visible = False
            self.map_note.object = ""
        else:
            self._syncing_clim = True
            try:   # bounds, step, label and value at once (one message)
                self.clim_slider.param.update(value=self.clims[layer.key], visible=True,
                                              **self._clim_specs[layer.key])
            finally:
                self._syncing_clim = False
            self.map_note.object = f"**{html.escape(layer.title)}**: {html.escape(layer.note)}."
            for fmt, widget in (("exr", self.download_exr), ("fits", self.download_fits),
                                ("png", self.download_png)):
                widget.filename = f"{layer.key}{EXPORT_FORMATS[fmt]}"
        for w in (self.auto_button, self.download_exr, self.download_fits, self.download_png):
            w.disabled = layer is None
        self._update_profiles()

    @batched
    def _update_profiles(self, event: Any = None) -> None:
        row, col = self.row_slider.value, self.col_slider.value
        self.profiles.update(self.active_layer, row, col)
        for view in self.grid_views:
            view.set_crosshair(row, col)

    def _on_pointer(self, x: float | None = None, y: float | None = None) -> None:
        hit = map_plots.pixel_values(self.layers, x, y)
        if hit is None:
            return
        col, row, values = hit
        parts = []
        for key, text in values.items():
            layer = self.layers[key]
            unit = f" {layer.unit}" if layer.unit and text != "NaN" else ""
            parts.append(f"{layer.symbol} = **{text}**{unit}")
        self.readout.object = f"x = {col}, y = {row}: " + " · ".join(parts)

    def _on_tap(self, x: float | None = None, y: float | None = None) -> None:
        hit = map_plots.pixel_values(self.layers, x, y)
        if hit is not None:
            col, row, _ = hit
            self.row_slider.value, self.col_slider.value = row, col

    def _on_auto(self, event: Any = None) -> None:
        layer = self.active_layer
        if layer is not None:
            spec = self._clim_specs[layer.key]
            lo, hi = map_plots.default_clim(layer)
            self.clim_slider.value = (max(spec["start"], lo), min(spec["end"], hi))

    def export(self, fmt: str) -> bytes:
        """The selected map as the bytes of an EXR, FITS or PNG file (see :func:`export_bytes`;
        PNG uses the selected map's current colour range)."""
        layer = self.active_layer
        if layer is None:
            raise CcdError("export", "no map to export: compute the maps first")
        return export_bytes(layer, fmt, self.clims[layer.key])

    def _download(self, fmt: str) -> io.BytesIO | None:
        try:
            return io.BytesIO(self.export(fmt))
        except (CcdError, OSError, ValueError) as err:
            self.state.error = f"export as {fmt.upper()} failed: {err}"
            return None
