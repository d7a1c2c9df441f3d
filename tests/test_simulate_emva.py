"""The emva1288 simulator preset: an EMVA 1288 exposure-time series whose datasheet recovers the
camera it was drawn from.

Tolerances
----------
* Figures against truth: 4 of the datasheet's stated standard errors (fixed seeds; over 40 seeds
  of this 64x48 series the z-scores of every tested figure had a standard deviation of 0.7-1.2),
  and each stated error below about twice the largest relative error seen over 12 other seeds
  (``RECOVERED``), so a figure that is merely within a wide error does not pass.
* The simulated frames against the model's expectations: 4 standard errors of the statistic
  (a pair's mean: √(σ²/(2N)); a variance from N pixels: √(2/(N − 1)) σ²).
* The truth's split against the release 4.0 equations written out here, on the float32 truth
  maps: 1e-5 relative (the maps are the float64 patterns rounded to float32, a relative 6e-8 per
  value; the parts are sums of squares without cancellation).
* Against the reference implementation (emva1288 1.0.2) on the same files: 1e-7 relative, the
  remainder of its ``leastsq`` fits (see tests/test_datasheet.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.emva.datasheet import emva_figures
from ccdcore.io.frames import read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate
from ccdcore.simulate.emva import DESCRIPTOR_NAME

SIZE = (64, 48)          # W x H: M = 48 rows, N = 64 columns
Z = 4.0
PARTS = ("row", "col", "pixel")
#: the figures the datasheet must recover, with the largest relative error it may state
RECOVERED = {"K": 0.03, "QE": 0.03, "sigma_d": 0.25, "u_I_mean": 0.03, "u_I_var": 0.07,
             "DSNU1288": 0.05, "DSNU1288_row": 0.12, "DSNU1288_col": 0.08,
             "DSNU1288_pixel": 0.07, "PRNU1288_row": 0.025, "PRNU1288_col": 0.015,
             "PRNU1288_pixel": 0.008}


@pytest.fixture(scope="module", params=(1, 2))
def series(request, tmp_path_factory):
    root = tmp_path_factory.mktemp(f"emva{request.param}")
    truth = simulate("emva1288", root, seed=request.param, size=SIZE)
    figures = emva_figures(root / DESCRIPTOR_NAME, with_ptc=False)
    return root, truth, figures


def _split(a: np.ndarray) -> dict[str, float]:
    """The release 4.0 split of a noiseless image (σ²_y.stack = 0), from the equations:
    s²_y.cav = (1/N) Σ_n (μ[n] − μ)², s²_y.rav = (1/M) Σ_m (μ[m] − μ)², s²_y with N − 1,
    col = [(MN − M) cav − N (s² − rav)]/(MN − M − N), row = [(MN − N) rav − M (s² − cav)]/(…),
    pixel = MN (s² − cav − rav)/(…)."""
    a = a.astype(np.float64)
    M, N = a.shape
    mu = a.mean()
    s2 = a.var(ddof=1)
    cav = np.mean((a.mean(axis=0) - mu) ** 2)
    rav = np.mean((a.mean(axis=1) - mu) ** 2)
    d = M * N - M - N
    return {"col": ((M * N - M) * cav - N * (s2 - rav)) / d,
            "row": ((M * N - N) * rav - M * (s2 - cav)) / d,
            "pixel": M * N * (s2 - cav - rav) / d, "total": s2}


# --------------------------------------------------------------------------------------------
# the files
# --------------------------------------------------------------------------------------------
def test_descriptor_and_manifest_hold_the_series(series):
    root, truth, figures = series
    lines = (root / DESCRIPTOR_NAME).read_text().splitlines()
    assert lines[:2] == ["v 4.0", "n 12 64 48"]
    desc, folder = open_session(root / DESCRIPTOR_NAME), open_session(root)
    assert desc.ok and folder.ok and not desc.warnings and desc.source == "emva1288"
    key = (lambda r: (r.relpath, r.role, r.level, r.exposure, r.photons))
    assert [key(r) for r in desc.frames] == [key(r) for r in folder.frames]
    steps, L = truth["steps"], truth["L"]
    assert len(desc.by_role("ptc")) == 2 * steps + L and len(desc.by_role("dark")) == 2 * steps + L
    levels = desc.ptc_levels()
    assert [len(levels[lv]) for lv in sorted(levels)] == [2] * steps + [L]
    for lv, t, p in zip(sorted(levels), truth["exposures"], truth["photons"]):
        assert levels[lv][0].exposure == t and levels[lv][0].photons == p
    for rec in desc.frames[:4]:
        frame = desc.read(rec)
        assert frame.dtype == np.uint16 and frame.shape == (48, 64)
    # the manifest gives the very same figures
    a, b = figures.to_dict(), emva_figures(root, with_ptc=False).to_dict()
    assert {k for k in a if a[k] != b[k]} == {"source"}


def test_series_spans_dark_to_beyond_saturation(series):
    _, truth, f = series
    Y = [p.u_y - p.u_y_dark for p in f.points]
    sat = f.index_u_ysat
    assert Y[0] < 0.01 * Y[sat]                      # the first point is nearly dark
    assert sat < len(Y) - 1                          # points beyond the saturation point
    assert max(Y[sat + 1:]) < 1.1 * Y[sat] and f.points[-1].s2_y < 0.1 * f.points[sat].s2_y
    spatial = f.spatial.u_y - f.spatial_dark.u_y
    assert 0.4 < spatial / Y[sat] < 0.6              # the spatial set at about 50 %
    assert not f.quantisation_limited and f.sigma_y_dark_measured > 0.5
    assert f.notes == ()                             # nothing floored, clipped or missing


def test_frames_follow_the_camera_model(series):
    root, truth, _ = series
    t_map = load_truth(root)
    D, P = t_map.map("dsnu").astype(np.float64), t_map.map("prnu").astype(np.float64)
    K, s2q, sd0, uI = truth["K"], 1.0 / 12.0, truth["sigma_d"], truth["u_I_mean"]
    off = truth["dark_offset_e"] + D.mean()
    b = truth["black_offset_dn"]
    s = open_session(root)
    levels = s.ptc_levels()
    n = D.size
    # the dark pair at the longest exposure and the bright pair at the middle of the series
    darks = [r for r in s.by_role("dark") if r.exposure == truth["exposures"][-1]]
    mid = len(truth["exposures"]) // 2
    bright = levels[mid + 1]
    t_b, mu_p = bright[0].exposure, bright[0].photons
    for recs, e in ((darks[:2], uI * truth["exposures"][-1]),
                    (bright, truth["qe"] * mu_p * P.mean() + uI * t_b)):
        a, c = (s.read(r).astype(np.float64) for r in recs)
        var = K * K * (e + sd0 ** 2) + s2q
        assert abs((a.mean() + c.mean()) / 2 - (K * (e + off) + b)) < Z * math.sqrt(var / (2 * n))
        assert abs(np.var(a - c) / 2 - var) < Z * math.sqrt(2 / (n - 1)) * var
    # the patterns sit where the maps say: the average images less K·D (dark) and less
    # K·η·μ_p·P (bright less dark) keep only the temporal noise of the average
    sp = levels[len(levels)]
    spd = [r for r in s.by_role("dark") if r.exposure == sp[0].exposure]
    L, t_sp, mu_sp = len(sp), sp[0].exposure, sp[0].photons
    avg_d = sum(s.read(r).astype(np.float64) for r in spd) / L
    avg_b = sum(s.read(r).astype(np.float64) for r in sp) / L
    v_d = (K * K * (uI * t_sp + sd0 ** 2) + s2q) / L
    v_b = (K * K * (truth["qe"] * mu_sp + uI * t_sp + sd0 ** 2) + s2q) / L
    left_d = np.var(avg_d - K * D, ddof=1)
    left_b = np.var(avg_b - avg_d - K * truth["qe"] * mu_sp * P, ddof=1)
    assert abs(left_d - v_d) < Z * math.sqrt(2 / (n - 1)) * v_d
    assert abs(left_b - (v_b + v_d)) < Z * math.sqrt(2 / (n - 1)) * (v_b + v_d)


def test_truth_is_the_release_4_split_of_the_drawn_maps(series):
    root, truth, _ = series
    t = load_truth(root)
    D, P = t.map("dsnu").astype(np.float64), t.map("prnu").astype(np.float64)
    sd, sp = _split(D), _split(P)
    for part in (*PARTS, "total"):
        name = "" if part == "total" else f"_{part}"
        assert truth[f"DSNU1288{name}"] == pytest.approx(math.sqrt(sd[part]), rel=1e-5), part
        assert truth[f"PRNU1288{name}"] == pytest.approx(
            100 * math.sqrt(sp[part]) / P.mean(), rel=1e-5), part
    assert truth["QE"] == pytest.approx(100 * truth["qe"] * P.mean(), rel=1e-6)
    assert truth["generating"] == {"dsnu_row_e": 2.0, "dsnu_col_e": 3.0, "dsnu_pixel_e": 4.0,
                                   "prnu_row_percent": 0.4, "prnu_col_percent": 0.6,
                                   "prnu_pixel_percent": 1.0}


# --------------------------------------------------------------------------------------------
# the datasheet recovers the camera
# --------------------------------------------------------------------------------------------
def test_datasheet_recovers_the_truth(series):
    _, truth, f = series
    d = f.to_dict()
    for name, largest in RECOVERED.items():
        value, err = d[name], d[f"{name}_err"]
        assert value is not None and 0 < err < largest * truth[name], name
        assert abs(value - truth[name]) < Z * err, (name, value, err, truth[name])
    # the release 3.1 total against the definition on the noiseless images (the subtraction of
    # the dark variance keeps a cross term of P and D, see ccdcore.simulate.emva)
    assert abs(f.PRNU1288 - truth["PRNU1288_images"]) < Z * f.PRNU1288_err


def test_dark_current_below_the_range_is_bounded(tmp_path):
    """0.1 e-/s over 0.5 s moves the dark mean by 0.005 DN: half the error of the slope (about
    0.2 e-/s from 8 exposure times of 64x48 pixels), so the figure is bounded, not given."""
    truth = simulate("emva1288", tmp_path, seed=2, size=SIZE, steps=8, L=4, dark_current_e=0.1)
    f = emva_figures(tmp_path / DESCRIPTOR_NAME, with_ptc=False)
    dc = f.dark_current
    assert dc.u_I_mean is None and dc.u_I_var is None
    assert truth["u_I_mean"] < dc.u_I_mean_bound < 2.0 and truth["u_I_var"] < dc.u_I_var_bound
    note = next(n for n in f.notes if n.startswith("u_I_mean is not"))
    assert f"below {dc.u_I_mean_bound:.3g} e-/s" in note and "0.001 to 0.5 s" in note
    d = f.to_dict()
    assert d["u_I_mean"] is None and d["u_I_mean_err"] is None


# --------------------------------------------------------------------------------------------
# determinism, the command line, the reference implementation
# --------------------------------------------------------------------------------------------
def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes(tmp_path):
    small = dict(size=(16, 12), steps=4, L=3)
    a, b, c = (tmp_path / x for x in "abc")
    simulate("emva1288", a, seed=7, **small)
    simulate("emva1288", b, seed=7, **small)
    simulate("emva1288", c, seed=8, **small)
    fa, fb, fc = _files(a), _files(b), _files(c)
    assert len(fa) == 4 * 4 + 2 * 3 + 5 and fa == fb
    frames = [k for k in fa if k.startswith("images/")]
    assert all(fa[k] != fc[k] for k in frames)


def test_command_line_writes_the_preset(tmp_path, capsys):
    out = tmp_path / "cam"
    assert main(["simulate", "emva1288", str(out), "--seed", "3", "--size", "24x16"]) == 0
    assert "wrote emva1288 session" in capsys.readouterr().out
    truth = load_truth(out)
    assert truth["preset"] == "emva1288" and truth["seed"] == 3 and truth["size"] == [24, 16]
    assert open_session(out / DESCRIPTOR_NAME).ok
    assert read_image(out / "images/image0000.tif").shape == (16, 24)


def test_reference_implementation_reads_the_descriptor(series, monkeypatch):
    import logging

    # emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (docs/notes.md)
    monkeypatch.setattr(np, "asfarray", lambda a, dtype=np.float64: np.asarray(a, dtype=dtype),
                        raising=False)
    from emva1288.process import Data1288, LoadImageData, ParseEmvaDescriptorFile, Results1288

    root, _, f = series
    logging.disable(logging.INFO)
    try:
        parsed = ParseEmvaDescriptorFile(str(root / DESCRIPTOR_NAME))
        ref = Results1288(Data1288(LoadImageData(parsed.images).data).data)
    finally:
        logging.disable(logging.NOTSET)
    names = ("K", "QE", "sigma_d", "u_I_mean", "u_I_var", "DSNU1288", "PRNU1288",
             *(f"{w}_{p}" for w in ("DSNU1288", "PRNU1288") for p in PARTS))
    for name in names:
        assert f.to_dict()[name] == pytest.approx(float(getattr(ref, name)), rel=1e-7), name


# ------------------------------------------------------------------ a real sensor's nonlinearity
def test_nonlinearity_bends_the_response_and_is_off_by_default(tmp_path):
    """``nonlinearity`` = a multiplies K e by 1 + a(1 − 8x(1 − x)): +a at the ends, −a at half
    of saturation; off (0) the frames are the linear camera's bytes and the truth has no key."""
    from ccdcore.simulate.emva import bowl

    x = np.array([1e-9, 0.25, 0.5, 1.0])
    np.testing.assert_allclose(bowl(x * 100.0, 0.005, 100.0) / (x * 100.0),
                               [1.005, 0.9975, 0.995, 1.005], rtol=1e-9)
    lin = simulate("emva1288", tmp_path / "lin", seed=2, size=(32, 24), steps=5, L=3)
    off = simulate("emva1288", tmp_path / "off", seed=2, size=(32, 24), steps=5, L=3,
                   nonlinearity=0.0)
    bent = simulate("emva1288", tmp_path / "bent", seed=2, size=(32, 24), steps=5, L=3,
                    nonlinearity=0.02)
    assert "nonlinearity" not in lin and "nonlinearity" not in off
    assert bent["nonlinearity"]["amplitude"] == 0.02
    assert bent["nonlinearity"]["saturation_dn"] == pytest.approx(0.1 * 35000.0)
    name = "images/image0008.tif"           # the third bright pair, near half of saturation
    a = read_image(tmp_path / "lin" / name).astype(float)
    assert np.array_equal(a, read_image(tmp_path / "off" / name))
    b = read_image(tmp_path / "bent" / name).astype(float)
    signal = a.mean() - 100.0                       # black offset 100 DN
    x_mid = signal / (0.1 * 35000.0)
    want = signal * 0.02 * (1.0 - 8.0 * x_mid * (1.0 - x_mid))
    # the same noise stream: the difference is the bend, within the pair mean's rounding
    assert b.mean() - a.mean() == pytest.approx(want, abs=0.1 * abs(want) + 0.05)
    assert want < 0                                  # below the line near half of saturation


def test_nonlinearity_is_checked(tmp_path):
    from ccdcore.errors import CcdError

    with pytest.raises(CcdError, match="nonlinearity"):
        simulate("emva1288", tmp_path / "x", seed=0, size=(32, 24), steps=5, L=3,
                 nonlinearity=0.1)
