"""Sustained frame rate the IMU reader takes without loss over a real pseudo-terminal.

A producer process writes pre-encoded frames to the pty master at a paced rate with
non-blocking writes (a serial line has no flow control: what the reader does not take
in time is lost) and counts what it could not write; the reader under test reads the
slave for a fixed time and checks the sequence numbers. A rate passes when no frame is
lost or damaged. Compared in the same run: triadcal's reader (SerialImu: chunked reads,
vectorised checksums) and the obvious alternative, pyserial readline() per frame plus a
per-frame checksum. Prints the highest passing rate of each and their ratio.

    python benchmarks/capture.py [--seconds 2] [--protocol nmea]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import pty
import time
import tty

import serial

from triadcal.hardware.drivers.imu import SerialImu
from triadcal.hardware.protocols import Frame, get_protocol, nmea

RATES = (250, 500, 1000, 2000, 4000, 8000, 16000, 32000, 64000)


def producer(master: int, rate: float, seconds: float, protocol: str, ready, result):
    codec = get_protocol(protocol)
    n = int(rate * seconds)
    frames = [codec.encode(Frame(k, k / rate, (0.1 * k % 1, -0.5, 1.0), (20.1, 20.2, 20.3))) for k in range(n)]
    os.set_blocking(master, False)
    ready.wait()
    time.sleep(0.1)
    t0 = time.monotonic()
    k = lost = 0
    while k < n:
        due = min(n, int((time.monotonic() - t0) * rate) + 1)
        if due > k:
            blob = b"".join(frames[k:due])
            try:
                w = os.write(master, blob)
            except BlockingIOError:
                w = 0
            if w < len(blob):      # the line has no flow control: the rest is lost
                lost += due - k
            k = due
        time.sleep(0.001)
    time.sleep(0.3)
    result.put((n, lost))


def naive_reader(port: str, seconds: float):
    """pyserial readline() per frame and a per-frame checksum."""
    ser = serial.Serial(port, timeout=0.05)
    seqs, bad = [], 0
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        line = ser.readline()
        if not line:
            continue
        try:
            body, cs = line.strip()[1:].split(b"*")
            if nmea.checksum(body) != int(cs, 16):
                bad += 1
                continue
            seqs.append(nmea.decode_body(body).seq)
        except ValueError:
            bad += 1
    ser.close()
    return seqs, bad


def triadcal_reader(port: str, seconds: float, protocol: str):
    imu = SerialImu(port, protocol=protocol, stall_timeout_s=60.0)
    imu.open()
    seqs = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        seqs.extend(f.seq for f in imu.read())
    imu.close()
    return seqs, imu.parser_stats.corrupted


def trial(reader: str, rate: float, seconds: float, protocol: str):
    m, s = pty.openpty()
    tty.setraw(s)
    port = os.ttyname(s)
    ctx = mp.get_context("fork")
    ready, result = ctx.Event(), ctx.Queue()
    proc = ctx.Process(target=producer, args=(m, rate, seconds, protocol, ready, result))
    proc.start()
    os.close(s)
    t0 = time.monotonic()
    ready.set()
    seqs, bad = (naive_reader(port, seconds + 0.6) if reader == "readline" else
                 triadcal_reader(port, seconds + 0.6, protocol))
    n, lost_w = result.get(timeout=30)
    proc.join()
    os.close(m)
    ok = (not lost_w and not bad and seqs == list(range(n)))
    return ok, n, len(seqs), lost_w, time.monotonic() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--protocol", choices=("nmea", "binary"), default="nmea")
    args = ap.parse_args()
    print(f"IMU reader over a pty, {args.protocol} frames, {args.seconds:g} s per rate, {os.cpu_count()} cores")
    best = {}
    readers = ("triadcal", "readline") if args.protocol == "nmea" else ("triadcal",)
    for reader in readers:
        best[reader] = 0
        for rate in RATES:
            ok, n, got, lost, _ = trial(reader, rate, args.seconds, args.protocol)
            print(f"  {reader:9s} {rate:6d} frames/s: sent {n}, received {got}, overrun {lost}: "
                  f"{'no loss' if ok else 'LOSS'}", flush=True)
            if not ok:
                break
            best[reader] = rate
    for reader, rate in best.items():
        print(f"sustained without loss: {reader} >= {rate} frames/s")
    if "readline" in best:
        print(f"ratio triadcal / readline: {best['triadcal'] / max(best['readline'], 1):.1f}x "
              f"(target >= 2000 frames/s: {'met' if best['triadcal'] >= 2000 else 'NOT met'})")


if __name__ == "__main__":
    main()
