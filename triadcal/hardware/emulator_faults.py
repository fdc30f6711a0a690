"""The faults the emulator injects (:class:`FaultPlan`): into the IMU's stream, the bench's commands
and the chamber's answers; split from emulator.py, which plays the instruments on ptys."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence


@dataclass
class FaultPlan:
    """Faults to inject into the IMU stream; times in instrument seconds.

    Per frame: ``garbage_prob`` a burst of 1-16 random bytes before it, ``bitflip_prob`` one
    bit flipped inside it (a bad checksum), ``drop_prob`` not sent at all (its sequence
    number is used, so the receiver sees a gap). ``disconnects``: ``(at_s, for_s)`` pairs,
    the IMU line goes away and comes back on a new pty behind the same name.
    ``stalls``: ``(at_s, for_s)`` pairs, the IMU sends nothing (and uses no sequence numbers).
    ``bench_ignore_prob``: the bench drops a command line without a word (drawn from the
    bench's own random stream, so the IMU thread's draws do not change which lines);
    ``bench_ignore_lines``: 1-based numbers of the command lines the bench drops, always (a
    deterministic fault for tests).

    Bench and chamber faults a capture must not take for data (docs/hardware.md, "What a visit must
    be"), each counted in the bench's move commands (``POS``) to a new target (a visit redone at its
    position is no move: a loaded machine's incomplete window redid P1, the chamber "died" there and
    not at P2, and a test that counted on it failed): ``bench_creep_deg_s``: once it has
    reported its position in position (``POS?``), axis 1 creeps on at this rate (deg/s), and ``POS?``
    says so; ``bench_stuck_after_moves``:
    after this many moves the bench does not move any more but reports each commanded target as its
    position, in position; ``bench_stat_error_after_moves``: after this many moves ``STAT?`` answers
    ``-113,"Undefined header"``; ``chamber_dies_after_moves``: after this many moves the chamber
    answers no Modbus request and its heater is off (the air goes back to ``EmulatorTiming.start_C``).
    0: never.
    """

    garbage_prob: float = 0.0
    bitflip_prob: float = 0.0
    drop_prob: float = 0.0
    disconnects: Sequence[tuple] = ()
    stalls: Sequence[tuple] = ()
    bench_ignore_prob: float = 0.0
    bench_ignore_lines: Sequence[int] = ()
    bench_creep_deg_s: float = 0.0
    bench_stuck_after_moves: int = 0
    bench_stat_error_after_moves: int = 0
    chamber_dies_after_moves: int = 0

    @classmethod
    def all_faults(cls, start_s: float = 60.0) -> "FaultPlan":
        """A bit of everything, for demonstrations and tests."""
        return cls(garbage_prob=0.01, bitflip_prob=0.01, drop_prob=0.01,
                   disconnects=((start_s, 60.0),), stalls=((start_s + 240.0, 120.0),),
                   bench_ignore_prob=0.1)
