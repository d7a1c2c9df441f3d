"""The Maps page's Scene tab: the scene variation V_S and the variance budget (Figs. 3 and 4).

Public objects
--------------
SceneTab
    The part of :class:`ccdcore_app.pages.maps.page.MapsPage` (a ``param`` mixin: the tab's state
    and its watchers) that shows V_S ± error per patch and per light level, the eq. 57 fit (Fig. 3)
    and the variance budget (Fig. 4) of the chosen patch
    (:func:`ccdcore.product.make.budget_inputs`,
    :func:`ccdcore.scene.variance_budget`).
"""
from __future__ import annotations

import html
from typing import Any

import panel as pn
import param

from ccdcore.errors import CcdError
from ccdcore.product.make import budget_inputs, requirement
from ccdcore.scene import variance_budget

from ...plots import maps as map_plots
from .._choices import set_choices
from .tables import (data_table, display_frame, maps_alert, scene_level_frame,
                           scene_patch_frame)

__all__ = ["SceneTab"]


class SceneTab(param.Parameterized):
    """Mixin of the Maps page: the Scene tab (see the module docstring)."""

    state: Any

    scene = param.Dict(default=None, allow_None=True, precedence=-1, doc=(
        "The scene variation per patch shown (state.results.scene), or None."))
    patch = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "The scene patch whose light levels and variance budget (Fig. 4) are shown."))

    def _build_scene_tab(self) -> None:
        self.patch_table = data_table()
        self.patch_select = pn.widgets.Select.from_param(self.param.patch, label="Patch",
                                                         width=260)
        self.level_table = data_table()
        self.fit_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", height=380,
                                          linked_axes=False, css_classes=["ccd-scene-fit"])
        self.budget_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", height=380,
                                             linked_axes=False, css_classes=["ccd-budget"])
        self.budget_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            styles={"font-size": "0.88em", "color": "#495057"})
        self.scene_alert = maps_alert("", "danger")
        self.scene_empty = pn.pane.Markdown(
            "No scene variation yet: compute the maps with a session holding photon-transfer "
            f"frames and {requirement('scene').capture}.", sizing_mode="stretch_width")

    def _scene_tab_layout(self) -> pn.Column:
        """The Scene tab: V_S per patch, the fit, the chosen patch's levels and budget."""
        return pn.Column(
            self.scene_empty, self.scene_alert,
            pn.Row(pn.Card(self.patch_table, title="V_S per patch (eq. 57 fit across levels)",
                           collapsible=False, sizing_mode="stretch_width"),
                   sizing_mode="stretch_width"),
            self.fit_pane,
            pn.Card(self.patch_select, self.level_table,
                    title="Per light level (eqs. 54–58)", collapsible=False,
                    sizing_mode="stretch_width"),
            self.budget_pane, self.budget_note,
            sizing_mode="stretch_width", name="Scene")

    # ======================================================================== scene =========
    def _set_scene(self, scene: dict | None) -> None:
        """Show ``scene`` (V_S per patch): its patches to choose from, keeping the chosen one."""
        if scene is self.scene:
            return
        names = list(scene or {})
        patch = self.patch if self.patch in names else next(iter(names), None)
        set_choices(self, {"patch": (self.patch_select, names, patch)}, scene=scene)

    @param.depends("scene", watch=True)
    def _show_scene(self) -> None:
        scene = self.scene
        has = bool(scene)
        self.scene_empty.visible = not has
        for w in (self.patch_table, self.fit_pane, self.patch_select, self.level_table,
                  self.budget_pane, self.budget_note):
            w.visible = has
        if has:
            self.patch_table.value = display_frame(scene_patch_frame(scene))
            self.fit_pane.object = map_plots.scene_fit_plot(scene)

    @param.depends("scene", "patch", watch=True)
    def _update_patch(self) -> None:
        variation = (self.scene or {}).get(self.patch)
        if variation is None:
            return
        self.level_table.value = display_frame(scene_level_frame(variation))
        results = self.state.results
        dark, fp, noise = results.dark, results.fixed_pattern, results.ptc
        self.scene_alert.visible = False
        if dark is None or fp is None or noise is None:
            self.budget_pane.object = None
            return
        bits = getattr(getattr(self.state.session, "camera", None), "bits", None)
        inputs = budget_inputs(dark, fp, noise, variation, bits)
        try:
            budget = variance_budget(**inputs)
        except CcdError as err:
            self.scene_alert.object = f"**Variance budget:** {html.escape(str(err))}"
            self.scene_alert.visible = True
            self.budget_pane.object = None
            return
        self.budget = budget
        self.budget_pane.object = map_plots.budget_plot(budget)
        self.budget_note.object = (
            f"Patch **{html.escape(variation.name)}**: V_S = {inputs['V_S']:.4g}, "
            f"A = {inputs['A']:.4g} DN/e⁻, σ²_C = {inputs['sigma_c2']:.4g} DN², dark spatial "
            f"variance {inputs['dark_spatial_var']:.4g} DN² (D̂_D without its averaging noise), "
            f"σ_K² = {inputs['sigma_K2']:.4g} (K̂'s spatial variance less its mean estimation "
            f"variance), b0 = {inputs['black_level']:g} DN, D̄ = {inputs['dark_mean']:.4g} DN. "
            "Below the crossing the sensor noise dominates; above it K and the scene texture do.")
