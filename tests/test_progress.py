"""Progress reports and cancellation of long reductions (ccdcore.progress)."""
from __future__ import annotations

from pathlib import Path

import pytest

from ccdcore.noise import photon_transfer
from ccdcore.product import ESTIMATE_STEPS, estimate_all
from ccdcore.progress import Cancelled, Tracker, checkpoint, tracking
from ccdcore.session import open_session

DEMO = Path(__file__).resolve().parents[1] / "assets" / "healey94"


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

    def __call__(self, step, fraction):
        super().__call__(step, fraction)
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
        rec("next step", 0.5)
