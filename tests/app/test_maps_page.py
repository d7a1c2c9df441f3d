"""The Maps page without a browser: computing on the healey94 demo, the summary values, map
selection, export, linked axes, planning, and sessions that lack frames."""
from __future__ import annotations

import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
import ccdcore.fixedpattern
from ccdcore_app.plots import maps as map_plots
from ccdcore_app.plots import base as plots
from ccdcore_app.image_view import HistogramView
from ccdcore_app.pages.maps import page as maps
from ccdcore_app.pages.maps.page import (MAPS_ESTIMATES, PAPER_PLAN_INPUTS, MapsPage, export_bytes,
                            missing_sentences, scene_patch_frame)
from ccdcore_app.state import AppState
from ccdcore.common import format_pm
from ccdcore.io.frames import read_image
from ccdcore.planning import check_session_plan, plan_acquisition
from ccdcore.product.make import Requirement, budget_inputs, estimate_all, missing_frames
from ccdcore.session import open_session
from _coro import run as _run


@pytest.fixture(scope="module")
def reference(assets):
    """ccdcore's own estimates of the demo, computed independently of the page."""
    return estimate_all(open_session(assets / "healey94"))


class _Counter:
    """Wraps a function and counts its calls."""

    def __init__(self, func):
        self.func, self.calls = func, 0

    def __call__(self, *args, **kwargs):
        self.calls += 1
        return self.func(*args, **kwargs)


@pytest.fixture(scope="module")
def counted(assets):
    """The page on the healey94 demo after 'Compute maps' (computed once for the module), and
    how often the correction check and the plot builders ran meanwhile."""
    state = AppState(allowed_roots=[assets.resolve()])
    assert state.load(assets / "healey94")
    page = MapsPage(state, auto_compute=False)
    counts = {"correction_check": _Counter(ccdcore.fixedpattern.correction_check),
              "show_layer": _Counter(map_plots.show_layer),
              "scene_fit_plot": _Counter(map_plots.scene_fit_plot),
              "budget_plot": _Counter(map_plots.budget_plot)}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ccdcore.fixedpattern, "correction_check", counts["correction_check"])
        for name in ("show_layer", "scene_fit_plot", "budget_plot"):
            mp.setattr(map_plots, name, counts[name])
        _run(page.compute())
    return page, {name: c.calls for name, c in counts.items()}


@pytest.fixture(scope="module")
def computed(counted):
    return counted[0]


def _cell(df, quantity: str) -> str:
    return str(df.loc[df["quantity"] == quantity, "this session"].iloc[0])


def test_compute_fills_the_shared_results(computed):
    results = computed.state.results
    for key in ("ptc", "estimates", "dark", "fixed_pattern", "plan", "scene",
                "correction_check"):
        assert getattr(results, key) is not None, key
    assert results.ptc is results.estimates.noise
    assert computed.state.error == ""
    assert set(computed.layers) == set(map_plots.MAP_TITLES)


def test_maps_and_summary_equal_ccdcore(computed, reference):
    """The page shows ccdcore's numbers (the same estimates as calibrate()), exactly."""
    dark, fp = reference.dark, reference.fixed_pattern
    np.testing.assert_array_equal(computed.layers["K"].data, fp.K)
    np.testing.assert_array_equal(computed.layers["dark"].data, dark.mean_map)
    np.testing.assert_array_equal(computed.layers["n_rejected"].data, fp.n1 - fp.n1_used)
    np.testing.assert_array_equal(computed.layers["K_err"].data, np.sqrt(fp.K_var))
    d, f = dark.to_dict(), fp.to_dict()
    dark_table, fp_table = computed.dark_table.object, computed.fp_table.object
    assert _cell(dark_table, "D̂_D mean (DN)") == format_pm(d["mean"], d["mean_sem"])
    assert _cell(dark_table, "D̂_D spatial std (DN)") == f"{d['spatial_std']:.4g}"
    assert _cell(dark_table, "hot pixels") == str(d["n_hot"])
    assert _cell(fp_table, "K̂ mean") == f"{f['mean']:.6f}"
    assert _cell(fp_table, "K̂ spatial std") == f"{f['spatial_std']:.4g}"
    assert _cell(fp_table, "σ̂ (std of the slopes m_i)") == f"{f['sigma_hat']:.4g}"
    assert _cell(fp_table, "eq. 50 bound √((p·σ̂)²/n̂_1)") == f"{f['sd_bound']:.4g}"
    assert _cell(fp_table, "measured error √mean(var[K̂])") == \
        f"{np.sqrt(f['K_var_mean']):.4g}"
    # the paper's values sit beside them
    assert set(dark_table["paper"]) >= {"10.74", "0.555"}
    assert set(fp_table["paper"]) >= {"0.99998", "3.72e-3"}
    # the sec. VII-A correction check on the max-intensity frame
    check = computed.state.results.correction_check
    assert check.to_dict() == reference.correction_check.to_dict()
    assert _cell(computed.check_table.object, "pixels changed by > 1 q") == \
        f"{100 * check.frac_gt_1q:.1f} %"
    assert computed.check_card.visible and computed.check_table.visible


def test_plan_and_scene_equal_ccdcore(computed, reference):
    plan = computed.state.results.plan
    assert plan.to_dict() == reference.plan.to_dict()
    # the demo has 12 configurations x 4 frames, fewer than the plan: a warning at the top
    warnings = check_session_plan(computed.state.session, plan)
    assert warnings and computed.plan_alert.visible
    assert "12 configurations" in computed.plan_alert.object
    assert f"n1 = {plan.n1_required}" in computed.plan_alert.object
    scene = computed.state.results.scene
    assert list(scene) == list(reference.scene)
    for name, var in reference.scene.items():
        assert scene[name].V_S == var.V_S and scene[name].V_S_err == var.V_S_err
    table = scene_patch_frame(scene)
    assert list(table["patch"]) == list(scene)
    assert computed.patch_table.visible and computed.fit_pane.object is not None


def test_variance_budget_of_the_chosen_patch(computed):
    results = computed.state.results
    for name in results.scene:
        computed.patch_select.value = name
        budget = computed.budget
        assert budget.parameters["V_S"] == pytest.approx(max(results.scene[name].V_S, 0))
        total = sum(budget.fractions[k] for k in budget.fractions)
        np.testing.assert_allclose(total, 1.0, rtol=1e-12)   # fractions of one total
    inputs = budget_inputs(results.dark, results.fixed_pattern, results.ptc,
                           results.scene[name], 8)
    assert inputs["dark_spatial_var"] == pytest.approx(results.dark.spatial_std_signal ** 2)
    assert inputs["mu"][0] == pytest.approx(results.dark.mean)
    assert inputs["mu"][-1] == 255


def test_map_selection_switches_the_data(computed):
    page = computed
    page.active_select.value = "dark"
    assert page.active_layer.key == "dark"
    row = page.row_slider.value
    drawn = page.profiles.sources                 # what the two profile plots draw now
    np.testing.assert_array_equal(drawn["row"].data["value"], page.layers["dark"].data[row])
    assert page.download_exr.filename == "dark.exr"
    # the one colour-range slider now shows the dark map's range, bounds and label
    spec = page._clim_specs["dark"]
    assert page.clim_slider.value == page.clims["dark"] == map_plots.default_clim(
        page.layers["dark"])
    assert (page.clim_slider.start, page.clim_slider.end, page.clim_slider.label) == \
        (spec["start"], spec["end"], "Colour range of D̂_D (DN)")
    page.clim_slider.value = (spec["start"], spec["end"])     # moved for the dark map only
    page.active_select.value = "K"
    np.testing.assert_array_equal(drawn["row"].data["value"], page.layers["K"].data[row])
    assert page.clim_slider.value == page.clims["K"] == map_plots.default_clim(page.layers["K"])
    assert page.clims["dark"] == (spec["start"], spec["end"])
    assert (page.map_views["K"].mapper.low, page.map_views["K"].mapper.high) == page.clims["K"]
    # a column profile follows the column slider
    page.col_slider.value = 17
    np.testing.assert_array_equal(drawn["col"].data["value"], page.layers["K"].data[:, 17])
    assert page.profiles.col.title.text == "Column profile, x = 17"
    # the grid follows the shown maps
    page.shown_select.value = ["dark", "n1_used"]
    assert len(page.grid_pane.objects) == 2
    page.shown_select.value = ["K", "dark", "n_rejected", "flags"]
    assert len(page.grid_pane.objects) == 4
    assert [v.plane is page.layers[k].data for v, k in
            zip(page.grid_views, ("K", "dark", "n_rejected", "flags"))] == [True] * 4
    # the crosshair marks the profile row and column on every map
    page.row_slider.value = 11
    for view in page.grid_views:
        assert (view._spans[0].location, view._spans[1].location) == (11, 17)


def test_cursor_readout_and_tap(computed):
    page = computed
    page._on_pointer(x=10.2, y=20.7)
    k = page.layers["K"].data[21, 10]
    assert page.readout.object.startswith("x = 10, y = 21: ")
    assert f"K̂ = **{k:.5f}**" in page.readout.object
    page._on_pointer(x=-5, y=3)             # outside the maps: the readout stays
    assert page.readout.object.startswith("x = 10, y = 21: ")
    page._on_tap(x=30, y=40)
    assert (page.row_slider.value, page.col_slider.value) == (40, 30)


def test_colour_range_and_auto(computed):
    page = computed
    page.active_select.value = "K"
    slider = page.clim_slider
    lo, hi = map_plots.default_clim(page.layers["K"])
    assert lo + hi == pytest.approx(2.0)    # diverging map centred on 1
    slider.value = (0.995, 1.001)
    page._on_auto()
    assert slider.value == pytest.approx((lo, hi))


def test_export_reads_back_bit_exact(computed, tmp_path):
    page = computed
    page.active_select.value = "K"
    expected = page.layers["K"].data.astype(np.float32)
    for fmt, ext in (("exr", ".exr"), ("fits", ".fits")):
        path = tmp_path / f"K{ext}"
        path.write_bytes(page._download(fmt).getvalue())
        back = read_image(path)
        assert back.dtype == np.float32
        np.testing.assert_array_equal(back, expected)
    # PNG: 16-bit grey levels of the map scaled to the current colour range
    page.clim_slider.value = (0.99, 1.01)
    path = tmp_path / "K.png"
    path.write_bytes(page.export("png"))
    png = read_image(path)
    assert png.dtype == np.uint16 and png.shape == expected.shape
    np.testing.assert_array_equal(png, map_plots.scaled_uint16(page.layers["K"].data,
                                                               (0.99, 1.01)))
    assert png.min() == 0 and png.max() == 65535      # K̂ spans more than 0.99..1.01
    assert "colour range" in page.download_png.description


def test_export_bytes_of_a_small_map(tmp_path):
    data = np.array([[0.0, 1.0], [np.nan, 3.5]], dtype=np.float32)
    layer = map_plots.MapLayer("m", "m", "m", "", data)
    (tmp_path / "m.fits").write_bytes(export_bytes(layer, "fits"))
    np.testing.assert_array_equal(read_image(tmp_path / "m.fits"), data)
    assert map_plots.scaled_uint16(data, (0.0, 2.0)).tolist() == [[0, 32768], [0, 65535]]
    with pytest.raises(ValueError):
        export_bytes(layer, "jpeg")


def test_maps_share_linked_axes(computed):
    """Zooming one map zooms all: the Bokeh figures of the grid share one x and one y range,
    and a zoom draws the visible part of every map again."""
    views = computed.grid_views
    assert len(views) >= 2
    figures = [v.figure for v in views]
    assert [p.object for p in computed.grid_pane.objects] == figures
    assert len({id(f.x_range) for f in figures}) == 1
    assert len({id(f.y_range) for f in figures}) == 1
    figures[0].x_range.update(start=9.5, end=29.5)
    figures[0].y_range.update(start=49.5, end=39.5)
    views[0]._ranges(None)
    for view in views:
        image = view.source.data["image"][0]
        np.testing.assert_array_equal(image, view.plane[40:50, 10:30].astype(np.float32))
    views[0].zoom_out()

def test_planning_panel_with_the_papers_inputs(computed):
    page = computed
    page._on_paper_inputs()
    plan = plan_acquisition(**{k: v for k, v in PAPER_PLAN_INPUTS.items()})
    assert page.plan_result.to_dict() == plan.to_dict()
    assert plan.n1_hat == 11                  # σ̂ = 2.7e-3 reproduces the paper's n̂_1
    assert f"n1 = {plan.n1_required}" in page.plan_numbers.object
    assert f"n2 = {plan.n2_required}" in page.plan_numbers.object
    assert plan.n1_formula in page.plan_formulas.object
    assert plan.n2_formula in page.plan_formulas.object
    alts = page.plan_alternatives.value
    assert dict(zip(alts["n2"], alts["chosen"]))[plan.n2_required] == "✓"
    # a typed input changes the plan; a bad one is an alert, not an exception
    page.plan_bits.value = 12
    assert page.plan_result.n1_required == plan_acquisition(
        **{**PAPER_PLAN_INPUTS, "bits": 12}).n1_required
    page.plan_A.value = 0.0
    assert page.plan_result is None and page.plan_error.visible
    assert "need A &gt; 0" in page.plan_error.object   # (escaped for Markdown)
    # back to this session's estimates: the session's own plan
    page._on_session_inputs()
    session_plan = page.state.results.plan
    assert page.plan_result.n1_required == session_plan.n1_required
    assert page.plan_result.n2_required == session_plan.n2_required


def test_session_without_darks_says_what_to_capture(assets):
    state = AppState(allowed_roots=[assets.resolve()])
    assert state.load(assets / "tsin01")
    page = MapsPage(state, auto_compute=False)
    assert not page._wants_auto_compute()
    assert page.info_alert.visible and page.info_alert.alert_type == "info"
    assert "No `dark` frames" in page.info_alert.object
    assert "No `fixed_pattern` or `dark` frames" in page.info_alert.object
    # everything the page shows is missing, each said once, in ccdcore's words
    lacking = missing_frames(state.session, MAPS_ESTIMATES)
    assert [req.estimate for req, _ in lacking] == list(MAPS_ESTIMATES)
    assert len(missing_sentences(state.session)) == len(MAPS_ESTIMATES)
    for req, _ in lacking:
        assert req.capture in page.info_alert.object and req.purpose in page.info_alert.object
    _run(page.compute())                     # nothing to estimate: still no error, no maps
    assert state.error == "" and page.layers == {}
    assert page.maps_empty.visible and not page.plan_alert.visible


def test_bad_frames_are_an_alert_and_the_page_keeps_working(small_session, tmp_path, assets):
    """One ptc level only: photon transfer refuses (CcdError) and the page shows it."""
    state = AppState(allowed_roots=[tmp_path.resolve(), assets.resolve()])
    assert state.load(small_session)
    page = MapsPage(state, auto_compute=False)
    assert page._wants_auto_compute()
    _run(page.compute())
    assert page.error_alert.visible and "ptc level" in page.error_alert.object
    assert not page.compute_button.loading
    # another session clears the alert's cause and computes fine
    assert state.load(assets / "healey94")
    assert "Press **Compute maps**" in page.info_alert.object
    results = page.state.results
    assert results.estimates is None and results.ptc is None and page.layers == {}
    assert not page.error_alert.visible


def test_map_plot_functions():
    plane = np.arange(12, dtype=np.float64).reshape(3, 4)
    layer = map_plots.MapLayer("k", "K", "K", "", 1 + plane / 100, kind="diverging", centre=1)
    lo, hi = map_plots.default_clim(layer)
    assert lo + hi == pytest.approx(2.0)
    flags = map_plots.MapLayer("f", "F", "flag", "", np.zeros((3, 4)), kind="flags")
    assert map_plots.default_clim(flags) == (-0.5, 2.5)
    hit = map_plots.pixel_values({"k": layer, "f": flags}, 3.4, 1.6)
    assert hit == (3, 2, {"k": f"{1 + 11 / 100:.5f}", "f": "normal"})
    assert map_plots.pixel_values({"k": layer}, 4.6, 0) is None
    cols = map_plots.profile_columns(layer, 1, 9)
    assert cols["row"]["value"].tolist() == (1 + plane[1] / 100).tolist()
    assert cols["col"]["value"].tolist() == (1 + plane[:, 3] / 100).tolist()  # clipped to x = 3
    assert cols["at"] == {"row": 1, "col": 3}
    with pytest.raises(ValueError):
        map_plots.scaled_uint16(plane, (1.0, 1.0))


def test_page_builds_its_layout(computed):
    view = computed.__panel__()
    assert view is computed.__panel__()       # built once, shown again
    computed.tab_bar.value = "Planning"
    assert computed.tab_content.objects[0].name == "Planning"
    computed.tab_bar.value = "Maps"


def test_a_complete_session_lacks_nothing(assets):
    assert missing_sentences(open_session(assets / "healey94")) == []


def test_the_correction_check_is_computed_once(counted):
    """estimate_all makes the correction check (on the max-intensity frame); the page shows
    that one and runs no second check."""
    page, counts = counted
    assert counts["correction_check"] == 1
    assert page.state.results.correction_check is page.state.results.estimates.correction_check
    assert page.check_table.visible


def test_compute_builds_each_plot_once(counted):
    """One batch of state changes per compute: each shown map (K̂ and D̂_D), the scene fit and
    the budget of the chosen patch are each drawn once."""
    _, counts = counted
    assert counts["show_layer"] == 2
    assert counts["scene_fit_plot"] == 1
    assert counts["budget_plot"] == 1


def test_missing_frames_text_comes_from_ccdcores_requirements(assets, monkeypatch):
    """The info alert says what ccdcore's requirement says (no text of the app's own)."""
    req = Requirement("dark", ("dark",), "the purpose of a test requirement",
                      "what a test requirement asks to capture")
    asked = []

    def fake(session, estimates=None):
        asked.append(tuple(estimates))
        return [(req, ("dark", "a flagged frame"))]

    monkeypatch.setattr(maps, "missing_frames", fake)
    state = AppState(allowed_roots=[assets.resolve()])
    assert state.load(assets / "tsin01")
    page = MapsPage(state, auto_compute=False)
    assert asked and asked[-1] == MAPS_ESTIMATES
    assert page.info_alert.object == ("**No `dark` frames and no a flagged frame** for the "
                                      "purpose of a test requirement: capture what a test "
                                      "requirement asks to capture.")


def test_choices_on_computed_maps_update_the_plots_in_place(assets):
    """The selected map, the profile sliders and a colour range change data and options of
    the drawn plots, never the plots: the same Bokeh figures before and after."""
    from bokeh.document import Document

    state = AppState(allowed_roots=[assets.resolve()])
    assert state.load(assets / "healey94")
    page = MapsPage(state, auto_compute=False)
    _run(page.compute())
    root = page.__panel__().get_root(Document())

    def models(kind: str) -> dict:
        return {m.id: m for m in root.references() if type(m).__name__ == kind}

    figures = set(models("figure"))
    assert len(figures) >= 2 + 2 + 2      # maps, their histograms, two profiles

    def profile_values() -> list[set]:
        """The values the two profile plots draw."""
        return [set(src.data["value"]) for src in models("ColumnDataSource").values()
                if "value" in src.data]

    row = page.row_slider.value
    page.active_select.value = "dark"
    dark = page.layers["dark"].data
    assert set(dark[row]) in profile_values() and set(dark[:, 0]) not in profile_values()
    page.row_slider.value = row + 3
    page.col_slider.value = 5
    assert set(dark[row + 3]) in profile_values() and set(dark[:, 5]) in profile_values()
    slider = page.clim_slider
    lo, hi = slider.value
    slider.value = (lo, (lo + hi) / 2)
    mappers = [m for m in root.references() if type(m).__name__ == "LinearColorMapper"]
    assert any(m.high == pytest.approx((lo + hi) / 2) for m in mappers)
    bands = [m for m in root.references() if type(m).__name__ == "BoxAnnotation"]
    assert any(b.left == lo and b.right == pytest.approx((lo + hi) / 2) for b in bands)
    assert set(models("figure")) == figures


# ------------------------------------------------------------------------- overviews ------
def test_overview_blocks_mean_extreme_and_max():
    rng = np.random.default_rng(3)
    plane = rng.normal(1.0, 0.01, (60, 90))
    # every pixel when the screen has room; the crop covers every pixel the ranges overlap
    out, bounds, f = plots.overview(plane, (10.2, 20.7), (0, 59), 400, 400)
    assert f == 1 and bounds == (9.5, -0.5, 21.5, 59.5)
    np.testing.assert_array_equal(out, plane[:, 10:22])
    # 90 x 60 pixels on 30 x 30 screen pixels: blocks of 3 x 3
    mean, bounds, f = plots.overview(plane, None, None, 30, 30, how="mean")
    assert f == 3 and mean.shape == (20, 30) and bounds == (-0.5, -0.5, 89.5, 59.5)
    np.testing.assert_allclose(mean, plane.reshape(20, 3, 30, 3).mean(axis=(1, 3)),
                               rtol=1e-12)
    # one cold pixel survives as itself in the extreme view; the mean dilutes it by f^2
    plane[31, 47] = 0.5
    ext, _, _ = plots.overview(plane, None, None, 30, 30, how="extreme", centre=1.0)
    mean, _, _ = plots.overview(plane, None, None, 30, 30, how="mean")
    assert ext[10, 15] == 0.5 and np.nanmin(ext) == 0.5
    assert mean[10, 15] == pytest.approx(plane[30:33, 45:48].mean()) and mean.min() > 0.9
    block = plane[0:3, 0:3]
    assert ext[0, 0] == block.flat[np.argmax(np.abs(block - 1.0))]
    # partial edge blocks and NaN: ignored, a block of NaN only stays NaN
    odd = np.arange(7 * 5, dtype=np.float64).reshape(7, 5)
    odd[0:3, 0:3] = np.nan
    mx, bounds, f = plots.overview(odd, None, None, 2, 3, how="max")
    assert f == 3 and mx.shape == (3, 2) and bounds == (-0.5, -0.5, 5.5, 8.5)
    assert np.isnan(mx[0, 0]) and mx[2, 1] == odd[6, 4] and mx[0, 1] == odd[2, 4]
    mean, _, _ = plots.overview(odd, None, None, 2, 3, how="mean")
    assert mean[2, 0] == pytest.approx(odd[6, 0:3].mean())
    with pytest.raises(ValueError, match="how"):
        plots.overview(odd, None, None, 2, 3, how="median")


def _blocks_reference(crop, f, how, centre):
    """Block reduction written out block by block (what plots.overview must return)."""
    nh, nw = -(-crop.shape[0] // f), -(-crop.shape[1] // f)
    out = np.full((nh, nw), np.nan)
    for i in range(nh):
        for j in range(nw):
            block = crop[i * f:(i + 1) * f, j * f:(j + 1) * f].astype(np.float64).ravel()
            block = block[np.isfinite(block)]
            if block.size == 0:
                continue
            if how == "mean":
                out[i, j] = block.sum() / block.size
            elif how == "max":
                out[i, j] = block.max()
            else:
                out[i, j] = block[np.argmax(np.abs(block - centre))]
    return out


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.float32, np.float64,
                                   np.bool_, np.int16])
def test_overview_equals_the_block_by_block_reduction(dtype):
    rng = np.random.default_rng(11)
    plane = (rng.random((53, 71)) * 200).astype(dtype)
    if np.issubdtype(dtype, np.floating):
        plane[rng.random(plane.shape) < 0.05] = np.nan
        plane[0:4, 0:4] = np.nan                                # a block of NaN only
    # the whole map, and the pixels ranges x 3.2..60.7, y 5.0..40.4 overlap (columns 3..61,
    # rows 5..40)
    for x_range, y_range, crop in ((None, None, plane), ((3.2, 60.7), (5.0, 40.4),
                                                         plane[5:41, 3:62])):
        for how in ("mean", "max", "extreme"):
            out, _, f = plots.overview(plane, x_range, y_range, 7, 9, how=how, centre=100.0)
            assert f > 1
            np.testing.assert_allclose(out, _blocks_reference(crop, f, how, 100.0),
                                       rtol=1e-12, equal_nan=True)


def test_zoomed_out_map_view_says_what_a_screen_pixel_shows():
    data = np.ones((100, 160), dtype=np.float32)
    data[40, 70] = 1.3                                   # one hot pixel
    layer = map_plots.MapLayer("K", "Fixed pattern K", "K", "", data, "RdBu_r",
                               kind="diverging", centre=1.0)
    view = map_plots.layer_view(layer, frame_width=40)
    map_plots.show_layer(view, layer, (0.9, 1.1), "extreme")
    image = view.source.data["image"][0]
    assert view.figure.title.text == "Fixed pattern K \u00b7 extreme pixel of 4\u00d74 px"
    assert np.nanmax(image) == pytest.approx(1.3)
    assert (view.mapper.low, view.mapper.high) == (0.9, 1.1)
    map_plots.show_layer(view, layer, (0.9, 1.1), "mean")
    image = view.source.data["image"][0]
    assert view.figure.title.text.endswith("mean of 4\u00d74 px")
    assert np.nanmax(image) == pytest.approx(1 + 0.3 / 16)
    # counts and flags always show the largest value; flags as three labelled categories
    flags = map_plots.MapLayer("flags", "Hot / dead", "flag", "", np.zeros((100, 160)),
                               list(map_plots.FLAG_COLORS), kind="flags")
    flags.data[3, 3] = 1
    view = map_plots.layer_view(flags, frame_width=40)
    map_plots.show_layer(view, flags, map_plots.default_clim(flags), "mean")
    assert "largest of 4\u00d74 px" in view.figure.title.text
    assert view.source.data["image"][0].max() == 1
    assert view.mapper.palette == list(map_plots.FLAG_COLORS)
    assert view.color_bar.major_label_overrides == {0: "normal", 1: "hot", 2: "dead"}


def test_histogram_counts_every_finite_value_in_plain_numbers():
    data = np.arange(12, dtype=np.float64).reshape(3, 4)
    data[0, 0] = np.nan
    layer = map_plots.MapLayer("d", "D", "D", "DN", data)
    values, bins = map_plots.histogram_input(layer)
    assert bins == 100
    hist = HistogramView()
    hist.show(values, (2.0, 9.0), bins=bins)
    assert sum(hist.source.data["top"]) == 11          # NaN left out
    assert (hist.band.left, hist.band.right) == (2.0, 9.0)
    assert hist.figure.yaxis[0].formatter.format == "0,0"
    counts = map_plots.MapLayer("n", "N", "n", "", np.array([[0, 1], [1, 3]], np.float32),
                                kind="count")
    values, bins = map_plots.histogram_input(counts)
    hist.show(values, bins=bins)
    np.testing.assert_array_equal(hist.source.data["top"], [1, 2, 0, 1])   # one bin per value


def test_what_a_darks_and_flats_session_cannot_give_folds_below_one_line(tmp_path):
    """A cooled CCD's biases, darks and flats (no photon-transfer pairs, no fixed-pattern
    frames): once the dark map is shown, the five estimates it cannot give are one folded card,
    not five paragraphs pushing the map below the first view (a real CCD's set did)."""
    from ccdcore.simulate import simulate

    root = tmp_path / "lab"
    simulate("ccdlab", root, seed=0, size=(64, 48))
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root)
    page = MapsPage(state, auto_compute=False)
    _run(page.compute())
    assert state.results.estimates is not None and page.layers
    lines = missing_sentences(state.session)
    assert len(lines) > 1
    assert not page.info_alert.visible
    assert page.info_card.visible and page.info_card.collapsed
    assert page.info_card.title.startswith(f"{len(lines)} estimates this session's frames "
                                           "cannot give")
    for line in lines:
        assert line in page.info_details.object
