"""Sec. 3.2 on a bracket that behaves like a real camera (the committed demo
``assets/tsin01-camera``: sRGB-like tone curve with toe and knee, structured scene, vignetting,
exposure errors, Bayer demosaicing, JPEG), where the estimator as first built fell behind the
classic methods: what a real bracket taught, pinned without real data."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ccdcore.response.brackets import load_bracket
from ccdcore.response.methods import response_of
from ccdcore.response.scale import rms_error
from ccdcore.session import open_session

DEMO = Path(__file__).resolve().parents[1] / "assets" / "tsin01-camera"


@pytest.fixture(scope="module")
def camera():
    s = open_session(DEMO)
    br = load_bracket(s)
    truth = json.loads((DEMO / "truth.json").read_text())
    return br, np.asarray(truth["g"], np.float64), response_of(br, "tsin"), \
        response_of(br, "debevec")


def test_sec32_converges_and_predicts_like_the_best_classic_method(camera):
    br, _, tsin, deb = camera
    assert all(r.converged for r in tsin.responses)
    assert tsin.warnings() == ()
    # measured: 4.13 / 3.84 DN against Debevec's 4.09 / 3.81; the estimator before the real-data
    # changes gave 4.47 / 4.27 here (and collapsed on a real bracket)
    assert tsin.agreement.rms < 1.04 * deb.agreement.rms
    assert tsin.agreement.rms_fitted < 1.04 * deb.agreement.rms_fitted
    # the agreement is in the JSON, per channel and per pair
    d = tsin.to_dict()["agreement"]
    assert [c["channel"] for c in d["channels"]] == list(br)
    assert len(d["channels"][0]["pairs"]) == br["R"].n_images - 1


def test_sec32_recovers_the_camera_curve(camera):
    """Against the true (knee-shaped) curve, within 1.6 times the classic method's error
    (measured 0.019-0.030 against Debevec's 0.017-0.021); never a collapsed curve."""
    br, truth, tsin, deb = camera
    for ch in br:
        e = rms_error(tsin[ch].g, truth)
        assert e < 1.6 * rms_error(deb[ch].g, truth), (ch, e)
        g = tsin[ch].g[10:246]
        assert np.all(np.diff(g) > 0), ch                # strictly increasing where readable
