"""The Change detection page without a browser: what it computes and shows on the bundled change
demo, that the false-alarm slider re-thresholds the same result in place, and what it says for
a session without reference/target brackets or with brackets it cannot use."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
from bokeh.document import Document
from scipy import stats

from ccdcore_app.plots import change as change_plots
from ccdcore_app.plots.change import ABOVE_COLOUR, BELOW_COLOUR, label_colour, label_rgb, pack_rgba
from ccdcore_app.pages import change as change_page
from ccdcore_app.pages.change import DEFAULT_PFA, PFA_STEPS, ChangePage, compute_change
from ccdcore_app.state import AppState
from ccdcore.change.detector import LABEL_CHANGE, ChangeOptions
from ccdcore.common import format_pm
from _coro import run as _run


def _page(path, **kw):
    state = AppState()
    assert state.load(path)
    page = ChangePage(state, auto=False, **kw)
    _run(page.refresh())
    return state, page


def _models(root) -> dict[str, set[str]]:
    """The ids of the figures and data sources under a rendered Bokeh root."""
    found: dict[str, set[str]] = {}
    for m in root.references():
        found.setdefault(type(m).__name__, set()).add(m.id)
    return {k: found.get(k, set()) for k in ("figure", "ColumnDataSource")}


@pytest.fixture(scope="module")
def shown(assets):
    state, page = _page(assets / "change")
    root = page.__panel__().get_root(Document())
    return state, page, root


@pytest.fixture
def at_default(shown):
    """The page back at the default display after a test moved it."""
    _, page, _ = shown
    yield shown
    page.param.update(pfa=DEFAULT_PFA, overlay=True, stops=0.0)


def test_result_is_computed_cached_and_shown(shown):
    state, page, _ = shown
    assert page.error == "" and state.error == "" and not page.error_alert.visible
    assert page.content.visible
    res, inputs = state.results.change[ChangeOptions(pfa=DEFAULT_PFA)]
    assert page.result is res and page.inputs is inputs
    np.testing.assert_array_equal(page.labels, res.labels)
    assert page.count_number.value == np.count_nonzero(res.labels == LABEL_CHANGE) > 0
    assert page.threshold_number.value == pytest.approx(res.threshold)
    assert page.observed_number.value == pytest.approx(res.observed_pfa(res.threshold))
    # the d² map holds d² under the best cluster; the pictures their tone-mapped radiance
    np.testing.assert_array_equal(page.d2_view.plane, res.d2_best)
    H, W = res.labels.shape
    for view in (page.labels_view, page.ref_view, page.tgt_view, page.pred_view):
        assert view.rgb.shape == (H, W, 3) and view.shown_rgba().shape == (H, W)
    for pane in (page.labels_pane, page.ref_pane, page.tgt_pane, page.pred_pane, page.d2_pane):
        assert pane.visible
    # every view shares one zoom
    ranges = {(id(v.figure.x_range), id(v.figure.y_range)) for v in page.views}
    assert len(ranges) == 1
    # a second refresh for the same session computes nothing
    _run(page.refresh())
    assert page.result is res


def test_pictures_are_the_radiance_tone_mapped(shown):
    _, page, _ = shown
    res, inputs = page.result, page.inputs
    white = change_plots.white_point(inputs.E_ref, inputs.E_tgt)
    for view, E in ((page.ref_view, inputs.E_ref), (page.tgt_view, inputs.E_tgt),
                    (page.pred_view, res.predicted)):
        expected = change_plots.tone_map_rgb(E, white, 0.0)
        np.testing.assert_array_equal(view.rgb, expected)
        np.testing.assert_array_equal(view.shown_rgba(), pack_rgba(expected))


def test_pfa_slider_rethresholds_in_place_without_refitting(at_default, monkeypatch):
    """Each slider value gives ccdcore's labels at that P (ChangeResult.at), the counts and
    readouts follow, the labels image the browser holds changes, and no figure or data source
    is built again; nothing is fitted again."""
    state, page, root = at_default
    res = page.result

    def refit(*a, **k):
        raise AssertionError("the slider must not fit M again")

    monkeypatch.setattr(change_page, "session_change", refit)
    before = _models(root)
    shown_before = page.labels_view.shown_rgba().copy()
    assert page.pfa_slider.options == PFA_STEPS
    changed = []
    for pfa in (0.05, 1e-4, 0.2):
        page.pfa_slider.value = pfa                      # as the browser's slider sets it
        assert page.pfa == pfa
        labels, thr = res.at(pfa)
        np.testing.assert_array_equal(page.labels, labels)
        n = int(np.count_nonzero(labels == LABEL_CHANGE))
        changed.append(n)
        assert page.count_number.value == n
        assert page.threshold_number.value == pytest.approx(thr)
        assert page.observed_number.value == pytest.approx(res.observed_pfa(thr))
        assert page.hist.span.location == pytest.approx(thr)
        assert page.hist.chi2_span.location == pytest.approx(res.chi2_threshold(pfa))
        assert f"{n:,}" in page.legend.object
        assert f"| Requested false-alarm probability P | {pfa:g} |" in page.details.object
        # the data source of the labels image holds these labels over the target
        expected = pack_rgba(label_rgb(labels, page.tgt_view.rgb))
        np.testing.assert_array_equal(page.labels_view.shown_rgba(), expected)
    assert changed[1] < changed[0] < changed[2]          # fewer changes at a lower P
    assert not np.array_equal(page.labels_view.shown_rgba(), shown_before)
    assert _models(root) == before
    assert page.result is res and state.results.change    # same result, still cached


def test_background_histogram_against_chi2(at_default):
    """Fig. 6: the background's d² as a density against χ² with dof degrees of freedom; the
    bars beyond the threshold are the background's false alarms."""
    _, page, _ = at_default
    res = page.result
    bars = page.hist.bars.data
    left, right, top = (np.asarray(bars[k]) for k in ("left", "right", "top"))
    assert left[0] == 0.0 and right[-1] >= res.background.max()
    assert np.sum(top * (right - left)) == pytest.approx(1.0)
    counts, _ = np.histogram(res.background, bins=np.append(left, right[-1]))
    np.testing.assert_array_equal(bars["count"], counts)
    curve = page.hist.curve.data
    np.testing.assert_allclose(curve["chi2"], stats.chi2.pdf(curve["x"], res.dof))
    np.testing.assert_allclose(curve["scaled"],
                               stats.chi2.pdf(curve["x"] / res.scale, res.dof) / res.scale)
    centre = np.asarray(bars["centre"])
    colours = np.asarray(bars["color"])
    assert set(colours[centre > res.threshold]) <= {ABOVE_COLOUR}
    assert set(colours[centre <= res.threshold]) == {BELOW_COLOUR}
    labels = page.hist.labels()
    assert f"{res.dof} degrees of freedom" in labels["chi2"]
    page.pfa = 0.2
    thr = res.at(0.2)[1]
    assert labels != page.hist.labels() and f"{thr:.4g}" in page.hist.labels()["threshold"]
    colours = np.asarray(page.hist.bars.data["color"])
    assert set(colours[centre > thr]) == {ABOVE_COLOUR}


def test_cluster_table_shows_m_with_its_uncertainty(at_default):
    _, page, _ = at_default
    res = page.result
    table = page.cluster_table.object
    assert len(table) == len(res.clusters) * res.clusters[0].M.shape[0]
    assert list(table.columns[-3:]) == ["→ R′", "→ G′", "→ B′"]
    counts = res.counts(page.labels)
    for i, c in enumerate(res.clusters):
        err = np.sqrt(np.diag(c.M_cov)).reshape(c.M.shape)
        block = table.iloc[i * c.M.shape[0]:(i + 1) * c.M.shape[0]]
        assert block.iloc[0]["pixels"] == f"{counts.get(c.label, 0):,}"
        for k in range(c.M.shape[0]):
            for j, ch in enumerate("RGB"):
                assert block.iloc[k][f"→ {ch}′"] == format_pm(c.M[k, j], err[k, j])
    page.pfa = 0.2                                       # the members follow the slider
    counts = res.counts(res.at(0.2)[0])
    assert page.cluster_table.object.iloc[0]["pixels"] == f"{counts[0]:,}"


def test_overlay_and_exposure_change_the_display_only(at_default):
    _, page, _ = at_default
    E = page.inputs.E_tgt.copy()
    page.overlay = False
    labels = page.labels
    rgba = page.labels_view.shown_rgba().view(np.uint8).reshape(labels.shape + (4,))
    background = np.round(change_plots._rgb(label_colour(0)) * 255)
    np.testing.assert_array_equal(rgba[labels == 0][:, :3],
                                  np.broadcast_to(background, rgba[labels == 0][:, :3].shape))
    assert "the target in grey" not in page.legend.object
    before = page.ref_view.shown_rgba().copy()
    page.stops = 1.0
    assert not np.array_equal(page.ref_view.shown_rgba(), before)
    np.testing.assert_array_equal(page.inputs.E_tgt, E)


def test_pointer_reads_radiance_d2_and_label(at_default):
    _, page, _ = at_default
    res, inputs = page.result, page.inputs
    row, col = np.argwhere(page.labels == LABEL_CHANGE)[0]
    page._on_pointer(float(col) + 0.2, float(row) - 0.3)
    text = page.readout.object
    assert f"row {row}, col {col}" in text and "**change**" in text
    assert f"{inputs.E_tgt[row, col, 0]:.4g}" in text
    assert f"{res.d2[row, col, 0]:.4g}" in text
    page._on_pointer(float("nan"), 2.0)                      # off the frame: ignored
    page._on_pointer(1e6, 2.0)
    assert page.readout.object == text


def test_compute_change_passes_the_tracker_straight_through(monkeypatch):
    """One progress convention, ``progress(fraction, message)``: the app's tracker goes to
    ccdcore as it is, no adapter between them."""
    from ccdcore.progress import Tracker

    seen = []

    def fake(session, options, progress=None):
        seen.append(progress)
        progress(0.25, "fitting")
        return "result", {"options": options}

    monkeypatch.setattr(change_page, "session_change", fake)
    tracker = Tracker()
    out = compute_change(object(), progress=tracker)
    assert seen == [tracker] and tracker.step == "fitting" and tracker.fraction == 0.25
    assert out[1]["options"].pfa == DEFAULT_PFA


def test_session_without_brackets_shows_the_error_and_the_app_goes_on(assets):
    """tsin01 has one bracket, neither reference nor target: an info (as the other pages say
    what a session of another kind lacks) says what to capture, no error; nothing is computed;
    opening the change demo afterwards works."""
    state, page = _page(assets / "tsin01")
    assert not page.error_alert.visible and page.error == ""
    assert page.info_alert.visible
    assert page.info_alert.object.startswith("No reference or target frames in this session.")
    assert "`reference/` and `target/`" in page.info_alert.object
    assert not page.content.visible and page.result is None
    assert state.error == "" and not state.busy and state.results.change == {}
    assert state.load(assets / "change")
    _run(page.refresh())
    assert page.error == "" and not page.error_alert.visible
    assert page.content.visible and page.result is not None
    assert page.count_number.value == np.count_nonzero(page.result.labels == LABEL_CHANGE)


def test_unusable_brackets_show_ccdcore_error(assets, tmp_path):
    """Every target frame saturated: ccdcore's error (no pixel with a radiance in both
    brackets) in the alert, no result, the page still usable."""
    from ccdcore.io.frames import write_image

    root = tmp_path / "s"
    shutil.copytree(assets / "change", root)
    for f in sorted((root / "target").glob("*.tif")):
        write_image(f, np.full((96, 128, 3), 255, np.uint8))
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root)
    page = ChangePage(state, auto=False)
    _run(page.refresh())
    assert page.error_alert.visible and "pixels have a radiance in both" in page.error
    assert page.result is None and not page.content.visible
    assert not state.busy
    page.pfa = 0.05                                      # nothing to show: no failure


def test_cancelled_detection_can_be_started_again(shown, assets, monkeypatch):
    """Cancel (ccdcore.progress.Cancelled in the worker): no error from ccdcore, the page says
    it was cancelled and offers to start again; the next refresh computes."""
    from ccdcore.progress import Cancelled

    _, done, _ = shown
    calls = []

    def cancelled(session, options, progress=None):
        calls.append("cancelled")
        progress(0.5, "fitting")
        raise Cancelled("cancelled during fitting")

    def finished(session, options, progress=None):
        calls.append("finished")
        return done.result, done.inputs

    state = AppState()
    assert state.load(assets / "change")
    page = ChangePage(state, auto=False)
    monkeypatch.setattr(change_page, "compute_change", cancelled)
    _run(page.refresh())
    assert page.result is None and "cancelled" in page.error and page.retry_button.visible
    assert state.error == "" and not state.busy and not page.progress_row.visible
    monkeypatch.setattr(change_page, "compute_change", finished)
    _run(page.refresh())
    assert calls == ["cancelled", "finished"]
    assert page.result is done.result and page.error == "" and not page.retry_button.visible
    assert page.count_number.value == np.count_nonzero(done.result.labels == LABEL_CHANGE)


def test_a_session_opened_while_computing_is_shown_next(shown, assets, monkeypatch):
    """Another session opened during the computation: its result is dropped and the new
    session is refreshed (here one without reference or target frames: what to capture)."""
    _, done, _ = shown
    state = AppState()
    assert state.load(assets / "change")
    page = ChangePage(state, auto=False)
    page.auto = True                     # refresh on its own, but not at construction

    def slow(session, options, progress=None):
        state.load(assets / "tsin01")    # the user opens another session meanwhile
        return done.result, done.inputs

    monkeypatch.setattr(change_page, "compute_change", slow)
    monkeypatch.setattr(change_page.pn.state, "execute", lambda *a, **k: None)
    _run(page.refresh())
    assert page.result is None and page.info_alert.visible
    assert page.info_alert.object.startswith("No reference or target frames")
    assert state.results.change == {}


def test_single_frames_session_shows_the_result_and_its_sources(tmp_path):
    """A plain folder of one reference and one target PNG (no exposure, as video frames come):
    the page computes through the frame-set path and names the response and noise sources."""
    from ccdcore.change.frames import FRAME_MIN_REGION
    from ccdcore.simulate.change_frames import write_frame_pair

    root = tmp_path / "frames"
    write_frame_pair(root, 0)
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root)
    page = ChangePage(state, auto=False)
    _run(page.refresh())
    assert page.error == "" and page.result is not None and page.content.visible
    assert page.inputs.kinds == {"reference": "frames", "target": "frames"}
    assert page.result.min_region == FRAME_MIN_REGION
    notes = page.notes_pane.object
    assert "- Response: assumed: the sRGB standard curve" in notes
    assert "- Noise: reference: assumed" in notes
    page.__panel__().get_root(Document())
    page.pfa = 0.05                                      # re-thresholds without a traceback
    assert page.count_number.value == np.count_nonzero(page.result.at(0.05)[0] == LABEL_CHANGE)


def test_half_a_change_session_is_an_error_naming_what_is_missing(tmp_path):
    """Reference frames without a target: an error that names the missing role (an info is
    for a session of another kind)."""
    from ccdcore.simulate.change_frames import write_frame_pair

    root = tmp_path / "half"
    write_frame_pair(root, 0)
    shutil.rmtree(root / "target")
    state = AppState(allowed_roots=[tmp_path.resolve()])
    assert state.load(root)
    page = ChangePage(state, auto=False)
    _run(page.refresh())
    assert page.error_alert.visible and not page.info_alert.visible
    assert page.error.startswith("This session has 'target' frames missing")
    assert page.result is None
