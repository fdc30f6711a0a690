"""A visit's window starts after the bench is in position by the instrument's present, not by the
first frame read after it (hardware/capture.py, _visit).

The clean-clone CI ci59, on a loaded machine: "visit 27 (P03, 0, 180) of the ramp after P02
(180, 0): the bench did not move ... w changed by 6.41e-05" on the emulator's healthy bench. The
first frame read after the in-position reply was still a queued one, 100 s of instrument time old
at x500, so the window (settle 3 s, tau 20 s) lay before the move. Here a fake reader hands the
frames over a fixed lag behind the instrument's clock (stamped when they arrived, as the driver's
reader thread stamps them) and the unit's output steps at the move: every frame of the window comes
after the move.
"""
from __future__ import annotations

import time

from triadcal.hardware.capture import CaptureSettings, _visit
from triadcal.hardware.protocols import Frame
from triadcal.hardware.runner import _Runner

SCALE, RATE, LAG_S = 500.0, 10.0, 40.0        # instrument s per wall s, Hz, instrument s the pump is behind


class Clock:
    def __init__(self):
        self.w0 = time.monotonic()

    def now(self):
        return (time.monotonic() - self.w0) * SCALE


class LaggingStream:
    """Frames at RATE on the instrument clock, handed over LAG_S behind it; the output is +1 before
    the bench's move and -1 after (the moment the bench got the command)."""

    def __init__(self, clock, bench):
        self.clock, self.bench, self.k = clock, bench, 0

    def get(self, timeout):
        time.sleep(min(timeout, 0.002))
        upto = self.clock.now() - LAG_S
        out = []
        while self.k / RATE <= upto:
            t = self.k / RATE
            w = -1.0 if self.bench.moved_at is not None and t >= self.bench.moved_at else 1.0
            out.append(Frame(self.k, t, (0.0, 0.0, w), (25.0, 25.0, 25.0), wall_s=self.clock.w0 + t / SCALE))
            self.k += 1
        return out


class Bench:
    def __init__(self, clock):
        self.clock, self.moved_at = clock, None

    def move_to(self, a1, a2):
        self.moved_at = self.clock.now()

    def in_position(self):
        return True

    def position(self):
        return (0.0, 180.0)


class Nothing:
    def write(self, *a, **k):
        pass

    def append(self, *a, **k):
        pass


def test_the_window_lies_after_the_move_when_the_frames_lag():
    clock = Clock()
    bench = Bench(clock)
    settings = CaptureSettings(tau_s=20.0, settle_s=3.0)
    run = _Runner(LaggingStream(clock, bench), Nothing(), Nothing(), 1, settings, temperature_required=True)
    t_end = time.monotonic() + 3.0
    while time.monotonic() < t_end:              # 3 s of wall: 1500 s of instrument, the rate measured
        run.pump(0.01)
    row = _visit(run, bench, Nothing(), settings, "v1", 0.0, 180.0, lambda ev: None, {})
    assert row is not None, run.visit_problem
    assert row["w"][2] == -1.0, row["w"]                     # every frame after the move (old: +1 frames in it)
    assert row["mid_instrument_s"] - settings.tau_s / 2 >= bench.moved_at + settings.settle_s - 1.0 / RATE
