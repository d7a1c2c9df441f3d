"""Progress reports and cancellation of long reductions (ccdcore.progress): the one
``progress(fraction, message)`` convention, its helpers (within, silent, Steps), the tracker,
and every long function of ccdcore and the report keeping to the convention."""
from __future__ import annotations

from numbers import Real
from pathlib import Path

import numpy as np
import pytest

from ccdcore.noise import photon_transfer
from ccdcore.product.make import ESTIMATE_STEPS, estimate_all
from ccdcore.progress import (Cancelled, Progress, Steps, Tracker, checkpoint, silent,
                              tracking, within)
from ccdcore.session import open_session

ASSETS = Path(__file__).resolve().parents[1] / "assets"
DEMO = ASSETS / "healey94"


class Recorder(Tracker):
    """A tracker that keeps every (step, fraction, done, total) it went through and cancels
    itself after ``stop_after`` frames."""

    def __init__(self, steps=(), stop_after: int | None = None):
        super().__init__(steps)
        self.seen: list[tuple[str, float, int, int | None]] = []
        self.frames_read = 0
        self.stop_after = stop_after

    def frame(self, done=None, total=None):
        self.frames_read += 1
        if self.stop_after is not None and self.frames_read > self.stop_after:
            self.cancel()
        super().frame(done, total)
        self.seen.append((self.step, self.fraction, self.done, self.total))

    def __call__(self, fraction, message):
        super().__call__(fraction, message)
        self.seen.append((self.step, self.fraction, self.done, self.total))


def test_estimate_all_reports_every_step_and_frame_in_order():
    session = open_session(DEMO)
    rec = Recorder(ESTIMATE_STEPS)
    with tracking(rec):
        est = estimate_all(session, progress=rec)
    assert est.fixed_pattern is not None
    fractions = [f for _, f, _, _ in rec.seen]
    assert fractions == sorted(fractions)                  # never goes back
    assert rec.seen[-1][:2] == ("done", 1.0)
    steps = [s for s, *_ in rec.seen]
    order = [name for name, _ in ESTIMATE_STEPS]
    assert [s for i, s in enumerate(steps) if i == 0 or s != steps[i - 1]] == order
    # within a step the fraction advances with the frames, up to the next step's start
    start = dict(ESTIMATE_STEPS)
    fp = [(f, d, t) for s, f, d, t in rec.seen if s == "fixed pattern"]
    assert fp[-1][2] is not None and fp[-1][1] == fp[-1][2] - 1        # frames done of total
    assert start["fixed pattern"] < fp[-1][0] < start["planning"]
    # every frame of the demo is read by some estimate, each through a checkpoint (but the
    # max-intensity frame, which the correction check reads alone)
    assert rec.frames_read >= len(session.frames) - 1


def test_cancel_stops_at_the_next_frame():
    session = open_session(DEMO)
    rec = Recorder(stop_after=5)
    with tracking(rec), pytest.raises(Cancelled, match="cancelled during"):
        photon_transfer(session)
    assert rec.frames_read == 6          # the sixth frame's checkpoint raised, no frame after
    # read-ahead path too
    rec = Recorder(stop_after=3)
    with tracking(rec), pytest.raises(Cancelled):
        for _ in session.iter_frames(session.frames, read_ahead=2):
            pass
    assert rec.frames_read == 4


def test_no_tracker_no_effect_and_trackers_do_not_leak():
    checkpoint(1, 2)                     # outside tracking: nothing happens
    session = open_session(DEMO)
    rec = Tracker()
    with tracking(rec):
        list(session.iter_frames(session.frames[:3]))
    assert rec.done == 2 and rec.total == 3 and rec.fraction == pytest.approx(2 / 3)
    assert "frame 2 of 3" in rec.describe()
    list(session.iter_frames(session.frames[:3]))          # after the block: not counted
    assert rec.done == 2
    rec.cancel()
    with pytest.raises(Cancelled):
        rec(0.5, "next step")


# --------------------------------------------------------------------------------------------
# the convention and its helpers
# --------------------------------------------------------------------------------------------
class Recording:
    """A Progress keeping every call as it came, to be checked afterwards."""

    def __init__(self):
        self.calls: list[tuple[object, object]] = []

    def __call__(self, fraction, message):
        self.calls.append((fraction, message))

    def check(self, what: str) -> None:
        """Every call ``(number in [0, 1], non-empty str)``, the fractions never decreasing."""
        assert self.calls, f"{what}: no progress reported"
        for fraction, message in self.calls:
            assert isinstance(fraction, Real) and not isinstance(fraction, bool), \
                f"{what}: fraction {fraction!r} (message {message!r}): arguments in the old order?"
            assert 0.0 <= fraction <= 1.0, f"{what}: fraction {fraction} outside [0, 1]"
            assert isinstance(message, str) and message.strip(), \
                f"{what}: message {message!r} at {fraction}"
        fractions = [float(f) for f, _ in self.calls]
        back = [(a, b) for a, b in zip(fractions, fractions[1:]) if b < a]
        assert not back, f"{what}: the fraction went back {back[:3]}"


def test_recording_check_refuses_the_old_argument_order():
    rec = Recording()
    rec("photon transfer", 0.0)              # (step, fraction): the convention this replaced
    with pytest.raises(AssertionError, match="old order"):
        rec.check("old order")
    rec = Recording()
    rec(0.5, "b")
    rec(0.25, "a")
    with pytest.raises(AssertionError, match="went back"):
        rec.check("backwards")


def test_within_maps_its_range_and_clamps():
    rec = Recording()
    part = within(rec, 0.2, 0.6)
    for f in (0.0, 0.5, 1.0, -0.5, 3.0):
        part(f, "step")
    assert [f for f, _ in rec.calls] == pytest.approx([0.2, 0.4, 0.6, 0.2, 0.6])
    assert all(m == "step" for _, m in rec.calls)
    within(rec, 0.3, 0.3)(0.7, "empty range")            # a point: always its start
    assert rec.calls[-1] == (pytest.approx(0.3), "empty range")
    within(rec, 0.0, 1.0)(np.float32(0.25), "numpy scalar")
    assert rec.calls[-1] == (pytest.approx(0.25), "numpy scalar")
    assert isinstance(rec.calls[-1][0], float)
    for lo, hi in ((0.5, 0.4), (-0.1, 0.5), (0.5, 1.1)):
        with pytest.raises(ValueError, match="start <= end"):
            within(rec, lo, hi)


def test_nested_within_composes_ranges_and_prefixes():
    rec = Recording()
    outer = within(rec, 0.5, 1.0, prefix="change detection: ")
    inner = within(outer, 0.0, 0.5, prefix="channel R: ")
    inner(0.0, "iteration 1")
    inner(1.0, "iteration 2")
    inner(2.0, "beyond")                                  # clamped by the inner range
    outer(1.0, "done")
    assert rec.calls == [(pytest.approx(0.5), "change detection: channel R: iteration 1"),
                         (pytest.approx(0.75), "change detection: channel R: iteration 2"),
                         (pytest.approx(0.75), "change detection: channel R: beyond"),
                         (pytest.approx(1.0), "change detection: done")]
    deep = within(within(within(rec, 0.0, 0.5), 0.5, 1.0), 0.5, 1.0)
    deep(0.5, "three deep")                               # 0.5 + 0.5 * (0.5 + 0.5 * 0.5)
    assert rec.calls[-1][0] == pytest.approx(0.5 * (0.5 + 0.5 * (0.5 + 0.5 * 0.5)))


def test_within_none_and_silent_do_nothing():
    assert silent(0.5, "anything") is None
    assert within(None, 0.2, 0.4) is silent
    within(None, 0.2, 0.4)(0.5, "nobody listens")
    within(within(None, 0.0, 0.5), 0.5, 1.0, prefix="x: ")(1.0, "still nobody")
    Steps(None, ESTIMATE_STEPS)("fixed pattern")
    Steps(None, ESTIMATE_STEPS).within("response")(0.5, "nobody")


def test_a_str_fraction_is_refused_by_within_and_the_tracker():
    rec = Recording()
    with pytest.raises(TypeError, match=r"progress\(fraction, message\)"):
        within(rec, 0.0, 1.0)("photon transfer", 0.5)
    with pytest.raises(TypeError, match=r"progress\(fraction, message\)"):
        Tracker(ESTIMATE_STEPS)("photon transfer", 0.0)
    with pytest.raises(TypeError):
        within(rec, 0.0, 1.0)(0.5, None)
    assert rec.calls == []


def test_steps_report_their_table_and_give_each_step_its_range():
    rec = Recording()
    steps = Steps(rec, ESTIMATE_STEPS)
    for name, _ in ESTIMATE_STEPS:
        steps(name)
    assert rec.calls == [(start, name) for name, start in ESTIMATE_STEPS]
    start = dict(ESTIMATE_STEPS)
    rec.calls.clear()
    part = steps.within("fixed pattern", prefix="K: ")
    part(0.0, "a")
    part(1.0, "b")
    assert rec.calls == [(pytest.approx(start["fixed pattern"]), "K: a"),
                         (pytest.approx(start["planning"]), "K: b")]
    rec.calls.clear()
    steps.within("done")(0.5, "after the last")          # the last step runs to 1
    assert rec.calls == [(pytest.approx(1.0), "after the last")]
    with pytest.raises(KeyError):
        steps("no such step")


def test_a_tracker_is_a_progress_that_starts_a_step_at_the_fraction():
    tracker = Tracker(ESTIMATE_STEPS)
    progress: Progress = tracker            # the protocol: any f(fraction, message)
    progress(0.3, "fixed pattern")
    assert tracker.step == "fixed pattern" and tracker.fraction == pytest.approx(0.3)
    tracker.frame(1, 2)                     # half the step's frames: halfway to "planning"
    assert tracker.fraction == pytest.approx(0.3 + 0.5 * (0.55 - 0.3))
    assert tracker.describe() == "fixed pattern: frame 1 of 2"
    within(tracker, 0.55, 0.6)(0.5, "planning")   # sub-ranges reach the tracker too
    assert tracker.step == "planning" and tracker.fraction == pytest.approx(0.575)


# --------------------------------------------------------------------------------------------
# every long function keeps to it
# --------------------------------------------------------------------------------------------
def test_estimate_all_and_calibrate_report_fraction_then_message():
    from ccdcore.product.make import calibrate

    rec = Recording()
    estimate_all(open_session(DEMO), progress=rec)
    rec.check("estimate_all")
    assert rec.calls == [(start, name) for name, start in ESTIMATE_STEPS]
    rec = Recording()
    calibrate(DEMO, progress=rec)
    rec.check("calibrate")


def _emva_descriptor(root: Path) -> Path:
    """A small EMVA 1288 data set by the reference package's generator (test_datasheet's)."""
    from test_datasheet import generate

    gen = generate(root, steps=8, L=4, width=32, height=24, u_esat=60000.0,
                   dark_signal_0=50.0)
    return Path(gen.descriptor_path)


def test_emva_figures_report_fraction_then_message(tmp_path):
    from ccdcore.emva.datasheet import EMVA_STEPS, emva_figures

    rec = Recording()
    emva_figures(_emva_descriptor(tmp_path / "emva"), progress=rec)
    rec.check("emva_figures")
    assert rec.calls == [(start, name) for name, start in EMVA_STEPS]


@pytest.mark.parametrize("method", ["tsin", "debevec", "robertson", "mitsunaga-nayar"])
def test_response_of_reports_fraction_then_message(method):
    from ccdcore.response.brackets import load_bracket
    from ccdcore.response.methods import METHODS, response_of

    assert method in METHODS
    brackets = load_bracket(open_session(ASSETS / "tsin01"))
    rec = Recording()
    response_of(brackets, method, progress=rec)
    rec.check(f"response_of {method}")
    rec = Recording()                       # the same through a sub-range: stays inside it
    response_of(brackets, method, progress=within(rec, 0.25, 0.5, prefix="response: "))
    rec.check(f"response_of {method} within")
    assert all(0.25 <= f <= 0.5 and m.startswith("response: ") for f, m in rec.calls)


@pytest.mark.parametrize("demo", ["healey94", "change"])
def test_build_report_reports_fraction_then_message(demo):
    """healey94: the calibration's steps as a part of the report's; change: only brackets, so
    no estimate and change detection (its response estimate and fit nested in it)."""
    from ccdcore_report import build_report

    rec = Recording()
    build_report(ASSETS / demo, progress=rec)
    rec.check(f"build_report {demo}")
    assert rec.calls[-1] == (1.0, "done")
    messages = [m for _, m in rec.calls]
    if demo == "healey94":
        assert "calibrate: photon transfer" in messages and "writing the report" in messages
    else:
        assert any(m.startswith("change detection: channel ") for m in messages)
