"""The EMVA 1288 parts of the pages without a browser, on a set of emva1288's DatasetGenerator
(an exposure-time series with a dark current, a spatial set, DSNU and PRNU with row, column and
pixel parts): the Walkthrough's fit range (the fit's levels and the gate follow it), its
datasheet table (every row, in the standard's order), the dark current of the dark step, and
the Maps page's EMVA 1288 spatial tab (computed once per session, read back from the cache)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel extensions, as serving does)
from _coro import run as _run
from ccdcore import guide
from ccdcore.common import format_pm
from ccdcore.emva.datasheet import emva_figures
from ccdcore.emva.sheet import DATASHEET, datasheet_rows
from ccdcore.noise import EMVA_FIT_FRACTION, photon_transfer
from ccdcore.session import open_session
from ccdcore_app.cache.store import ResultCache
from ccdcore_app.pages.maps import page as maps
from ccdcore_app.pages.maps.page import EMVA_TAB, MapsPage, emva_spatial_layout
from ccdcore_app.pages.walkthrough import WalkthroughPage, emva_table
from ccdcore_app.state import AppState

H, W = 24, 32


def make_emva_set(out: Path) -> Path:
    """emva1288's generator (12 exposure steps, a spatial set of 8 frames, 12-bit TIFF) with a
    dark current (dark_current_ref=3000) and DSNU and PRNU patterns with row, column and pixel
    parts; its descriptor."""
    # emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (docs/notes.md)
    np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731
    from emva1288.camera.dataset_generator import DatasetGenerator

    rng = np.random.default_rng(1)
    dsnu = (rng.normal(0.0, 2.0, (H, W)) + rng.normal(0.0, 1.5, (H, 1))
            + rng.normal(0.0, 1.0, (1, W)))
    prnu = (1.0 + rng.normal(0.0, 0.01, (H, W)) + rng.normal(0.0, 0.005, (H, 1))
            + rng.normal(0.0, 0.005, (1, W)))
    gen = DatasetGenerator(steps=12, L=8, image_format="tif", outdir=str(out), width=W,
                           height=H, bit_depth=12, seed=5, dsnu=dsnu, prnu=prnu,
                           dark_current_ref=3000, u_esat=60000.0, dark_signal_0=50.0)
    return Path(gen.descriptor_path)


@pytest.fixture
def run_now(monkeypatch):
    """``pn.state.execute`` runs its callback to the end at once (its coroutine in a thread of
    its own, as ``_run``): after a browser test the Panel server's loop may be running, and then
    Panel only schedules the callback."""
    import inspect

    import panel as pn

    def execute(callback, *args, **kwargs):
        result = callback()
        if inspect.isawaitable(result):
            _run(result)

    monkeypatch.setattr(pn.state, "execute", execute)


@pytest.fixture(scope="module")
def emva_set(tmp_path_factory) -> Path:
    return make_emva_set(tmp_path_factory.mktemp("emva") / "set")


@pytest.fixture(scope="module")
def figures_json(emva_set):
    """The EMVA 1288 figures of the set as the pages keep them (their record)."""
    return emva_figures(open_session(emva_set), with_ptc=False).summary()


@pytest.fixture(scope="module")
def walked(emva_set):
    """The Walkthrough on the EMVA set after its dark and photon-transfer steps."""
    state = AppState(allowed_roots=[emva_set.parent])
    assert state.load(str(emva_set))
    page = WalkthroughPage(state, auto=False)
    _run(page.run_step("dark"))
    _run(page.run_step("ptc"))
    return page


def _used(noise) -> list[int]:
    return [p.level for p in noise.points if p.used]


def test_the_fit_range_control_sets_the_fit_and_the_gate(walked, emva_set, monkeypatch):
    from ccdcore_app.pages.walkthrough import ptc

    reads = []
    monkeypatch.setattr(ptc, "emva_of_frames", lambda s: reads.append(s))  # read once before
    page, session = walked, open_session(emva_set)
    step = page.steps["ptc"]
    # an EMVA set starts with the EMVA 1288 range
    assert step.fit_range == step.range_select.value == "emva"
    emva_fit = photon_transfer(session, fit_fraction=EMVA_FIT_FRACTION)
    every = photon_transfer(session)
    noise = page.results.ptc.noise
    assert _used(noise) == _used(emva_fit) and noise.A == emva_fit.A
    out_of_range = [p.level for p in noise.points if p.exclusion == "range"]
    assert out_of_range and set(out_of_range) <= set(_used(every))
    gate = page.gates["ptc"]
    assert gate.reasons[:2] == guide.ptc_gate(emva_fit).reasons[:2]
    assert any("EMVA 1288 range" in r for r in gate.reasons)
    linearity = step.linearity_pane.object
    # the control: every level below saturation
    step.range_select.value = "paper"
    assert page.results.ptc is None and page.results.emva is None and "ptc" not in page.gates
    _run(page.run_step("ptc"))
    noise = page.results.ptc.noise
    assert _used(noise) == _used(every) and noise.A == every.A
    assert not any(p.exclusion == "range" for p in noise.points)
    assert "fit range: every level below saturation (the paper's range)" in \
        page.gates["ptc"].reasons
    # the plots follow: the transfer plot's used points are the fit's
    used_src = step.figs.sources[("transfer", "used")].data
    assert sorted(used_src["level"]) == sorted(_used(every))
    # the EMVA points did not change: the deviation-from-linearity plot is the same figure
    assert step.linearity_pane.object is linearity
    # nor were the frames read again: only σ_d from the new intercept changed
    assert reads == []
    assert page.results.emva.sigma_d_ptc == emva_figures(
        session, noise=every).summary().sigma_d_ptc
    # back to the EMVA range
    step.range_select.value = "emva"
    _run(page.run_step("ptc"))
    assert _used(page.results.ptc.noise) == _used(emva_fit)


def test_a_session_without_photon_counts_fits_every_level(emva_set, assets):
    state = AppState(allowed_roots=[emva_set.parent, assets])
    assert state.load(str(emva_set))
    page = WalkthroughPage(state, auto=False)
    assert page.steps["ptc"].fit_range == "emva"
    # another session: its own default, the paper's range (no photon counts)
    assert state.load(str(assets / "healey94"))
    assert page.steps["ptc"].fit_range == page.steps["ptc"].range_select.value == "paper"
    _run(page.run_step("ptc"))
    assert page.results.ptc.noise.fit_fraction is None
    assert not page.steps["ptc"].emva_holder.visible


def test_the_datasheet_table_has_every_row(walked, emva_set):
    page = walked
    figures = page.results.emva
    session = open_session(emva_set)
    want = emva_figures(session, noise=photon_transfer(
        session, fit_fraction=EMVA_FIT_FRACTION)).summary()
    assert figures.K == want.K and figures.DSNU1288 == want.DSNU1288
    table = page.steps["ptc"].emva_table.object
    assert table.equals(emva_table(figures))
    rows = datasheet_rows(figures)
    assert len(table) == len(DATASHEET) == len(rows)
    assert list(table["figure"]) == [name for _, _, name, _, _ in DATASHEET]
    assert list(table["symbol"]) == [symbol for _, _, _, symbol, _ in DATASHEET]
    # each section named on its first row
    assert [s for s in table["section"] if s] == list(dict.fromkeys(r.section for r in rows))
    determined = [r for r in rows if r.value is not None]
    missing = [r for r in rows if r.value is None]
    assert determined and missing       # this set leaves parts of the DSNU split undetermined
    for r, (_, line) in zip(rows, table.iterrows()):
        if r.value is None:
            assert line["value"] == "not determined" and line["note"] == r.note
            assert r.note
        else:
            assert line["note"] == ""
            if r.error:
                assert "±" in line["value"]
            assert line["value"].endswith(r.unit)
    by_symbol = {line["symbol"]: line["value"] for _, line in table.iterrows()}
    assert by_symbol["K"] == format_pm(want.K, want.K_err, unit="DN/e⁻")
    assert by_symbol["PRNU1288.row"] == format_pm(want.PRNU1288_row, want.PRNU1288_row_err,
                                                  unit="%")
    # the dark current is in the table, resolved (the generator's dark current is large)
    assert figures.u_I_mean is not None and figures.u_I_var is not None
    # the deviation from linearity is shown with the figures
    assert page.steps["ptc"].emva_holder.visible
    linearity = page.steps["ptc"].linearity_pane.object
    assert linearity is not None and list(linearity.select(dict(name="deviation-fit")))


def test_the_spatial_plots_open_with_their_card(walked, run_now):
    step = walked.steps["ptc"]
    assert step.spatial_card.visible and step.spatial_card.collapsed
    assert step.spatial_pane.object is None          # nothing sent before it is opened
    step.spatial_card.collapsed = False
    layout = step.spatial_pane.object
    titles = {f.title.text for f in layout.select(dict(type=_figure_type()))}
    assert {"Horizontal spectrogram of the DSNU", "Vertical spectrogram of the PRNU",
            "Logarithmic histogram of the PRNU",
            "Accumulated histogram of the DSNU"} <= titles
    step.spatial_card.collapsed = True
    step.spatial_card.collapsed = False
    assert step.spatial_pane.object is layout        # not built again


def _figure_type():
    from bokeh.plotting import figure

    return figure


def test_the_dark_step_shows_the_dark_current(walked):
    page = walked
    figures = page.results.emva
    dark = page.steps["dark"]
    assert dark.current_holder.visible
    text = dark.current_text.object
    assert "μ_I.mean" in text and "μ_I.var" in text and "e⁻/s" in text
    assert f"{figures.u_I_mean:.0f}"[:2] in text
    layout = dark.current_pane.object
    titles = [f.title.text for f in layout.children]     # side by side: mean, variance
    assert titles[0].startswith("Mean dark signal against exposure time: μ_I.mean = ")
    assert titles[1].startswith("Temporal dark variance against exposure time: μ_I.var = ")
    # the dark-signal plot shows the dark points, so the plain dark-level plot is hidden
    assert not dark.level_plot.visible
    points = layout.children[0].select_one(dict(name="dark-points")).data_source.data
    np.testing.assert_allclose(sorted(points["t"]),
                               sorted(d.exposure for d in figures.dark_points))


def test_an_undetermined_dark_current_says_why(figures_json):
    from ccdcore_app.pages.walkthrough.dark import dark_current_markdown

    note = ("u_I_mean is not resolved: 1.2 ± 3 e-/s over 0.001 to 0.01 s is within 2 standard "
            "errors of zero")
    text = dark_current_markdown(dataclasses.replace(
        figures_json, u_I_mean=None, u_I_mean_err=None, u_I_var=12.5, u_I_var_err=1.5,
        notes=(note,)))
    assert f"μ_I.mean: not determined — {note}" in text
    assert "μ_I.var = **12.5 ± 1.5 e⁻/s**" in text


def test_the_maps_page_shows_the_emva_spatial_tab(emva_set, assets, tmp_path, monkeypatch,
                                                  run_now):
    calls = []
    compute = maps.emva_spatial_figures

    def counted(session):
        calls.append(session)
        return compute(session)

    monkeypatch.setattr(maps, "emva_spatial_figures", counted)
    state = AppState(allowed_roots=[emva_set.parent, assets],
                     cache=ResultCache(tmp_path / "cache"))
    assert state.load(str(emva_set))
    page = MapsPage(state, auto_compute=False)
    page.__panel__()
    assert EMVA_TAB in page.tab_bar.options
    assert page.emva is None and page.emva_pane.object is None
    page.tab_bar.value = EMVA_TAB                   # showing the tab computes the figures
    assert len(calls) == 1 and page.emva is not None
    want = emva_figures(open_session(emva_set), with_ptc=False).summary()
    assert page.emva.spatial_plots == want.spatial_plots
    layout = page.emva_pane.object
    assert len(list(layout.select(dict(name="spectrum")))) == 4
    figs = {f.title.text: f for f in layout.select(dict(type=_figure_type()))}
    drawn = figs["Horizontal spectrogram of the DSNU"].select_one(dict(name="spectrum"))
    spectrum = want.spatial_plots.spectrograms.DSNU_horizontal
    amplitude = np.array(spectrum.amplitude, float)
    np.testing.assert_allclose(drawn.data_source.data["y"], amplitude[amplitude > 0])
    for start in ("Horizontal profile of the signal", "Vertical profile of the dark image",
                  "Logarithmic histogram of the DSNU", "Accumulated histogram of the PRNU"):
        assert any(title.startswith(start) for title in figs), start
    assert "DSNU1288" in page.emva_note.object and "PRNU1288" in page.emva_note.object
    # once per session: another visit does not compute again
    page.tab_bar.value = "Maps"
    page.tab_bar.value = EMVA_TAB
    assert len(calls) == 1
    # another browser session on the same files reads it back from the disk cache
    other_state = AppState(allowed_roots=[emva_set.parent], cache=state.cache)
    assert other_state.load(str(emva_set))
    other = MapsPage(other_state, auto_compute=False)
    other.__panel__()
    _run(other.compute_emva())
    assert len(calls) == 1 and "from the cache" in other_state.status
    assert other.emva.spatial_plots == page.emva.spatial_plots
    # a session without photon counts has no such tab; the tab shown goes back to Maps
    assert state.load(str(assets / "healey94"))
    assert EMVA_TAB not in page.tab_bar.options and page.tab_bar.value == "Maps"
    assert page.emva is None


def test_the_spatial_layout_is_none_without_spatial_plots(figures_json):
    assert emva_spatial_layout(dataclasses.replace(figures_json, spatial_plots=None)) is None


def test_the_dark_step_says_when_the_emva_figures_cannot_be_made(emva_set, monkeypatch):
    from ccdcore.errors import CcdError
    from ccdcore_app.pages.walkthrough import ptc

    def refuse(session):
        raise CcdError(session.label, "every point saturated")

    monkeypatch.setattr(ptc, "emva_of_frames", refuse)
    state = AppState(allowed_roots=[emva_set.parent])
    assert state.load(str(emva_set))
    page = WalkthroughPage(state, auto=False)
    _run(page.run_step("dark"))
    dark = page.steps["dark"]
    assert page.results.emva is None and page.results.dark is not None
    assert dark.current_holder.visible and dark.current_pane.object is None
    assert "could not be made" in dark.current_text.object
    assert any("the EMVA 1288 figures could not be made" in r and "every point saturated" in r
               for r in page.gates["ptc"].reasons)
    _run(page.run_step("ptc"))                      # drawn: the photon transfer, no datasheet
    assert page.results.ptc.noise is not None
    assert not page.steps["ptc"].emva_holder.visible
