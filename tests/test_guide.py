"""Tests of ccdcore.guide: the walkthrough's gates on the demos and on sessions built to fail."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ccdcore import guide
from ccdcore.io.frames import write_image
from ccdcore.noise import photon_transfer
from ccdcore.product.make import CalibrationProduct, calibrate
from ccdcore.session import open_session

ASSETS = Path(__file__).resolve().parents[1] / "assets"


@pytest.fixture(scope="module")
def h94():
    s = open_session(ASSETS / "healey94")
    return s, photon_transfer(s), calibrate(s)


def _session(tmp: Path, frames: list[tuple[str, dict, np.ndarray]], bits: int = 12) -> Path:
    lines = ["schema = 1", "[camera]", f"bits = {bits}", 'layout = "mono"', ""]
    for rel, keys, data in frames:
        write_image(tmp / rel, data)
        lines += ["[[frames]]", f'path = "{rel}"'] + [
            f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in keys.items()]
        lines.append("")
    (tmp / "session.toml").write_text("\n".join(lines))
    return tmp


def test_steps_have_unique_slugs_in_order() -> None:
    assert [s.slug for s in guide.STEPS] == ["plan", "session", "dark", "ptc", "pattern",
                                             "response", "verify", "export"]


def test_session_gate_lists_each_problem_with_its_fix(tmp_path: Path, h94) -> None:
    assert guide.session_gate(h94[0]).status == "pass"
    rng = np.random.default_rng(0)
    _session(tmp_path, [(f"d{i}.tif", {"role": "dark"}, rng.integers(0, 50, (8, 8)).astype(
        np.uint16)) for i in range(2)])
    text = (tmp_path / "session.toml").read_text() + '[[frames]]\npath = "gone.tif"\nrole = "dark"\n'
    (tmp_path / "session.toml").write_text(text)
    gate = guide.session_gate(open_session(tmp_path))
    assert gate.status == "fail"
    assert any("gone.tif" in r and guide.FIXES["file-not-found"] in r for r in gate.reasons)


def test_dark_step_recovers_the_dark_current_and_flags_clipping(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    frames = []
    for t in (0.1, 0.2, 0.4, 0.8):
        for i in range(16 if t == 0.4 else 4):
            frames.append((f"d_{t}_{i}.tif", {"role": "dark", "exposure": t},
                           rng.normal(100 + 40 * t, 3.0, (32, 32)).round().astype(np.uint16)))
    step = guide.dark_step(open_session(_session(tmp_path / "a", frames)))
    # levels of 4 or 16 frames × 1024 pixels: each mean to ±3/64 DN or better, the slope to
    # about ±0.07 DN/s
    assert step.drift == pytest.approx(40.0, abs=0.3)
    assert [lv["n"] for lv in step.levels] == [4, 4, 16, 4]
    assert step.dark.s == 16 and step.dark.exposure == 0.4   # the exposure with most frames
    assert step.gate.status == "pass"
    clipped = [(f"z{i}.tif", {"role": "dark", "exposure": 0.1},
                np.clip(rng.normal(0.5, 1.0, (32, 32)), 0, None).round().astype(np.uint16))
               for i in range(16)]
    gate = guide.dark_step(open_session(_session(tmp_path / "b", clipped))).gate
    assert gate.status == "warn" and any("offset" in n for n in gate.next)


def test_dark_step_skips_without_darks() -> None:
    gate = guide.dark_step(open_session(ASSETS / "tsin01")).gate
    assert gate.status == "skip" and gate.next


def test_ptc_gate_judges_the_deviation_and_names_the_worst_level(h94) -> None:
    """On the demo the points agree with the line (Q > 0.01): pass. With Q forced down the
    same points (within ±1 % of the line) still pass, χ² shown; a level 20 % below the line
    (as a clipped one) fails and is named."""
    _, noise, _ = h94
    assert noise.Q > 0.01 and guide.ptc_gate(noise).status == "pass"
    resolved = guide.ptc_gate(replace(noise, Q=1e-5, chi2=3.0 * noise.dof))
    assert resolved.status == "pass" and "χ² resolves" in resolved.summary
    assert any(f"χ² = {3.0 * noise.dof:.3g}" in r for r in resolved.reasons)
    used = [p for p in noise.points if p.used]
    low = used[-1]
    points = tuple(replace(p, var=0.8 * p.var) if p is low else p for p in noise.points)
    gate = guide.ptc_gate(replace(noise, points=points, Q=1e-9))
    assert gate.status == "fail" and f"exclude level {low.level} " in gate.next[0]
    assert "beyond ±10 %" in gate.summary


def test_session_plan_follows_the_frames(tmp_path: Path) -> None:
    """A lab session gets every step and the lab plan; a bracket the response step, flats the
    flat field, scenes nothing -- each with what is missing, in words."""
    every = tuple(s.slug for s in guide.STEPS)
    none = guide.session_plan(None)
    assert none.kind == "none" and none.steps == every and none.lab_plan
    lab = guide.session_plan(open_session(ASSETS / "healey94"))
    assert lab.kind == "lab" and lab.steps == every and lab.lab_plan
    assert lab.missing == (guide.MISSING["bracket"],)
    bracket = guide.session_plan(open_session(ASSETS / "tsin01"))
    assert bracket.kind == "bracket" and not bracket.lab_plan
    assert bracket.steps == ("plan", "session", "response", "export")
    assert "bracket of a scene" in bracket.missing[0] and "gain" in bracket.missing[0]
    gate = bracket.gate()
    assert gate.status == "pass" and "Response curve and HDR" in gate.summary
    flats = guide.session_plan(open_session(ASSETS / "delasarte07"))     # rgb: no D̂_D step
    assert flats.kind == "flats" and flats.steps == ("plan", "session", "pattern", "verify",
                                                     "export")
    assert flats.missing == (guide.MISSING["ptc"],)
    img = np.full((16, 16), 100, np.uint16)
    _session(tmp_path / "flat1", [(f"f{i}.tif", {"role": "flat", "exposure": 0.1}, img)
                                  for i in range(3)])
    one = guide.session_plan(open_session(tmp_path / "flat1"))
    assert one.kind == "flats" and one.steps == ("plan", "session", "pattern", "verify",
                                                 "export")
    assert any("zero dark" in m for m in one.missing)
    assert any("second exposure" in m for m in one.missing)
    _session(tmp_path / "scenes", [(f"s{i}.tif", {"role": "scene"}, img) for i in range(2)])
    scenes = guide.session_plan(open_session(tmp_path / "scenes"))
    assert scenes.kind == "scenes" and scenes.steps == ("plan", "session")
    assert scenes.gate().status == "warn" and "read as scenes" in scenes.missing[0]


def test_pattern_step_on_the_demos(h94) -> None:
    s, noise, _ = h94
    d = guide.dark_step(s)
    step = guide.pattern_step(s, dark=d.dark, noise=noise)
    # the demo has 12 configurations of 4 frames: fewer than sec. V-B asks for
    assert step.gate.status == "warn" and step.plan_warnings
    assert step.fixed_pattern.n1 == 12 and step.correction_check is not None
    dl = open_session(ASSETS / "delasarte07")
    step = guide.pattern_step(dl)
    assert step.gate.status == "pass" and step.snup_rows
    assert all(r["after"] < r["before"] for r in step.snup_rows)
    assert {r["frame"] for r in step.snup_rows}.isdisjoint(
        {r.relpath for r in dl.flat_groups()[step.flat.base_key]})
    assert guide.pattern_step(open_session(ASSETS / "tsin01")).gate.status == "skip"


def test_verify_measures_held_out_frames(h94) -> None:
    s, noise, product = h94
    v = guide.verify(s, product, noise=noise)
    assert v.gate.status == "pass" and v.rows
    used = {r.relpath for r in s.dark_frames()} | {r.relpath for r in s.by_role("fixed_pattern")}
    assert all(r.frame not in used for r in v.rows)
    # one row recomputed by hand: the raw frame less the mean dark level, the corrected frame
    r = v.rows[0]
    rec = next(x for x in s.frames if x.relpath == r.frame)
    raw = s.read(rec).astype(np.float64)
    before = raw - float(np.mean(product.maps["dark"]))
    after = product.correct(s.read(rec)).astype(np.float64)
    assert r.before == pytest.approx(100 * before.std() / before.mean(), rel=1e-9)
    assert r.after == pytest.approx(100 * after.std() / after.mean(), rel=1e-9)
    mu = before.mean() + float(np.mean(product.maps["dark"])) - noise.black_level_dn
    floor = 100 * math.sqrt(noise.A * mu + noise.sigma_c2) / before.mean() * math.sqrt(1 - 1 / 81)
    assert r.floor == pytest.approx(floor, rel=1e-9)
    assert all(x.local_after < x.local_before for x in v.rows)


def test_verify_fails_a_wrong_product(h94) -> None:
    s, noise, product = h94
    rng = np.random.default_rng(2)
    maps = dict(product.maps)
    maps["K"] = (1.0 + 0.02 * rng.standard_normal(maps["K"].shape)).astype(np.float32)
    wrong = CalibrationProduct(maps=maps, estimates=product.estimates, camera=product.camera)
    assert guide.verify(s, wrong, noise=noise).gate.status == "fail"


def test_verify_skips_a_session_without_uniform_frames() -> None:
    s = open_session(ASSETS / "tsin01")
    empty = CalibrationProduct(maps={"dark": np.zeros((2, 2), np.float32)})
    assert guide.verify(s, empty).gate.status == "skip"


def test_response_gate_reports_the_hdr_merge() -> None:
    from ccdcore.response.brackets import bracket_records
    from ccdcore.response.hdr import FLAG_OK, merge
    from ccdcore.response.bracket_fit import session_response

    s = open_session(ASSETS / "tsin01")
    res = session_response(s)
    hdr = merge([s.read(r) for r in bracket_records(s)], res.models(), layout=s.camera.layout,
                bloom_radius=res.bloom_radius)
    gate = guide.response_gate(res, hdr)
    assert gate.status == "pass"
    ok = (hdr.flags == FLAG_OK) & (hdr.radiance > 0)
    med = 100 * float(np.median(hdr.sigma[ok] / hdr.radiance[ok]))
    line = next(r for r in gate.reasons if r.startswith("HDR radiance"))
    assert f"{int(ok.sum()):,} of {ok.size:,} values merged" in line
    assert f"{med:.3g} %" in line
    assert not any(r.startswith("HDR") for r in guide.response_gate(res).reasons)


def test_a_change_session_is_frames_to_compare_not_an_empty_one(tmp_path):
    """Reference and target frames (a lobby's): the Walkthrough says they are frames to
    compare on the Change detection page, not that the session holds no frames."""
    from ccdcore.guide import session_plan
    from ccdcore.session import open_session
    from ccdcore.simulate.change_frames import write_frame_pair

    write_frame_pair(tmp_path / "pair", 0, n_reference=3)
    plan = session_plan(open_session(tmp_path / "pair"))
    assert plan.kind == "change" and not plan.lab_plan
    assert plan.summary.startswith("frames to compare (3 reference, 1 target)")
    assert "Change detection page" in plan.summary
    assert plan.steps == ("plan", "session")
