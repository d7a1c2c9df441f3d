"""The Walkthrough page without a browser: each step's gate is ccdcore.guide's verdict on the
loaded session, steps lacking frames skip with a message, a change recomputes the later steps,
and the export writes the product and the report."""
from __future__ import annotations

from pathlib import Path

import pytest

from _coro import run as _run
from ccdcore_app.pages.walkthrough import DOWNSTREAM, WalkthroughPage
from ccdcore_app.state import AppState
from ccdcore import guide
from ccdcore.capture import plan_captures
from ccdcore.noise import photon_transfer
from ccdcore.product.make import load_product
from ccdcore.session import open_session


def _page(path: Path, roots=None) -> WalkthroughPage:
    state = AppState(allowed_roots=[path.parent, *(roots or [])])
    assert state.load(str(path))
    return WalkthroughPage(state, auto=False)


def _walk(page: WalkthroughPage) -> dict[str, str]:
    for s in guide.STEPS:
        _run(page.run_step(s.slug))
    return {k: g.status for k, g in page.gates.items()}


def test_healey94_steps_follow_the_guide(assets: Path) -> None:
    page = _page(assets / "healey94")
    status = _walk(page)
    s = open_session(assets / "healey94")
    noise = photon_transfer(s)
    d = guide.dark_step(s)
    assert status["session"] == guide.session_gate(s).status == "pass"
    assert status["dark"] == d.gate.status
    assert status["ptc"] == guide.ptc_gate(noise).status
    assert page.results.ptc.noise.A == noise.A
    assert status["pattern"] == guide.pattern_step(s, dark=d.dark, noise=noise).gate.status
    assert status["response"] == "skip"
    assert "bracket" in page.gates["response"].summary
    verified = page.results.verify                  # a VerifyResult(product, check)
    product, verification = verified.product, verified.check
    assert status["verify"] == verification.gate.status == "pass"
    assert set(product.maps) >= {"dark", "K"}
    # the plan is made from the session's bit depth
    assert page.bits == 8 and page.plan is not None
    assert page.plan.n_frames == plan_captures(8, page.gain, read_noise_e=page.read_noise_e,
                                               pixels=page.pixels,
                                               exposure_half=page.exposure_half_ms / 1e3
                                               ).n_frames
    assert page.progress.value == len(guide.STEPS)


def test_a_session_without_flats_or_brackets_skips_with_a_message(assets: Path) -> None:
    page = _page(assets / "tsin01")
    status = _walk(page)
    assert status["dark"] == status["ptc"] == status["pattern"] == "skip"
    assert status["response"] == "pass"
    hdr = page.results.response.hdr
    assert hdr.radiance.shape[:2] == open_session(assets / "tsin01").header(
        open_session(assets / "tsin01").frames[0]).shape[:2]
    assert any(r.startswith("HDR radiance") for r in page.gates["response"].reasons)
    for slug in ("dark", "ptc", "pattern"):
        assert page.gates[slug].next, slug          # each says what to capture
    assert "ptc" in page.gates["ptc"].summary
    dl = _walk(_page(assets / "delasarte07"))
    assert dl["pattern"] == "pass" and dl["ptc"] == "skip" and dl["response"] == "skip"


def test_leaving_out_a_level_recomputes_the_later_steps(assets: Path) -> None:
    page = _page(assets / "healey94")
    _walk(page)
    before = page.results.ptc.noise
    page.exclude = [3]
    assert not (set(DOWNSTREAM["ptc"]) | {"ptc"}) & set(page.gates)
    assert page.results.report is None and page.steps["export"].report_download.disabled
    assert "dark" in page.gates and "session" in page.gates      # earlier steps are kept
    _walk(page)
    after = page.results.ptc.noise
    assert after.A != before.A
    assert not next(p for p in after.points if p.level == 3).used
    ref = photon_transfer(open_session(assets / "healey94"), exclude_levels=[3])
    assert after.A == ref.A
    product = page.results.verify.product
    assert product.estimates.noise.A == pytest.approx(ref.A, rel=1e-12)


def test_plan_inputs_replan(assets: Path) -> None:
    page = _page(assets / "healey94")
    n = page.plan.n_frames
    page.exposure_half_ms = 20.0
    assert page.plan.group("Photon transfer pairs").frames[0][1]["exposure"] == pytest.approx(
        2 * plan_captures(8, page.gain, read_noise_e=page.read_noise_e
                          ).group("Photon transfer pairs").frames[0][1]["exposure"], rel=1e-3)
    page.read_noise_e = 30.0
    assert page.plan.n_frames != n
    assert page.gates["plan"].status == "pass"


def test_export_writes_the_product_and_the_report(assets: Path, tmp_path: Path) -> None:
    page = _page(assets / "healey94", roots=[tmp_path])
    _walk(page)
    export = page.steps["export"]
    assert not export.report_download.disabled
    assert export.report_bytes().getvalue().decode() == page.results.report
    listed = export.estimates_table.object            # each estimate with its rows
    made = page.results.verify.product.estimates
    assert list(listed["estimate"]) == list(made.made())
    noise = dict(zip(listed["estimate"], listed["headline"]))["noise"]
    assert all(f"{r.label} = {r.shown}" in noise for r in made.noise.rows())
    page.export_folder = str(tmp_path / "calib")
    _run(page.save())
    assert page.gates["export"].status == "pass", page.gates["export"]
    product = load_product(tmp_path / "calib")
    assert set(product.maps) >= {"dark", "K"}
    html = (tmp_path / "calib" / "report.html").read_text()
    assert html == page.results.report                # built once, saved as built
    assert "<html" in html.lower() and "photon transfer" in html.lower()
    # a folder outside the allowed roots is refused, nothing written
    page.export_folder = "/proc/not-allowed"
    _run(page.save())
    assert page.gates["export"].status == "fail"


def test_an_emva_session_shows_the_emva_figures(tmp_path: Path) -> None:
    import numpy as np

    # emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (docs/notes.md)
    np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731
    from emva1288.camera.dataset_generator import DatasetGenerator

    from ccdcore_app.pages.walkthrough import emva_table
    from ccdcore.emva.datasheet import emva_figures

    gen = DatasetGenerator(steps=20, L=4, image_format="tif", outdir=str(tmp_path / "d"),
                           width=32, height=24, bit_depth=12, seed=5)
    descriptor = Path(gen.descriptor_path)
    page = _page(descriptor)
    _run(page.run_step("ptc"))
    figures = page.results.emva
    s = open_session(descriptor)
    want = emva_figures(s, noise=photon_transfer(s)).summary()
    assert figures.K == want.K and figures.QE == want.QE
    table = emva_table(figures)
    assert list(table["figure"])[:3] == ["Quantum efficiency", "Responsivity",
                                         "Overall system gain"]
    assert "±" in table["value"][0]
    assert page.steps["ptc"].emva_holder.visible
    page.exclude = [1]                       # a new photon transfer drops the figures too
    assert page.results.emva is None


def test_dark_step_plots_a_dark_series_and_lists_few_exposures(assets: Path, tmp_path) -> None:
    """Many dark exposures (a dark-current series): a plot of the level against the exposure,
    not a long table; one exposure (healey94): the table."""
    import numpy as np

    from ccdcore.io.frames import write_image
    from ccdcore_app.pages.walkthrough import DARK_TABLE_MAX, dark_level_columns

    root = tmp_path / "series"
    times = [0.01 * (i + 1) for i in range(12)]
    for i, t in enumerate(times):
        for k in range(2):
            write_image(root / "dark" / f"d{i:02d}_{k}.fits",
                        np.full((8, 8), 100 + 50 * i + k, np.uint16), exposure=t)
    page = _page(root)
    _run(page.run_step("dark"))
    step = page.results.dark
    assert len(step.levels) == 12 > DARK_TABLE_MAX
    dark = page.steps["dark"]
    assert dark.level_plot.visible and not dark.levels_table.visible
    data = dark.level_source.data
    np.testing.assert_allclose(data["exposure"], times)
    np.testing.assert_allclose(data["mean"], [100.5 + 50 * i for i in range(12)])
    assert list(data["n"]) == [2] * 12
    assert dark.level_fig.xaxis[0].axis_label == "exposure (s)"
    assert dark.level_fig.yaxis[0].axis_label == "mean dark level (DN)"
    # the map has a title of its own: no stray "·" before "mean of 2×2 px"
    assert dark.view.title == "Dark reference D̂_D (DN)"
    # few exposures: the table, no plot
    few = _page(assets / "healey94")
    _run(few.run_step("dark"))
    few_dark = few.steps["dark"]
    assert few_dark.levels_table.visible and not few_dark.level_plot.visible
    assert list(few_dark.levels_table.object["exposure (s)"]) == ["0.033"]
    # the pure part: unknown exposures left out, sorted, a missing error drawn as none
    cols = dark_level_columns([{"exposure": 0.2, "n": 3, "mean": 5.0, "sem": 0.1},
                               {"exposure": None, "n": 1, "mean": 9.0, "sem": float("nan")},
                               {"exposure": 0.1, "n": 1, "mean": 4.0, "sem": float("nan")}])
    assert list(cols["exposure"]) == [0.1, 0.2] and list(cols["sem"]) == [0.0, 0.1]
    assert list(cols["hi"]) == [4.0, 5.1]


def test_one_step_object_per_guide_step_and_typed_results(assets: Path) -> None:
    """The page's registry follows ccdcore.guide.STEPS; the results are typed, and a change
    drops exactly the results DOWNSTREAM names."""
    from ccdcore_app.pages.walkthrough import STEP_TYPES, Results
    from ccdcore_app.pages.walkthrough.verify import VerifyResult

    page = _page(assets / "healey94")
    assert list(page.steps) == list(STEP_TYPES) == [s.slug for s in guide.STEPS]
    assert all(step.slug == slug and step.page is page for slug, step in page.steps.items())
    assert not any(name.startswith("_run_") for name in dir(page))
    _walk(page)
    assert isinstance(page.results, Results) and isinstance(page.results.verify, VerifyResult)
    assert page.results.verify.check.gate == page.gates["verify"]
    page.robust = True
    for name in DOWNSTREAM["ptc"] + ("ptc",):
        assert getattr(page.results, name) is None, name
    assert page.results.dark is not None and page.results.plan is not None
    with pytest.raises(KeyError):
        Results().drop(["nothing"])


def test_the_steps_follow_what_the_session_holds(assets: Path, tmp_path: Path) -> None:
    """A bracket is not given a lab plan: the plan step says what it allows and what is
    missing (ccdcore.guide.session_plan's words), the step list shows its steps only; flats get
    the flat field; a lab session keeps the full plan and every step."""
    page = _page(assets / "tsin01")
    cover = guide.session_plan(open_session(assets / "tsin01"))
    assert page.coverage == cover and cover.kind == "bracket"
    assert page.plan is None and not page.steps["plan"].lab.visible
    assert page.gates["plan"] == cover.gate()
    assert page.gates["plan"].reasons == cover.missing
    assert "exposure bracket" in page.steps["plan"].coverage.object
    shown = [s for s, b in page.step_buttons.items() if b.visible]
    assert shown == ["plan", "session", "response", "export"]
    assert page.progress.max == 4
    # the titles count the steps listed, not every step the Walkthrough knows
    assert page.title_panes["response"].object == "### Step 3 of 4: Response curve and HDR"
    page.go("session", +1)                        # Next skips the steps a bracket lacks
    assert page.step == "response"
    page.go("response", -1)
    assert page.step == "session"
    flats = _page(assets / "delasarte07")
    assert flats.coverage.kind == "flats" and flats.plan is None
    assert [s for s, b in flats.step_buttons.items() if b.visible] == [
        "plan", "session", "pattern", "verify", "export"]
    lab = _page(assets / "healey94")
    assert lab.coverage.kind == "lab" and lab.plan is not None
    assert lab.steps["plan"].lab.visible
    assert all(b.visible for b in lab.step_buttons.values())
    # a new session: the plan follows it
    assert lab.state.load(str(assets / "tsin01"))
    assert lab.coverage.kind == "bracket" and lab.plan is None
    assert lab.gates["plan"].summary == cover.gate().summary
    assert lab.title_panes["export"].object.startswith("### Step 4 of 4: ")


def test_the_response_step_says_the_librarys_verdict_with_its_registration(assets: Path) -> None:
    from ccdcore_app.plots.response import verdict_markdown

    page = _page(assets / "tsin01")
    _walk(page)
    res = page.results.response.response
    assert res.verdict.registration and res.verdict.moving.startswith("moving objects:")
    step = page.steps["response"]
    assert step.verdict_alert.object == verdict_markdown(res.verdict)
