"""The bracket's own exposures and the response verdict, on a camera-like bracket whose listed
exposures are wrong for part of it (the simulator's ``real-listed-wrong`` bundle: 12 frames
listed one stop apart, four neighbouring pairs actually at ratio 1, as two real Nikon brackets
showed): the estimate finds them, the default response uses them, the result at the listed
exposures is not trusted and its suggestion helps."""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ccdcore.response.brackets import load_bracket
from ccdcore.response.exposures import estimate_exposures
from ccdcore.response.methods import response_of
from ccdcore.response.verdict import (DOUBTFUL, FAILED, TRUSTED, ResponseVerdict, at_start,
                                      response_verdict)
from ccdcore.session import open_session
from ccdcore.simulate import simulate

SIZE = (128, 96)
ASSETS = Path(__file__).resolve().parents[1] / "assets"


def _bracket(root: Path, seed: int):
    out = root / f"wrong{seed}"
    simulate("tsin01", out, seed=seed, camera="real-listed-wrong", size=SIZE)
    truth = json.loads((out / "truth.json").read_text())
    return out, load_bracket(open_session(out)), truth


@pytest.fixture(scope="module")
def wrong(tmp_path_factory):
    return _bracket(tmp_path_factory.mktemp("listed"), 1)


@pytest.fixture(scope="module")
def results(wrong):
    _, br, _ = wrong
    return response_of(br), response_of(br, exposures="listed")


def _true_ln_ratios(truth) -> np.ndarray:
    """The true ln a_{k+1}/a_k, averaged over the channels (each frame's gain includes its
    white balance)."""
    A = np.asarray([f["a"] for f in truth["frames"]], np.float64)
    return np.diff(np.log(A), axis=0).mean(axis=1)


@pytest.mark.parametrize("seed", [1, 2, 4])
def test_estimated_ratios_recover_the_truth_within_their_errors(tmp_path, seed):
    """Every pair's ln ratio within 3.5 of its stated standard errors of the truth (measured
    on seeds 1-5: at most 2.8 but for the darkest pair of seed 3, 4.0); the listed exposures
    are found wrong and the wrong pairs named, as one run."""
    _, br, truth = _bracket(tmp_path, seed)
    ex = estimate_exposures(br)
    assert ex.used == "estimated" and ex.converged
    s = ex.summary()
    lr = np.diff(np.log(ex.estimated))
    err = np.asarray([p.error / p.estimated for p in s.pairs])
    z = (lr - _true_ln_ratios(truth)) / err
    assert np.all(np.abs(z) < 3.5), np.round(z, 2)
    # the four pairs at half the listed ratio, k04 .. k08, named as one run
    runs = [r for r in s.off_runs() if "s0_k04 to s0_k08" in r]
    assert len(runs) == 1, s.off_runs()
    assert 0.45 <= float(runs[0].split("step ")[1].split("×")[0]) <= 0.55
    wrong = [p.j for p in s.off_pairs() if p.factor < 0.7]
    assert wrong == [4, 5, 6, 7]


def test_listed_exposures_kept_when_right():
    """The committed camera demo's listed exposures are right within its 3 % errors: kept."""
    br = load_bracket(open_session(ASSETS / "tsin01-camera"))
    ex = estimate_exposures(br)
    assert ex.used == "listed"
    assert ex.summary().off_runs() == ()


def test_gauge_follows_the_majority_of_pairs(wrong):
    """The u-ambiguity is fixed by the pairs that agree with their listed ratios: the right
    pairs come out at their listed ratio within 10 %, not rescaled towards the wrong ones."""
    _, br, _ = wrong
    s = estimate_exposures(br).summary()
    right = [p.factor for p in s.pairs if p.j not in (4, 5, 6, 7)]
    assert all(0.9 < f < 1.1 for f in right), right


def test_default_response_uses_the_brackets_own_exposures(results):
    """The default result predicts the bracket within 1.15x of its fitted-ratio figure (the
    curve's shape alone); at the listed exposures it is off by far more. Measured: 3.99 / 3.86
    DN against 11.2 / 4.6 DN."""
    own, listed = results
    assert own.exposures.used == "estimated"
    assert own.agreement.rms < 1.15 * own.agreement.rms_fitted
    assert listed.agreement.rms > 2.0 * own.agreement.rms
    assert own.verdict.status == TRUSTED
    assert all(r.converged and not at_start(r.g, own.levels) for r in own.responses)
    # the product's record holds the exposures, the verdict and which curve
    d = own.summary()
    assert d.verdict == own.verdict and d.exposures.used == "estimated"
    assert d.requested == "auto" and d.method in ("tsin", "debevec")


def test_listed_exposures_give_a_doubtful_verdict_whose_next_step_helps(results):
    own, listed = results
    v = listed.verdict
    assert v.status == DOUBTFUL
    assert v.next_step == "--exposures estimated"
    assert v.frames                                   # the worst pair's frames, named
    assert listed.warnings() == (v.line(),)
    # the suggestion, followed, gives a trusted result that predicts better
    assert own.verdict.status == TRUSTED
    assert own.agreement.rms < 0.6 * listed.agreement.rms


def test_a_curve_at_its_starting_line_is_failed_not_converged(results):
    """A sec. 3.2 result whose curve never left the straight starting line is failed, even when
    its fit says converged (what the real brackets showed before the exposures were
    estimated)."""
    own, _ = results
    L = own.levels
    line = np.arange(L, dtype=np.float64) / (L - 1)
    stuck = tuple(replace(r, g=line.copy(), method="tsin", converged=True)
                  for r in own.responses)
    bad = replace(own, method="tsin", responses=stuck, verdict=None)
    v = response_verdict(bad, own.compared)
    assert v.status == FAILED and "starting line" in v.reason
    assert bad.warnings() == (v.line(),)


def test_a_clearly_better_challenger_makes_the_result_doubtful(results):
    """Another method's curve that predicts the bracket clearly better: doubtful, and the next
    step names that method."""
    own, _ = results
    other = replace(own.agreement, rms=own.agreement.rms / 2.0)
    v = response_verdict(replace(own, method="tsin"), {"debevec": other})
    assert v.status == DOUBTFUL and v.next_step == "--method debevec"
    same = replace(own.agreement, rms=own.agreement.rms * 0.99)
    assert response_verdict(replace(own, method="tsin"), {"debevec": same}).status == TRUSTED


def test_verdict_line_is_the_same_words_in_the_record():
    v = ResponseVerdict(DOUBTFUL, "why", ("a.png",), "--method debevec")
    assert v.line() == "doubtful: why (frames a.png); next step: --method debevec"
    assert ResponseVerdict.from_dict(v.to_dict(), "x") == v
    assert not math.isnan(len(v.rows()))


def test_an_unconverged_white_balance_fit_suggests_the_fit_without_it(results):
    """The gains' joint fit that stops without converging (as on a real night bracket): the
    step drops the gains; the fit without them converges on the same bracket."""
    own, _ = results
    stuck = tuple(replace(r, white_balance=True, converged=False, method="tsin")
                  for r in own.responses)
    v = response_verdict(replace(own, method="tsin", responses=stuck, verdict=None), {})
    assert v.status == DOUBTFUL and v.next_step == "--method tsin without --white-balance"
    assert own.method == "tsin" and all(r.converged and not r.white_balance
                                        for r in own.responses)
