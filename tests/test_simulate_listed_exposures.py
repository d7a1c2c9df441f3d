"""The tsin01 option ``listed_step_factors``: a bracket whose listed exposures are wrong for part of
it (real Nikon brackets listed one stop apart have four neighbouring pairs whose images fit a
ratio of about 1 -- the shutter did not change), and the bundle ``camera="real-listed-wrong"``.

The manifest lists the nominal times; frame k is exposed c_k t_k with c_0 = 1 and
c_(k+1) = c_k f_k, f_k the factor of pair k (frames k, k+1) of the true against the listed ratio.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.simulate import camera, load_truth, tsin
from ccdcore.simulate import simulate as simulate_preset
NEW_KEYS = {"listed_step_factors", "listed_step_cumulative", "true_exposure", "listed_steps"}


def _sig(x: float, digits: int = 12) -> float:
    """``x`` to ``digits`` significant digits (truth.json's floats carry 12)."""
    return float(f"{x:.{digits}g}")


def _rounded(obj, digits: int):
    """Every float of a parsed JSON value to ``digits`` significant digits."""
    if isinstance(obj, dict):
        return {k: _rounded(v, digits) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_rounded(v, digits) for v in obj]
    return _sig(obj, digits) if isinstance(obj, float) else obj


def _digest(root: Path) -> str:
    """sha256 over the manifest's bytes, the frames' pixels and truth.json (its floats rounded to
    9 digits: the 12th may move by one unit between CPUs, tests/test_assets.py); the float maps
    (truth/*.exr) do not depend on the exposures: only their names count (their values may
    differ by an ulp between CPUs)."""
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if not p.is_file():
            continue
        h.update(p.relative_to(root).as_posix().encode())
        if p.suffix == ".exr":
            continue
        if p.suffix == ".json":
            text = json.dumps(_rounded(json.loads(p.read_text()), 9), sort_keys=True)
            h.update(text.encode())
        elif p.suffix == ".toml":
            h.update(p.read_bytes())
        else:
            z = read_image(p)
            h.update(str(z.shape).encode())
            h.update(np.ascontiguousarray(z).tobytes())
    return h.hexdigest()


def _all_bytes(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


# digests of sessions written before listed_step_factors existed (same function, same options)
PINNED = {
    "protocol": (dict(seed=7, size=(32, 24)),
                 "bf428c8f31a29f1f831fdf01d3baf11f1c20e535e1d98011eac4e208b5f2477f"),
    "protocol-wb-bayer": (dict(seed=12, size=(16, 12), bayer="grbg", blooming=True,
                               white_balance=True),
                          "e5f7718053826658922e828bb322b46bc0bf330ca7e098985a7c4b2576bb41df"),
    "real": (dict(seed=3, size=(48, 32), camera="real"),
             "fb30f454bac3eff28ba8c0e1e3b94aeceac1c76f2b1037efdd4222ddffc491da"),
}


# ---------------------------------------------------------------------------------------------
# off by default: every existing session unchanged


@pytest.mark.parametrize("name", list(PINNED))
def test_default_sessions_are_unchanged(tmp_path, name):
    kw, digest = PINNED[name]
    truth = simulate_preset("tsin01", tmp_path / "a", **kw)
    assert _digest(tmp_path / "a") == digest
    assert not NEW_KEYS & set(truth)
    assert all("true_exposure" not in f for f in truth["frames"])
    if "camera_model" in truth:
        assert "listed_step_factors" not in truth["camera_model"]["options"]
    # the option at its default, given explicitly (None, or no pair named): the same bytes
    simulate_preset("tsin01", tmp_path / "b", listed_step_factors=None, **kw)
    simulate_preset("tsin01", tmp_path / "c", listed_step_factors={}, **kw)
    assert _all_bytes(tmp_path / "a") == _all_bytes(tmp_path / "b") == _all_bytes(tmp_path / "c")


# ---------------------------------------------------------------------------------------------
# the truth follows the factors exactly

# pairs 2, 3 and 5 of an 8-frame bracket (7 pairs), each with its own factor: shifting the pair
# index, or applying a factor to its own frame only (not to all later ones), changes c
STEPS = {2: 0.5, 3: 0.25, 5: 1.5}
EXPECTED_C = [1.0, 1.0, 1.0, 0.5, 0.125, 0.125, 0.1875, 0.1875]      # c_(k+1) = c_k f_k
NOISE_FREE = dict(sigma_s=0.0, sigma_c1=0.0, sigma_c2=0.0)
BRACKET = dict(n_exposures=8, ratio=2.0, t_max=1.0)


def test_listed_steps_cumulates_from_the_first_frame():
    pairs, c = camera.listed_steps(8, STEPS)
    assert pairs == [1.0, 1.0, 0.5, 0.25, 1.0, 1.5, 1.0]
    assert c == EXPECTED_C
    # JSON's string keys and a full sequence mean the same
    assert camera.listed_steps(8, {"2": 0.5, "3": 0.25, "5": 1.5}) == (pairs, c)
    assert camera.listed_steps(8, pairs) == (pairs, c)
    # general factors: the product in order, rounded to 12 digits
    _, c2 = camera.listed_steps(4, {0: 0.9, 2: 0.7})
    assert c2 == [1.0, 0.9, 0.9, _sig(0.9 * 0.7)]


def test_true_exposures_follow_the_factors_exactly(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=5, size=(32, 24), listed_step_factors=STEPS,
                            **BRACKET, **NOISE_FREE)
    manifest = tomllib.loads((tmp_path / "session.toml").read_text())
    listed = np.array([f["exposure"] for f in manifest["frames"]])
    t = np.array(truth["t"])
    # the manifest keeps the listed (nominal) times: one stop apart, exactly
    np.testing.assert_array_equal(listed, t)
    assert np.all(listed[1:] / listed[:-1] == 2.0) and listed[-1] == 1.0
    assert truth["listed_step_factors"] == [1.0, 1.0, 0.5, 0.25, 1.0, 1.5, 1.0]
    assert truth["listed_step_cumulative"] == EXPECTED_C
    true = t * np.array(EXPECTED_C)                      # powers of two times 1 or 1.5: exact
    assert truth["true_exposure"] == [true.tolist()]
    assert truth["exposure_factor"] == [EXPECTED_C]
    assert truth["a"] == [true.tolist()]                 # mono, no white balance: a_k = true t_k
    for k, f in enumerate(truth["frames"]):
        assert f["exposure"] == t[k] and f["true_exposure"] == true[k] and f["a"] == true[k]
        assert f["exposure_factor"] == EXPECTED_C[k]
    # the true ratio of pair p is its listed ratio times f_p; frames before pair 2 as listed
    np.testing.assert_array_equal(true[1:] / true[:-1],
                                  2.0 * np.array(truth["listed_step_factors"]))
    np.testing.assert_array_equal(true[:3], t[:3])
    # recorded as an option of the camera model (JSON keys are strings)
    assert truth["camera_model"]["options"]["listed_step_factors"] == {"2": 0.5, "3": 0.25,
                                                                        "5": 1.5}
    assert "pair(s) 2 (x0.5), 3 (x0.25), 5 (x1.5)" in (tmp_path / "session.toml").read_text()
    # the images were formed with the true exposures (noise free: exactly)
    E = load_truth(tmp_path).map("E").astype(float)
    for k, f in enumerate(truth["frames"]):
        z = read_image(tmp_path / f["path"])
        expected = np.rint(tsin.response(np.minimum(true[k] * E, 1.0))).astype(np.uint8)
        assert np.array_equal(z, expected)
        if EXPECTED_C[k] != 1.0:                          # and visibly not with the listed ones
            listed_z = np.rint(tsin.response(np.minimum(t[k] * E, 1.0)))
            assert np.count_nonzero(z != listed_z) > 0.5 * z.size


def test_factors_multiply_the_exposure_errors_and_white_balance(tmp_path):
    """With lognormal exposure errors and white balance the errors are drawn as before (same
    stream): the exposure factor is c_k times the error, a_k = t_k w_kc x that factor."""
    kw = dict(seed=8, size=(16, 16), layout="rgb", white_balance=True, wb_sigma=0.03,
              offset_sigma=0.0, exposure_error=0.03, n_stacks=2, **BRACKET)
    plain = simulate_preset("tsin01", tmp_path / "plain", **kw)
    wrong = simulate_preset("tsin01", tmp_path / "wrong", listed_step_factors=STEPS, **kw)
    eps0, eps1 = np.array(plain["exposure_factor"]), np.array(wrong["exposure_factor"])
    np.testing.assert_allclose(eps1, eps0 * np.array(EXPECTED_C), rtol=1e-11, atol=0)
    t = np.array(wrong["t"])
    np.testing.assert_allclose(wrong["true_exposure"], t * eps1, rtol=1e-11, atol=0)
    a0, a1 = np.array(plain["a"]), np.array(wrong["a"])          # (stacks, frames, channels)
    np.testing.assert_allclose(a1, a0 * np.array(EXPECTED_C)[None, :, None], rtol=1e-11, atol=0)
    per_frame = [f["true_exposure"] for f in wrong["frames"]]
    assert per_frame == np.ravel(wrong["true_exposure"]).tolist()


@pytest.mark.parametrize("steps", [
    {7: 0.5}, {-1: 0.5}, {2: 0.0}, {2: -0.5}, {2: math.nan}, {2: math.inf}, {"two": 0.5},
    {2.0: 0.5}, {2: True}, [0.5, 0.5], 0.5,
])
def test_bad_listed_step_factors_raise(tmp_path, steps):
    with pytest.raises(CcdError):
        simulate_preset("tsin01", tmp_path, seed=0, size=(16, 16), listed_step_factors=steps,
                        **BRACKET)


# ---------------------------------------------------------------------------------------------
# the bundle: a camera-like bracket whose listed exposures are wrong for part of it

SIZE = (96, 64)
WRONG = [4, 5, 6, 7]


@pytest.fixture(scope="module")
def listed_wrong(tmp_path_factory):
    root = tmp_path_factory.mktemp("listed_wrong")
    start = time.perf_counter()
    truth = simulate_preset("tsin01", root, seed=3, size=SIZE, camera="real-listed-wrong")
    elapsed = time.perf_counter() - start
    frames = [read_image(root / f["path"]) for f in truth["frames"]]
    return root, truth, frames, elapsed


def test_bundle_is_the_real_camera_with_four_wrong_pairs(listed_wrong):
    root, truth, frames, elapsed = listed_wrong
    assert elapsed < 2.0                                          # measured about 0.1 s
    bundle, real = camera.CAMERAS["real-listed-wrong"], camera.CAMERAS["real"]
    assert {**real, "n_exposures": 12, "t_max": 16.0,
            "listed_step_factors": {4: 0.5, 5: 0.5, 6: 0.5, 7: 0.5}} == bundle
    manifest = tomllib.loads((root / "session.toml").read_text())
    listed = np.array([f["exposure"] for f in manifest["frames"]])
    assert listed.size == 12 and np.all(listed[1:] / listed[:-1] == 2.0)   # listed one stop apart
    pairs = truth["listed_step_factors"]
    assert [p for p, f in enumerate(pairs) if f != 1.0] == WRONG
    assert all(pairs[p] == 0.5 for p in WRONG)
    assert len(pairs) - len(WRONG) > len(pairs) / 2                       # most pairs are right
    assert truth["listed_step_cumulative"] == [1.0] * 5 + [0.5, 0.25, 0.125] + [0.0625] * 4
    # the true bracket ends where the "real" camera's does (a = 1), within its exposure errors
    true = np.array(truth["true_exposure"][0])
    assert 0.9 < true[-1] < 1.1 and 0.9 < true[8] / true[4] < 1.1


def test_wrong_pairs_show_in_the_images(listed_wrong):
    """Median code of frames k and k+1 over the pixels readable in both (codes 10..245, every
    channel): nearly equal for a pair truly at ratio 1, well apart for one at ratio 2.  At the
    median codes (20-60, in the tone curve's power-law part, d z / d ln a ~ 20 DN) a ratio of 2
    moves the median by ~14 DN; the exposure errors and white balance (3 % each per frame, so
    under 10 % on a pair's ratio at 2 sigma) by ~2 DN.  Measured: wrong pairs |diff| <= 2 DN,
    right pairs >= 10 DN (seeds 0-9, 11)."""
    _, truth, frames, _ = listed_wrong
    for p in range(len(frames) - 1):
        a, b = frames[p].astype(float), frames[p + 1].astype(float)
        ok = (a >= 10) & (a <= 245) & (b >= 10) & (b <= 245)
        assert ok.sum() > 1000, p
        diff = np.median(b[ok]) - np.median(a[ok])
        if p in WRONG:
            assert abs(diff) <= 4, (p, diff)
        else:
            assert diff >= 8, (p, diff)


def test_truth_a_matches_the_images(listed_wrong):
    """Per frame, ``a`` estimated from the green channel as sum(g(z) - b) / sum(E_effective)
    over the pixels whose noise-free code lies in 30..200 (selected on the truth, not on the
    noisy code, so without selection bias) agrees with the truth's ``a`` within 8 % (measured
    within 4.5 % over seeds 0-9: demosaicing, sharpening and JPEG near edges and lights), while
    the listed times are 2 ... 16 times off from frame 5 on.  At this seed every frame has at
    least 200 such pixels (the darkest frame of some seeds has fewer, mostly glow and edges, and
    is off by more: 16 % at 68 pixels)."""
    root, truth, frames, _ = listed_wrong
    Ee = load_truth(root).map(truth["radiance_map"]).astype(float)[..., 1]
    tone = camera.make_tone("srgb-knee")
    g = np.array(truth["g"])
    est = []
    for f, z in zip(truth["frames"], frames):
        a, b = f["a"][1], f["b"][1]
        mu = tone.f(a * Ee + b)
        ok = (mu > 30) & (mu < 200)
        assert ok.sum() >= 200
        est.append((g[z[..., 1][ok].astype(int)] - b).sum() / Ee[ok].sum())
    est = np.array(est)
    a = np.array([f["a"][1] for f in truth["frames"]])
    listed = np.array(truth["t"])
    assert np.all(np.abs(est / a - 1) < 0.08), est / a
    c = np.array(truth["listed_step_cumulative"])
    # the images know the true steps: est / listed = c_k x (3 % exposure error, 3 % white
    # balance, the 8 % above)
    np.testing.assert_allclose(est / listed, c, rtol=0.2)
    assert np.all(est[5:] / listed[5:] < 0.6)


def test_bundle_is_deterministic_and_reachable_from_the_camera_preset(tmp_path):
    kw = dict(seed=4, size=(48, 32))
    simulate_preset("tsin01", tmp_path / "a", camera="real-listed-wrong", **kw)
    simulate_preset("tsin01-camera", tmp_path / "b", camera="real-listed-wrong", **kw)
    # the same bracket, spelled out with the factors as JSON keys
    spelled = {**camera.CAMERAS["real"], "n_exposures": 12, "t_max": 16.0,
               "listed_step_factors": {"4": 0.5, "5": 0.5, "6": 0.5, "7": 0.5}}
    t_c = simulate_preset("tsin01", tmp_path / "c", **spelled, **kw)
    a, b, c = (_all_bytes(tmp_path / x) for x in "abc")
    assert a == b
    assert a.keys() == c.keys()
    assert {k: v for k, v in a.items() if k != "truth.json" and k != "session.toml"} == \
        {k: v for k, v in c.items() if k != "truth.json" and k != "session.toml"}
    assert t_c["listed_step_factors"] == json.loads(a["truth.json"])["listed_step_factors"]
