"""App logic without a browser: the state object, the Session page wiring and the plot functions."""
from __future__ import annotations

import asyncio
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
from ccdcore_app.plots import base as plots
from ccdcore_app.pages import PAGES, build_page
from ccdcore_app.pages.session import SessionPage, frames_frame, groups_frame
from ccdcore_app.state import AppState, demo_sessions
from _coro import run as _run


@pytest.fixture
def state(tmp_path, assets):
    return AppState(allowed_roots=[tmp_path.resolve(), assets.resolve()])


def test_demo_sessions_are_found(assets):
    assert set(demo_sessions(assets)) == {"healey94", "delasarte07", "tsin01", "tsin01-camera",
                                          "change", "emva1288"}


def test_an_installed_package_writes_its_demos_once(tmp_path, monkeypatch, assets):
    """Installed without assets/ beside the package, the app writes the demos into the user's
    data folder on first use: the same bytes as the committed ones (the simulators are
    deterministic), and never again once there."""
    import ccdcore_app
    from ccdcore_app import state as st

    fake_pkg = tmp_path / "site" / "ccdcore_app"
    fake_pkg.mkdir(parents=True)
    monkeypatch.setattr(ccdcore_app, "__file__", str(fake_pkg / "__init__.py"))
    monkeypatch.delenv(st.ASSETS_ENV, raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    where = tmp_path / "data" / "ccdcore" / "demos"
    assert st.assets_dir() == where
    found = demo_sessions()
    assert set(found) == set(demo_sessions(assets))
    for name in ("tsin01", "healey94"):
        for f in (assets / name).rglob("*.toml"):
            assert (where / name / f.relative_to(assets / name)).read_bytes() == f.read_bytes()
    stamp = (where / "tsin01" / "session.toml").stat().st_mtime_ns
    assert set(demo_sessions()) == set(found)
    assert (where / "tsin01" / "session.toml").stat().st_mtime_ns == stamp
    assert not [p for p in where.iterdir() if p.name.startswith(".")]    # no leftovers


def test_load_demo_fills_state(state, healey94):
    assert state.load(healey94)
    assert state.session is not None and state.error == ""
    assert "96 frames" in state.status and "valid" in state.status
    assert state.session_path == str(healey94.resolve())


@pytest.mark.parametrize("bad,words", [("nowhere", "not"), ("", "empty")])
def test_bad_paths_become_messages_and_keep_the_session(state, healey94, tmp_path, bad, words):
    state.load(healey94)
    path = tmp_path / bad if bad else ""
    assert not state.load(path)
    assert words in state.error
    assert state.session is not None and state.session_path == str(healey94.resolve())


def test_paths_outside_the_allowed_roots_are_refused(tmp_path, assets):
    st = AppState(allowed_roots=[assets.resolve()])
    assert not st.load(tmp_path)
    assert "outside the folders" in st.error


def test_broken_manifest_names_the_file(state, broken_manifest):
    assert not state.load(broken_manifest)
    assert "session.toml" in state.error


def test_async_load(state, healey94):
    assert _run(state.load_async(healey94))
    assert state.session is not None and not state.busy


def test_session_page_tables_and_problems(state, problem_session):
    page = SessionPage(state)
    state.load(problem_session)
    groups = page.groups_table.value
    assert set(groups["role"]) >= {"dark", "ptc"}
    frames = page.frames_table.value
    assert "dark/d0.tif" in set(frames["relpath"])
    texts = " ".join(a.object for a in page.problem_alerts)
    assert "missing.tif" in texts and "darkish" in texts
    assert any(a.alert_type == "danger" for a in page.problem_alerts)


def test_session_page_preview_of_an_unreadable_frame_is_an_alert(state, unreadable_session):
    page = SessionPage(state)
    state.load(unreadable_session)
    page.frame = "scene/bad.tif"
    _run(page._on_frame())
    assert page.preview_alert.visible and "bad.tif" in page.preview_alert.object
    page.frame = "dark/d0.tif"
    _run(page._on_frame())
    assert not page.preview_alert.visible and page.image_view.plane is not None


def test_plain_folder_shows_inference_and_writes_the_draft(state, plain_folder):
    page = SessionPage(state)
    assert state.load(plain_folder)
    assert page.draft_card.visible
    assert "exposure" in page.inferred_pane.object
    page._on_draft()
    assert (plain_folder / "session.toml.draft").is_file()
    assert not (plain_folder / "session.toml").exists()


def test_tables_of_a_demo(healey94):
    from ccdcore.session import open_session

    s = open_session(healey94)
    groups, frames = groups_frame(s), frames_frame(s)
    assert groups["count"].sum() == len(s.frames)
    assert len(frames) == len(s.frames)
    # sizes read width x height (the demo is 256 px wide, 192 px tall), as the CLI's --size WxH
    height, width = s.header(s.frames[0]).shape[:2]
    assert (width, height) == (256, 192)
    assert set(groups["size (W×H)"]) == set(frames["size (W×H)"]) == {"256 × 192"}


def test_every_page_builds(state):
    for spec in PAGES:
        view = build_page(spec, state)
        assert view is not None


def test_plot_functions():
    plane = np.arange(12, dtype=np.uint16).reshape(3, 4)
    edges = plots.histogram_edges(plane)
    assert len(edges) == 13 and edges[0] == -0.5           # one bin per DN
    lo, hi = plots.auto_clim(np.arange(1000.0))
    assert 4 < lo < 6 and 993 < hi < 995
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[..., 0] = 200
    assert tuple(plots.channel_planes(rgb)) == ("R", "G", "B", "L")
    assert plots.channel_planes(rgb[..., 0]) == {}                  # mono: the frame itself
    assert plots.channel_data(rgb, "R").max() == 200
    assert plots.channel_data(rgb, "L").max() == pytest.approx(200 * 0.2126, rel=1e-6)


@pytest.mark.parametrize("demo", ["healey94", "delasarte07"])
def test_every_page_lays_out_without_bokeh_validation_issues(demo, assets):
    """Bokeh validates each document it serves and logs a warning per bad layout (e.g. a fixed
    sizing mode without a height); a served page should give none."""
    import panel as pn
    from bokeh.core.validation.check import check_integrity
    from bokeh.models import GridPlot, Plot

    def framed(model) -> bool:  # sized by its frame(s), as plots.fixed_size makes image views
        if isinstance(model, GridPlot):
            return all(framed(child[0]) for child in model.children)
        return (isinstance(model, Plot) and model.frame_width is not None
                and model.frame_height is not None)

    state = AppState(allowed_roots=[assets.resolve()])
    state.load(assets / demo)
    for spec in PAGES:
        models = pn.panel(build_page(spec, state)).get_root().references()
        found = check_integrity(models)
        # a plot (or grid of plots) with fixed frame sizes has a fixed size, though bokeh's
        # W-1005 asks for width and height regardless
        exempt = {f"id='{m.id}'" for m in models if framed(m)}
        # (an empty holder, W-1002, is filled when results arrive)
        issues = [str(i) for i in (*found.error, *found.warning) if i.code != 1002
                  and not (i.code == 1005 and any(e in i.extra for e in exempt))]
        assert issues == [], spec.slug


def test_set_choices_gives_watchers_only_the_final_choice():
    """A served Select replaces a value missing from its new options by the first option;
    set_choices gives the widget options and value together, so watchers see the final choice
    once (the widgets here have Bokeh models, as in a served page)."""
    import panel as pn
    import param

    from ccdcore_app.pages._choices import set_choices

    class Page(param.Parameterized):
        choice = param.Selector(default=None, objects=[], allow_None=True)
        ticks = param.ListSelector(default=[], objects=[])
        data = param.Dict(default={})
        seen = param.List(default=[])

        @param.depends("data", "choice", "ticks", watch=True)
        def _watch(self):
            self.seen = [*self.seen, (self.choice, list(self.ticks))]

    page = Page()
    select = pn.widgets.Select.from_param(page.param.choice)
    boxes = pn.widgets.CheckBoxGroup.from_param(page.param.ticks)
    select.get_root(), boxes.get_root()
    set_choices(page, {"choice": (select, {"A": "a", "B": "b"}, "b"),
                       "ticks": (boxes, {"one": 1, "two": 2}, [2])}, data={"x": 1})
    assert page.seen == [("b", [2])]
    assert (select.value, boxes.value) == ("b", [2])
    assert list(select.options) == ["A", "B"] and list(boxes.options) == ["one", "two"]
    set_choices(page, {"choice": (select, ["c", "d"], "d")}, trigger=False)
    assert page.seen == [("b", [2])] and select.value == "d" and page.choice == "d"
    select.value = "c"                                   # the user's choice reaches watchers
    assert page.seen[-1] == ("c", [2])


def test_compute_reports_progress_and_cancel_stops_it(tmp_path):
    """A tracked computation shows its step and frames in ``status``/``progress`` while it
    runs; ``cancel`` stops it at the next frame: None, no error, status says cancelled."""
    import threading
    import time

    from ccdcore.product.make import ESTIMATE_STEPS, estimate_all

    demo = Path(__file__).resolve().parents[2] / "assets" / "healey94"
    state = AppState(allowed_roots=[demo.parent])
    assert state.load(demo)
    statuses: list[tuple[int, str]] = []
    state.param.watch(lambda e: statuses.append((state.progress, state.status)), "status")
    gate = threading.Event()
    original = state.session.read

    def slow_read(rec):                      # slow enough for several progress reports
        time.sleep(0.03)
        gate.set()
        return original(rec)

    object.__setattr__(state.session, "read", slow_read)

    async def run_and_cancel():
        task = asyncio.ensure_future(state.compute(estimate_all, state.session,
                                                   steps=ESTIMATE_STEPS, pass_progress=True,
                                                   label="maps"))
        while not any("frame" in text for _, text in statuses):
            await asyncio.sleep(0.05)
        assert state.busy and state.cancellable
        state.cancel()
        return await task

    with ThreadPoolExecutor(1) as pool:   # the browser tests may run an event loop in this thread
        assert pool.submit(asyncio.run, run_and_cancel()).result() is None
    assert state.error == "" and state.status == "Cancelled maps."
    assert not state.busy and not state.cancellable and state.progress == -1
    shown = [(p, t) for p, t in statuses if "frame" in t]
    assert shown and all(0 <= p < 100 for p, _ in shown)
    # the step and its frame count (which step the first report catches depends on the
    # machine's speed: photon transfer reads its 16 frames ahead in threads)
    steps = "|".join(re.escape(name) for name, _ in ESTIMATE_STEPS)
    assert re.fullmatch(rf"Computing maps: ({steps}): frame \d+ of \d+ \.\.\.", shown[0][1]), \
        shown[0][1]
    assert state.results.estimates is None


def test_warm_up_imports_every_built_page_once():
    import sys

    from ccdcore_app import main
    from ccdcore_app.pages import PAGES

    main.start_warm_up()
    thread = main._warm_thread
    main.start_warm_up()                          # once per process
    assert main._warm_thread is thread or main._warmed
    if thread is not None:
        thread.join(timeout=120)
    assert main._warmed
    for spec in PAGES:
        assert spec.module in sys.modules
