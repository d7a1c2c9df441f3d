"""The Flat field page without a browser: every number shown is ccdcore's (de Lasarte et al. 2007
on the bundled ``delasarte07`` demo), the widgets are wired, and bad sessions become alerts."""
from __future__ import annotations

from pathlib import Path

import holoviews as hv
import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
from ccdcore_app.plots import flat as flat_plots
from ccdcore_app.pages.flat_field import (NO_FLAT_MESSAGE, ZERO_DARK_MESSAGE, FlatFieldPage,
                                  default_frame)
from ccdcore_app.state import AppState, FlatResults
from ccdcore.common import format_pm
from ccdcore.flatfield.fit import (BaseRecommendation, FlatField, base_image_study,
                               flat_field_from_session, recommend_base, zero_dark)
from ccdcore.io.frames import write_image
from ccdcore.flatfield.uniformity import snup, snup_vs_averaging
from _coro import run as _run


@pytest.fixture(scope="module")
def delasarte07() -> Path:
    from ccdcore_app.state import assets_dir

    return assets_dir() / "delasarte07"


@pytest.fixture(scope="module")
def loaded(delasarte07):
    """The page on the demo, NZDI setting, recommended base, fully computed (shared: the
    module's tests only read it, or restore what they change)."""
    state = AppState(allowed_roots=[delasarte07.parent.resolve()])
    assert state.load(delasarte07)
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    assert page.error == "" and state.error == ""
    return page


def test_results_are_typed_and_kept_by_setting_and_base(loaded):
    flat = loaded.state.results.flat
    assert isinstance(flat, FlatResults)
    assert isinstance(flat.recommendations["NZDI"], BaseRecommendation)
    key = loaded.base_select.value
    assert isinstance(flat.fields[("NZDI", key)], FlatField)
    assert flat.fields[("NZDI", key)] is loaded.flat
    assert flat.studies["NZDI"] is not None and flat.settings is not None


def test_recommended_base_is_marked_chosen_and_explained(loaded):
    session = loaded.state.session
    rec = recommend_base(session, setting="NZDI")
    assert dict(loaded.setting_select.options) == {"NZDI": "NZDI", "ZDI": "ZDI"}
    assert loaded.offset == "NZDI" and loaded.setting_select.value == "NZDI"
    assert loaded.base_select.value == rec.key
    marked = [label for label, key in loaded.base_select.options.items()
              if label.endswith("(recommended)")]
    assert len(marked) == 1 and loaded.base_select.options[marked[0]] == rec.key
    assert loaded.recommend_alert.visible and rec.reason in loaded.recommend_alert.object
    assert set(loaded.base_select.options.values()) == set(session.flat_groups(setting="NZDI"))
    # cached in the shared results, by setting and base
    assert loaded.state.results.flat.recommendations["NZDI"].key == rec.key
    assert ("NZDI", rec.key) in loaded.state.results.flat.fields


def test_snup_table_is_ccdcores_before_and_after(loaded):
    session = loaded.state.session
    rec = recommend_base(session, setting="NZDI")
    ff = flat_field_from_session(session, setting="NZDI", base=rec.key)
    groups = session.flat_groups(setting="NZDI")
    relpath = default_frame(rec, groups)
    assert loaded.frame_select.value == relpath
    record = next(r for recs in groups.values() for r in recs if r.relpath == relpath)
    frame = session.read(record)
    before = snup(frame, layout="rgb")
    after = snup(ff.correct(frame), layout="rgb")
    table = loaded.snup_table.object
    assert list(table["channel"]) == ["R", "G", "B"]
    for c, row in zip(before.channels, table.itertuples(index=False)):
        assert row[2] == format_pm(c.snup, c.snup_err)
        a = after[c.name]
        assert row[4] == format_pm(a.snup, a.snup_err)
        assert loaded.view.after[c.name].snup == a.snup   # the exact numbers, not re-estimated
    assert loaded.view.after["G"].snup < loaded.view.before["G"].snup / 2  # it did correct
    # the maps shown are ccdcore's G and O of the chosen channel
    assert np.array_equal(loaded.flat.G, ff.G) and np.array_equal(loaded.flat.O, ff.O)
    c = {"R": 0, "G": 1, "B": 2}[loaded.channel]
    assert np.array_equal(loaded.g_view.plane, ff.G[..., c])
    assert np.array_equal(loaded.o_view.plane, ff.O[..., c])
    assert loaded.g_pane.visible and loaded.o_pane.visible
    # before and after: the frame and its correction, zoomed together, one colour range
    assert np.array_equal(loaded.before_view.plane, loaded.view.raw[..., c])
    assert np.array_equal(loaded.after_view.plane, loaded.view.corrected[..., c])
    assert loaded.after_view.figure.x_range is loaded.before_view.figure.x_range
    assert loaded.o_view.figure.y_range is loaded.g_view.figure.y_range
    assert (loaded.before_view.mapper.low, loaded.before_view.mapper.high) == \
        (loaded.after_view.mapper.low, loaded.after_view.mapper.high)
    assert "0 flagged pixels" in loaded.flag_pane.object
    assert "4 dark frames at 0.04 s" in loaded.setup_pane.object


def test_pixel_readout_shows_raw_corrected_g_and_o(loaded):
    loaded._on_pointer(x=10.2, y=5.8)
    view, flat = loaded.view, loaded.flat
    c = {"R": 0, "G": 1, "B": 2}[loaded.channel]
    text = loaded.readout.object
    assert text.startswith("x = 10, y = 6")
    assert f"{view.raw[6, 10, c]:g} DN" in text and f"{view.corrected[6, 10, c]:.2f} DN" in text
    assert f"G = {flat.G[6, 10, c]:.4f}" in text


def test_choosing_another_base_changes_the_after_snup(loaded):
    session = loaded.state.session
    shown = dict(loaded.after_snup)
    other = (2, 0.04)
    try:
        loaded.base_select.value = other
        _run(loaded.show_base())
        ff = flat_field_from_session(session, setting="NZDI", base=other)
        record = loaded._records[loaded.frame_select.value]
        expected = snup(ff.correct(session.read(record)), layout="rgb")
        assert loaded.after_snup == {c.name: format_pm(c.snup, c.snup_err)
                                     for c in expected.channels}
        assert loaded.after_snup != shown
        assert "corrected with base L2 \u00b7 40 ms" in loaded.snup_title.object
    finally:
        loaded.base_select.value = recommend_base(session, setting="NZDI").key
        _run(loaded.show_base())
    assert loaded.after_snup == shown


def test_zero_dark_warning_for_zdi_and_not_for_nzdi(delasarte07):
    state = AppState(allowed_roots=[delasarte07.parent.resolve()])
    state.load(delasarte07)
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    assert not page.zero_alert.visible
    page.setting_select.value = "ZDI"
    _run(page.show_setting())
    darks = [r for g in state.session.dark_groups(setting="ZDI").values() for r in g]
    zd = zero_dark(state.session.iter_frames(darks), layout="rgb")
    assert zd.clipped
    assert page.zero_alert.visible and page.zero_alert.alert_type == "warning"
    assert ZERO_DARK_MESSAGE in page.zero_alert.object and zd.warning in page.zero_alert.object
    assert all(k.startswith("zdi/") for k in page._records)
    page.setting_select.value = "NZDI"
    _run(page.show_setting())
    assert not page.zero_alert.visible


def _elements(overlay, kind):
    return [e for e in overlay if isinstance(e, kind)]


def test_averaging_plot_and_table_hold_ccdcores_numbers(loaded):
    session = loaded.state.session
    key = loaded.base_select.value
    avg = snup_vs_averaging(session.iter_frames(session.flat_groups(setting="NZDI")[key]),
                            layout="rgb")
    overlay = loaded.avg_pane.object
    scatters = {s.label: s for s in _elements(overlay, hv.Scatter)}
    assert set(scatters) == {"R", "G", "B"}
    for name, scatter in scatters.items():
        rows = avg.channel(name)
        assert list(scatter.dimension_values(0)) == [r.N for r in rows] == [1, 2, 4, 8]
        assert np.allclose(scatter.dimension_values(1), [r.snup for r in rows])
    curves = {c.label: c for c in _elements(overlay, hv.Curve)}
    g = curves["G predicted"]
    assert np.allclose(g.dimension_values(1)[0], avg.channel("G")[0].predicted)
    assert len(loaded.avg_table.object) == len(avg.rows)


def test_linearity_plot_shades_the_range_and_marks_saturation(loaded):
    lin = loaded.recommendation.linearity
    c = loaded.channel
    overlay = loaded.lin_pane.object
    span = _elements(overlay, hv.HSpan)[0]
    assert span.data[0] == pytest.approx(lin.ranges[c][0])
    assert span.data[1] == pytest.approx(lin.upper[c])
    hlines = [h.data for h in _elements(overlay, hv.HLine)]
    assert any(h == pytest.approx(lin.saturation_dn[c]) for h in hlines)
    onsets = {f.saturation_exposure for f in lin.fits if f.channel == c} - {None}
    assert onsets and onsets <= {v.data for v in _elements(overlay, hv.VLine)}
    points = [p for p in lin.points if p.channel == c]
    shown = sum(len(s) for s in _elements(overlay, hv.Scatter))
    assert shown == len(points)
    table = loaded.lin_table.object
    assert list(table["channel"]) == list(lin.channels)


def test_base_study_heatmap_and_table_are_ccdcores(loaded):
    session = loaded.state.session
    study = base_image_study(session, setting="NZDI")
    c = loaded.channel
    heat = loaded.study_pane.object
    groups = list(session.flat_groups(setting="NZDI"))
    assert len(heat) == len(groups) * (len(groups) + 1)       # + the uncorrected row
    table = study.table(c)
    rec = study.recommended
    df = loaded.study_table.value
    star = flat_plots.group_label(rec) + " \u2605"
    assert star in df.columns and "uncorrected" in df.columns
    row = df[df["corrected group"] == flat_plots.group_label(groups[0])].iloc[0]
    assert row[star] == round(table[rec][groups[0]], 3)
    assert row["uncorrected"] == round(table[None][groups[0]], 3)


def test_table_2_and_k_comparison_with_the_truth(loaded):
    settings = loaded.settings_table.object
    assert set(settings["setting"]) == {"NZDI", "ZDI"} and len(settings) == 6
    zero = loaded.zero_table.object
    assert set(zero[zero["clipped at zero"] == "yes"]["setting"]) == {"ZDI"}
    kmap = loaded.kmap_table.object
    assert list(kmap["channel"]) == ["R", "G", "B"]
    assert "residual G (%)" in kmap.columns       # truth.json's true flat field was used
    assert not loaded.kmap_alert.visible


def test_session_without_flats_says_what_to_capture(assets):
    state = AppState(allowed_roots=[assets.resolve()])
    state.load(assets / "healey94")
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    assert page.info_alert.visible and page.info_alert.object == NO_FLAT_MESSAGE
    assert not page.content.visible and not page.error_alert.visible


def test_no_session_is_an_info_alert():
    page = FlatFieldPage(AppState(), auto=False)
    assert page.info_alert.visible and "No session loaded" in page.info_alert.object


def test_flats_without_darks_use_the_zero_dark_form_and_the_page_keeps_working(tmp_path, assets):
    root = tmp_path / "nodark"
    rng = np.random.default_rng(11)
    entries = []
    for t in (0.01, 0.02, 0.04):
        for i in range(2):
            frame = np.clip(rng.normal(4000 * t, 2.0, (16, 24)), 0, 255).astype(np.uint8)
            write_image(root / f"flat_{t}_{i}.tif", frame, exposure=t, bits=8)
            entries.append(f'[[frames]]\npath = "flat_{t}_{i}.tif"\nrole = "flat"\nlevel = 1\n'
                           f"exposure = {t}\n")
    (root / "session.toml").write_text('schema = 1\n[camera]\nname = "t"\nbits = 8\n'
                                       'layout = "mono"\n\n' + "\n".join(entries))
    state = AppState(allowed_roots=[tmp_path.resolve(), assets.resolve()])
    assert state.load(root), state.error
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    # no darks: the flat field is made in de Lasarte's zero-dark form, and the page says so
    assert not page.error_alert.visible, page.error_alert.object
    assert page.flat is not None and page.flat.dark_source == "zero"
    assert "zero-dark form (DL_0 = 0)" in page.setup_pane.object
    assert page.recommendation is not None         # the linearity part still shows
    assert page.lin_pane.object is not None
    # the page keeps working: open the demo next
    state.load(assets / "delasarte07")
    _run(page.refresh())
    assert not page.error_alert.visible and page.after_snup


def test_choices_the_page_makes_schedule_nothing_the_users_schedule_their_step(delasarte07,
                                                                               monkeypatch):
    """The offset, base and frame choices are page parameters: a value the page sets itself
    (with its options, set_choices) schedules no step; a value the user picks schedules the
    step showing it, once."""
    import panel as pn

    state = AppState(allowed_roots=[delasarte07.parent.resolve()])
    assert state.load(delasarte07)
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    scheduled = []
    monkeypatch.setattr(pn.state, "execute", lambda step, **kw: scheduled.append(step))
    page.auto = True
    options = dict(page.param.base.names)
    other = next(k for k in options.values() if k != page.base)
    page._choose("base", options, other)             # the page's own choice
    assert scheduled == [] and page.base_select.value == other
    page.base_select.value = page.recommendation.key  # the user's
    assert scheduled == [page.show_base]
    page.setting_select.value = "ZDI"
    page.frame_select.value = next(f for f in page.param.frame.objects if f != page.frame)
    assert scheduled == [page.show_base, page.show_setting, page.show_frame]


def test_an_rgb_session_after_a_mono_one_sets_channel_options_and_value_together(delasarte07):
    """Served widgets see the channel's options and value change at once: with the options
    first, the button group cleared its value, which the channel selector refuses."""
    from bokeh.document import Document

    state = AppState(allowed_roots=[delasarte07.parent.resolve()])
    assert state.load(delasarte07)
    page = FlatFieldPage(state, auto=False)
    # as after a mono session: the page and its served widget hold the channel "L"
    page.param.channel.objects = ["L"]
    page.channel = "L"
    page.channel_select.param.update(options=["L"], value="L")
    page.__panel__().get_root(Document())
    _run(page.refresh())
    assert page.error == "" and state.error == ""
    assert list(page.param.channel.objects) == ["R", "G", "B"]
    assert page.channel == "R" and page.channel_select.value == "R"
    assert list(page.channel_select.options) == ["R", "G", "B"]


def test_cooled_ccd_darks_at_several_exposures_and_temperatures_show_the_dark_model(tmp_path):
    """An SBIG-like set (biases, darks at 5 exposures and 2 temperatures, flats at 23 s): the
    page shows the flat field with DL_0 from the dark model at the flats' temperature and the
    held-out check, without a traceback."""
    from ccdcore.simulate.ccdlab import simulate

    root = tmp_path / "lab"
    simulate(root, seed=5, size=(48, 32))
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root), state.error
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    assert not page.error_alert.visible, page.error_alert.object
    flat = page.flat
    assert flat.dark_source == "model" and flat.dark_model.temperature == -5.0
    assert "dark model o + c·t at 23 s" in page.setup_pane.object
    assert "-5 °C" in page.setup_pane.object and "16 darks at other temperatures" in \
        page.setup_pane.object
    assert "Held-out check: pass" in page.held_pane.object
    table = page.held_table.object
    assert list(table["verdict"]) == ["pass"]
    assert float(table["SNUP / floor"][0]) == pytest.approx(flat.held_out.channels[0].ratio,
                                                            abs=1e-3)


def test_camera_files_declared_as_flats_show_the_zero_dark_flat_field(tmp_path):
    """A DSLR's flats named as the camera named them, opened with the flat role declared
    (``--role flat``): two aperture groups, no darks, the zero-dark note and the held-out
    check within the base group."""
    from ccdcore.session import open_session

    root = tmp_path / "dslr"
    rng = np.random.default_rng(2)
    y, x = np.mgrid[0:24, 0:32]
    r2 = ((x - 16) ** 2 + (y - 12) ** 2) / (16 ** 2 + 12 ** 2)
    k = 0
    for t, corner in ((1 / 320, 0.8), (1 / 350, 0.9)):
        for _ in range(5):
            level = np.array([120.0, 130.0, 190.0]) * (1 - (1 - corner) * r2)[..., None]
            frame = level + rng.normal(0, 1.5, level.shape)
            write_image(root / f"DSC_{k:04d}.tif", np.clip(np.rint(frame), 0, 255)
                        .astype(np.uint8), exposure=t)
            k += 1
    state = AppState(allowed_roots=[tmp_path.resolve()])
    session = open_session(root, role="flat")
    assert state._apply(root, session, "")
    page = FlatFieldPage(state, auto=False)
    _run(page.refresh())
    assert not page.error_alert.visible, page.error_alert.object
    assert page.flat.dark_source == "zero" and page.flat.layout == "rgb"
    assert "zero-dark form" in page.setup_pane.object
    assert list(page.held_table.object["channel"]) == ["R", "G", "B"]
    assert page.flat.held_out.n_fit == 4
