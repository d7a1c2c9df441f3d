"""The Response & HDR page without a browser: what it computes and shows, and what it says
without a bracket or with a bracket it cannot use."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from app.pages.response_hdr import NO_BRACKET_MESSAGE, ResponsePage
from app.response_plots import tone_map
from app.state import AppState
from ccdcore.response.methods import METHODS
from _coro import run as _run


def _page(path, **kw):
    state = AppState()
    assert state.load(path)
    page = ResponsePage(state, auto=False, **kw)
    _run(page.refresh())
    return state, page


@pytest.fixture(scope="module")
def shown(assets):
    return _page(assets / "tsin01")


def test_every_method_is_drawn_with_its_curve(shown):
    state, page = shown
    assert page.error == "" and state.error == ""
    for m in METHODS:
        np.testing.assert_array_equal(page.curves.curve(m), page.responses[m]["L"].g)
    band = page.curves.band.data
    e = page.responses["tsin"]["L"].g_err
    np.testing.assert_allclose(band["hi"] - band["lo"], 4 * e)
    assert list(page.noise_table.object["method"]) == [m.label for m in METHODS.values()]


def test_method_choice_moves_the_band_without_recomputing(shown):
    state, page = shown
    cached = state.results.response[(page.bloom_radius, False)]["responses"]
    page.method = "robertson"
    band = page.curves.band.data
    np.testing.assert_allclose(band["lo"], page.responses["robertson"]["L"].g
                               - 2 * page.responses["robertson"]["L"].g_err)
    assert state.results.response[(page.bloom_radius, False)]["responses"] is cached
    _run(page.show_hdr())
    assert page.hdr is state.results.response[(page.bloom_radius, False)]["hdr"]["robertson"]
    page.method = "tsin"


def test_hdr_readout_reads_radiance_and_sigma(shown):
    _, page = shown
    _run(page.show_hdr())
    page._on_pointer(3.2, 5.4)
    e = page.hdr.radiance[5, 3]
    assert "row 5, col 3" in page.readout.object
    assert f"{e:.3g}"[:4] in page.readout.object
    page._on_pointer(float("inf"), 2.0)                       # off the frame: ignored
    page._on_pointer(500.0, 2.0)


def test_tone_changes_only_the_display(shown):
    _, page = shown
    _run(page.show_hdr())
    radiance = page.hdr.radiance.copy()
    before = page.rad_view.plane.copy()
    page.param.update(stops=2.0, tone="log")
    assert not np.allclose(np.nan_to_num(page.rad_view.plane), np.nan_to_num(before))
    np.testing.assert_array_equal(page.hdr.radiance, radiance)
    page.param.update(stops=0.0, tone="gamma 2.2")


def test_tone_map_maps_the_white_point():
    E = np.linspace(0.001, 1.0, 1000)
    out = tone_map(E, 0.0, "gamma 2.2")
    assert out.min() >= 0 and out.max() == 1.0
    assert np.isclose(out[500], (E[500] / np.percentile(E, 99.5)) ** (1 / 2.2))
    assert np.isnan(tone_map(np.array([np.nan, 1.0]), 0, "log")[0])
    with pytest.raises(ValueError):
        tone_map(E, 0, "sepia")


def test_session_without_bracket_says_what_to_capture(assets):
    _, page = _page(assets / "healey94")
    assert page.info_alert.visible and page.info_alert.object == NO_BRACKET_MESSAGE
    assert not page.content.visible


def test_unusable_bracket_shows_an_error_and_the_app_goes_on(assets, tmp_path):
    """Every frame saturated: one error naming the frame, the page stays usable."""
    from ccdcore.io import write_image

    root = tmp_path / "s"
    shutil.copytree(assets / "tsin01", root)
    for f in sorted((root / "bracket").glob("*.tif")):
        write_image(f, np.full((128, 128), 255, np.uint8))
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root)
    page = ResponsePage(state, auto=False)
    _run(page.refresh())
    assert page.error_alert.visible and "saturated" in page.error
    assert "s0_k00.tif" in page.error
    assert page.responses is None


def test_white_balance_gains_on_the_page(assets):
    """Ticking the gains recomputes sec. 3.2 with them (cached apart); the table shows a_k / t_k
    off 1 only for that method."""
    state, page = _page(assets / "tsin01")
    page.param.update(white_balance=True)
    page._session = None
    _run(page.refresh())
    assert (3, True) in state.results.response and (3, False) in state.results.response
    c = page.responses["tsin"]["L"]
    assert c.white_balance and not np.allclose(c.a, c.t)
    assert np.allclose(page.responses["debevec"]["L"].a, c.t)
    assert "a_k / t_k" in page.ab_table.object.columns
