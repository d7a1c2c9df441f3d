"""The Photon transfer page without a browser: its wiring to ccdcore and its plot functions."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from bokeh.document import Document

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
from ccdcore_report import ptc as ptc_plots
from ccdcore_app.pages.photon_transfer import (NO_PTC_MESSAGE, PhotonTransferPage, parameter_frame,
                                       verdict_message)
from ccdcore_app.state import AppState
from ccdcore.common import check_roi, format_pm
from ccdcore.guide import ptc_gate
from ccdcore.errors import CcdError
from ccdcore.io.frames import write_image
from ccdcore.noise import USER_EXCLUDED, photon_transfer
from ccdcore.planning import check_session_plan, plan_acquisition
from ccdcore.product.make import Estimates
from _coro import run as _run


@pytest.fixture
def state(tmp_path, assets):
    return AppState(allowed_roots=[tmp_path.resolve(), assets.resolve()])


@pytest.fixture(scope="module")
def demo_pt(assets):
    return photon_transfer(assets / "healey94")


def _page(state: AppState, path: Path) -> PhotonTransferPage:
    assert state.load(path), state.error
    page = PhotonTransferPage(state, auto=False)
    _run(page.refresh())
    return page


def _ptc_session(root: Path, means: list[float], *, inflate: dict[int, float] | None = None,
                 seed: int = 11) -> Path:
    """Mono 12-bit pairs of 64x64 frames with σ²_N = A·μ + σ²_C (A = 0.25, σ²_C = 9); the
    variance of the levels in ``inflate`` (level -> factor) is multiplied by the factor."""
    rng = np.random.default_rng(seed)
    inflate = inflate or {}
    entries = []
    for level, mean in enumerate(means, start=1):
        var = (0.25 * mean + 9.0) * inflate.get(level, 1.0)
        for k in "ab":
            frame = np.clip(np.rint(rng.normal(mean, math.sqrt(var), (64, 64))), 0, 4095)
            write_image(root / f"ptc/L{level}_{k}.tif", frame.astype(np.uint16), bits=12,
                        exposure=0.01)
            entries.append(f'[[frames]]\npath = "ptc/L{level}_{k}.tif"\nrole = "ptc"\n'
                           f'level = {level}\nexposure = 0.01\n')
    (root / "session.toml").write_text(
        'schema = 1\n[camera]\nname = "robust test"\nbits = 12\nlayout = "mono"\n'
        'black_level = 0\n\n' + "\n".join(entries))
    return root


# ------------------------------------------------------------------------- the demo --------
def test_demo_fit_equals_photon_transfer(state, healey94, demo_pt):
    page = _page(state, healey94)
    assert page.result is not None and page.error == ""
    # the same estimator on the same frames: equal to rounding
    assert page.result.A == pytest.approx(demo_pt.A, rel=0, abs=1e-12)
    assert page.result.sigma_c2 == pytest.approx(demo_pt.sigma_c2, rel=0, abs=1e-12)
    assert page.result.black_level_source == demo_pt.black_level_source
    assert page.result.notes == demo_pt.notes
    assert len(page.points) == 8 and all(p.used for p in page.points)
    # shared with the other pages under the agreed names
    assert state.results.ptc is page.result
    assert state.results.ptc_points == page.points
    # the parameter table, the verdict, the plots
    table = page.parameter_table.object
    a_row = table[table["symbol"] == "A"].iloc[0]
    assert a_row["value"] == format_pm(demo_pt.A, demo_pt.A_err)
    assert a_row["unit"] == "DN/e\u207b"
    assert set(table["symbol"]) >= {"A", "1/A", "\u03c3\u00b2_C", "\u03c3_R", "A\u00b7\u03c3_R",
                                     "q\u00b2/12", "b\u2080", "\u03c7\u00b2", "\u03bd", "Q"}
    assert page.verdict_alert.visible and page.verdict_alert.alert_type == "success"
    assert page.verdict_alert.object.startswith("**Passed**")
    drawn_points, drawn_fit = page.drawn                  # what the three plots draw
    assert len(drawn_points) == 8 and drawn_fit is page.result
    assert len(page.points_table.object) == 8
    assert page.level_select.value == list(range(1, 9))
    assert not page.info_alert.visible and not page.error_alert.visible
    assert page.content.visible


def test_excluding_a_level_refits_at_once_and_marks_the_point(state, healey94, demo_pt):
    page = _page(state, healey94)
    page.level_select.value = [lv for lv in range(1, 9) if lv != 8]
    assert page.result.A != demo_pt.A
    expected = photon_transfer(healey94, exclude_levels=[8])
    assert page.result.A == pytest.approx(expected.A, rel=0, abs=1e-12)
    p8 = next(p for p in page.result.points if p.level == 8)
    assert not p8.used and p8.exclusion == "user" and p8.reason == USER_EXCLUDED
    assert page.points_table.object.iloc[7]["status"] == "excluded"
    table = page.parameter_table.object
    assert table[table["symbol"] == "A"].iloc[0]["value"] == format_pm(expected.A,
                                                                          expected.A_err)
    assert state.results.ptc is page.result
    # back to all levels
    page._on_all_levels()
    assert page.result.A == pytest.approx(demo_pt.A, rel=0, abs=1e-12)


def test_too_few_levels_is_an_alert_and_the_points_stay(state, healey94):
    page = _page(state, healey94)
    page.level_select.value = [1, 2]
    assert page.result is None
    assert page.error_alert.visible and "need at least 3" in page.error_alert.object
    assert len(page.drawn[0]) == 8 and page.drawn[1] is None  # points
    assert page.parameter_table.object.empty and not page.verdict_alert.visible
    assert list(page.points_table.object["status"]).count("excluded") == 6
    page.level_select.value = [1, 2, 3]
    assert page.result is not None and not page.error_alert.visible


def test_roi_apply_changes_the_pixels_and_full_frame_resets(state, healey94):
    page = _page(state, healey94)
    assert page.shape == (192, 256)
    page.x_input.value, page.y_input.value, page.w_input.value, page.h_input.value = \
        10, 20, 64, 32
    assert _run(page.apply_roi())
    assert page.roi == (10, 20, 64, 32) and page.result.roi == (10, 20, 64, 32)
    assert {p.n_pixels for p in page.result.points} == {64 * 32}
    expected = photon_transfer(healey94, roi=(10, 20, 64, 32))
    assert page.result.A == pytest.approx(expected.A, rel=0, abs=1e-12)
    assert state.results.ptc_points == page.points
    assert "64 \u00d7 32" in page.roi_status.object
    assert _run(page.full_frame())
    assert page.roi is None and {p.n_pixels for p in page.result.points} == {256 * 192}
    assert (page.w_input.value, page.h_input.value) == (256, 192)


def test_bad_roi_is_an_alert_and_keeps_the_fit(state, healey94, demo_pt):
    page = _page(state, healey94)
    page.x_input.value, page.w_input.value = 200, 100
    assert not _run(page.apply_roi())
    # the alert says what ccdcore's ROI check says about this region
    with pytest.raises(CcdError) as refused:
        check_roi((200, 0, 100, 192), (192, 256))
    assert page.error_alert.visible and refused.value.problem in page.error_alert.object
    assert page.result is not None and page.result.roi is None
    assert page.result.A == pytest.approx(demo_pt.A, rel=0, abs=1e-12)


def test_box_drawn_on_the_preview_sets_the_inputs(state, healey94):
    page = _page(state, healey94)
    view = page.preview_view
    assert view.plane is not None and page.preview_pane.visible and view.on_box is not None
    # pixel centres are at integers: the box takes the pixels whose centres it holds
    view.on_box((-0.5, 9.6, 63.5, 41.4))
    assert page._pending_roi() == (0, 10, 64, 32)
    # the outline follows the inputs, along the pixel edges
    assert (view._box.left, view._box.top, view._box.right, view._box.bottom) == \
        (-0.5, 9.5, 63.5, 41.5)
    view.on_box((249.8, 180.0, 400.0, 300.0))  # clipped to the frame
    assert page._pending_roi() == (250, 180, 6, 12)
    view.on_box((5.1, 5.2, 5.3, 5.4))  # inside one pixel: that pixel
    assert page._pending_roi()[2:] == (1, 1)


def test_robust_mode_drops_the_outlier(state, tmp_path):
    root = _ptc_session(tmp_path / "outlier", [150, 500, 900, 1400, 2000, 2600, 3200],
                        inflate={4: 1.3})
    page = _page(state, root)
    assert page.result.verdict == "model rejected"
    assert page.verdict_alert.alert_type == "danger"
    page.robust = True
    assert page.result.robust_dropped == (4,)
    assert "level 4" in page.robust_pane.object
    p4 = next(p for p in page.result.points if p.level == 4)
    assert not p4.used and p4.exclusion == "robust"
    expected = photon_transfer(root, robust=True)
    assert page.result.A == pytest.approx(expected.A, rel=0, abs=1e-12)
    page.robust = False
    assert page.result.robust_dropped == () and all(p.used for p in page.result.points)


def test_the_emva_range_refits_without_reading_frames(state, assets, monkeypatch):
    """The EMVA 1288 range (0–70 % of the saturation signal) is a refit of the measured points:
    the levels above it are left out as "range", the verdict says which range was used, and
    unticking it gives the default fit back."""
    from ccdcore.noise import EMVA_FIT_FRACTION

    root = assets / "healey94"
    page = _page(state, root)
    default = page.result
    assert "every level below saturation" in page.verdict_alert.object
    import ccdcore_app.pages.photon_transfer as pt_page

    monkeypatch.setattr(pt_page, "ptc_points", None)      # no frame may be read again
    monkeypatch.setattr(pt_page, "photon_transfer", None)
    page.emva_range = True
    expected = photon_transfer(root, fit_fraction=EMVA_FIT_FRACTION)
    assert [p.used for p in page.result.points] == [p.used for p in expected.points]
    assert any(p.exclusion == "range" for p in page.result.points)
    assert page.result.A == pytest.approx(expected.A, rel=1e-12)
    assert "EMVA 1288 range" in page.verdict_alert.object
    page.emva_range = False
    assert page.result is default


def test_a_session_without_ptc_frames_says_what_to_capture(state, assets):
    page = _page(state, assets / "tsin01")
    assert page.info_alert.visible and page.info_alert.object == NO_PTC_MESSAGE
    assert "three or more light levels" in page.info_alert.object
    assert not page.content.visible and page.result is None


def test_two_levels_show_the_points_and_why_there_is_no_fit(state, tmp_path):
    root = _ptc_session(tmp_path / "two", [300, 2000])
    page = _page(state, root)
    assert page.result is None and len(page.points) == 2
    assert page.error_alert.visible and "need at least 3" in page.error_alert.object
    assert len(page.drawn[0]) == 2 and page.drawn[1] is None


def test_no_session_and_session_change(state, healey94, assets):
    page = PhotonTransferPage(state, auto=False)
    assert page.info_alert.visible and "No session" in page.info_alert.object
    _run(page.refresh())
    assert page.result is None
    state.load(healey94)
    _run(page.refresh())
    assert page.result is not None
    page.level_select.value = [1, 2, 3, 4]
    state.load(assets / "tsin01")
    assert page.result is None and page.level_select.options == {}  # forgotten at once
    _run(page.refresh())
    assert page.info_alert.visible and not page.content.visible


def test_reuses_another_pages_fit_without_its_choices(state, healey94, demo_pt):
    state.load(healey94)
    state.results.ptc = photon_transfer(healey94, exclude_levels=[3])
    page = PhotonTransferPage(state, auto=False)
    _run(page.refresh())
    assert page.result.A == pytest.approx(demo_pt.A, rel=0, abs=1e-12)
    assert all(p.used for p in page.result.points)
    assert state.results.ptc_points == page.points


def test_plan_warnings_are_shown(state, tmp_path):
    root = _ptc_session(tmp_path / "plan", [150, 900, 2000, 3200])
    page = _page(state, root)
    assert not page.plan_alert.visible
    plan = plan_acquisition(page.result, bits=12, sigma_hat=2e-3)
    warnings = check_session_plan(state.session, plan)
    assert warnings  # no fixed-pattern frames at all
    state.results.estimates = Estimates(noise=page.result, plan=plan,
                                        plan_warnings=tuple(warnings))
    assert page.plan_alert.visible and warnings[0] in page.plan_alert.object


# ------------------------------------------------------------------------- formatting -------
def test_format_pm_and_verdicts(demo_pt):
    assert format_pm(0.0034649085, 4.759e-05) == "0.003465 \u00b1 0.000048"
    assert format_pm(288.6, 3.96) == "288.6 \u00b1 4.0"
    assert format_pm(12346.0, 678.0) == "12350 \u00b1 680"
    assert format_pm(float("nan"), 1.0) == "n/a"
    assert format_pm(2.5) == "2.5"
    # the page shows the gate of ccdcore.guide in the Walkthrough's words (one verdict)
    kind, text = verdict_message(demo_pt)
    gate = ptc_gate(demo_pt)
    assert kind == "success" and text.startswith(f"**{gate.label}** \u2014 {gate.summary}")
    assert gate.label == "Passed" and f"Q = {demo_pt.Q:.3g}" in text
    # a level 30 % off the line, resolved by its errors: failed, naming the two worst levels
    used = [p for p in demo_pt.points if p.used]
    bad = used[len(used) // 2]
    points = tuple(dataclasses.replace(p, var=p.var * 1.3) if p is bad else p
                   for p in demo_pt.points)
    off = dataclasses.replace(demo_pt, points=points, chi2=1e4, Q=1e-30)
    kind, text = verdict_message(off)
    assert kind == "danger" and text.startswith("**Failed**")
    assert ptc_gate(off).summary in text
    z = {p.level: (p.var - (off.A * p.mu + off.sigma_c2)) / p.var_err
         for p in off.points if p.used}
    worst = sorted(z, key=lambda lv: -abs(z[lv]))[:2]
    assert off.worst_levels(2) == [(lv, z[lv]) for lv in worst] and worst[0] == bad.level
    assert "largest residuals: " + ", ".join(
        f"level {lv} ({z[lv]:+.1f} \u03c3)" for lv in worst) in text
    frame = parameter_frame(demo_pt, (192, 256))
    assert "full frame (256 \u00d7 192 px)" in frame.iloc[-1]["value"]
    assert "from the manifest" in frame[frame["symbol"] == "b\u2080"].iloc[0]["value"]


# ------------------------------------------------------------------------- plot functions ---
def test_transfer_columns_band_line_and_points(healey94):
    pt = photon_transfer(healey94, exclude_levels=[2])
    cols = ptc_plots.transfer_columns(pt.points, pt)
    band = cols["band"]
    mu = band["mu"]
    value, std = pt.fit.predict(mu)
    # the band is exactly LineFit.predict: centre the line, half-width its std
    np.testing.assert_array_equal(band["var"], value)
    np.testing.assert_allclose(band["upper"] - band["var"], std, rtol=0, atol=1e-12)  # rounding
    np.testing.assert_allclose(band["var"] - band["lower"], std, rtol=0, atol=1e-12)
    assert mu.min() <= min(p.mu for p in pt.points) and mu.max() >= max(p.mu for p in pt.points)
    np.testing.assert_allclose(band["var"], pt.A * mu + pt.sigma_c2, rtol=1e-12)
    used, excluded = cols["used"], cols["excluded"]
    assert used["level"] == [1, 3, 4, 5, 6, 7, 8]
    assert excluded["level"] == [2] and excluded["reason"] == [USER_EXCLUDED]   # in the hover
    np.testing.assert_array_equal(used["err"], [p.var_err for p in pt.points if p.used])
    np.testing.assert_allclose(used["hi"] - used["var"], used["err"], rtol=1e-9)
    # without a fit: the points only (the band empty, the same sources)
    bare = ptc_plots.transfer_columns(pt.points)
    assert len(bare["band"]["mu"]) == 0 and set(bare) == set(cols)
    assert bare["used"]["level"] == used["level"] and bare["excluded"]["level"] == [2]


def test_residual_and_loglog_columns(healey94):
    pt = photon_transfer(healey94)
    res = ptc_plots.residual_columns(pt)
    assert res["excluded"]["level"] == []   # every level used: no hollow point
    expected = [(p.var - (pt.A * p.mu + pt.sigma_c2)) / p.var_err for p in pt.points]
    np.testing.assert_allclose(res["used"]["residual"], expected, rtol=1e-9)
    np.testing.assert_array_equal(res["used"]["err"], 1.0)
    assert ptc_plots.residual_limit(res) == max(3.8, max(abs(v) for v in expected) + 1.2)
    log = ptc_plots.loglog_columns(pt.points, pt)
    np.testing.assert_allclose(log["used"]["sigma"], [math.sqrt(p.var) for p in pt.points])
    np.testing.assert_allclose(log["used"]["err"],
                               [p.var_err / (2 * math.sqrt(p.var)) for p in pt.points])
    grid = log["model"]["mu"]
    np.testing.assert_allclose(log["model"]["sigma"] ** 2, pt.A * grid + pt.sigma_c2,
                               rtol=1e-12)
    np.testing.assert_allclose(log["floor"]["sigma"], math.sqrt(pt.sigma_c2))
    np.testing.assert_allclose(log["shot"]["sigma"] ** 2, pt.A * grid, rtol=1e-12)
    lo, hi = ptc_plots.loglog_limits(log)
    assert lo == pytest.approx(0.25 * min(min(log["used"]["sigma"]), math.sqrt(pt.sigma_c2)))
    assert hi == pytest.approx(1.6 * max(log["used"]["sigma"]))
    assert ptc_plots.residual_columns(None)["used"]["level"] == []
    assert ptc_plots.loglog_limits(ptc_plots.loglog_columns(())) is None


def test_figures_update_in_place_and_hide_empty_legend_entries(healey94):
    pt = photon_transfer(healey94, exclude_levels=[2])
    figs = ptc_plots.PtcFigures()
    sources = dict(figs.sources)
    figs.update(pt.points, pt)
    assert figs.sources == sources                          # the same source objects
    assert list(figs.sources[("transfer", "excluded")].data["level"]) == [2]
    assert figs.loglog.y_range.start == pytest.approx(
        ptc_plots.loglog_limits(ptc_plots.loglog_columns(pt.points, pt))[0])
    assert all(item.visible for item in figs.transfer.legend[0].items)
    every = photon_transfer(healey94).points                # all used, and no fit: the band,
    figs.update(every, None)                                # the line, the hollow group empty
    shown = {item.label.value: item.visible for item in figs.transfer.legend[0].items}
    assert shown == {"fit \u00b11\u03c3": False,
                     "\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C": False,
                     "used levels": True, "excluded levels": False}


def _models(root) -> dict[str, list]:
    """The figures and data sources under a rendered Bokeh root, by type name."""
    found: dict[str, list] = {}
    for m in root.references():
        found.setdefault(type(m).__name__, []).append(m)
    return found


def test_each_choice_refits_and_draws_once(state, healey94, monkeypatch):
    """Levels, robust mode and points are page parameters: a tick, the robust mode or new
    points (an applied ROI, which also sets the ticks) refit and draw the curve once each."""
    page = _page(state, healey94)
    page.__panel__().get_root(Document())          # rendered: the plots follow their stream
    calls = []
    draw = ptc_plots.transfer_columns
    monkeypatch.setattr(ptc_plots, "transfer_columns",
                        lambda *a, **k: calls.append(1) or draw(*a, **k))
    page.level_select.value = [lv for lv in range(1, 9) if lv != 8]
    assert len(calls) == 1 and page.result.points[7].exclusion == "user"
    page.robust = True
    assert len(calls) == 2
    page.robust = False
    page.x_input.value, page.y_input.value, page.w_input.value, page.h_input.value = \
        0, 0, 128, 96
    assert _run(page.apply_roi())
    assert len(calls) == 4 and page.result.roi == (0, 0, 128, 96)
    assert page.levels == [lv for lv in range(1, 9) if lv != 8]   # the ticks are kept


def test_a_level_toggle_updates_the_plots_in_place(state, healey94):
    """Unticking a level changes the data of the drawn glyphs, not the plots: the same Bokeh
    figures and data sources before and after (a new figure costs the browser seconds)."""
    page = _page(state, healey94)
    root = page.__panel__().get_root(Document())
    before = _models(root)
    figures = {m.id for m in before["figure"]}
    sources = {m.id for m in before["ColumnDataSource"]}
    assert len(figures) == 4               # transfer, residuals, log-log, frame preview

    def excluded_levels() -> list[int]:
        """The levels drawn hollow in the transfer plot (read from the Bokeh data)."""
        drawn = []
        for src in _models(root)["ColumnDataSource"]:
            if "status" in src.data and "var" in src.data:
                drawn += [int(lv) for lv, st in zip(src.data["level"], src.data["status"])
                          if st == "excluded"]
        return sorted(set(drawn))

    assert excluded_levels() == []
    page.level_select.value = [lv for lv in range(1, 9) if lv != 3]
    after = _models(root)
    assert {m.id for m in after["figure"]} == figures
    assert {m.id for m in after["ColumnDataSource"]} == sources
    assert excluded_levels() == [3]
    legend = [item for m in after["Legend"] for item in m.items]
    assert any(item.visible for item in legend)
    page.level_select.value = list(range(1, 9))    # back: the hollow group is empty again
    assert excluded_levels() == []
    hidden = [item for m in _models(root)["Legend"] for item in m.items if not item.visible]
    assert hidden, "the empty 'excluded levels' entry stays in the legend"


def test_residual_axis_follows_the_used_levels_and_clips_the_excluded(demo_pt):
    """A level far beyond saturation (here 5e6 σ off the line) is excluded: it no longer sets
    the axis; it is drawn as a triangle at the edge with its true residual for the hover."""
    pts = list(demo_pt.points)
    far = dataclasses.replace(pts[-1], level=99, mu=pts[-1].mu * 1.1,
                              var=pts[-1].var + 5e6 * pts[-1].var_err)
    low = dataclasses.replace(pts[-2], level=98, var=pts[-2].var - 2.0 * pts[-2].var_err)
    res = dataclasses.replace(demo_pt, points=tuple(pts) + (
        dataclasses.replace(far, used=False, exclusion="nonlinear", reason="beyond"),
        dataclasses.replace(low, used=False, exclusion="user", reason="excluded by user")))
    cols = ptc_plots.residual_columns(res)
    used = np.asarray(cols["used"]["residual"])
    limit = ptc_plots.residual_limit(cols)
    assert limit == max(3.8, float(np.abs(used).max()) + 1.2) < 10
    split = ptc_plots.clip_residuals(cols, limit)
    assert split["excluded"]["level"] == [98]                      # inside: drawn as it is
    clipped = split["clipped"]
    assert clipped["level"] == [99] and clipped["marker"] == ["triangle"]
    assert clipped["y"][0] == pytest.approx(ptc_plots.CLIP_AT * limit)
    assert clipped["residual"][0] == pytest.approx(5e6, rel=1e-3)
    assert clipped["reason"] == ["beyond"]
    # below the axis: an inverted triangle
    down = ptc_plots.clip_residuals({"excluded": {**clipped, "residual": np.array([-50.0]),
                                                  "err": np.ones(1), "lo": np.zeros(1),
                                                  "hi": np.zeros(1)}}, 4.0)
    assert down["clipped"]["marker"] == ["inverted_triangle"]
    assert down["clipped"]["y"][0] == pytest.approx(-ptc_plots.CLIP_AT * 4.0)
    # the figures: the axis set from the used levels, the clipped layer fed
    figs = ptc_plots.PtcFigures()
    figs.update(res.points, res)
    assert (figs.residual.y_range.start, figs.residual.y_range.end) == (-limit, limit)
    assert list(figs.sources[("residual", "clipped")].data["level"]) == [99]
    assert list(figs.sources[("residual", "excluded")].data["level"]) == [98]
