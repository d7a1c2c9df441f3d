"""The photon-transfer gate on simulated cameras with a real sensor's slight nonlinearity.

With a million pixels per frame the points' statistical errors (√(2/M) ≈ 0.14 % of σ̂²_N,
eq. 40) are far below the few tenths of a percent of nonlinearity of a good real camera (the
EMVA 1288 reference CCD: a linearity error of −0.62 … +0.48 %), so χ² (eq. 42) rejects the line
on every good camera: the gate must still pass or warn, saying why, and fail a camera that is
truly bad (5 % nonlinear, or a level clipped by the full well).
"""
from __future__ import annotations

from pathlib import Path

import pytest

from ccdcore import guide
from ccdcore.noise import EMVA_FIT_FRACTION, photon_transfer
from ccdcore.session import open_session
from ccdcore.simulate import emva, healey


def _emva_gate(tmp: Path, a: float, size: tuple[int, int], steps: int):
    emva.simulate(tmp, seed=3, size=size, steps=steps, L=3, nonlinearity=a)
    noise = photon_transfer(open_session(tmp), fit_fraction=EMVA_FIT_FRACTION)
    return noise, guide.ptc_gate(noise)


def test_a_good_camera_with_a_million_pixels_passes_though_chi2_rejects_the_line(tmp_path):
    """0.5 % nonlinearity, 1024 × 1024 pixels, the EMVA 1288 range: χ² is many times its
    degrees of freedom (the old Q-only gate failed it), the gate passes and says why."""
    noise, gate = _emva_gate(tmp_path, 0.005, (1024, 1024), 12)
    assert noise.chi2 > 10 * noise.dof and noise.Q < 1e-6
    assert gate.status in ("pass", "warn"), gate
    assert "χ² resolves" in " ".join(gate.reasons)
    assert any(f"χ² = {noise.chi2:.3g} with {noise.dof} degrees of freedom" in r
               for r in gate.reasons)
    lo, hi, _ = guide.ptc_deviation(noise)
    assert 0.003 < max(abs(lo), abs(hi)) <= guide.PTC_DEVIATION_PASS   # resolved, small
    # the gain's error includes the nonlinearity (Birge ratio), and still meets 5 %
    assert "√(χ²/ν)" in gate.reasons[0]
    assert noise.A == pytest.approx(0.1, rel=0.01)


def test_the_same_camera_linear_passes_within_its_errors(tmp_path):
    noise, gate = _emva_gate(tmp_path, 0.0, (256, 192), 12)
    assert gate.status == "pass" and "within their errors" in gate.summary


@pytest.mark.parametrize("preset", ["emva1288", "healey94"])
def test_a_five_percent_nonlinear_camera_fails(tmp_path, preset):
    if preset == "emva1288":
        noise, gate = _emva_gate(tmp_path, 0.05, (128, 96), 16)
    else:
        healey.simulate(tmp_path, seed=1, size=(256, 192), n_dark=2, n1=1, n2=1, patches=(),
                        max_intensity=None, nonlinearity=0.05)
        noise = photon_transfer(open_session(tmp_path))
        gate = guide.ptc_gate(noise)
    assert gate.status == "fail", gate
    assert "beyond ±10 %" in gate.summary
    assert gate.next and "exclude level" in gate.next[0]


def test_a_level_clipped_by_the_full_well_fails(tmp_path):
    """The full well at 75 % of the ADC range and the top level past it: no value reaches the
    ADC's full scale, and with the linearity rule relaxed the fit keeps the level, whose
    variance falls off the line: the gate fails."""
    healey.simulate(tmp_path, seed=1, size=(128, 96), n_dark=2, n1=1, n2=1, patches=(),
                    max_intensity=None, levels=[0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 1.05],
                    full_well_e=0.75 * 255 / 0.0034)
    noise = photon_transfer(open_session(tmp_path), linearity_tolerance=10.0)
    assert all(p.used for p in noise.points)
    gate = guide.ptc_gate(noise)
    assert gate.status == "fail", gate
