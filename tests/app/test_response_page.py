"""The Response & HDR page without a browser: on opening it computes the library's default
result only and shows its verdict in the library's words; other methods when asked (the method
choice, "Compare all methods"); the exposures choice; what it says without a bracket or with a
bracket it cannot use; a colour bracket's channel choice, the prediction agreement, and one
computation shared by every browser session."""
from __future__ import annotations

import asyncio
import dataclasses
import html
import shutil
import time

import numpy as np
import pytest
from bokeh.document import Document

import ccdcore_app.cache.store
import ccdcore_app.pages.response_hdr as response_hdr
from ccdcore_app.cache.store import SharedResults
from ccdcore_app.pages.response_hdr import (AUTO_LABEL, LABELS, NO_BRACKET_MESSAGE,
                                            ResponsePage)
from ccdcore_app.plots.response import VERDICT_ALERTS, details_markdown, md_text, tone_map
from ccdcore_app.state import AppState
from ccdcore.channels import channel_names
from ccdcore.errors import CcdError
from ccdcore.response.methods import AUTO, METHODS
from ccdcore.response.verdict import ResponseVerdict
from ccdcore.simulate import simulate
from _coro import run as _run

KEY = (3, False, "auto")      # the page's cache key with its default options


@pytest.fixture(autouse=True)
def _own_store(monkeypatch):
    """Each test shares results through its own process-wide store (no test sees another's)."""
    monkeypatch.setattr(ccdcore_app.cache.store, "_SHARED", SharedResults())


def _page(path, **kw):
    state = AppState()
    assert state.load(path)
    page = ResponsePage(state, auto=False, **kw)
    _run(page.refresh())
    return state, page


def _rendered(pane) -> str:
    """The HTML a Markdown pane (an alert) sends to the browser, unescaped once (Panel sends
    it escaped)."""
    return html.unescape(pane.get_root(Document()).text)


@pytest.fixture(scope="module")
def shown(assets):
    return _page(assets / "tsin01")


def test_only_the_default_is_computed_on_open(shown):
    state, page = shown
    assert page.error == "" and state.error == ""
    assert list(page.responses) == [AUTO]
    assert list(state.results.response) == [KEY]
    res = page.responses[AUTO]
    assert res.requested == AUTO and res.method in ("tsin", "debevec")
    np.testing.assert_array_equal(page.curves.curve(AUTO), res["L"].g)
    for m in METHODS:                              # the others are not computed, nor drawn
        assert page.curves.curve(m).size == 0
    band = page.curves.band.data
    np.testing.assert_allclose(band["hi"] - band["lo"], 4 * res["L"].g_err)
    assert list(page.noise_table.object["method"]) == [f"{AUTO_LABEL}: "
                                                       f"{METHODS[res.method].label}"]
    # the HDR is merged with the default result
    assert page.hdr is state.results.response[KEY]["hdr"][AUTO]


def test_the_verdict_is_the_librarys_line(shown):
    _, page = shown
    res = page.responses[AUTO]
    alert = page.verdict_alert
    assert alert.visible and alert.object == md_text(res.verdict.line())
    # the registration and the moving pixels, in the library's words, below the curves
    assert page.verdict_details.object == details_markdown(res.verdict)
    # the registration and the moving pixels, in the library's words, below the line
    assert res.verdict.registration and res.verdict.moving.startswith("moving objects:")
    assert alert.alert_type == VERDICT_ALERTS[res.verdict.status]
    assert f">{html.escape(res.verdict.line(), quote=False)}</p>" in _rendered(alert)
    note = page.exposures_note.object
    assert md_text(res.selection) in note
    if res.exposures is not None:
        assert md_text(res.exposures.summary().line()) in note
    assert not hasattr(response_hdr, "untrusted_reason")
    assert not hasattr(response_hdr, "TRUST_FACTOR")


def test_verdict_styles_and_escapes_file_names(rgb_shown):
    """Doubtful is a warning, failed a danger alert; a frame name is shown as it is, never as
    Markdown or HTML."""
    _, page, _ = rgb_shown
    saved = page.responses[AUTO]
    frames = ("<b>k_1*</b>.tif", "[x](y) $z$.tif")
    try:
        for status, alert_type in (("doubtful", "warning"), ("failed", "danger"),
                                   ("trusted", "success")):
            verdict = ResponseVerdict(status, "the images disagree with the exposures used",
                                      frames, "--exposures estimated")
            page.responses[AUTO] = dataclasses.replace(saved, verdict=verdict)
            page.method = AUTO
            page._render_agreement()
            assert page.verdict_alert.alert_type == alert_type
            assert page.verdict_alert.object == md_text(verdict.line())
            text = _rendered(page.verdict_alert)
            assert f"<p>{html.escape(verdict.line(), quote=False)}</p>" in text, text
            assert "<b>" not in text and "<a " not in text and "<em>" not in text
    finally:
        page.responses[AUTO] = saved
        page._render_agreement()


def test_choosing_a_method_computes_it_and_overlays_it(shown):
    state, page = shown
    entry = state.results.response[KEY]
    default = page.responses[AUTO]
    page.method = "robertson"
    _run(page.show_method())
    assert list(page.responses) == [AUTO, "robertson"] and page.responses is entry["responses"]
    rob = page.responses["robertson"]
    assert rob.requested == "robertson" and rob.method == "robertson"
    band = page.curves.band.data
    np.testing.assert_allclose(band["lo"], rob["L"].g - 2 * rob["L"].g_err)
    np.testing.assert_array_equal(page.curves.curve("robertson"), rob["L"].g)
    np.testing.assert_array_equal(page.curves.curve(AUTO), default["L"].g)   # overlaid
    assert page.verdict_alert.object == md_text(rob.verdict.line())
    assert page.hdr is entry["hdr"]["robertson"]
    # back to the default: nothing recomputed
    page.method = AUTO
    _run(page.show_method())
    assert page.responses[AUTO] is default and page.hdr is entry["hdr"][AUTO]
    assert page.verdict_alert.object == md_text(default.verdict.line())


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
    assert not page.content.visible and not page.verdict_alert.visible


def test_unusable_bracket_shows_an_error_and_the_app_goes_on(assets, tmp_path):
    """Every frame saturated: one error naming the frame, the page stays usable."""
    from ccdcore.io.frames import write_image

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
    assert md_text("s0_k00.tif") in page.error_alert.object     # escaped where shown
    assert page.responses is None and not page.verdict_alert.visible


def test_white_balance_gains_on_the_page(assets):
    """Ticking the gains recomputes the default with them (cached apart); sec. 3.2 chosen
    estimates them, the table shows a_k / t_k off 1; a classic method takes the exposures as
    they are."""
    state, page = _page(assets / "tsin01")
    page.param.update(white_balance=True)
    page._session = None
    _run(page.refresh())
    assert (3, True, "auto") in state.results.response and KEY in state.results.response
    res = page.responses[AUTO]
    assert res.requested == AUTO and page.verdict_alert.object == md_text(res.verdict.line())
    page.method = "tsin"
    _run(page.show_method())
    c = page.responses["tsin"]["L"]
    assert c.white_balance and not np.allclose(c.a, c.t)
    assert "a_k / t_k" in page.ab_table.object.columns
    page.method = "debevec"
    _run(page.show_method())
    d = page.responses["debevec"]["L"]
    assert not d.white_balance and np.allclose(d.a, d.t)
    assert page.error == ""


# ------------------------------------------------------------------ exposures ----------------
@pytest.fixture(scope="module")
def wrong_root(tmp_path_factory):
    """A camera-like bracket whose listed exposures are wrong for a run of pairs."""
    root = tmp_path_factory.mktemp("wrong") / "listed-wrong"
    simulate("tsin01", root, seed=1, camera="real-listed-wrong", size=(96, 64))
    return root


def test_wrong_listed_exposures_are_estimated_and_named(wrong_root):
    state = _state(wrong_root)
    page = ResponsePage(state, auto=False)
    _run(page.refresh())
    assert page.error == "", page.error
    res = page.responses[AUTO]
    assert res.exposures is not None and res.exposures.used == "estimated"
    summary = res.exposures.summary()
    runs = summary.off_runs()
    assert runs, "the simulated off pairs are named"
    note = page.exposures_note.object
    assert md_text(summary.line()) in note
    for run in runs:
        assert f"- {md_text(run)}" in note
    assert page.verdict_alert.object == md_text(res.verdict.line())
    # listed: the exposures as they are, cached apart; back to auto: nothing recomputed
    default = res
    page.exposures = "listed"
    page._session = None
    _run(page.refresh())
    assert (3, False, "listed") in state.results.response
    listed = page.responses[AUTO]
    assert listed.exposures is None and listed is not default
    assert "exposures: listed" in page.exposures_note.object
    assert page.verdict_alert.object == md_text(listed.verdict.line())
    page.exposures = "estimated"
    page._session = None
    _run(page.refresh())
    assert page.responses[AUTO].exposures.used == "estimated"
    page.exposures = "auto"
    page._session = None
    _run(page.refresh())
    assert page.responses[AUTO] is default
    assert sorted(k[2] for k in state.results.response) == ["auto", "estimated", "listed"]


def test_exposures_choice_is_a_selector_with_its_doc():
    p = ResponsePage.param.exposures
    assert list(p.objects) == ["auto", "listed", "estimated"] and p.default == "auto"
    assert "listed" in p.doc and "estimated" in p.doc
    page = ResponsePage(AppState(), auto=False)
    assert list(page.exposures_select.options) == ["auto", "listed", "estimated"]
    page.exposures_select.value = "listed"              # as a click in the browser does
    assert page.exposures == "listed"
    labels = list(page.method_select.options)
    assert labels == [AUTO_LABEL, *(m.label for m in METHODS.values())]


# ------------------------------------------------------------------ a colour bracket ---------

@pytest.fixture(scope="module")
def rgb_root(tmp_path_factory):
    """A small simulated colour bracket (tsin01 pipeline, one E per channel)."""
    root = tmp_path_factory.mktemp("rgb") / "bracket"
    simulate("tsin01", root, seed=11, size=(64, 48), layout="rgb")
    return root


def _state(root) -> AppState:
    state = AppState(allowed_roots=[root.parent.resolve()])
    assert state.load(root), state.error
    return state


def _models(root) -> dict[str, set[str]]:
    found: dict[str, set[str]] = {}
    for m in root.references():
        found.setdefault(type(m).__name__, set()).add(m.id)
    return {k: found.get(k, set()) for k in ("figure", "ColumnDataSource")}


@pytest.fixture(scope="module")
def rgb_shown(rgb_root):
    """The page on the colour bracket, rendered into a Bokeh document *before* the bracket
    is shown (as in a browser: the served channel buttons then take part), then every method
    compared: the figure's models are the same before and after (sources fed, nothing
    rebuilt)."""
    state = _state(rgb_root)
    page = ResponsePage(state, auto=False)
    root = page.__panel__().get_root(Document())
    _run(page.refresh())
    assert list(page.responses) == [AUTO]
    before = _models(root)
    _run(page.compare_all())
    assert _models(root) == before
    return state, page, root


def test_compare_all_methods_adds_the_others(rgb_shown):
    state, page, _ = rgb_shown
    assert list(page.responses) == [AUTO, *METHODS]
    assert page.compare and not page.compare_button.disabled
    for m in (AUTO, *METHODS):
        np.testing.assert_array_equal(page.curves.curve(m), page.responses[m]["R"].g)
        assert page.curves.lines[m].visible
        assert page.responses[m].requested == m
    assert list(state.results.response) == [KEY]


def test_rgb_bracket_sets_the_channel_choice_consistently(rgb_shown):
    state, page, root = rgb_shown
    assert page.error == "" and state.error == "", (page.error, state.error)
    assert list(page.param.channel.objects) == ["R", "G", "B"] and page.channel == "R"
    assert list(page.channel_select.options) == ["R", "G", "B"]
    assert page.channel_select.value == "R" and page.channel_select.visible
    # the served radio group holds the same labels and the active button
    model = next(m for m in root.references() if type(m).__name__ == "RadioButtonGroup"
                 and list(m.labels) == ["R", "G", "B"])
    assert model.active == 0


def test_rgb_channel_choice_shows_each_channel_in_place(rgb_shown):
    _, page, root = rgb_shown
    before = _models(root)
    curves = {}
    for ch in ("G", "B", "R"):
        page.channel_select.value = ch                  # as a click in the browser does
        assert page.channel == ch
        for m, r in page.responses.items():
            np.testing.assert_array_equal(page.curves.curve(m), r[ch].g)
        curves[ch] = page.curves.curve("debevec").copy()
    assert not np.array_equal(curves["R"], curves["G"])  # three curves, not one shown thrice
    assert _models(root) == before                       # sources fed, nothing rebuilt


def _known(monkeypatch, **by_channels):
    """``compute_response`` replaced by the results already computed (counted, slowed), by
    the session's channels and the method: the tests of sharing and of the channel choice need
    results, not the estimators' time. A copy each call, as a computation gives a new
    object."""
    def known(session, method=AUTO, *args, **kwargs):
        found = by_channels["".join(channel_names(session.camera.layout))][method]
        return dataclasses.replace(found)
    counted = _Counting(known)
    monkeypatch.setattr(response_hdr, "compute_response", counted)
    return counted


def test_new_session_with_other_channels_keeps_choice_and_widget_in_step(
        rgb_root, rgb_shown, shown, assets, monkeypatch):
    """RGB, then a mono bracket, then RGB again on the same rendered page."""
    _known(monkeypatch, RGB=rgb_shown[1].responses, L=shown[1].responses)
    state = AppState(allowed_roots=[rgb_root.parent.resolve(), assets.resolve()])
    page = ResponsePage(state, auto=False)
    page.__panel__().get_root(Document())
    for root, names in ((rgb_root, ["R", "G", "B"]), (assets / "tsin01", ["L"]),
                        (rgb_root, ["R", "G", "B"])):
        assert state.load(root)
        _run(page.refresh())
        assert page.error == "", page.error
        assert list(page.param.channel.objects) == names
        assert list(page.channel_select.options) == names
        assert page.channel == page.channel_select.value == names[0]
        assert page.channel_select.visible == (len(names) > 1)
        assert list(page.responses) == [AUTO]


# ------------------------------------------------------------------ agreement ----------------
def test_agreement_tables_show_every_curve_and_the_chosen_ones_pairs(rgb_shown):
    _, page, _ = rgb_shown
    pooled = page.agreement_table.object
    default = page.responses[AUTO]
    assert list(pooled["method"]) == [f"{AUTO_LABEL}: {METHODS[default.method].label}",
                                      *(LABELS[m] for m in METHODS)]
    for m, row in zip((AUTO, *METHODS), pooled.to_dict("records")):
        a = page.responses[m].agreement
        assert list(row.values())[1:] == [f"{a.rms:.2f}", f"{a.rms_fitted:.2f}",
                                          f"{a.rms_blend:.2f}"], m
    for method in ("robertson", "debevec"):
        page.method = method
        res = page.responses[method]
        assert page.verdict_alert.object == md_text(res.verdict.line())
        pairs = page.pairs_table.object
        assert len(pairs) == res.t.size - 1
        t = res.t
        for ch in res.channels:
            for p, (_, row) in zip(res.agreement[ch].pairs, pairs.iterrows()):
                assert row["images"] == f"{p.j + 1}\u2192{p.k + 1}"
                assert row[f"{ch}: RMS"] == f"{p.rms:.2f}"
                assert row[f"{ch}: fitted"] == f"{p.rms_fitted:.2f}"
                assert row[f"{ch}: ratio fit/nominal"] == \
                    f"{p.ratio_fitted / (t[p.k] / t[p.j]):.3f}"
        assert md_text(LABELS[method]) in page.pairs_note.object
    page.method = AUTO


def test_default_agreement_lists_its_challenger(rgb_root):
    """Before any other method is computed, the table shows the curve the default was checked
    against (the library's ``compared``)."""
    state = _state(rgb_root)
    page = ResponsePage(state, auto=False)
    _run(page.refresh())
    res = page.responses[AUTO]
    rows = page.agreement_table.object.to_dict("records")
    assert len(rows) == 1 + len(res.compared) and res.compared
    for (name, a), row in zip(res.compared.items(), rows[1:]):
        assert row["method"].startswith(f"{LABELS[name]} (challenger")
        assert list(row.values())[1] == f"{a.rms:.2f}"


# ------------------------------------------------------------------ shared computations ------
class _Counting:
    """``func`` counted, each call slowed (so a second caller arrives while it runs)."""

    def __init__(self, func, delay: float = 0.5):
        self.func, self.delay, self.calls = func, delay, 0

    def __call__(self, *args, **kwargs):
        self.calls += 1
        time.sleep(self.delay)
        return self.func(*args, **kwargs)


async def _ticking(until: "asyncio.Future") -> int:
    """How many 20 ms sleeps the event loop runs until ``until`` is done."""
    ticks = 0
    while not until.done():
        await asyncio.sleep(0.02)
        ticks += 1
    return ticks


def _gather_with_ticks(*coros):
    async def go():
        work = asyncio.ensure_future(asyncio.gather(*coros))
        ticks = await _ticking(work)
        return await work, ticks
    return _run(go())


def test_two_pages_on_one_state_compute_once(rgb_root, rgb_shown, monkeypatch):
    responses = _known(monkeypatch, RGB=rgb_shown[1].responses)
    hdr = _Counting(response_hdr.compute_hdr)
    monkeypatch.setattr(response_hdr, "compute_hdr", hdr)
    state = _state(rgb_root)
    one, two = ResponsePage(state, auto=False), ResponsePage(state, auto=False)
    _, ticks = _gather_with_ticks(one.refresh(), two.refresh())
    assert responses.calls == 1 and hdr.calls == 1
    assert one.responses is two.responses and one.hdr is two.hdr
    assert list(one.responses) == [AUTO]
    assert one.error == two.error == state.error == ""
    assert ticks >= 20                 # the event loop ran on while both waited (> 0.4 s)


def test_browser_sessions_share_one_computation(rgb_root, rgb_shown, monkeypatch):
    """Two browser sessions (two states, each opening the folder) on one server: one
    computation, which the second waits for; a third, later, gets it at once."""
    responses = _known(monkeypatch, RGB=rgb_shown[1].responses)
    hdr = _Counting(response_hdr.compute_hdr)
    monkeypatch.setattr(response_hdr, "compute_hdr", hdr)
    first, second = _state(rgb_root), _state(rgb_root)
    assert first.session is not second.session
    statuses: list[str] = []
    second.param.watch(lambda e: statuses.append(e.new), "status")
    one, two = ResponsePage(first, auto=False), ResponsePage(second, auto=False)
    _, ticks = _gather_with_ticks(one.refresh(), two.refresh())
    assert responses.calls == 1 and hdr.calls == 1
    assert one.responses[AUTO] is two.responses[AUTO] and one.hdr is two.hdr
    assert any("another browser tab" in s for s in statuses), statuses
    assert ticks >= 20
    third = ResponsePage(_state(rgb_root), auto=False)
    _run(third.refresh())
    assert responses.calls == 1 and hdr.calls == 1
    assert third.responses[AUTO] is one.responses[AUTO]
    # a method asked for in one session is shared with the others too
    one.method = "robertson"
    _run(one.show_method())
    third.method = "robertson"
    _run(third.show_method())
    assert responses.calls == 2 and third.responses["robertson"] is one.responses["robertson"]
    # other options are another computation
    third.param.update(bloom_radius=0)
    third._session = None
    _run(third.refresh())
    assert responses.calls == 4        # the default and the chosen method, with radius 0
    assert third.responses[AUTO] is not one.responses[AUTO]
    third.param.update(exposures="listed")
    third._session = None
    _run(third.refresh())
    assert responses.calls == 6


def _slow(progress=None, fail: bool = False, steps: int = 60):
    for i in range(steps):
        progress(i / steps, "working")        # raises Cancelled once cancelled
        time.sleep(0.02)
    if fail:
        raise CcdError("bracket", "every frame saturated")
    return {"value": 42}


def _two_callers(rgb_root, func, act=None, *, delay: float = 0.2):
    """Session one starts ``func`` shared, session two asks for it ``delay`` later; ``act``
    (states) runs after another ``delay``. Both outcomes and the calls."""
    counted = _Counting(func, delay=0.0)
    store = SharedResults()
    one, two = _state(rgb_root), _state(rgb_root)

    async def go():
        a = asyncio.ensure_future(one.shared_compute("slow", {}, counted, label="slow",
                                                     pass_progress=True, store=store))
        await asyncio.sleep(delay)
        b = asyncio.ensure_future(two.shared_compute("slow", {}, counted, label="slow",
                                                     pass_progress=True, store=store))
        await asyncio.sleep(delay)
        if act is not None:
            act(one, two)
        return await a, await b
    return (*_run(go()), counted.calls, one, two)


def test_a_cancelled_shared_computation_is_taken_over_by_the_waiter(rgb_root):
    a, b, calls, one, two = _two_callers(rgb_root, _slow, lambda one, two: one.cancel())
    assert a is None and b == {"value": 42} and calls == 2
    assert one.status == "Cancelled slow." and two.error == ""


def test_a_waiter_cancelling_stops_only_its_wait(rgb_root):
    a, b, calls, one, two = _two_callers(rgb_root, _slow, lambda one, two: two.cancel())
    assert a == {"value": 42} and b is None and calls == 1
    assert two.status == "Stopped waiting for slow." and not two.busy


def test_a_shared_error_reaches_every_waiter_once_computed(rgb_root):
    a, b, calls, one, two = _two_callers(rgb_root, lambda progress: _slow(progress, True))
    assert a is None and b is None and calls == 1
    assert one.error == two.error == "bracket: every frame saturated"


def test_the_simulators_truth_is_drawn_on_the_reported_scale(wrong_root):
    """A camera-like simulation's true g has a scale of its own (its tone curve's headroom):
    drawn as it is, it lay far below every estimate. It is drawn with g(z_hi) = z_hi / 255,
    the scale every curve is reported on, its shape unchanged."""
    import json

    from ccdcore.response.scale import reference_codes

    truth = np.asarray(json.loads((wrong_root / "truth.json").read_text())["g"])
    state = _state(wrong_root)
    page = ResponsePage(state, auto=False)
    _run(page.refresh())
    drawn = np.asarray(page.curves.truth.data["g"], np.float64)
    _, z_hi = reference_codes(256)
    assert drawn[z_hi] == pytest.approx(z_hi / 255, rel=1e-12)
    np.testing.assert_allclose(drawn / drawn[z_hi], truth / truth[z_hi], rtol=1e-12)


def test_the_truths_legend_entry_only_where_there_is_a_truth():
    """A simulation shows its truth's line and legend entry; a bracket without truth.json (a
    real camera's) shows neither."""
    from ccdcore_app.plots.response import ResponseFigure

    curves = ResponseFigure(list(METHODS), {m: m for m in METHODS})
    g = np.linspace(0.0, 1.0, 256)
    curves.show({"tsin": (g, 0.01 * g)}, "tsin", False, truth=g ** 1.2)
    assert curves.truth_line.visible and curves.legend.items[0].visible
    assert curves.legend.items[0].label.value == "simulator's truth"
    curves.show({"tsin": (g, 0.01 * g)}, "tsin", False, truth=None)
    assert not curves.truth_line.visible and not curves.legend.items[0].visible
    # only the curves drawn have an entry: not the methods not computed
    shown = [item.label.value for item in curves.legend.items if item.visible]
    assert shown == ["tsin"]
    curves.show({"tsin": (g, 0.01 * g), "debevec": (g, 0.01 * g)}, "tsin", True)
    assert [item.label.value for item in curves.legend.items if item.visible] == ["tsin",
                                                                                  "debevec"]
