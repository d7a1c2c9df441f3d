"""Every gate of ccdcore.guide on both sides of its threshold.

tests/test_guide.py runs the gates on the demos and on sessions far from their limits; here each
gate reads inputs built to sit just below and just above (or exactly at) the limit its
docstring states (the module docstring's "Gate rules"):

* session: an error fails, warnings warn, none passes;
* dark: more than 0.5 % hot + dead pixels (of the map's pixels) warns; more than 1 % of the dark
  frames' values at exactly zero warns; fewer than 16 dark frames warns;
* photon transfer: a deviation of the points from the line that chi2 resolves (Q < 0.01) passes
  within +-3 %, warns within +-10 %, fails beyond, on either side; Q >= 0.01 passes; the
  linearity error of the means (datasheet LE in %, or from photon counts) passes within +-1 %,
  warns within +-3 %, fails beyond; sigma(A)/A times sqrt(chi2/dof) (when above 1) above 5 %
  warns; fewer than 3 levels used fails;
* pattern: a held-out flat less uniform after the correction fails;
* response: a channel that did not converge warns;
* verify: frames with more than 1 % of pixels at full scale, or a mean below 10 % of full scale,
  are left out; the measure the correction is made to lower (SNUP for a flat field, the
  pixel-scale nonuniformity for K̂) must not grow (fail); the pixel-scale nonuniformity above
  1.5x the noise floor 100 sigma_N(mu)/mu sqrt(1 - 1/w^2) (mu with the black level removed)
  warns.

The inputs are stand-ins (SimpleNamespace) carrying exactly the attributes each gate reads.
"""
from __future__ import annotations

import math
from types import SimpleNamespace as NS

import numpy as np
import pytest
from scipy.ndimage import uniform_filter
from scipy.optimize import brentq

from ccdcore import guide


# ------------------------------------------------------------------------------ session -----
def _problem(code: str, severity: str):
    class P:
        def __str__(self):
            return f"{code} problem"
    p = P()
    p.code, p.severity = code, severity
    return p


@pytest.mark.parametrize("errors, warnings, status", [(0, 0, "pass"), (0, 1, "warn"),
                                                      (1, 0, "fail"), (1, 1, "fail")])
def test_session_gate(errors, warnings, status):
    errs = [_problem("file-not-found", "error") for _ in range(errors)]
    warns = [_problem("deprecated-note", "warning") for _ in range(warnings)]
    s = NS(problems=errs + warns, errors=errs, warnings=warns, frames=[1, 2], label="s",
           roles=lambda: {"dark": 2})
    gate = guide.session_gate(s)
    assert gate.status == status
    assert len(gate.reasons) == errors + warnings


# --------------------------------------------------------------------------------- dark -----
def _dark_session(zeros: int):
    """Two 50 x 100 dark frames (10,000 values) of level 100 with ``zeros`` values at 0."""
    frames = []
    left = zeros
    for _ in range(2):
        f = np.full((50, 100), 100, np.uint16)
        k = min(left, f.size)
        f.ravel()[:k] = 0
        left -= k
        frames.append(f)
    recs = [NS(exposure=0.1, relpath=f"d{i}.tif") for i in range(2)]
    return NS(dark_frames=lambda: recs, camera=NS(layout="mono"),
              iter_frames=lambda rr: list(zip(rr, frames)))


def _dark(flagged: int, s: int = 16, n: int = 20_000):
    """A dark reference of ``n`` pixels with ``flagged`` of them hot or dead (split between the
    two masks, so that the gate must add them)."""
    hot = np.zeros(n, bool)
    dead = np.zeros(n, bool)
    hot[:flagged // 2] = True
    dead[n - (flagged - flagged // 2):n] = True
    return NS(mean_map=np.zeros((100, n // 100)), hot_mask=hot.reshape(100, -1),
              dead_mask=dead.reshape(100, -1), s=s, mean=100.0, spatial_std=1.0)


@pytest.mark.parametrize("flagged, status", [(0, "pass"), (1, "pass"), (100, "pass"),
                                             (101, "warn")])
def test_dark_hot_dead_fraction(flagged, status):
    """0.5 % of 20,000 pixels is 100: 100 flagged passes, 101 warns (a fraction of the map's
    pixels, not a count: one flagged pixel passes)."""
    step = guide.dark_step(_dark_session(0), dark=_dark(flagged))
    assert step.gate.status == status
    assert any(f"{flagged // 2} hot and {flagged - flagged // 2} dead" in r
               for r in step.gate.reasons)
    assert any("flagged" in r for r in step.gate.reasons) == (status == "warn")


@pytest.mark.parametrize("zeros, status", [(0, "pass"), (100, "pass"), (101, "warn")])
def test_dark_zero_fraction(zeros, status):
    """1 % of the frames' 10,000 values is 100: 100 zeros pass, 101 warn."""
    gate = guide.dark_step(_dark_session(zeros), dark=_dark(0)).gate
    assert gate.status == status
    assert any("offset" in n for n in gate.next) == (status == "warn")


@pytest.mark.parametrize("s, status", [(15, "warn"), (16, "pass")])
def test_dark_frame_count(s, status):
    assert guide.dark_step(_dark_session(0), dark=_dark(0, s=s)).gate.status == status


# ---------------------------------------------------------------------- photon transfer -----
def _ptc(Q: float = 1e-6, dev: float = 0.0, used: int = 6, A_rel_err: float = 0.01,
         dof: int | None = None, chi2_dof: float = 1.0, photons: bool = False):
    """A photon-transfer result on the line var = 0.01 mu + 2, every point on it but the last
    used one, whose variance deviates from the line by the fraction ``dev`` (the worst level);
    with ``photons`` each level carries mu / 0.5 photons (an EMVA 1288 set, means linear)."""
    pts = []
    for i in range(8):
        mu = 100.0 * (i + 1)
        line = 0.01 * mu + 2.0
        var = line * (1.0 + dev) if i == used - 1 else line
        pts.append(NS(level=i + 1, mu=mu, var=var, var_err=0.001 * line, used=i < used,
                      clipped_fraction=0.0, photons=2.0 * mu if photons else None))
    dof = used - 2 if dof is None else dof
    return NS(points=pts, Q=Q, dof=dof, A=0.01, A_err=0.01 * A_rel_err, sigma_c2=2.0,
              sigma_c2_err=0.1, chi2=chi2_dof * max(dof, 1), fit_fraction=None,
              fit_range="every level below saturation")


PASS, FAIL = guide.PTC_DEVIATION_PASS, guide.PTC_DEVIATION_FAIL


@pytest.mark.parametrize("dev, status", [
    (0.0, "pass"), (0.999 * PASS, "pass"), (-0.999 * PASS, "pass"),
    (1.001 * PASS, "warn"), (-1.001 * PASS, "warn"), (0.999 * FAIL, "warn"),
    (-0.999 * FAIL, "warn"), (1.001 * FAIL, "fail"), (-1.001 * FAIL, "fail"), (-0.3, "fail")])
def test_ptc_gate_deviation_tolerance(dev, status):
    """A deviation χ² resolves (Q < 0.01) is judged by its size: within ±3 % passes, within
    ±10 % warns, beyond fails -- on both sides of the line (a low, clipped level fails too)."""
    assert (PASS, FAIL) == (0.03, 0.10)          # fractions, not percent
    gate = guide.ptc_gate(_ptc(dev=dev))
    assert gate.status == status
    assert any("χ² = " in r and "Q = " in r for r in gate.reasons)      # always shown
    assert any(f"{100 * dev:+.2f}" in r for r in gate.reasons)
    if status != "pass":
        assert "exclude level 6 " in gate.next[0]          # the worst level
        assert f"{100 * dev:+.2f} %" in gate.summary


@pytest.mark.parametrize("Q, status", [(1.0, "pass"), (0.01, "pass"),
                                       (np.nextafter(0.01, 0), "warn"), (0.0, "warn")])
def test_ptc_gate_judges_the_deviation_only_when_chi2_resolves_it(Q, status):
    """Q >= 0.01: the points agree with the line within their errors (a 5 % deviation is
    noise then); below, the 5 % deviation is resolved and warns."""
    gate = guide.ptc_gate(_ptc(Q, dev=0.05))
    assert gate.status == status
    assert ("within their errors" in gate.summary) == (status == "pass")


@pytest.mark.parametrize("used, status", [(2, "fail"), (3, "pass")])
def test_ptc_gate_levels(used, status):
    gate = guide.ptc_gate(_ptc(0.5, used=used))
    assert gate.status == status


def test_ptc_gate_without_degrees_of_freedom_fails():
    """dof = 0 leaves Q undefined (nan): not a pass."""
    assert guide.ptc_gate(_ptc(0.9, dof=0)).status == "fail"


@pytest.mark.parametrize("rel, chi2_dof, status", [
    (0.05, 1.0, "pass"), (0.0501, 1.0, "warn"), (0.0501, 0.2, "warn"),
    (0.01, 24.9, "pass"), (0.01, 25.1, "warn"), (0.0099, 25.1, "pass")])
def test_ptc_gate_gain_error_includes_the_nonlinearity(rel, chi2_dof, status):
    """σ(A)/A times the Birge ratio √(χ²/ν) (only when χ²/ν > 1) above 5 % warns: 1 % with
    χ²/ν = 25.1 is 5.01 %."""
    gate = guide.ptc_gate(_ptc(0.5, A_rel_err=rel, chi2_dof=chi2_dof))
    assert gate.status == status
    assert any("above 5 %" in r for r in gate.reasons) == (status == "warn")
    if chi2_dof > 1:
        assert any("√(χ²/ν)" in r for r in gate.reasons)


@pytest.mark.parametrize("le, status", [
    ((-1.0, 0.5), "pass"), ((-0.62, 0.48), "pass"), ((-1.01, 0.5), "warn"),
    ((0.0, 1.01), "warn"), ((-0.2, 3.0), "warn"), ((-3.01, 0.2), "fail"),
    ((0.2, 3.01), "fail")])
def test_ptc_gate_linearity_error_of_the_datasheet(le, status):
    """EMVA 1288 sec. 6.7's LE (the datasheet's LE_min, LE_max in %): within ±1 % passes
    (the reference CCD's −0.62 … +0.48 %), within ±3 % warns, beyond fails."""
    emva = NS(LE_min=le[0], LE_max=le[1])
    gate = guide.ptc_gate(_ptc(0.5), emva=emva)
    assert gate.status == status
    assert any("linearity error LE" in r and "datasheet" in r for r in gate.reasons)


@pytest.mark.parametrize("off, status", [(0.008, "pass"), (-0.014, "warn"), (0.014, "warn"),
                                         (-0.05, "fail")])
def test_ptc_gate_linearity_error_from_photon_counts(off, status):
    """Without a datasheet, the LE of the used levels' means against their photon counts (the
    line through the means takes up a part of one level's offset)."""
    noise = _ptc(0.5, photons=True)
    noise.points[3].mu *= 1.0 + off            # level 4 off the line of the means
    noise.points[3].var = 0.01 * noise.points[3].mu + 2.0
    lo, hi = guide.ptc_linearity(noise)
    assert min(lo, hi, key=lambda v: -abs(v)) == pytest.approx(off, rel=0.25)
    assert guide.ptc_gate(noise).status == status
    assert guide.ptc_linearity(_ptc(0.5)) is None        # no photon counts: not judged


# ------------------------------------------------------------------------------ pattern -----
@pytest.mark.parametrize("after, status", [(1.0, "pass"), (np.nextafter(2.0, 0), "pass"),
                                           (2.0, "pass"), (np.nextafter(2.0, 3), "fail")])
def test_pattern_step_held_out_flat(monkeypatch, after, status):
    """A held-out flat whose SNUP after the correction exceeds (not equals) the SNUP before
    fails the step; SNUP is stubbed: 2 % before, ``after`` after."""
    import ccdcore.flatfield.fit as ff
    import ccdcore.flatfield.uniformity as un

    raw = np.full((8, 8), 2000, np.uint16)
    corrected = np.full((8, 8), 1.0)
    flat = NS(base_key=(1, 0.1), correct=lambda frame, where=None: corrected)
    monkeypatch.setattr(ff, "flat_field_from_session", lambda s, base=None: flat)

    def snup(frame, layout=None):
        v = after if frame is corrected else 2.0
        return _Snup(v)

    monkeypatch.setattr(un, "snup", snup)
    recs = {(1, 0.1): [NS(relpath="base.tif")], (2, 0.2): [NS(relpath="held.tif")]}
    s = NS(fixed_pattern_configs=lambda: {}, flat_groups=lambda: recs,
           camera=NS(bits=12, layout="mono"), read=lambda rec: raw)
    step = guide.pattern_step(s)
    assert step.gate.status == status
    assert [r["frame"] for r in step.snup_rows] == ["held.tif"]


class _Snup:
    def __init__(self, v):
        self.channels = [NS(name="L", snup=v)]

    def __getitem__(self, name):
        return self.channels[0]


def test_pattern_step_without_held_out_flats_warns(monkeypatch):
    """Held-out flats outside 10-90 % of full scale are not used: the check is missing, warn."""
    import ccdcore.flatfield.fit as ff

    flat = NS(base_key=(1, 0.1), correct=lambda frame, where=None: frame)
    monkeypatch.setattr(ff, "flat_field_from_session", lambda s, base=None: flat)
    recs = {(1, 0.1): [NS(relpath="base.tif")], (2, 0.2): [NS(relpath="held.tif")]}
    # the base group's neighbours at exactly 10 % and 90 % of full scale are outside the
    # open range (warn); just inside, they are used (a constant frame: SNUP 0 -> 0, pass)
    for level, status in ((0.9 * 4095, "warn"), (0.1 * 4095, "warn"),
                          (np.nextafter(0.9 * 4095, 0), "pass"),
                          (np.nextafter(0.1 * 4095, 4095), "pass")):
        s = NS(fixed_pattern_configs=lambda: {}, flat_groups=lambda: recs,
               camera=NS(bits=12, layout="mono"),
               read=lambda rec, v=level: np.full((8, 8), v))
        assert guide.pattern_step(s).gate.status == status


@pytest.mark.parametrize("d1, d2, dark, status", [(0, 0, 1, "pass"), (-1, 0, 1, "warn"),
                                                   (0, -1, 1, "warn"), (0, 0, 0, "warn"),
                                                   (1, 1, 1, "pass")])
def test_pattern_step_against_the_plan(monkeypatch, d1, d2, dark, status):
    """K̂ against the plan of sec. V-B: n1 = ceil(10 2^(2b) (p sigma)^2 worst) configurations of
    n2 = ceil(sigma_N^2(mu_max) / 0.2) frames.  At 8 bits, sigma = 2.7e-3, p = 1.5, worst 1:
    n1_hat = 10 * 65536 * (4.05e-3)^2 = 10.75 -> 11; A = 0.01, sigma_C^2 = 1:
    (0.01 * 255 + 1) / 0.2 = 17.75 -> 18.  One configuration or one frame short warns, as does
    a session without dark frames; the plan met (or exceeded) passes.  fixed_pattern_map is
    stubbed (only its sigma and worst ratio are read)."""
    import ccdcore.fixedpattern as fpm

    fp = NS(n1=11 + d1, n1_hat=11 + d1, sigma_hat=2.7e-3, worst_ratio=1.0, spatial_std=0.01)
    monkeypatch.setattr(fpm, "fixed_pattern_map", lambda s, d, window=9, p=1.5: fp)
    configs = {c: [NS(relpath=f"c{c}_{i}.tif") for i in range(18 + (d2 if c == 0 else 0))]
               for c in range(11 + d1)}
    s = NS(fixed_pattern_configs=lambda: configs, dark_frames=lambda: [NS()] * dark,
           camera=NS(bits=8, layout="mono"), max_intensity_frame=lambda: None,
           flat_groups=lambda: {})
    noise = NS(A=0.01, sigma_c2=1.0, black_level_dn=0.0)
    step = guide.pattern_step(s, dark=object(), noise=noise)
    assert (step.plan.n1_required, step.plan.n2_required) == (11, 18)
    assert step.gate.status == status
    assert bool(step.plan_warnings) == (status == "warn")


# ----------------------------------------------------------------------------- response -----
@pytest.mark.parametrize("status, gate_status", [("trusted", "pass"), ("doubtful", "warn"),
                                                  ("failed", "fail")])
def test_response_gate_is_the_verdict(status, gate_status):
    """The gate says what the library's verdict says, in its words, and never passes over a
    doubtful or failed curve; the verdict's next step is the gate's."""
    from ccdcore.response.verdict import ResponseVerdict

    v = ResponseVerdict(status, "because", ("a.png", "b.png"),
                        "" if status == "trusted" else "--exposures estimated")
    ch = {n: NS(iterations=3, converged=True, sigma_s=0.01, sigma_c2=1.0) for n in "RG"}
    gate = guide.response_gate(_Res(ch, v))
    assert gate.status == gate_status
    assert gate.summary == v.line()
    assert bool(gate.next) == (status != "trusted")
    if gate.next:
        assert "--exposures estimated" in gate.next[0]


class _Res:
    def __init__(self, ch, verdict):
        self._ch = ch
        self.channels = list(ch)
        self.verdict = verdict
        self.exposures = None
        self.selection = ""
        self.compared = {}
        self.method = "tsin"

    def __getitem__(self, name):
        return self._ch[name]


# ------------------------------------------------------------------------------- verify -----
W = 9          # verify's default window


def _local(x: np.ndarray, w: int = W) -> float:
    """The pixel-scale nonuniformity as VerifyRow defines it: 100 sigma(D - D_w) / mean, D_w the
    w x w mean (edges reflected)."""
    x = np.asarray(x, np.float64)
    return float(100.0 * np.std(x - uniform_filter(x, size=w, mode="reflect")) / np.mean(x))


def _snup(x: np.ndarray) -> float:
    x = np.asarray(x, np.float64)
    return float(100.0 * np.std(x) / np.mean(x))


class _Product:
    """A product whose correction returns the frame given for each record's name."""

    def __init__(self, out: dict[str, np.ndarray], flat: bool, dark_level: float = 0.0):
        self.out = out
        self.maps = {"flat_G": np.ones((2, 2))} if flat else {
            "dark": np.full((2, 2), dark_level, np.float32), "K": np.ones((2, 2))}
        self.estimates = {}

    def correct(self, raw, name=None):
        return self.out[name]


def _session(frames: dict[str, np.ndarray], bits: int = 12):
    recs = [NS(relpath=k, role="scene") for k in frames]
    return NS(camera=NS(layout="mono", bits=bits), read=lambda rec: frames[rec.relpath]), recs


def _frames(seed: int = 0, shape=(64, 64), level: float = 2000.0):
    """A raw frame: level, a smooth illumination ramp (10 %), and pixel-scale pattern (1 %)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]] / shape[1]
    shading = 1.0 + 0.1 * (x + y)
    detail = 0.01 * rng.standard_normal(shape)
    return level * shading * (1 + detail), level * shading, level * shading * detail


@pytest.mark.parametrize("eps, status", [(-1e-6, "pass"), (1e-6, "fail")])
def test_verify_flat_product_judged_by_snup(eps, status):
    """A flat-field product: SNUP after just below / just above SNUP before decides; the
    pixel-scale part grows in both cases (it is not the flat field's measure)."""
    raw, smooth, _ = _frames(1)
    mean = raw.mean()
    # after: the deviations from the mean scaled so that SNUP = (1 + eps) * SNUP before, but
    # reshuffled into pixel-scale noise (a smooth frame turned rough): local nonuniformity grows
    dev = (raw - mean).ravel()
    rough = np.random.default_rng(9).permutation(dev).reshape(raw.shape)
    after = mean + rough * (1 + eps)
    assert _snup(after) == pytest.approx(_snup(raw) * (1 + eps), rel=1e-9)
    assert _local(after) > _local(raw)
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": after}, flat=True), records=recs)
    assert v.gate.status == status
    r = v.rows[0]
    assert (r.after > r.before) == (eps > 0)


@pytest.mark.parametrize("eps, status", [(-1e-6, "pass"), (1e-6, "fail")])
def test_verify_k_product_judged_by_the_pixel_scale_part(eps, status):
    """A K̂ product (eq. 51) keeps illumination shading by design: its measure is the pixel-scale
    nonuniformity.  After: the shading doubled (SNUP grows a lot) and the pixel-scale part
    (1 + eps) times the raw frame's: it passes just below, fails just above."""
    raw, smooth, detail = _frames(2)
    target = _local(raw) * (1 + eps)

    def after_of(f):                                  # shading doubled, detail scaled by f
        return 2.0 * smooth - smooth.mean() + f * (raw - smooth)

    f = brentq(lambda f: _local(after_of(f)) - target, 0.5, 1.5, xtol=1e-15, rtol=1e-15)
    after2 = after_of(f)
    assert _local(after2) == pytest.approx(target, rel=1e-11)
    assert _snup(after2) > 1.5 * _snup(raw)
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": after2}, flat=False), records=recs)
    assert v.gate.status == status
    r = v.rows[0]
    assert r.local_after == pytest.approx(target, rel=1e-9)
    assert r.local_before == pytest.approx(_local(raw), rel=1e-9)


@pytest.mark.parametrize("side, status", [(1 + 1e-6, "pass"), (1 - 1e-6, "warn")])
def test_verify_noise_floor(side, status):
    """The pixel-scale nonuniformity after the correction against 1.5x the noise floor
    100 sqrt(A mu + sigma_C^2) / mean sqrt(1 - 1/w^2), mu the raw mean with the black level b0
    removed (the product's dark offset is removed from the raw frame first and added back for
    mu).  A is chosen so that 1.5x the floor is just above (pass) or just below (warn) it."""
    raw, _, _ = _frames(3)
    dark_level, b0, sc2 = 150.0, 64.0, 4.0
    raw = raw + dark_level
    after = (raw - dark_level) * 1.0
    # after: less pixel-scale structure than before (no fail), a known local nonuniformity
    base = uniform_filter(after, size=W, mode="reflect")
    after = base + 0.5 * (after - base)
    local_after = _local(after)
    mean = float(np.mean(raw - dark_level))           # the "before" plane's mean
    mu = mean + dark_level - b0
    # 1.5 * 100 sqrt(A mu + sc2) / mean * sqrt(1 - 1/81) = side * local_after
    root = side * local_after / (1.5 * 100.0 * math.sqrt(1 - 1 / W ** 2)) * mean
    A = (root ** 2 - sc2) / mu
    assert A > 0
    noise = NS(A=A, sigma_c2=sc2, black_level_dn=b0)
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": after}, flat=False, dark_level=dark_level),
                     records=recs, noise=noise)
    r = v.rows[0]
    floor = 100.0 * math.sqrt(A * mu + sc2) / mean * math.sqrt(1 - 1 / W ** 2)
    assert r.floor == pytest.approx(floor, rel=1e-9)
    assert r.local_after == pytest.approx(local_after, rel=1e-9)
    assert r.local_after < r.local_before
    assert v.gate.status == status


@pytest.mark.parametrize("at_top, kept", [(100, True), (101, False)])
def test_verify_leaves_out_clipped_frames(at_top, kept):
    """More than 1 % of the pixels at full scale leaves a frame out: 100 of 10,000 (1 %) stay,
    101 go."""
    top = 4095
    raw = np.full((100, 100), 2000.0) + np.random.default_rng(4).normal(0, 5, (100, 100))
    raw.ravel()[:at_top] = top
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": raw}, flat=True), records=recs)
    assert bool(v.rows) == kept
    assert v.gate.status == ("pass" if kept else "skip")


@pytest.mark.parametrize("level, kept", [(409.5, True), (np.nextafter(409.5, 0), False)])
def test_verify_leaves_out_dark_frames(level, kept):
    """A mean below 10 % of full scale (409.5 DN at 12 bits) leaves a frame out; at it, kept
    (a constant frame: its mean is exact)."""
    raw = np.full((64, 64), level)
    assert (raw.mean() < 0.1 * 4095) == (not kept)
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": raw}, flat=True), records=recs)
    assert bool(v.rows) == kept


@pytest.mark.parametrize("flat", [True, False])
def test_verify_an_unchanged_frame_is_not_worse(flat):
    """"Must not exceed": a correction that leaves the measure exactly as it was (here the
    frame itself) does not fail the step."""
    raw, _, _ = _frames(6)
    s, recs = _session({"a.tif": raw})
    v = guide.verify(s, _Product({"a.tif": raw.copy()}, flat=flat), records=recs)
    r = v.rows[0]
    assert (r.after, r.local_after) == (r.before, r.local_before)
    assert v.gate.status == "pass"
