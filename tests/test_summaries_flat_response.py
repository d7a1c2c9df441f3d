"""The records ``calibration.json`` stores for the flat field (de Lasarte et al. 2007) and the
response (Tsin, Ramesh & Kanade 2001): ``FlatFieldSummary`` / ``FlatChannelSummary``,
``ResponseSummary`` / ``ResponseScaleSummary`` and the agreement's summaries (sec. 4.2).

Each record is built from a fresh result on the demo sessions of ``assets/`` (fixed data): its
JSON is the result's ``to_dict()`` (the response's without ``files``), it reads back equal, a
damaged object is refused naming the key's path, and its rows show the result's figures.
"""
from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ccdcore.common import json_safe
from ccdcore.errors import CcdError
from ccdcore.flatfield.fit import (FlatChannel, FlatChannelSummary, FlatFieldSummary, flat_field,
                               flat_field_from_session)
from ccdcore.response.agreement import (AgreementSummary, ChannelAgreement,
                                        ChannelAgreementSummary, PairAgreement,
                                        PairAgreementSummary)
from ccdcore.response.brackets import load_bracket
from ccdcore.response.hdr import ResponseModel
from ccdcore.response.methods import (ResponseScaleSummary, ResponseSummary, response_of)
from ccdcore.session import open_session

ASSETS = Path(__file__).resolve().parents[1] / "assets"


def text(d):
    return json.dumps(d, allow_nan=False)


def round_trips(cls, s):
    """``cls.from_dict`` of ``s``'s JSON text is ``s``, and the JSON is already plain."""
    d = s.to_dict()
    assert json_safe(d) == d
    assert cls.from_dict(json.loads(text(d)), "calibration.json") == s


def refused(cls, d, path):
    """``cls.from_dict(d)`` raises a CcdError naming the file and the key's path (``path`` a
    regular expression: arrays' items may be numbered)."""
    with pytest.raises(CcdError) as err:
        cls.from_dict(d, "calibration.json")
    message = str(err.value)
    assert message.startswith("calibration.json: ") and re.search(path, message), message
    return message


def row(rows, label):
    found = [r for r in rows if r.label == label]
    assert len(found) == 1, (label, [r.label for r in rows])
    return found[0]


# ---- flat field ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flats():
    session = open_session(ASSETS / "delasarte07")
    rng = np.random.default_rng(1)
    base = rng.normal(100.0, 3.0, (16, 12))
    base[0, 0] = 5.0                     # below the dark level: flagged
    arrays = flat_field([rng.normal(10.0, 1.0, (16, 12)) for _ in range(3)], [base])
    return {"auto": flat_field_from_session(session, base="auto"),
            "zdi": flat_field_from_session(session, setting="ZDI"),
            "arrays": arrays}


@pytest.mark.parametrize("name", ["auto", "zdi", "arrays"])
def test_flat_summary_is_the_stored_json(flats, name):
    ff = flats[name]
    s = ff.summary()
    assert text(s.to_dict()) == text(ff.to_dict()) == text(json_safe(ff.to_dict()))
    assert list(s.to_dict()) == ["layout", "shape", "n_dark", "n_base", "channels", "n_flagged",
                                 "noise_limit", "window", "flag_rule", "base", "setting",
                                 "dark_exposure", "notes"]
    round_trips(FlatFieldSummary, s)
    for c, cs in zip(ff.channels, s.channels):
        assert cs == c.summary() and text(cs.to_dict()) == text(c.to_dict())
        round_trips(FlatChannelSummary, cs)


def test_flat_summary_values(flats):
    s = flats["auto"].summary()
    assert s.base == (3, 0.04) and isinstance(s.base[0], int)
    assert s.setting == "NZDI" and s.dark_exposure == 0.04 and s.shape == (64, 96, 3)
    assert [c.name for c in s.channels] == ["R", "G", "B"]
    a = flats["arrays"].summary()
    assert a.base is None and a.setting is None and a.n_flagged == 1 and a.n_base == 1
    # a number that is not finite is None in the record
    assert FlatChannel("L", math.nan, 1.0, 2.0, 0, 4).summary().k is None


def test_flat_summary_refuses_damage(flats):
    d = flats["auto"].summary().to_dict()
    bad = copy.deepcopy(d)
    bad["channels"][1]["k"] = "120"
    assert "'120'" in refused(FlatFieldSummary, bad, r"channels(\[1\])?\.k'? must be")
    bad = copy.deepcopy(d)
    del bad["n_base"]
    refused(FlatFieldSummary, bad, "'n_base' is missing")
    bad = copy.deepcopy(d)
    del bad["channels"][0]["n_pixels"]
    refused(FlatFieldSummary, bad, r"channels(\[0\])?\.n_pixels' is missing")
    bad = copy.deepcopy(d)
    bad["base"] = [3, 0.04, 1]
    refused(FlatFieldSummary, bad, "'base' must be")
    bad = copy.deepcopy(d)
    bad["base"] = ["three", 0.04]
    refused(FlatFieldSummary, bad, r"'base(\[0\])?' must be")
    bad = copy.deepcopy(d)
    bad["n_flagged"] = 1.5
    refused(FlatFieldSummary, bad, "'n_flagged' must be an integer")


def test_flat_rows(flats):
    ff = flats["auto"]
    s = ff.summary()
    rows = s.rows()
    assert 5 <= len(rows) <= 12
    assert row(rows, "flagged pixels").value == s.n_flagged == int(ff.flags.sum())
    assert row(rows, "base image").value == ff.base.n
    assert row(rows, "base image").shown == f"level 3, exposure 0.04 s ({ff.base.n} frames)"
    assert row(rows, "dark image").value == ff.dark.n
    assert row(rows, "offset setting").text == "NZDI"
    for c in ff.channels:
        r = row(rows, f"k, {c.name}")
        assert r.value == c.k and r.unit == "DN"
    assert row(rows, "dark pixels at 0").value == 0.0 and row(rows, "dark pixels at 0").text is None
    # a zero-clipped dark image: its largest fraction, flagged in words
    z = flats["zdi"].summary()
    worst = max(c.dark_zero_fraction for c in z.channels)
    r = row(z.rows(), "dark pixels at 0")
    assert worst > 0.01 and r.value == pytest.approx(100 * worst) and r.text.endswith("clipped at zero")
    c = s.channels[0]
    crows = c.rows()
    assert row(crows, "k").value == c.k and row(crows, "⟨DL_0⟩").value == c.dark_level
    assert row(crows, "⟨DL_B⟩").value == c.base_level
    assert row(crows, "flagged").value == c.n_flagged


# ---- response --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def responses():
    mono = load_bracket(open_session(ASSETS / "tsin01"))
    rgb = load_bracket(open_session(ASSETS / "tsin01-camera"))
    return {"tsin": response_of(mono, "tsin"), "debevec": response_of(mono, "debevec"),
            "rgb-wb": response_of(rgb, "tsin", white_balance=True)}


def stored(result):
    """What ``calibrate`` stores under ``estimates["response"]``."""
    return json_safe({k: v for k, v in result.to_dict().items() if k != "files"})


@pytest.mark.parametrize("name", ["tsin", "debevec", "rgb-wb"])
def test_response_summary_is_the_stored_json(responses, name):
    r = responses[name]
    s = r.summary()
    assert text(s.to_dict()) == text(stored(r))
    keys = list(r.to_dict())
    assert keys[keys.index("exposure_times") + 1] == "files"
    assert [k for k in keys if k != "files"] == list(s.to_dict())
    assert r.to_dict()["files"] == list(r.files)
    round_trips(ResponseSummary, s)
    round_trips(ResponseScaleSummary, s.scale)
    round_trips(AgreementSummary, s.agreement)
    assert s.agreement == r.agreement.summary_record()
    assert s.agreement.line() == r.agreement.summary()
    for ch, cs in zip(r.agreement.channels, s.agreement.channels):
        assert cs == ch.summary() and text(cs.to_dict()) == text(ch.to_dict())
        round_trips(ChannelAgreementSummary, cs)
        for p, ps in zip(ch.pairs, cs.pairs):
            assert text(ps.to_dict()) == text(p.to_dict())
            round_trips(PairAgreementSummary, ps)


def test_response_summary_values(responses):
    s = responses["rgb-wb"].summary()
    assert s.channels == ("R", "G", "B") and s.levels == 256
    assert s.scale == ResponseScaleSummary(230, 230 / 255, False)
    assert len(s.g) == 3 and len(s.g[0]) == 256 and s.white_balance == (True, True, True)
    assert set(s.notes) == {"R", "G", "B"} and all(isinstance(n, tuple) for n in s.notes.values())
    # the warnings are the verdict's line when it is not trusted (ccdcore.response.verdict)
    res = responses["rgb-wb"]
    assert s.warnings == res.warnings()
    assert s.warnings == (() if res.verdict.trusted else (res.verdict.line(),))
    assert s.verdict == res.verdict
    assert s.agreement["G"].channel == "G"


def test_agreement_figures_not_finite_are_none():
    nan = math.nan
    p = PairAgreement(0, 1, 0, nan, nan, 2.0, nan)
    ps = p.summary()
    assert (ps.rms, ps.rms_fitted, ps.ratio, ps.ratio_fitted) == (None, None, 2.0, None)
    round_trips(PairAgreementSummary, ps)
    c = ChannelAgreement("L", (p,), nan, nan, nan, 0, 0)
    assert c.summary().rms is None and text(c.summary().to_dict()) == text(c.to_dict())
    round_trips(ChannelAgreementSummary, c.summary())


def test_older_products_without_the_later_keys(responses):
    """Products made before white balance and the agreement lack those keys: they read with
    the defaults."""
    d = stored(responses["tsin"])
    for key in ("white_balance", "agreement", "warnings"):
        del d[key]
    s = ResponseSummary.from_dict(d, "calibration.json")
    assert s.white_balance == () and s.agreement is None and s.warnings == ()
    assert set(s.models("calibration.json")) == {"L"}


def test_response_summary_refuses_damage(responses):
    d = stored(responses["tsin"])
    bad = copy.deepcopy(d)
    bad["g"][0][5] = "0.1"
    refused(ResponseSummary, bad, r"'g(\[0\]\[5\])?' must be")
    bad = copy.deepcopy(d)
    del bad["levels"]
    refused(ResponseSummary, bad, "'levels' is missing")
    bad = copy.deepcopy(d)
    bad["scale"]["offset"] = "no"
    refused(ResponseSummary, bad, "'scale.offset' must be true/false")
    bad = copy.deepcopy(d)
    bad["notes"]["L"] = "one note"
    refused(ResponseSummary, bad, "'notes.L' must be an array")
    # the agreement: through the response, records.py names 'agreement' (an optional record
    # reports its own key for now); read alone, the key's whole path
    bad = copy.deepcopy(d)
    bad["agreement"]["channels"][0]["pairs"][2]["rms"] = "big"
    refused(ResponseSummary, bad,
            r"'agreement(\.channels(\[0\])?\.pairs(\[2\])?\.rms)?' must be")
    refused(AgreementSummary, bad["agreement"], r"'channels(\[0\])?\.pairs(\[2\])?\.rms' must be")
    refused(ChannelAgreementSummary, bad["agreement"]["channels"][0],
            r"'pairs(\[2\])?\.rms' must be")
    bad = copy.deepcopy(d)
    del bad["agreement"]["code_range"]
    refused(ResponseSummary, bad, r"'agreement(\.code_range)?' (is missing|must be)")
    refused(AgreementSummary, bad["agreement"], "'code_range' is missing")
    bad = copy.deepcopy(d)
    bad["agreement"]["code_range"] = [10, 245, 3]
    refused(AgreementSummary, bad["agreement"], "'code_range' must be")
    bad = copy.deepcopy(d)
    del bad["agreement"]["channels"][0]["pairs"][0]["ratio"]
    refused(PairAgreementSummary, bad["agreement"]["channels"][0]["pairs"][0],
            "'ratio' is missing")
    bad = copy.deepcopy(d)
    bad["iterations"] = [3.5]
    refused(ResponseSummary, bad, "'iterations' must be an integer")


def test_response_rows(responses):
    r = responses["tsin"]
    s = r.summary()
    rows = s.rows()
    # method, 3 noise terms, 2 agreements, 3 exposure rows, the method chosen, the verdict
    assert 5 <= len(rows) <= 16
    assert row(rows, "method").text == "tsin"
    assert row(rows, "exposures used").text == r.exposures.used
    c = r["L"]
    for key, symbol in (("sigma_s", "σ_s"), ("sigma_c1", "σ_c1"), ("sigma_c2", "σ_c2")):
        x = row(rows, f"{symbol}, L")
        assert (x.value, x.error) == (getattr(c, key), getattr(c, f"{key}_err"))
    assert row(rows, "σ_c2, L").unit == "DN"
    ag = row(rows, "agreement RMS, own ratios")
    assert ag.value == r.agreement.rms and ag.unit == "DN"
    assert row(rows, "agreement RMS, fitted ratios").value == r.agreement.rms_fitted
    assert row(rows, "verdict").meaning == r.verdict.line()
    assert row(rows, "verdict").text == r.verdict.status
    wb = responses["rgb-wb"].summary()
    # + 6 noise terms of two more channels
    assert len(wb.rows()) == len(rows) + 6 + len(wb.exposures.off_runs()) \
        - len(s.exposures.off_runs())
    assert row(wb.rows(), "verdict").meaning == responses["rgb-wb"].verdict.line()
    assert row(wb.rows(), "σ_s, B").value == wb.sigma_s[2]
    a = s.agreement
    assert [x.value for x in a.rows()] == [a.rms, a.rms_fitted, a.rms_blend,
                                           sum(ch.n for ch in a.channels)]
    ch = a.channels[0]
    assert [x.value for x in ch.rows()] == [ch.rms, ch.rms_fitted, ch.rms_blend, ch.n]
    p = ch.pairs[0]
    assert [x.value for x in p.rows()] == [p.rms, p.rms_fitted, p.ratio, p.ratio_fitted]


# ---- the curves as the HDR merge takes them --------------------------------------------------
@pytest.mark.parametrize("name", ["tsin", "rgb-wb"])
def test_models_are_the_results_curves(responses, name):
    r = responses[name]
    models = ResponseSummary.from_dict(stored(r), "calibration.json").models("calibration.json")
    assert list(models) == list(r.channels)
    for ch, m in models.items():
        want = ResponseModel.of(r[ch])
        assert isinstance(m, ResponseModel)
        for key in ("g", "a", "b"):
            np.testing.assert_array_equal(getattr(m, key), getattr(want, key))
        assert (m.sigma_s, m.sigma_c1, m.sigma_c2) == (want.sigma_s, want.sigma_c1,
                                                       want.sigma_c2)


def _damaged(d, change):
    d = copy.deepcopy(d)
    change(d)
    return ResponseSummary.from_dict(d, "calibration.json")


@pytest.mark.parametrize("change, message", [
    (lambda d: d["g"][0].reverse(), "g of channel L is not a finite non-decreasing curve"),
    (lambda d: d["g"][0].__setitem__(7, None), "g of channel L is not a finite non-decreasing"),
    (lambda d: d["g"][0].__delitem__(slice(1, None)), "g of channel L is not a finite"),
    (lambda d: d["a"][0].__setitem__(0, -1.0), "a, b of channel L do not match or a is not "
                                               "positive"),
    (lambda d: d["b"][0].pop(), "a, b of channel L do not match"),
    (lambda d: d.__setitem__("g", []), "g has 0 entries for 1 channels"),
    (lambda d: d.__setitem__("sigma_c2", []), "sigma_c2 has 0 entries for 1 channels"),
])
def test_models_refuse_a_damaged_response(responses, change, message):
    s = _damaged(stored(responses["tsin"]), change)
    with pytest.raises(CcdError, match="^product/calibration.json: damaged response estimate: "
                                       + message):
        s.models("product/calibration.json")


def test_models_take_missing_noise_terms_as_zero(responses):
    s = _damaged(stored(responses["tsin"]), lambda d: d["sigma_c1"].__setitem__(0, None))
    assert s.models()["L"].sigma_c1 == 0.0
