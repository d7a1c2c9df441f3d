"""Pins for bugs planted in recently written modules that the rest of the suite let through.

Each expectation is independent of the code under test: a formula written out by hand, a
hand-built input, or a Monte Carlo with a fixed seed whose truth is known.  Never reads
/work/shared."""
from __future__ import annotations

import io
import math
import zipfile
from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore.dark.model import fit_dark_model
from ccdcore.records import positive_problems
from ccdcore.response.hdr_merge import HdrResult
from ccdcore.session.manifest import MAX_KEY_PARTS, MAX_NESTING, bound_problem
from ccdcore.session.temperature import match_temperature
from ccdcore_app.cache.store import entry_size_problem


# -- the dark model's errors: n − 2 degrees of freedom ------------------------------------------
def test_dark_model_errors_are_the_textbook_ols_errors_on_a_hand_built_design():
    """Two biases and two darks (t = 0, 0, 1, 1) whose residuals are ±e at both exposures:
    every frame has the same residual map, so the frames' noise model is flat and the weights
    equal; the fit is then ordinary least squares, whose residual variance is RSS/(n − 2) =
    4e²/2 = 2e², so var o = s²·Σt²/Δ = 2e²·2/4 = e² and var c = s²·n/Δ = 2e²·4/4 = 2e²
    (Δ = nΣt² − (Σt)² = 4), cov = −s²·Σt/Δ = −e²."""
    rng = np.random.default_rng(11)
    shape = (40, 30)
    o = rng.uniform(90.0, 110.0, shape)
    c = rng.uniform(0.5, 2.0, shape)
    e = rng.uniform(0.5, 3.0, shape)
    frames = [(0.0, o + e), (0.0, o - e), (1.0, o + c + e), (1.0, o + c - e)]
    m = fit_dark_model(frames)
    assert m.n == 4
    np.testing.assert_allclose(m.offset, o, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.current, c, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.offset_var, e ** 2, rtol=1e-6)
    np.testing.assert_allclose(m.current_var, 2 * e ** 2, rtol=1e-6)
    np.testing.assert_allclose(m.covariance, -e ** 2, rtol=1e-6)
    # the error of the dark at t: var o + t² var c + 2t cov = e²(1 + 2t² − 2t)
    np.testing.assert_allclose(m.error_var_at(0.5), e ** 2 * 0.5, rtol=1e-6)


def test_dark_model_noise_and_scale_recover_a_known_gaussian_noise():
    """Monte Carlo (fixed seed): six frames at 0, 0, 0, 10, 10, 10 s with Gaussian noise of
    σ² = 9 DN² at every exposure.  Each frame's temporal variance from the fit's residuals,
    corrected for its leverage h = 1/n + (t − t̄)²/Sxx = 1/6 + 25/150 = 1/3, is unbiased: the
    noise model σ²(t) = a + b·t is 9 at both exposures, and the per-pixel scale φ =
    RSS/(n − 2)/σ² averages 1 (E[RSS] = (n − 2)σ²)."""
    rng = np.random.default_rng(2024)
    shape = (160, 160)
    o = rng.uniform(95.0, 105.0, shape)
    c = rng.uniform(0.1, 0.3, shape)
    times = [0.0, 0.0, 0.0, 10.0, 10.0, 10.0]
    frames = [(t, o + c * t + rng.normal(0.0, 3.0, shape)) for t in times]
    m = fit_dark_model(frames)
    for t in (0.0, 10.0):
        assert m.noise_a + m.noise_b * t == pytest.approx(9.0, rel=0.04)
    # φ averaged over 25 600 pixels: its standard error is sqrt(2/4/25600) ≈ 0.0044
    assert float(np.mean(m.scale)) == pytest.approx(1.0, abs=0.04)
    # and the stated error of the offset is the true one (var o = σ²·Σt²/Δ = 9·300/900 = 3,
    # the variance of the mean of the three biases)
    assert float(np.mean(m.offset_var)) == pytest.approx(3.0, rel=0.05)
    assert float(np.mean((m.offset - o) ** 2)) == pytest.approx(3.0, rel=0.05)


# -- the manifest's bounds: limits included ------------------------------------------------------
def test_manifest_key_of_exactly_max_parts_is_accepted_one_more_is_refused():
    ok = ".".join(f"k{i}" for i in range(MAX_KEY_PARTS)) + " = 1\n"
    too_many = ".".join(f"k{i}" for i in range(MAX_KEY_PARTS + 1)) + " = 1\n"
    assert ok.count(".") == MAX_KEY_PARTS - 1
    assert bound_problem(ok) is None
    assert bound_problem(too_many) is not None
    # a table name counts the same way
    assert bound_problem("[" + ok.split(" =")[0] + "]\n") is None
    assert bound_problem("[" + too_many.split(" =")[0] + "]\n") is not None


def test_manifest_nesting_of_exactly_max_levels_is_accepted_one_more_is_refused():
    ok = "a = " + "[" * MAX_NESTING + "1" + "]" * MAX_NESTING + "\n"
    too_deep = "a = " + "[" * (MAX_NESTING + 1) + "1" + "]" * (MAX_NESTING + 1) + "\n"
    assert bound_problem(ok) is None
    assert bound_problem(too_deep) is not None


# -- temperature matching: the tolerance included -------------------------------------------------
def test_a_frame_exactly_at_the_tolerance_matches():
    recs = [SimpleNamespace(name=n, temperature=t)
            for n, t in (("at", -4.0), ("below", -6.0), ("off", -3.5), ("same", -5.0))]
    matched, other = match_temperature(recs, -5.0, 1.0)
    assert [r.name for r in matched] == ["at", "below", "same"]
    assert [r.name for r in other] == ["off"]


# -- positive_problems: an error of zero is allowed -----------------------------------------------
def test_a_standard_error_of_zero_is_not_a_problem():
    rec = SimpleNamespace(K=0.5, K_err=0.0, A_err=0.0)
    assert positive_problems(rec, ("K",), ("K_err", "A_err")) == []
    bad = SimpleNamespace(K=0.5, K_err=-1e-9)
    assert [k for k, _ in positive_problems(bad, ("K",), ("K_err",))] == ["K_err"]


# -- the cache: any compressed member is refused ----------------------------------------------------
def _deflated_of_equal_size() -> bytes:
    """A zip whose one member is deflated yet its compressed size equals its size (random
    bytes, which deflate does not shrink, padded with zeros until the sizes meet)."""
    rng = np.random.default_rng(5)
    head = rng.integers(0, 256, 2000, dtype=np.uint8).tobytes()
    for k in range(0, 400):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("extra.bin", head + b"\0" * k)
        info = zipfile.ZipFile(io.BytesIO(buf.getvalue())).infolist()[0]
        if info.compress_size == info.file_size:
            return buf.getvalue()
    raise AssertionError("no padding made the sizes equal")


def test_a_deflated_member_is_refused_even_when_its_sizes_agree(tmp_path):
    data = _deflated_of_equal_size()
    info = zipfile.ZipFile(io.BytesIO(data)).infolist()[0]
    assert info.compress_type == zipfile.ZIP_DEFLATED
    assert info.compress_size == info.file_size
    path = tmp_path / "entry.npz"
    path.write_bytes(data)
    problem = entry_size_problem(path)
    assert problem is not None and "compressed" in problem


# -- the HDR merge's flag counts --------------------------------------------------------------------
def test_flag_counts_name_each_flag_by_its_value():
    # 0 merged, 1 dark (upper bound), 2 saturated (lower bound), 3 bloomed
    flags = np.array([[0, 1, 1, 1], [2, 3, 3, 0], [0, 0, 0, 1]], np.uint8)
    shape = flags.shape
    res = HdrResult(radiance=np.ones(shape), sigma=np.full(shape, 0.1), flags=flags,
                    used=np.ones(shape, np.int16), channels=("Y",), layout="mono")
    assert res.flag_counts() == {"merged": 5, "dark": 4, "saturated": 1, "bloomed": 2, "moving": 0}
    text = " ".join(res.describe())
    assert "5 merged" in text and "4 dark in every image" in text
    assert "1 saturated in every image" in text and "2 merged from codes" in text
    assert math.isclose(5 / 12 * 100, 41.666666, rel_tol=1e-6) and "41.7 %" in text
