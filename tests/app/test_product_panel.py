"""The Calibration product panel without a browser: a product made by ccdcore on the bundled demos
opens, its summary lists what ccdcore made and skipped, applying and saving give exactly what
ccdcore gives, the SNUP is ccdcore's, and bad folders or frames become alerts."""
from __future__ import annotations

import dataclasses
import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from bokeh.document import Document

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
from ccdcore_app.pages.session import SessionPage
from ccdcore_app.product.panel import (CORRECT, IN_VIEW, LINEARISE, ROLE, ProductPanel,
                               estimate_headline, estimates_frame, save_corrected, snup_table,
                               view_roi)
from ccdcore_app.state import AppState
from ccdcore.common import format_pm, format_size
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_image, write_map
from ccdcore.noise import photon_transfer
from ccdcore.product.make import PRODUCT_FILE, apply_product, calibrate, load_product
from ccdcore.flatfield.uniformity import snup
from _coro import run as _run

SCENE = "scene/matte_grey_L03.tif"


@pytest.fixture(scope="module")
def made(tmp_path_factory, assets):
    """A product of healey94 made by ccdcore and saved; the folder, the loaded product and the
    temporary root (an allowed root of the app)."""
    root = tmp_path_factory.mktemp("products").resolve()
    folder = calibrate(assets / "healey94").save(root / "healey94-product")
    return folder, load_product(folder), root


@pytest.fixture
def state(made, assets, tmp_path):
    _, _, root = made
    return AppState(allowed_roots=[root, tmp_path.resolve(), assets.resolve()])


@pytest.fixture
def opened(state, made, healey94):
    """The panel with healey94 loaded and its product opened (nothing applied yet)."""
    folder, _, _ = made
    assert state.load(healey94)
    panel = ProductPanel(state, auto=False)
    assert _run(panel.open_product(folder)), panel.error
    return panel


def _apply(panel: ProductPanel, relpath: str, mode: str = CORRECT) -> None:
    panel.param.update(role=panel._records[relpath].role)
    panel.param.update(frame=relpath, mode=mode)
    _run(panel.apply())


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------------------ summary -------
def test_summary_lists_estimates_maps_skips_and_provenance(opened, made):
    folder, product, _ = made
    assert opened.product_path == str(folder) and not opened.error_alert.visible
    assert opened.summary.visible
    est = opened.estimates_table.object
    assert list(est["estimate"]) == list(product.estimates.made())
    headline = dict(zip(est["estimate"], est["headline"]))
    noise = product.estimates.noise
    assert format_pm(noise.A, noise.A_err) in headline["noise"]
    assert format_pm(noise.sigma_c2, noise.sigma_c2_err) in headline["noise"]
    dark = product.estimates.dark
    assert format_pm(dark.mean, dark.mean_sem) in headline["dark"]
    assert f"n1 = {product.estimates.fixed_pattern.n1}" in headline["fixed_pattern"]
    for name, v in product.estimates.scene.items():
        assert f"{name}: scene variation V_S = {format_pm(v.V_S, v.V_S_err)}" \
            in headline["scene"]
    maps = opened.maps_table.object
    assert list(maps["map"]) == sorted(product.maps)
    assert set(maps["size (W\u00d7H)"]) == {format_size(product.shape)} == {"256 \u00d7 192"}
    skipped = opened.skipped_table.object
    assert list(skipped["estimate"]) == [s.estimate for s in product.skipped]
    assert {"flat_field", "response"} <= set(skipped["estimate"])     # healey94 has neither
    assert list(skipped["reason"]) == [s.reason for s in product.skipped]
    assert product.provenance.session in opened.provenance_pane.object
    assert "eqs. 45-50" in opened.provenance_pane.object
    assert product.camera.name in opened.camera_pane.object
    # no response: correcting is the only mode
    assert list(opened.param.mode.objects) == [CORRECT] and opened.mode == CORRECT
    # the scene frames come first
    assert opened.role == "scene" and opened.frame == "scene/matte_grey_L01.tif"


# ------------------------------------------------------------------------------ applying ------
@pytest.mark.parametrize("relpath", [SCENE, "ptc/L03_b.tif"])
def test_applying_equals_product_correct_to_the_byte(opened, made, relpath):
    _, product, _ = made
    session = opened.state.session
    _apply(opened, relpath)
    raw = session.read(opened._records[relpath])
    expected = product.correct(raw)
    applied = opened.applied
    assert not opened.apply_alert.visible and applied is not None
    assert applied.relpath == relpath
    assert applied.corrected.dtype == np.float32
    assert applied.corrected.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(applied.raw, raw)
    # the views show the frame before and after, zoom linked
    np.testing.assert_array_equal(opened.before_view.plane, raw)
    assert opened.after_view.plane.tobytes() == expected.tobytes()
    assert opened.after_view.figure.x_range is opened.before_view.figure.x_range
    assert opened.before_pane.visible and opened.after_pane.visible
    # the readout gives both values of the pixel under the cursor
    opened._on_pointer(x=17.2, y=9.8)
    assert f"before **{raw[10, 17]} DN**" in opened.readout.object
    assert f"after **{float(expected[10, 17]):.6g} DN**" in opened.readout.object


def test_snup_before_and_after_are_ccdcore_s(opened):
    _apply(opened, SCENE)
    applied = opened.applied
    before = snup(applied.raw, layout="mono", where=SCENE)
    after = snup(applied.corrected, layout="mono", where=SCENE)
    assert applied.snup.before == before and applied.snup.after == after
    table = opened.shown_table()
    assert list(table["SNUP before (%)"]) == [format_pm(before["L"].snup, before["L"].snup_err)]
    assert list(table["SNUP after (%)"]) == [format_pm(after["L"].snup, after["L"].snup_err)]
    assert "whole frame" in opened.snup_title.object

    # over the part in view: zoom (linked), then choose "Current view"
    opened.before_view.figure.x_range.update(start=20.3, end=90.4)
    opened.before_view.figure.y_range.update(start=70.2, end=11.9)
    roi = opened.current_roi()
    assert roi == (20, 12, 71, 59)
    opened.view = IN_VIEW
    _run(opened.update_snup())
    before_v = snup(applied.raw, roi=roi, layout="mono")
    after_v = snup(applied.corrected, roi=roi, layout="mono")
    assert opened.shown_snup.before == before_v and opened.shown_snup.after == after_v
    table = opened.shown_table()
    assert list(table["SNUP after (%)"]) == [format_pm(after_v["L"].snup, after_v["L"].snup_err)]
    assert list(table["pixels"]) == [71 * 59]
    assert "x 20\u201390, y 12\u201370" in opened.snup_title.object


def test_headlines_of_an_emva_product_and_of_damaged_summaries(made, assets):
    from ccdcore.emva.datasheet import emva_figures

    _, product, _ = made
    # the demo's figures with these headline figures, no DSNU and no dark current
    emva = dataclasses.replace(
        emva_figures(assets / "emva1288", with_ptc=False).summary(), K=0.0123, K_err=0.0004,
        QE=51.2, QE_err=1.3, sigma_d=11.9, sigma_d_err=0.6, u_e_sat=9300.0, u_e_sat_err=120.0,
        DR_dB=58.1, DR_dB_err=0.4, DSNU1288=None, DSNU1288_err=None, PRNU1288=0.71,
        PRNU1288_err=0.05, u_I_mean=None, u_I_mean_err=None, u_I_var=None, u_I_var_err=None,
        dark_current=None)
    rows = estimates_frame(dataclasses.replace(product, emva1288=emva))
    headline = dict(zip(rows["estimate"], rows["headline"]))["emva1288"]
    assert f"K = {format_pm(0.0123, 0.0004)} DN/e⁻" in headline
    assert f"η = {format_pm(51.2, 1.3)} %" in headline and "DSNU" not in headline
    assert "μ_I.mean" not in headline                  # the product has no dark current
    assert f"PRNU1288 = {format_pm(0.71, 0.05)} %" in headline
    # what a summary does not hold reads "n/a", nothing raises; a scene without patches says so
    noise = dataclasses.replace(product.estimates.noise, A=0.01, A_err=None, sigma_c2=None)
    assert "gain A = 0.01 DN/e⁻" in estimate_headline(noise)
    assert "σ²_C = n/a" in estimate_headline(noise)
    assert estimate_headline({}) == "no patches"


def test_view_roi_covers_the_pixels_in_view_and_maps_cfa_planes_to_the_frame():
    assert view_roi((-0.5, 255.5), (191.5, -0.5), (192, 256), (192, 256)) is None
    assert view_roi((9.6, 20.4), (30.0, 10.0), (192, 256), (192, 256)) == (10, 10, 11, 21)
    # a pixel only touched by the edge of the view is out
    assert view_roi((2.5, 7.5), (3.5, 0.5), (192, 256), (192, 256)) == (3, 1, 5, 3)
    # a CFA plane is half the frame: its pixel (r, c) covers frame pixels (2r, 2c) ... +1
    assert view_roi((2.2, 5.4), (8.1, 3.7), (96, 128), (192, 256)) == (4, 8, 8, 10)
    # a view beside the plane keeps one pixel of its edge
    assert view_roi((300.0, 400.0), (-40.0, -20.0), (192, 256), (192, 256)) == (255, 0, 1, 1)


def test_an_undefined_snup_says_why(opened, made):
    _, product, _ = made
    session = opened.state.session
    # a dark frame whose dark-subtracted mean is <= 0
    dark = next(r for r in session.by_role("dark")
                if float(np.mean(product.correct(session.read(r)))) <= 0)
    _apply(opened, dark.relpath)
    pair = opened.applied.snup
    assert pair.before is not None and pair.after is None     # dark-subtracted: mean about 0
    assert "mean" in pair.after_error
    assert "After: SNUP undefined" in opened.snup_note.object
    table = snup_table(pair)
    assert list(table["SNUP after (%)"]) == [""] and table["SNUP before (%)"][0]


def test_a_frame_of_another_size_is_an_alert(opened, small_session, healey94):
    state = opened.state
    assert state.load(small_session)
    assert opened.applied is None and opened.role == "scene"
    _apply(opened, "ptc/p0.tif")
    assert opened.applied is None and opened.apply_alert.visible
    text = opened.apply_alert.object
    assert "ptc/p0.tif" in text and "32 \u00d7 24 px" in text and "256 \u00d7 192 px" in text
    assert not opened.before_pane.visible
    assert state.error == ""                   # the panel's own alert, not the app's
    # still working: back on the demo, the next frame is applied
    assert state.load(healey94)
    _apply(opened, SCENE)
    assert opened.applied is not None and not opened.apply_alert.visible


# ------------------------------------------------------------------------------ bad folders ---
def test_bad_folders_are_alerts_and_the_panel_keeps_working(opened, made, tmp_path):
    folder, product, _ = made
    empty = tmp_path / "empty"
    empty.mkdir()
    corrupt = Path(shutil.copytree(folder, tmp_path / "corrupt"))
    (corrupt / PRODUCT_FILE).write_text('{"schema": 1, "maps": {')
    wrong = Path(shutil.copytree(folder, tmp_path / "wrong-shape"))
    write_map(wrong / "maps" / "K_var.exr", np.ones((10, 12), np.float32))
    cases = [(tmp_path / "missing", "no calibration.json"),
             (empty, "not a calibration product"),
             (corrupt, "cannot read the product description"),
             (wrong, "maps of different shapes"),
             (Path("/etc"), "outside the folders")]
    for path, problem in cases:
        assert not _run(opened.open_product(path))
        text = opened.error_alert.object
        assert opened.error_alert.visible and str(path) in text and problem in text, text
        assert f"Still showing `{folder}`" in text
        assert opened.product is not None and opened.product_path == str(folder)
        assert opened.state.error == ""
    assert not _run(opened.open_product("  "))
    assert "no folder given" in opened.error_alert.object
    # still working: the good folder opens and applies
    assert _run(opened.open_product(folder))
    assert not opened.error_alert.visible
    _apply(opened, SCENE)
    assert opened.applied.corrected.tobytes() == product.correct(opened.applied.raw).tobytes()


# ------------------------------------------------------------------------------ saving --------
def test_save_writes_what_apply_product_writes(opened, made, tmp_path):
    _, product, _ = made
    session = opened.state.session
    scene = session.by_role("scene")
    before = {r.path: _digest(r.path) for r in scene}
    _apply(opened, SCENE)

    out = tmp_path / "out-one"
    written = _run(opened.save(out))
    reference = apply_product(product, [opened._records[SCENE].path], tmp_path / "ref-one")
    assert [p.name for p in written] == [p.name for p in reference] == ["matte_grey_L03.tif"]
    assert written[0].parent == out.resolve()
    got, want = read_image(written[0]), read_image(reference[0])
    assert got.dtype == np.float32 and got.tobytes() == want.tobytes()
    assert got.tobytes() == opened.applied.corrected.tobytes()
    assert opened.saved_alert.visible and str(written[0]) in opened.saved_alert.object

    # every frame of the role
    opened.scope = ROLE
    written = _run(opened.save(tmp_path / "out-role"))
    reference = apply_product(product, [r.path for r in scene], tmp_path / "ref-role")
    assert [p.name for p in written] == [p.name for p in reference]
    assert len(written) == len(scene) == 16
    for got, want in zip(written, reference):
        assert read_image(got).tobytes() == read_image(want).tobytes()
    assert "Wrote 16 files" in opened.saved_alert.object
    assert before == {r.path: _digest(r.path) for r in scene}      # inputs untouched


def test_frames_with_one_base_name_are_refused_before_anything_is_written(made, healey94,
                                                                          tmp_path):
    _, product, _ = made
    copies = []
    for sub, src in (("a", "scene/paper_L01.tif"), ("b", "scene/paper_L02.tif")):
        (tmp_path / sub).mkdir()
        copies.append(Path(shutil.copy(healey94 / src, tmp_path / sub / "frame.tif")))
    with pytest.raises(CcdError, match="same output name"):
        save_corrected(product, copies, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    # a frame of another size: nothing written either
    other = tmp_path / "small.tif"
    write_image(other, np.zeros((8, 8), np.uint8))
    with pytest.raises(CcdError, match="the product corrects 256 × 192 px frames"):
        save_corrected(product, [healey94 / "scene/paper_L01.tif", other], tmp_path / "out2")
    assert not (tmp_path / "out2").exists()


def test_save_refuses_input_folders_and_folders_outside_the_roots(opened, healey94, tmp_path):
    _apply(opened, SCENE)
    scene_dir = healey94 / "scene"
    listing = sorted(p.name for p in scene_dir.iterdir())
    for out, problem in [(scene_dir, "holds frames of the session"),
                         (Path("/etc/ccd-out"), "outside the folders"),
                         ("", "type the output folder")]:
        assert _run(opened.save(out)) == []
        assert opened.save_alert.visible and problem in opened.save_alert.object
        assert not opened.saved_alert.visible
    assert sorted(p.name for p in scene_dir.iterdir()) == listing
    assert not Path("/etc/ccd-out").exists()


# ------------------------------------------------------------------------------ other products -
def test_a_response_product_linearises_bracket_frames(state, assets, tmp_path):
    folder = calibrate(assets / "tsin01").save(tmp_path / "tsin01-product")
    product = load_product(folder)
    assert state.load(assets / "tsin01")
    panel = ProductPanel(state, auto=False)
    assert _run(panel.open_product(folder))
    assert list(panel.param.mode.objects) == [LINEARISE] and panel.mode == LINEARISE
    relpath = state.session.by_role("bracket")[4].relpath
    _apply(panel, relpath, LINEARISE)
    raw = state.session.read(panel._records[relpath])
    assert panel.applied.corrected.tobytes() == product.linearise(raw).tobytes()
    assert panel.applied.snup.after == snup(product.linearise(raw), layout="mono")
    written = _run(panel.save(tmp_path / "linear"))
    reference = apply_product(product, [panel._records[relpath].path], tmp_path / "ref",
                              linearise=True)
    assert read_image(written[0]).tobytes() == read_image(reference[0]).tobytes()
    # the whole bracket, frame by frame
    panel.scope = ROLE
    bracket = state.session.by_role("bracket")
    written = _run(panel.save(tmp_path / "linear-all"))
    reference = apply_product(product, [r.path for r in bracket], tmp_path / "ref-all",
                              linearise=True)
    assert len(written) == len(reference) == len(bracket)
    for got, want in zip(written, reference):
        assert read_image(got).tobytes() == read_image(want).tobytes()


def test_a_flat_field_product_on_colour_frames_per_channel(state, assets, tmp_path):
    folder = calibrate(assets / "delasarte07").save(tmp_path / "flat-product")
    product = load_product(folder)
    assert state.load(assets / "delasarte07")
    panel = ProductPanel(state, auto=False)
    assert _run(panel.open_product(folder))
    assert "flat_field" in list(panel.estimates_table.object["estimate"])
    relpath = state.session.by_role("flat")[30].relpath
    _apply(panel, relpath)
    raw = state.session.read(panel._records[relpath])
    assert panel.applied.corrected.tobytes() == product.correct(raw).tobytes()
    after = snup(product.correct(raw), layout="rgb")
    assert panel.applied.snup.after == after
    table = panel.shown_table()
    assert list(table["channel"]) == ["R", "G", "B"]
    assert list(table["SNUP after (%)"]) == [format_pm(c.snup, c.snup_err)
                                              for c in after.channels]
    # the views show one channel at a time
    assert panel.channel_select.visible and panel.channel == "L"
    panel.channel = "G"
    np.testing.assert_array_equal(panel.before_view.plane, raw[:, :, 1])
    np.testing.assert_array_equal(panel.after_view.plane, panel.applied.corrected[:, :, 1])


def test_a_product_calibrated_in_the_app(state, healey94, made):
    _, product, _ = made
    assert state.load(healey94)
    panel = ProductPanel(state, auto=False)
    assert _run(panel.calibrate_session())
    assert panel.product_path == "" and "not saved" in panel.camera_pane.object
    assert list(panel.product.estimates.made()) == list(product.estimates.made())
    _apply(panel, SCENE)
    assert panel.applied.corrected.tobytes() == product.correct(panel.applied.raw).tobytes()
    # the photon-transfer fit the app made (here over an ROI) is the product's noise model
    state.results.ptc = photon_transfer(state.session, roi=(0, 0, 64, 48))
    assert _run(panel.calibrate_session())
    assert panel.product.estimates.noise.roi == (0, 0, 64, 48)
    assert panel.product.estimates.noise.A == state.results.ptc.A


# ------------------------------------------------------------------------------ wiring --------
def test_widget_changes_update_data_not_plots(opened):
    root = opened.panel().get_root(Document())

    def models(kind: str) -> set[str]:
        return {m.id for m in root.references() if type(m).__name__ == kind}

    _apply(opened, SCENE)
    figures, sources = models("figure"), models("ColumnDataSource")
    assert len(figures) == 2
    _apply(opened, "scene/paper_L02.tif")
    opened.view = IN_VIEW
    _run(opened.update_snup())
    assert models("figure") == figures and models("ColumnDataSource") == sources


def test_release_drops_the_product_and_the_frames(opened):
    _apply(opened, SCENE)
    opened.release()
    assert opened.product is None and opened.applied is None and opened.shown_snup is None
    assert opened.before_view.plane is None and opened.after_view.plane is None


def test_the_session_page_shows_the_panel_in_a_tab(state, made, healey94):
    folder, _, _ = made
    page = SessionPage(state)
    layout = page.__panel__()
    assert layout is not None
    assert page.open_tabs._names == ["Open a session", "Calibration product"]
    assert page._product_panel is None and not page.open_tabs[1].objects   # not built yet
    page.open_tabs.active = 1                                                # first visit
    assert page.open_tabs[1].objects == [page.product_panel.panel()]
    page.open_tabs.active = 0
    page.open_tabs.active = 1
    assert page.open_tabs[1].objects == [page.product_panel.panel()]        # kept
    state.load(healey94)
    assert page.product_panel.param.frame.objects
    page.product_panel.auto = False
    assert _run(page.product_panel.open_product(folder))
    page.release()
    assert page.product_panel.product is None
