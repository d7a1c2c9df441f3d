"""Session page wiring, the app shell and the entry points, without a browser."""
from __future__ import annotations

import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel and HoloViews extensions, as serving does)
from ccdcore_app.plots import base as plots
from ccdcore_app.main import AppShell, _session_header, create_app
from ccdcore_app.pages import PAGES, build_page, get_page
from ccdcore_app.pages.session import MAX_ALERTS, SessionPage, inferred_summary
from ccdcore_app.state import AppState, is_allowed
from ccdcore.io.frames import write_image
from ccdcore.session import open_session
from _coro import run as _run
from conftest import make_session as make_manifest_session


@pytest.fixture
def state(tmp_path, assets):
    return AppState(allowed_roots=[tmp_path.resolve(), assets.resolve()])


def _show(page: SessionPage, relpath: str) -> None:
    page.frame = relpath
    _run(page._on_frame())


def test_open_demo_button_loads_the_chosen_demo_and_fills_the_page(state, assets):
    page = SessionPage(state)
    page.demo_select.value = "healey94"
    _run(page._on_open_demo())
    session = state.session
    assert session is not None and session.root == (assets / "healey94").resolve()
    # groups: one row per group, counts add up to the frames
    groups = page.groups_table.value
    assert groups["count"].sum() == len(session.frames)
    assert set(groups["role"]) == set(session.roles())
    # frames: every frame, paginated
    frames = page.frames_table.value
    assert list(frames["relpath"]) == [r.relpath for r in session.frames]
    assert page.frames_table.pagination == "remote" and page.frames_table.page_size < len(frames)
    assert "XC-77-like simulated CCD" in page.camera_pane.object
    assert [a.alert_type for a in page.problem_alerts] == ["success"]
    assert not page.draft_card.visible        # a manifest session: nothing inferred
    assert page.param.frame.objects == list(frames["relpath"])
    assert page.frame == session.frames[0].relpath


def test_selecting_a_table_row_previews_that_frame(state, healey94):
    page = SessionPage(state)
    state.load(healey94)
    page.frames_table.selection = [3]
    relpath = page.frames_table.value.iloc[3]["relpath"]
    assert page.frame == relpath
    _run(page._on_frame())
    rec = state.session.frames[3]
    expected = state.session.read(rec)
    np.testing.assert_array_equal(page._plane, expected)
    assert relpath in page.frame_info.object
    assert page.image_view.plane is not None and page.image_pane.visible and page.hist_pane.visible
    np.testing.assert_array_equal(page.image_view.plane, expected)
    assert page.hist_view.source.data["top"].sum() == expected.size
    # the colour range starts at the 0.5-99.5 % percentiles, inside the data range
    lo, hi = plots.auto_clim(expected)
    assert page.clim_slider.value == (max(lo, expected.min()), min(hi, expected.max()))
    assert page.clim_slider.start == expected.min() and page.clim_slider.end == expected.max()
    assert not page.channel_select.visible       # mono frame: no channel choice


def test_colour_frames_offer_channels_and_auto_range(state, small_session):
    page = SessionPage(state)
    state.load(small_session)
    _show(page, "scene/rgb.tif")
    rgb = state.session.read(state.session.frames[-1])
    assert page.channel_select.visible
    page.channel = "R"                            # the red channel is flat (4000) in the fixture
    np.testing.assert_array_equal(page._plane, rgb[..., 0])
    assert "channel R" in page.frame_info.object
    page.channel = "G"
    np.testing.assert_array_equal(page._plane, rgb[..., 1])
    page.channel = "L"
    np.testing.assert_allclose(page._plane, rgb[..., :3].astype(np.float32)
                               @ np.float32(plots.LUMINANCE_WEIGHTS), rtol=1e-6)
    # the user narrows the range; Auto restores the percentile range
    auto = page.clim_slider.value
    page.clim_slider.value = (page.clim_slider.start, page.clim_slider.start + 1)
    page._on_auto()
    assert page.clim_slider.value == auto


def test_pointer_readout_reports_the_exact_pixel(state, small_session):
    page = SessionPage(state)
    state.load(small_session)
    _show(page, "ptc/p1.tif")
    plane = state.session.read(state.session.frames[3])
    page._on_pointer(x=5.2, y=7.8)                 # nearest pixel centre: column 5, row 8
    assert page.readout.object == f"x = 5, y = 8: **{plane[8, 5]} DN**"
    before = page.readout.object
    page._on_pointer(x=500.0, y=2.0)               # outside the frame: unchanged
    assert page.readout.object == before


def test_unreadable_frame_then_a_good_one(state, unreadable_session):
    page = SessionPage(state)
    state.load(unreadable_session)
    # the open already names the bad file as a problem
    assert any("bad.tif" in a.object and a.alert_type == "danger" for a in page.problem_alerts)
    _show(page, "scene/bad.tif")
    assert page.preview_alert.visible and "scene/bad.tif" in page.preview_alert.object
    assert page.image_view.plane is None and not page.image_pane.visible
    _show(page, "dark/d1.tif")
    assert not page.preview_alert.visible and page.image_view.plane is not None


def test_plain_folder_warnings_are_yellow_and_inference_is_listed(state, plain_folder):
    page = SessionPage(state)
    assert state.load(plain_folder)
    kinds = {a.alert_type for a in page.problem_alerts}
    assert kinds == {"warning"}, [a.object for a in page.problem_alerts]
    summary = dict((k, n) for k, n, _ in inferred_summary(state.session))
    assert summary["role"] == 4 and summary["exposure"] == 4
    assert "**role** for 4 of 4 frames, from folder names" in page.inferred_pane.object
    assert page.draft_button.visible and "```toml" in page.draft_pane.object
    page._on_draft()
    draft = plain_folder / "session.toml.draft"
    assert page.notice_alert.visible and "session.toml.draft" in page.notice_alert.object
    # the draft is a manifest giving back the same frames and roles
    assert not (plain_folder / "session.toml").exists() and draft.is_file()
    draft.rename(plain_folder / "session.toml")
    reopened = open_session(plain_folder)
    assert reopened.source == "manifest"
    assert [(r.relpath, r.role, r.exposure) for r in reopened.frames] == \
        [(r.relpath, r.role, r.exposure) for r in state.session.frames]


def test_camera_folder_of_bracketed_jpegs_shows_the_inferred_bracket(state, tmp_path):
    """A plain folder of JPEGs with EXIF exposure times opens as one bracket stack."""
    root = tmp_path / "DCIM"
    y, x = np.mgrid[0:12, 0:16]
    for i, seconds in enumerate((0.002, 0.008, 0.032)):
        rgb = np.clip((x + y + 1)[..., None] * np.array([8.0, 6.0, 4.0]) * seconds * 40, 0, 255)
        write_image(root / f"IMG_{i}.jpg", rgb.astype(np.uint8), exposure=seconds,
                    attributes={"Make": "Canon", "Model": "Canon EOS 80D"})
    page = SessionPage(state)
    assert state.load(root)
    groups = page.groups_table.value
    assert list(groups["role"]) == ["bracket"] and list(groups["key"]) == ["1"]
    assert groups["exposure (s)"].iloc[0] == "0.002, 0.008, 0.032"
    assert "| Camera | Canon EOS 80D |" in page.camera_pane.object
    assert "| Layout | rgb |" in page.camera_pane.object
    text = page.inferred_pane.object
    assert "**role** for 3 of 3 frames, from folder names and, for exposure brackets, the " \
           "exposure times in the file headers" in text
    assert "**stack** for 3 of 3 frames, from the bracket's folder" in text
    assert any("stack 1 = 3 frames in the top-level folder" in a.object
               for a in page.problem_alerts)
    assert 'role = "bracket"' in page.draft_pane.object and "stack = 1" in page.draft_pane.object


def test_bad_inputs_are_alerts_and_the_page_keeps_its_session(state, healey94, broken_manifest,
                                                              tmp_path):
    page = SessionPage(state)
    state.load(healey94)
    frames_before = page.frames_table.value.copy()
    page.path_input.value = str(broken_manifest)
    _run(page._on_open_path())
    assert page.error_alert.visible and "session.toml" in page.error_alert.object
    page.path_input.value = str(tmp_path / "nope")
    _run(page._on_open_path())
    assert page.error_alert.visible and "nope: does not exist" in page.error_alert.object
    page.path_input.value = "/etc"
    _run(page._on_open_path())
    assert "outside the folders" in page.error_alert.object
    assert page.frames_table.value.equals(frames_before)
    assert state.session_path == str(healey94.resolve())
    # the next good open clears the alert
    page.path_input.value = str(healey94)
    _run(page._on_open_path())
    assert not page.error_alert.visible


def test_problem_alerts_are_capped(state, small_session):
    extra = "".join(f'\n[[frames]]\npath = "dark/missing{i}.tif"\nrole = "dark"\n'
                    for i in range(MAX_ALERTS + 5))
    with (small_session / "session.toml").open("a") as f:
        f.write(extra)
    page = SessionPage(state)
    state.load(small_session)
    alerts = page.problem_alerts
    assert len(alerts) == MAX_ALERTS + 1
    assert "more problems" in alerts[-1].object


def test_file_browser_is_restricted_to_the_allowed_roots(state, healey94, tmp_path):
    page = SessionPage(state)
    assert set(page.root_select.options.values()) == {str(r) for r in state.allowed_roots}
    page.root_select.value = str(healey94.parent.resolve())
    assert page.file_selector.root_directory == str(healey94.parent.resolve())
    _run(page._on_open_selected())                 # nothing selected: an alert
    assert page.error_alert.visible and "Nothing selected" in page.error_alert.object
    page.file_selector.value = [str(healey94 / "session.toml")]
    _run(page._on_open_selected())
    assert state.session is not None and not page.error_alert.visible
    assert is_allowed(healey94, state.allowed_roots) and not is_allowed("/etc", state.allowed_roots)


def test_shell_navigation(state):
    shell = AppShell(state)
    page = shell.page_view("session")
    assert shell.page == "session" and isinstance(page, SessionPage)
    assert list(shell.holders) == [p.slug for p in PAGES]           # one holder per page
    assert shell.holders["session"].objects[0] is page.__panel__()
    assert not any(h.objects for slug, h in shell.holders.items()   # unvisited: empty
                   if slug != "session")
    shell.nav.value = "flat_field"                                # the sidebar's button
    assert shell.page == "flat_field"
    shell.page = "flat_field"
    # one page visible, the visited ones kept hidden
    assert [h.visible for h in shell.holders.values()].count(True) == 1
    assert shell.holders["flat_field"].visible and not shell.holders["session"].visible
    shell.page = "session"                                        # e.g. from the address
    assert shell.nav.value == "session"
    assert shell.page_view("session") is page                     # kept, not rebuilt
    assert shell.holders["session"].visible
    assert shell.holders["session"].objects[0] is page.__panel__()
    assert shell.holders["flat_field"].objects                    # visited: kept
    assert [p.slug for p in PAGES][:1] == ["session"] and len(PAGES) == 7
    with pytest.raises(KeyError, match="known"):
        get_page("nope")
    assert build_page(get_page("session"), state).state is state


def test_create_app_opens_the_given_session_and_shows_it_in_the_header(healey94):
    template = create_app(healey94)
    st = template.app_state
    assert st.session is not None and st.session.root == healey94.resolve()
    assert is_allowed(healey94, st.allowed_roots)
    assert "healey94" in _session_header(st.session_path, st.status, st.busy)
    assert "No session loaded" in _session_header("", "", False)
    bad = create_app("/nonexistent/session")
    assert bad.app_state.session is None and "does not exist" in bad.app_state.error


def test_serve_entry_point_answers_on_localhost(warmed):
    import panel as pn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    try:
        ccdcore_app.main.serve(None, port=port, threaded=True)
        for _ in range(200):                       # wait for /liveness (at most ~20 s)
            try:
                with urllib.request.urlopen(url + "/liveness", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                time.sleep(0.1)
        with urllib.request.urlopen(url + "/", timeout=20) as r:
            body = r.read().decode()
        assert r.status == 200 and "ccdcore" in body
    finally:
        pn.state.kill_all_servers()


def test_python_dash_m_app_help():
    out = subprocess.run([sys.executable, "-m", "ccdcore_app", "--help"], capture_output=True, text=True,
                         cwd=Path(ccdcore_app.__file__).parents[1], timeout=60)
    assert out.returncode == 0 and "--port" in out.stdout and "SESSION" in out.stdout.upper()


def _bayer_session(root: Path) -> Path:
    """A raw Bayer (RGGB) session: two 2-D mosaic frames whose four CFA sites differ."""
    root.mkdir(parents=True)
    rng = np.random.default_rng(5)
    entries = []
    for i in range(2):
        raw = rng.integers(0, 100, (16, 20)).astype(np.uint16)
        raw[0::2, 0::2] += 3000      # R
        raw[0::2, 1::2] += 2000      # G1 (the green on the red row)
        raw[1::2, 0::2] += 1000      # G2
        write_image(root / f"ptc/raw{i}.tif", raw, exposure=0.01, bits=12)
        entries.append(f'[[frames]]\npath = "ptc/raw{i}.tif"\nrole = "ptc"\nlevel = 1\n')
    (root / "session.toml").write_text('schema = 1\n[camera]\nname = "bayer"\nbits = 12\n'
                                       'layout = "bayer-rggb"\n\n' + "\n".join(entries))
    return root


def test_bayer_frames_offer_the_four_cfa_planes(state, tmp_path, small_session):
    from ccdcore.channels import split_channels

    page = SessionPage(state)
    assert state.load(_bayer_session(tmp_path / "bayer")), state.error
    _show(page, "ptc/raw1.tif")
    raw = state.session.read(state.session.frames[1])
    assert page.channel_select.visible
    assert list(page.channel_select.options.values()) == ["R", "G1", "G2", "B"]
    assert list(page.param.channel.objects) == ["R", "G1", "G2", "B"]
    planes = split_channels(raw, "bayer-rggb")
    for name in ("R", "G1", "G2", "B"):
        page.channel = name
        np.testing.assert_array_equal(page._plane, planes[name])
        assert f"channel {name} (10 \u00d7 8 px plane)" in page.frame_info.object
    assert page._plane.min() < 100                 # B: the site without an offset
    # a colour frame next: the colour channels and the luminance instead of the CFA planes
    state.load(small_session)
    _show(page, "scene/rgb.tif")
    assert list(page.channel_select.options) == ["R", "G", "B", "Luminance"]
    assert page.channel == "B"                     # the choice is kept where it exists
    rgb = state.session.read(state.session.frames[-1])
    np.testing.assert_array_equal(page._plane, rgb[..., 2])
    with pytest.raises(ValueError):
        page.channel = "G1"


def test_groups_say_mixed_and_unreadable(state, small_session, unreadable_session):
    from ccdcore_app.pages.session import groups_frame

    root = small_session
    write_image(root / "dark/wide.tif", np.zeros((24, 40), np.uint16), exposure=0.01, bits=12)
    with (root / "session.toml").open("a") as f:
        f.write('\n[[frames]]\npath = "dark/wide.tif"\nrole = "dark"\nexposure = 0.01\n')
    groups = groups_frame(open_session(root)).set_index("role")
    assert groups.loc["dark", "size (W×H)"] == "mixed"        # 32 × 24 and 40 × 24
    assert groups.loc["dark", "dtype"] == "uint16"
    assert groups.loc["ptc", "size (W×H)"] == "32 × 24"
    bad = groups_frame(open_session(unreadable_session)).set_index("role")
    assert bad.loc["scene", "size (W×H)"] == "unreadable"


def test_histogram_counts_read_as_plain_numbers(state, healey94):
    """The preview's histogram labels its counts 150,000, not 1.5e+5, and counts every pixel."""
    from bokeh.models import NumeralTickFormatter

    page = SessionPage(state)
    state.load(healey94)
    _run(page._on_frame())
    [axis] = page.hist_view.figure.yaxis
    assert isinstance(axis.formatter, NumeralTickFormatter) and axis.formatter.format == "0,0"
    assert page.hist_view.source.data["top"].sum() == page._plane.size



def _camera_flats(root: Path, n: int = 4) -> Path:
    """A camera's folder of flat fields named as the camera named them (no manifest)."""
    rng = np.random.default_rng(11)
    root.mkdir(parents=True)
    for i in range(n):
        frame = np.clip(rng.normal(2000.0, 20.0, (24, 32)), 0, 4095).astype(np.uint16)
        write_image(root / f"IMG_{1000 + i}.tif", frame, exposure=0.01, bits=12)
    return root


def test_a_camera_folder_opens_as_flats_from_the_page_and_from_the_command_line(state,
                                                                                 tmp_path):
    """Named as the camera named them the images read as scenes; the page's role choice (and
    create_app's role, what ``ccdcore app FOLDER --role flat`` serves) makes them flats; a
    role for a session with a manifest is an alert, and the page keeps its session."""
    root = _camera_flats(tmp_path / "card")
    page = SessionPage(state)
    page.path_input.value = str(root)
    _run(page._on_open_path())
    assert state.session.roles() == {"scene": 4}
    page.role_select.value = "flat"
    _run(page._on_open_path())
    assert state.session.roles() == {"flat": 4} and not page.error_alert.visible
    page.path_input.value = str(make_manifest_session(tmp_path / "with_manifest"))
    _run(page._on_open_path())
    assert page.error_alert.visible and "applies to a plain folder" in page.error_alert.object
    assert state.session.roles() == {"flat": 4}
    app = create_app(root, allowed_roots=[tmp_path], role="flat")
    assert app.app_state.session.roles() == {"flat": 4}
