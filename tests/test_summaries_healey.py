"""Tests of the typed records of the Healey & Kondepudy (1994) estimates a calibration product
stores: photon transfer (:class:`PhotonTransferSummary`, :class:`PtcPointSummary`), the dark
reference (:class:`DarkSummary`), K̂ (:class:`FixedPatternSummary`), the acquisition plan
(:class:`PlanSummary`), the correction check (:class:`CorrectionCheckSummary`) and the scene
variation (:class:`SceneSummary`, :class:`SceneMeasurementSummary`).

Each summary must give the JSON the product stored before the records existed (``X.to_dict()``
through :func:`ccdcore.common.json_safe`), key order included; read back from that JSON it must
be equal; a damaged object must raise a :class:`CcdError` naming the key; and ``rows()`` must
show the result's own figures. The photon-transfer summary must give its result back
(:meth:`PhotonTransfer.from_summary`, whose summary is the same record).  The results come
from a small ``healey94`` simulation (fixed seed), made once for the module.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import pytest

from ccdcore.common import json_safe
from ccdcore.dark.frame import dark_reference
from ccdcore.dark.map import DarkSummary
from ccdcore.gates import ptc_gate
from ccdcore.errors import CcdError
from ccdcore.fixedpattern import correction_check, fixed_pattern_map
from ccdcore.kmap_kernels import FixedPatternSummary
from ccdcore.noise import EMVA_FIT_FRACTION, PhotonTransfer, fit_points, photon_transfer
from ccdcore.planning import (PlanAlternatives, PlanInputsSummary, PlanSummary,
                              check_session_plan, plan_acquisition)
from ccdcore.ptc_fit import PhotonTransferSummary, PtcPoint, PtcPointSummary
from ccdcore.records import Row
from ccdcore.scene import (CorrectionCheckSummary, SceneMeasurementSummary, SceneSummary,
                           fit_scene_variation, scene_variations)
from ccdcore.session import open_session
from ccdcore.simulate import simulate

# the keys, in order, of the objects calibration.json held before the records (healey94 demo)
NOISE_KEYS = ["A", "A_err", "sigma_c2", "sigma_c2_err", "cov", "chi2", "dof", "Q", "verdict",
              "points", "conversion_gain_e_per_dn", "conversion_gain_e_per_dn_err",
              "read_noise_e", "read_noise_e_err", "read_noise_dn", "read_noise_dn_err",
              "quantisation_dn2", "black_level_dn", "black_level_source", "roi", "bits",
              "robust_dropped", "notes", "linearity_tolerance", "source", "fit_fraction",
              "fit_range"]
POINT_KEYS = ["level", "mu", "var", "var_err", "used", "reason", "exclusion", "n_pairs",
              "n_pixels", "exposure", "mu_raw", "clipped_fraction", "photons"]
DARK_KEYS = ["s", "shape", "mean", "spatial_std", "spatial_std_signal", "mean_sem", "noise_var",
             "mean_good", "spatial_std_good", "n_hot", "n_dead", "hot_rule", "dead_rule",
             "exposure", "notes"]
FP_KEYS = ["n1", "n2", "window", "p", "shape", "mean", "spatial_std", "sigma_hat", "n1_hat",
           "var_bound", "sd_bound", "worst_ratio", "fraction_pixels_with_rejection",
           "n_rejected", "config_ids", "config_levels", "noise_var_e", "K_var_mean", "notes"]
PLAN_KEYS = ["n1_required", "n2_required", "n1_hat", "n1_hat_exact", "worst_ratio",
             "sigma2_n_max", "n2_exact", "n1_formula", "n2_formula", "n2_reading",
             "n2_alternatives", "inputs", "notes", "warnings"]
INPUT_KEYS = ["A", "sigma_c2", "bits", "sigma_hat", "p", "mu_max", "n2_var_limit", "black_level",
              "q", "s", "sigma2_n_dark"]
CHECK_KEYS = ["frac_gt_1q", "frac_gt_2q", "frac_gt_2q_of_gt_1q", "max_change_q", "mean_level",
              "n_pixels", "q"]
SCENE_KEYS = ["name", "V_S", "V_S_err", "chi2", "dof", "Q", "measurements", "excluded", "notes"]
MEASUREMENT_KEYS = ["path", "level", "roi", "n_pixels", "mu_D", "var_D", "E_invK2", "dark_mean",
                    "black_level", "sigma_N2", "sigma_KN2", "sigma_cal2", "y", "V_S", "V_S_err",
                    "V_S_err_population", "n_clipped", "used"]


@pytest.fixture(scope="module")
def est(tmp_path_factory):
    """Every Healey & Kondepudy estimate of a small simulated session, as calibrate makes
    them."""
    out = tmp_path_factory.mktemp("healey_summaries") / "session"
    simulate("healey94", out, seed=7, size=(64, 48), n_dark=4, levels=5, n1=4, n2=2)
    session = open_session(out)
    noise = photon_transfer(session)
    dark = dark_reference(session)
    fp = fixed_pattern_map(session, dark)
    plan = plan_acquisition(noise, bits=session.camera.bits, fixed_pattern=fp)
    check = correction_check(session.read(session.max_intensity_frame()), dark, fp)
    scene = scene_variations(session, dark, fp, noise, dark_var=dark.var_map / dark.s,
                             K_var=float(np.mean(fp.K_var)))
    return SimpleNamespace(noise=noise, dark=dark, fp=fp, plan=plan, check=check, scene=scene,
                           warnings=tuple(check_session_plan(session, plan)))


def _same_json(cls: type, summary: Any, stored: dict[str, Any]) -> dict[str, Any]:
    """The summary's JSON is that of ``stored`` (as the product wrote it: through json_safe),
    and the summary read back from it is equal to it."""
    d = summary.to_dict()
    text = json.dumps(d, allow_nan=False)
    assert text == json.dumps(json_safe(stored), allow_nan=False)
    assert cls.from_dict(json.loads(text), "calibration.json") == summary
    return d


def _row(rows: tuple[Row, ...], label: str) -> Row:
    found = [r for r in rows if r.label == label]
    assert len(found) == 1, f"{label!r} in {[r.label for r in rows]}"
    return found[0]


def _check_rows(rows: tuple[Row, ...], lo: int = 5) -> None:
    assert lo <= len(rows) <= 12
    assert len({r.label for r in rows}) == len(rows)
    for r in rows:
        assert isinstance(r, Row)
        assert r.value is None or (isinstance(r.value, (int, float))
                                   and math.isfinite(r.value))


# ---------------------------------------------------------------------------------------------
# photon transfer
# ---------------------------------------------------------------------------------------------
def test_photon_transfer_summary_is_the_stored_json(est):
    pt = est.noise
    s = pt.summary()
    d = _same_json(PhotonTransferSummary, s, pt.to_dict())
    assert list(d) == NOISE_KEYS
    assert list(d["points"][0]) == POINT_KEYS
    assert isinstance(s.cov, tuple) and all(isinstance(r, tuple) and len(r) == 2 for r in s.cov)
    assert s.cov[0][1] == pytest.approx(float(pt.cov[0, 1]))
    assert type(s.A) is float and type(s.dof) is int and type(s.points[0].level) is int
    for p, ps in zip(pt.points, s.points):
        assert ps == p.summary()
        _same_json(PtcPointSummary, ps, p.to_dict())


def test_photon_transfer_rows(est):
    pt, rows = est.noise, est.noise.summary().rows()
    _check_rows(rows)
    gain = _row(rows, "conversion gain")
    assert (gain.value, gain.error, gain.unit) == (pt.conversion_gain_e_per_dn,
                                                   pt.conversion_gain_e_per_dn_err, "e⁻/DN")
    assert _row(rows, "gain A").value == pt.A
    assert _row(rows, "σ²_C").error == pt.sigma_c2_err
    assert _row(rows, "read noise").value == pt.read_noise_e
    assert _row(rows, "read noise in DN").value == pt.read_noise_dn
    assert _row(rows, "χ²").value == pt.chi2 and str(pt.dof) in _row(rows, "χ²").meaning
    assert _row(rows, "goodness of fit Q").value == pt.Q
    assert _row(rows, "verdict").text == ptc_gate(pt).line()     # the Walkthrough's words
    assert _row(rows, "levels used").value == sum(p.used for p in pt.points)
    point_rows = pt.points[0].summary().rows()
    _check_rows(point_rows)
    assert _row(point_rows, "noise variance σ̂²_N").error == pt.points[0].var_err


def _points(slope: float, c: float) -> list[PtcPoint]:
    return [PtcPoint(level=i + 1, mu=m, var=slope * m + c, var_err=0.001 + 1e-4 * m, n_pairs=1,
                     n_pixels=1000, used=True, reason=None, exposure=None, mu_raw=m,
                     clipped_fraction=0.0) for i, m in enumerate((10.0, 20.0, 30.0, 40.0))]


def test_photon_transfer_summary_without_read_noise_or_gain():
    """σ²_C below q²/12 (no read noise) and a negative slope (no gain): None, not NaN."""
    for pt in (fit_points(_points(0.01, 0.05), bits=8),
               fit_points(_points(-0.001, 2.0), bits=12, roi=(1, 2, 3, 4))):
        s = pt.summary()
        assert math.isnan(pt.read_noise_e) and s.read_noise_e is None
        assert (s.read_noise_dn is None) == math.isnan(pt.read_noise_dn)
        _same_json(PhotonTransferSummary, s, pt.to_dict())
        assert _row(s.rows(), "read noise").value is None
    assert fit_points(_points(0.01, 0.05), bits=8).summary().read_noise_dn_err is None
    s = fit_points(_points(-0.001, 2.0), bits=12, roi=(1, 2, 3, 4)).summary()
    assert s.conversion_gain_e_per_dn is None and s.roi == (1, 2, 3, 4)
    assert _row(s.rows(), "conversion gain").value is None


def _same_or_both_nan(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def test_photon_transfer_from_summary_round_trips(est):
    """summary -> result -> summary is equal (also through the JSON), the result has the
    numbers of the one summarised (NaN where the summary holds None), and every point too."""
    cases = [est.noise, est.noise.refit(fit_fraction=EMVA_FIT_FRACTION),
             fit_points(_points(0.01, 0.05), bits=8),
             fit_points(_points(-0.001, 2.0), bits=12, roi=(1, 2, 3, 4))]
    for pt in cases:
        s = pt.summary()
        back = PhotonTransfer.from_summary(s)
        assert back.summary() == s
        read = PhotonTransferSummary.from_dict(json.loads(json.dumps(s.to_dict())), "c.json")
        assert PhotonTransfer.from_summary(read).summary() == s
        for f in ("A", "A_err", "sigma_c2", "sigma_c2_err", "chi2", "Q", "read_noise_e",
                  "read_noise_e_err", "read_noise_dn", "read_noise_dn_err",
                  "conversion_gain_e_per_dn", "conversion_gain_e_per_dn_err",
                  "quantisation_dn2", "black_level_dn", "linearity_tolerance"):
            assert type(getattr(back, f)) is float, f
            assert _same_or_both_nan(getattr(back, f), float(getattr(pt, f))), f
        np.testing.assert_array_equal(back.cov, pt.cov)
        assert back.cov.dtype == np.float64 and back.cov.shape == (2, 2)
        assert (back.dof, back.verdict, back.roi, back.bits, back.robust_dropped, back.notes,
                back.source, back.fit_fraction, back.fit_range) == (
                    pt.dof, pt.verdict, pt.roi, pt.bits, pt.robust_dropped, pt.notes, pt.source,
                    pt.fit_fraction, pt.fit_range)
        assert back.measure_notes == ()
        assert back.sigma_n2(10.0) == pytest.approx(pt.sigma_n2(10.0), rel=1e-15)
        assert len(back.points) == len(pt.points)
        for p, q in zip(pt.points, back.points):
            assert PtcPoint.from_summary(p.summary()) == q
            assert q.summary() == p.summary()
            assert q == p or all(_same_or_both_nan(getattr(q, f), getattr(p, f))
                                 if isinstance(getattr(p, f), float)
                                 else getattr(q, f) == getattr(p, f)
                                 for f in (fl.name for fl in dataclasses.fields(PtcPoint)))
    assert math.isnan(PhotonTransfer.from_summary(cases[2].summary()).read_noise_e)


# ---------------------------------------------------------------------------------------------
# dark reference, fixed pattern
# ---------------------------------------------------------------------------------------------
def test_dark_summary(est):
    dark = est.dark
    s = dark.summary()
    assert list(_same_json(DarkSummary, s, dark.to_dict())) == DARK_KEYS
    assert s.shape == dark.mean_map.shape and s.s == dark.s
    rows = s.rows()
    _check_rows(rows)
    mean = _row(rows, "mean level")
    assert (mean.value, mean.error, mean.unit) == (dark.mean, s.mean_sem, "DN")
    assert _row(rows, "hot pixels").value == int(dark.hot_mask.sum())
    assert _row(rows, "hot pixels").meaning == dark.hot_rule
    assert _row(rows, "temporal noise σ²_N").value == pytest.approx(dark.noise_var)


def test_dark_summary_of_one_frame():
    """One dark frame: no variance, so the spread of the signal and the error are None."""
    frame = np.random.default_rng(3).normal(10.0, 0.5, (12, 16))
    dark = dark_reference([frame])
    s = dark.summary()
    assert math.isnan(dark.spatial_std_signal)
    assert (s.spatial_std_signal, s.mean_sem, s.noise_var) == (None, None, None)
    _same_json(DarkSummary, s, dark.to_dict())
    json.dumps(dark.to_dict(), allow_nan=False)


def test_fixed_pattern_summary(est):
    fp = est.fp
    s = fp.summary()
    assert list(_same_json(FixedPatternSummary, s, fp.to_dict())) == FP_KEYS
    assert s.config_ids == tuple(fp.config_ids) and s.n1_hat == fp.n1_hat
    rows = s.rows()
    _check_rows(rows)
    assert _row(rows, "configurations n1").value == fp.n1
    assert _row(rows, "slope spread σ̂").value == fp.sigma_hat
    assert _row(rows, "eq. 50 bound").value == fp.var_bound
    assert _row(rows, "error of K̂ (mean)").value == pytest.approx(math.sqrt(np.mean(fp.K_var)))
    assert _row(rows, "pixels with a rejected slope").value == pytest.approx(
        100 * np.mean(fp.n1_used < fp.n1))


def test_fixed_pattern_summary_unbounded_with_named_configurations(est):
    """A pixel that kept no slope (eq. 50 bound infinite) and configuration ids that are
    names: None for the infinite figures, the ids as they are."""
    used = est.fp.n1_used.copy()
    used[0, 0] = 0
    fp = dataclasses.replace(est.fp, n1_used=used, var_bound=float("inf"),
                             config_ids=("left", 2, "right", 4), noise_var_e=float("nan"))
    s = fp.summary()
    assert (s.var_bound, s.sd_bound, s.worst_ratio, s.noise_var_e) == (None, None, None, None)
    assert s.config_ids == ("left", 2, "right", 4)
    _same_json(FixedPatternSummary, s, fp.to_dict())
    assert _row(s.rows(), "eq. 50 bound").text == "infinite"


# ---------------------------------------------------------------------------------------------
# acquisition plan
# ---------------------------------------------------------------------------------------------
def test_plan_summary_with_the_sessions_warnings(est):
    plan, warnings = est.plan, est.warnings
    assert warnings, "the small session should fall short of the plan"
    s = plan.summary(warnings)
    stored = dict(plan.to_dict(), warnings=list(warnings))   # what calibrate stores
    d = _same_json(PlanSummary, s, stored)
    assert list(d) == PLAN_KEYS and list(d["inputs"]) == INPUT_KEYS
    assert "warnings" not in plan.to_dict()
    assert plan.summary().warnings == () and plan.summary().to_dict()["warnings"] == []
    assert isinstance(s.inputs, PlanInputsSummary) and isinstance(s.n2_alternatives,
                                                                  PlanAlternatives)
    assert s.n2_alternatives.to_dict() == plan.n2_alternatives
    rows = s.rows()
    _check_rows(rows)
    assert _row(rows, "n1 (configurations)").value == plan.n1_required
    assert _row(rows, "n1 (configurations)").meaning == plan.n1_formula
    assert _row(rows, "n2 (frames each)").value == plan.n2_required
    assert _row(rows, "reading of the n2 rule").text == plan.n2_reading
    assert _row(rows, "shortfalls").value == len(warnings)


@pytest.mark.parametrize("kw, keys", [
    (dict(s=16, dark_level=12.0, n2_reading="with_dark"),
     ["paper", "difference", "requantised", "with_dark"]),
    (dict(n2_var_limit=0.05), ["paper", "difference"]),
    (dict(mu_max=800.0, black_level=64.0, n2_var_limit=0.1), ["paper", "difference",
                                                              "requantised"]),
])
def test_plan_alternatives_and_inputs(kw, keys):
    plan = plan_acquisition(0.0034, 1.12, 8, sigma_hat=2.7e-3, **kw)
    s = plan.summary()
    d = _same_json(PlanSummary, s, dict(plan.to_dict(), warnings=[]))
    assert list(d["n2_alternatives"]) == keys
    assert s.inputs.s == kw.get("s") and (s.inputs.sigma2_n_dark is None) == ("s" not in kw)
    assert s.inputs.mu_max == plan.inputs["mu_max"]


# ---------------------------------------------------------------------------------------------
# correction check, scene variation
# ---------------------------------------------------------------------------------------------
def test_correction_check_summary(est):
    check = est.check
    s = CorrectionCheckSummary.of(check)
    assert list(_same_json(CorrectionCheckSummary, s, check.to_dict())) == CHECK_KEYS
    rows = s.rows()
    _check_rows(rows)
    assert _row(rows, "pixels changed by more than 1 q").value == pytest.approx(
        100 * check.frac_gt_1q)
    assert _row(rows, "pixels changed by more than 2 q").unit == "%"
    assert _row(rows, "largest change").value == check.max_change_q
    assert _row(rows, "mean level of the image").value == check.mean_level


def test_scene_summaries(est):
    assert set(est.scene) == {"matte_grey", "paper", "fabric"}
    for name, sv in est.scene.items():
        s = sv.summary()
        d = _same_json(SceneSummary, s, sv.to_dict())
        assert list(d) == SCENE_KEYS and list(d["measurements"][0]) == MEASUREMENT_KEYS
        assert s.name == name and len(s.measurements) == len(sv.measurements)
        for m, u, ms in zip(sv.measurements, sv.used, s.measurements):
            assert ms == m.summary(u) and ms.used is bool(u)
            _same_json(SceneMeasurementSummary, ms, dict(m.to_dict(), used=bool(u)))
            assert "used" not in m.to_dict()
            assert ms.y == pytest.approx(m.y)
        rows = s.rows()
        _check_rows(rows)
        vs = _row(rows, "scene variation V_S")
        assert (vs.value, vs.error) == (sv.V_S, sv.V_S_err)
        assert _row(rows, "goodness of fit Q").value == sv.Q
        assert _row(rows, "levels used").value == sum(sv.used)
        m_rows = s.measurements[0].rows()
        _check_rows(m_rows)
        assert _row(m_rows, "mean μ̂_D").value == sv.measurements[0].mu_D


def test_scene_summary_of_one_level(est):
    """One level: χ² and Q are NaN in the result, None in the summary."""
    sv = fit_scene_variation(est.scene["paper"].measurements[:1], name="paper")
    s = sv.summary()
    assert (s.chi2, s.dof, s.Q) == (None, 0, None)
    _same_json(SceneSummary, s, sv.to_dict())
    assert _row(s.rows(), "χ²").value is None


# ---------------------------------------------------------------------------------------------
# damaged objects
# ---------------------------------------------------------------------------------------------
def _set(*path: Any, value: Any) -> tuple[tuple, Callable[[dict], None]]:
    def damage(d: dict) -> None:
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
    return path, damage


def _drop(*path: Any) -> tuple[tuple, Callable[[dict], None]]:
    def damage(d: dict) -> None:
        for k in path[:-1]:
            d = d[k]
        del d[path[-1]]
    return path, damage


#: (summary, (key path, damage)): a value of the wrong type, or a required key left out
DAMAGE = [
    ("noise", _set("A", value="0.003")),
    ("noise", _set("points", 1, "mu", value="x")),
    ("noise", _set("cov", 0, 1, value="x")),
    ("noise", _set("roi", value=[1, 2, 3])),
    ("noise", _drop("verdict")),
    ("noise", _drop("points", 0, "used")),
    ("dark", _set("n_hot", value=1.5)),
    ("dark", _drop("s")),
    ("fp", _set("config_levels", 2, value="x")),
    ("fp", _set("config_ids", 0, value=1.5)),
    ("fp", _drop("n1")),
    ("plan", _set("inputs", "bits", value="8")),
    ("plan", _set("n2_alternatives", "paper", value=None)),
    ("plan", _set("warnings", 0, value=3)),
    ("plan", _drop("inputs", "A")),
    ("check", _set("n_pixels", value="many")),
    ("check", _drop("frac_gt_1q")),
    ("scene", _set("measurements", 0, "roi", value=[1, 2, 3])),
    ("scene", _set("V_S", value="big")),
    ("scene", _drop("measurements", 2, "used")),
]


def _summary_of(est, what: str) -> tuple[type, Any]:
    return {"noise": (PhotonTransferSummary, est.noise.summary()),
            "dark": (DarkSummary, est.dark.summary()),
            "fp": (FixedPatternSummary, est.fp.summary()),
            "plan": (PlanSummary, est.plan.summary(est.warnings)),
            "check": (CorrectionCheckSummary, CorrectionCheckSummary.of(est.check)),
            "scene": (SceneSummary, est.scene["paper"].summary())}[what]


@pytest.mark.parametrize("what, damage", DAMAGE,
                         ids=[f"{w}-{'.'.join(map(str, p))}" for w, (p, _) in DAMAGE])
def test_damaged_object_names_the_key(est, what, damage):
    """The error names the file and the keys down to the damaged one (in order)."""
    path, spoil = damage
    cls, summary = _summary_of(est, what)
    d = json.loads(json.dumps(summary.to_dict()))
    spoil(d)
    with pytest.raises(CcdError) as err:
        cls.from_dict(d, "calibration.json")
    message = str(err.value)
    assert message.startswith("calibration.json")
    keys = [re.escape(k) for k in path if isinstance(k, str)]
    assert re.search(".*".join(keys), message), message
    if spoil.__qualname__.startswith("_drop"):
        assert "missing" in message
