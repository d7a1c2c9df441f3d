"""Illumination-invariant change detection, Tsin, Ramesh & Kanade (2001) sec. 5:
ccdcore.change.detector.

On the ``change`` preset at 256x192 (seed 0: a background lit anew, two shades of shadow, three
new objects; brackets of 7 exposures) against the simulator's truth. Tolerances:

* the issue's: recall and precision of the change mask >= 0.9, shadow called change <= 5 %,
  background false alarms within a factor 2 of the requested P = 0.01;
* the mean background d² near 3 (χ² with 3 degrees of freedom; the paper measured 3.38 ± 0.51
  over 21 scenes): within 0.5;
* each M within 4 of its own standard errors (from M's sandwich covariance) of the truth, plus
  0.1 % of the entry's scale for the response's own error (g is estimated from the reference
  bracket; both brackets share it, so it only enters through the radiance's shape); measured
  2.0-3.4 standard errors. Without the correction for the noise of the reference radiance
  (errors in the variables) the diagonal is 0.4 % low, 5-25 standard errors.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from ccdcore.change import detector as CH
from ccdcore.change import kernels as CK
from ccdcore.change.session import session_change
from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_image
from ccdcore.session import open_session
from ccdcore.simulate import change as sim


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("change") / "s0"
    sim.simulate(root, seed=0, size=(256, 192))
    truth = json.loads((root / "truth.json").read_text())
    changed = np.asarray(read_image(root / "truth/change_mask.png")) > 0
    shadow = np.asarray(read_image(root / "truth/shadow_mask.png"))
    result, inputs = session_change(open_session(root), CH.ChangeOptions(pfa=0.01))
    return root, truth, changed, shadow, result, inputs


def test_change_mask_recall_precision_and_shadows(scene):
    _, _, changed, shadow, r, _ = scene
    called = r.labels == CH.LABEL_CHANGE
    tp = np.count_nonzero(called & changed)
    assert tp / changed.sum() >= 0.9
    assert tp / called.sum() >= 0.9
    assert np.count_nonzero(called & (shadow > 0)) / np.count_nonzero(shadow > 0) <= 0.05
    # the two shades are found as clusters 1 and 2, most of each in one cluster
    for shade in (1, 2):
        labels, n = np.unique(r.labels[shadow == shade], return_counts=True)
        assert labels[np.argmax(n)] in (1, 2) and n.max() / n.sum() > 0.95


def test_false_alarm_rate_and_background_d2(scene):
    _, _, changed, shadow, r, _ = scene
    background = ~changed & (shadow == 0)
    observed = np.mean(r.labels[background] != 0)
    assert 0.005 <= observed <= 0.02
    d = r.to_dict()
    assert d["pfa_requested"] == 0.01
    assert abs(d["pfa_observed"] - 0.01) < 0.002          # the calibration's own sample
    assert abs(d["background_d2_mean"] - 3.0) < 0.5
    assert d["threshold_chi2"] == pytest.approx(stats.chi2.isf(0.01, 3))
    assert d["dof"] == 3
    # a stricter P: fewer pixels called, a higher threshold; M is not refitted
    labels, thr = r.at(0.001)
    assert thr > r.threshold
    assert np.count_nonzero(labels == 255) < np.count_nonzero(r.labels == 255)
    assert np.mean(labels[background] != 0) < 0.003


def test_transforms_close_to_the_simulators(scene):
    _, truth, _, shadow, r, _ = scene
    # the radiance is on the response's reported scale, the same for both brackets: M is free
    # of it, up to the response's small shape error
    want = [np.asarray(truth["M"])] + [np.asarray(m) for m in truth["M_shadows"]]
    assert len(r.clusters) == 3
    for c in r.clusters[1:]:                                # match shades by their cluster
        assert c.pixels > 1000
    order = [0]
    for c in r.clusters[1:]:
        shade = np.bincount(shadow[r.labels == c.label], minlength=3)[1:].argmax() + 1
        order.append(shade)
    for c, k in zip(r.clusters, order):
        err = np.sqrt(np.diag(c.M_cov)).reshape(3, 3)
        assert np.all(err > 0) and np.all(np.isfinite(err))
        tol = 4 * err + 0.001 * np.abs(want[k]).max()
        assert np.all(np.abs(c.M - want[k]) <= tol), (k, c.M, want[k])


def test_empirical_threshold_corrects_a_wrong_noise_scale(scene):
    """Sigmas 30 % too small make d² about twice χ²: the χ² threshold would call several
    times P of the background changed, the calibrated threshold keeps it near P."""
    _, _, changed, shadow, _, inp = scene
    r = CH.detect(inp.E_ref, 0.7 * inp.sigma_ref, inp.E_tgt, 0.7 * inp.sigma_tgt,
                  CH.ChangeOptions(pfa=0.01))
    background = ~changed & (shadow == 0)
    assert r.scale == pytest.approx(1 / 0.49, rel=0.15)
    assert 0.005 <= np.mean(r.labels[background] != 0) <= 0.02
    d = r.to_dict()
    assert d["pfa_observed_at_chi2_threshold"] > 4 * 0.01
    assert any("times χ²" in n for n in r.notes)


def test_prediction_d2_matches_the_clusters_map(scene):
    _, _, _, _, r, inp = scene
    c = r.clusters[0]
    d2 = CH.prediction_d2(inp.E_ref, inp.sigma_ref, inp.E_tgt, inp.sigma_tgt, c.M,
                          c.M_cov)
    np.testing.assert_allclose(d2[r.valid], r.d2[..., 0][r.valid], rtol=1e-9)
    np.testing.assert_allclose(r.predicted, inp.E_ref @ c.M, rtol=1e-12)


def test_d2_against_a_direct_computation():
    """d² and Σ_e⁻¹ of the compiled RGB kernel against numpy's inverse of
    Σ_e = Mᵀ diag(σ_E²) M + diag(σ_E'²) + J Σ_M Jᵀ, written out from sec. 5; and the generic path
    (two channels) the same way."""
    rng = np.random.default_rng(5)
    for C in (3, 2):
        n = 500
        E = rng.uniform(0.05, 0.6, (n, C))
        M = np.eye(C) * 0.9 + 0.05 * rng.standard_normal((C, C))
        Et = E @ M + 0.01 * rng.standard_normal((n, C))
        var, var_t = rng.uniform(1e-5, 1e-4, (2, n, C))
        A = 1e-3 * rng.standard_normal((C * C, C * C))
        Mc = A @ A.T
        d2, P = CK.error_d2(E, Et, var, var_t, M, Mc)
        for i in range(0, n, 97):
            J = np.kron(E[i][:, None], np.eye(C)).T        # ∂e_j/∂M_kj = E_k, vec M row-major
            S = M.T @ np.diag(var[i]) @ M + np.diag(var_t[i]) + J @ Mc @ J.T
            e = E[i] @ M - Et[i]
            assert d2[i] == pytest.approx(e @ np.linalg.solve(S, e), rel=1e-9)
            np.testing.assert_allclose(P[i], np.linalg.inv(S), rtol=1e-8)


def test_mono_scene_has_one_degree_of_freedom():
    """A grey camera: M is 1x1 (a gain); d² is χ² with 1 degree of freedom."""
    rng = np.random.default_rng(3)
    E = rng.uniform(0.05, 0.6, (120, 160))
    s = 0.002 + 0.01 * E
    Et = 0.8 * E
    Et[40:70, 50:90] = rng.uniform(0.05, 0.6, (30, 40))      # a new object
    st = 0.002 + 0.01 * Et
    Eo = E + s * rng.standard_normal(E.shape)
    Eto = Et + st * rng.standard_normal(E.shape)
    r = CH.detect(Eo, s, Eto, st, CH.ChangeOptions(pfa=0.01, max_clusters=1))
    assert r.dof == 1 and r.clusters[0].M.shape == (1, 1)
    assert r.clusters[0].M[0, 0] == pytest.approx(0.8, abs=5 * np.sqrt(r.clusters[0].M_cov[0, 0]))
    bg = np.ones(E.shape, bool)
    bg[40:70, 50:90] = False
    assert abs(np.mean(r.d2[..., 0][bg]) - 1.0) < 0.1
    assert 0.005 <= np.mean(r.labels[bg] != 0) <= 0.02


def test_bad_input_is_named():
    E = np.full((20, 30, 3), 0.2)
    s = np.full((20, 30, 3), 0.01)
    with pytest.raises(CcdError, match="differs from the ref"):
        CH.detect(E, s, E[:, :20], s[:, :20], names=("ref", "tgt"))
    bad = E.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(CcdError, match="NaN"):
        CH.detect(bad, s, E, s)
    with pytest.raises(CcdError, match="saturated or dark in every exposure"):
        CH.detect(E, np.full_like(s, np.inf), E, s)
    with pytest.raises(CcdError, match="false-alarm"):
        CH.detect(E, s, E, s, CH.ChangeOptions(pfa=0.0))


def test_undetermined_pixels_are_labelled_and_noted(scene):
    _, _, _, _, _, inp = scene
    s = inp.sigma_ref.copy()
    s[:30, :, :] = np.inf                                  # saturated in every exposure
    r = CH.detect(inp.E_ref, s, inp.E_tgt, inp.sigma_tgt)
    assert np.all(r.labels[:30] == CH.LABEL_UNDETERMINED)
    assert not np.any(r.labels[30:] == CH.LABEL_UNDETERMINED)
    assert any("label 254" in n for n in r.notes)


# -- the command line -------------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "assets" / "change"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_change_writes_masks_maps_and_json(capsys, tmp_path):
    code, out, err = run(capsys, "change", DEMO, "-o", tmp_path / "c", "--json")
    assert code == 0, err
    d = json.loads(out)
    for key in ("M", "clusters", "threshold", "pfa_requested", "pfa_observed",
                "background_d2_mean", "changed_pixels"):
        assert key in d
    mask = read_image(tmp_path / "c" / "change_mask.png")
    labels = read_image(tmp_path / "c" / "labels.png")
    d2 = read_image(tmp_path / "c" / "d2.exr")
    pred = read_image(tmp_path / "c" / "predicted_target.exr")
    assert mask.shape == labels.shape == d2.shape == (96, 128)
    assert pred.shape == (96, 128, 3)
    assert set(np.unique(mask)) <= {0, 255}
    assert np.count_nonzero(mask == 255) == d["changed_pixels"] == np.count_nonzero(labels == 255)
    assert [c["label"] for c in d["clusters"]] == list(range(len(d["clusters"])))
    assert len(d["M"]) == len(d["clusters"]) and np.shape(d["M"][0]) == (3, 3)
    truth = read_image(DEMO / "truth" / "change_mask.png") > 0
    assert np.count_nonzero((mask == 255) & truth) / truth.sum() >= 0.9
    code, out, err = run(capsys, "change", DEMO, "-o", tmp_path / "c")   # human summary
    assert code == 0 and "cluster 0 (background)" in out


def test_cli_change_bad_input(capsys, tmp_path):
    code, out, err = run(capsys, "change", ROOT / "assets" / "tsin01", "-o", tmp_path / "x")
    assert code == 2 and out == "" and "'reference'" in err
    assert len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "change", DEMO, "--pfa", "0.7", "-o", tmp_path / "x")
    assert code == 2 and "false-alarm" in err
    # a target bracket of another framing
    root = tmp_path / "s"
    shutil.copytree(DEMO, root)
    for f in sorted((root / "target").glob("*.tif")):
        write_image(f, read_image(f)[:80])
    code, out, err = run(capsys, "change", root, "-o", tmp_path / "y")
    assert code == 2 and out == "" and "target/k00.tif" in err and "Traceback" not in err
    # a target bracket of another camera (16-bit samples)
    other = tmp_path / "o"
    shutil.copytree(DEMO, other)
    for f in sorted((other / "target").glob("*.tif")):
        write_image(f, read_image(f).astype(np.uint16) * 257)
    code, out, err = run(capsys, "change", other, "-o", tmp_path / "z")
    assert code == 2 and out == "" and "Traceback" not in err
    assert "target/k00.tif" in err and "sample type" in err


def test_shade_factor_and_d2_against_a_direct_computation():
    """The shade of step 5, E' = k E M per row: k is the generalised least squares factor with
    Σ_e(k) = k² (Mᵀ Σ_E M + J Σ_M Jᵀ) + Σ_E' (checked against numpy at the returned k: the
    gradient of d²(k) with Σ_e held there vanishes), and on rows drawn from the model d² has
    the mean of χ² with C - 1 = 2 degrees of freedom (20 000 rows: sd of the mean 0.014)."""
    rng = np.random.default_rng(11)
    n, C = 20000, 3
    M = np.array([[0.9, 0.03, 0.0], [0.02, 0.8, 0.05], [0.0, 0.04, 0.7]])
    k_true = rng.uniform(0.5, 1.6, n)
    E_true = rng.uniform(0.1, 0.8, (n, C))
    var = (0.01 * E_true) ** 2 + 1e-5
    var_t = (0.012 * (E_true @ M)) ** 2 + 1e-5
    E = E_true + np.sqrt(var) * rng.standard_normal((n, C))
    Et = k_true[:, None] * (E_true @ M) + np.sqrt(var_t) * rng.standard_normal((n, C))
    k, d2 = CK.shade_d2(E, Et, var, var_t, M, np.zeros((9, 9)))
    assert np.all(np.isfinite(k)) and np.all(np.isfinite(d2))
    assert np.mean(d2) == pytest.approx(2.0, abs=0.05)
    # k within its own error of the truth: the error of k is about 1 % here
    assert np.median(np.abs(k / k_true - 1)) < 0.01
    Mc = 1e-6 * np.eye(9)
    k, d2 = CK.shade_d2(E[:50], Et[:50], var[:50], var_t[:50], M, Mc)
    for i in range(0, 50, 7):
        J = np.kron(E[i][:, None], np.eye(C)).T
        A = M.T @ np.diag(var[i]) @ M + J @ Mc @ J.T
        S = k[i] ** 2 * A + np.diag(var_t[i])
        P = E[i] @ M
        e = Et[i] - k[i] * P
        assert d2[i] == pytest.approx(e @ np.linalg.solve(S, e), rel=1e-6)
        assert abs(P @ np.linalg.solve(S, e)) < 1e-6 * abs(P @ np.linalg.solve(S, Et[i]))


def test_shade_threshold_has_one_degree_of_freedom_less(scene):
    r = scene[4]
    assert r.shade == (0.5, 2.0)
    assert r.shade_threshold(0.01) == pytest.approx(r.scale * stats.chi2.isf(0.01, 2))
    assert r.to_dict()["shade_pixels"] == int(np.count_nonzero(r.labels == CH.LABEL_SHADE))


def test_shade_option_checked():
    for bad in ((1.2, 2.0), (0.5, 0.9), (0.0, 2.0)):
        with pytest.raises(CcdError, match="shade"):
            CH.ChangeOptions(shade=bad).check()
    CH.ChangeOptions(shade=None).check()
