"""The readers of a capture folder's raw files (raw/imu_samples.csv, raw/events.jsonl) and the
answers the bench drivers read: a torn last line (a killed writer) is tolerated and reported, a
torn line a resumed writer ended is known for what it is, any other bad line is refused naming
the file, the line and the field; an instrument answer that is not what the protocol says is a
BenchError naming the command and the answer (never a ValueError from unpacking it). Real files,
and real pseudo-terminals with a scripted instrument on the other side."""

import json
import os
import select
import threading
import tty

import pytest

from triadcal.errors import InputError
from triadcal.hardware.drivers.bench import BenchError, ScpiBench, within_tolerance
from triadcal.hardware.drivers.bench_template import TemplateBench, parse_profile
from triadcal.hardware.protocols import Frame
from triadcal.hardware.storage import (RAW_COLUMNS, TORN_MARK, EventLog, RawStore, read_events,
                                       read_raw)

HEADER = ",".join(RAW_COLUMNS) + "\n"


def frames(n, start=0):
    return [Frame(k, 0.01 * k, (0.1 + k, -0.25, 9.80665), (20.5, 21.0, 21.25)) for k in range(start, start + n)]


def sample_line(seq, session=1, phase="record", visit="v1"):
    return f"{session},{seq},{0.01 * seq!r},0.5,-0.25,1.0,20.5,21.0,21.25,{phase},{visit}\n"


def write_raw(path, *lines, end=""):
    path.write_text(HEADER + "".join(lines) + end, encoding="ascii")
    return path


# -- raw/imu_samples.csv -----------------------------------------------------------------------
@pytest.mark.parametrize("bad, field", [
    ("1,2,0.02,0.5,-0.25\n", "has 5 fields"),
    ("x,2,0.02,0.5,-0.25,1.0,20.5,21.0,21.25,record,v1\n", "session 'x' is not an integer"),
    ("1,2.5,0.02,0.5,-0.25,1.0,20.5,21.0,21.25,record,v1\n", "seq '2.5' is not an integer"),
    ("1,2,0.02,0.5,abc,1.0,20.5,21.0,21.25,record,v1\n", "w_y 'abc' is not a number"),
    ("1,2,inf,0.5,-0.25,1.0,20.5,21.0,21.25,record,v1\n", "time_s 'inf' is not a finite number"),
    ("1,2,0.02,0.5,-0.25,nan,20.5,21.0,21.25,record,v1\n", "w_z 'nan' is not a finite number"),
    ("1,2,0.02,0.5,-0.25,1.0,20.5,21.0,21.25,recrod,v1\n", "phase 'recrod' is not one of"),
    ("\n", "has 1 fields"),
])
def test_a_malformed_raw_line_before_the_last_is_refused_naming_file_line_and_field(tmp_path, bad, field):
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0), sample_line(1), bad, sample_line(3))
    with pytest.raises(InputError) as exc:
        read_raw(path)
    text = str(exc.value)
    assert str(path) in text and "line 4:" in text and field in text


def test_nan_temperatures_are_samples(tmp_path):
    """An IMU output without temperatures writes nan there: those lines are samples."""
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0),
                     "1,1,0.01,0.5,-0.25,1.0,nan,nan,nan,soak,\n")
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 1] and raw["torn_lines"] == [] and raw["skipped_lines"] == 0
    assert raw["visit"].tolist() == ["v1", ""]


@pytest.mark.parametrize("tail", [
    "1,3,0.03,0.5,-0.2",                                      # killed mid-line: no newline
    "1,3,0.03,0.5,-0.25,1.0,20.5,21.0,21.25,record,v1",       # complete fields, but no newline
    "1,3,0.03,0.5,-0.2\n",                                    # the last line does not read
])
def test_a_torn_last_raw_line_is_tolerated_and_reported(tmp_path, tail):
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0), sample_line(1), sample_line(2), end=tail)
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 1, 2]
    assert raw["torn_lines"] == [5] and raw["skipped_lines"] == 1


def test_a_raw_store_reopened_after_a_torn_line_marks_it_and_every_complete_line_is_read(tmp_path):
    """The torn fragment is a prefix of a sample that reads as one (visit v1 of v12, w_x 0.1 of
    0.1234): the reopened store ends it with the mark, so it is neither glued to the next line
    nor read as a sample, and it is reported; the file before is kept byte for byte."""
    path = tmp_path / "raw" / "imu_samples.csv"
    s = RawStore(path)
    s.append(frames(3), 1, "record", "v12")
    s.close()
    with open(path, "a", encoding="ascii") as fh:        # what a kill in the middle of a write leaves
        fh.write("1,3,0.03,0.1,-0.25,9.80665,20.5,21.0,21.25,record,v1")
    before = path.read_bytes()
    s = RawStore(path)
    s.append(frames(2, start=10), 2, "move", "v2")
    s.close()
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 1, 2, 10, 11]
    assert raw["visit"].tolist() == ["v12"] * 3 + ["v2"] * 2
    assert raw["session"].tolist() == [1, 1, 1, 2, 2]
    assert raw["w"][:, 0].tolist() == [0.1, 1.1, 2.1, 10.1, 11.1]
    assert raw["torn_lines"] == [5] and raw["skipped_lines"] == 1
    data = path.read_bytes()
    assert data.startswith(before)
    assert data[len(before):].startswith((TORN_MARK + "\n").encode())


def test_a_torn_session_end_ended_by_a_writer_of_before_the_mark_is_a_torn_line(tmp_path):
    """Folders resumed before the mark: the torn end of session 1 ended by a bare newline, and
    session 2 after it, is tolerated and reported; the same line inside a session is refused."""
    torn = "1,2,0.02,0.5,-0.25,1.0,20.5,21.\n"
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0), sample_line(1), torn,
                     sample_line(7, session=2), sample_line(8, session=2))
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 1, 7, 8] and raw["torn_lines"] == [4]
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0), sample_line(1), torn,
                     sample_line(7, session=1))
    with pytest.raises(InputError, match="line 4: has 8 fields"):
        read_raw(path)
    path = write_raw(tmp_path / "imu_samples.csv", torn, sample_line(7, session=2))
    with pytest.raises(InputError, match="line 2: has 8 fields"):
        read_raw(path)


def test_a_kill_while_the_mark_is_written_is_a_torn_line_again(tmp_path):
    path = write_raw(tmp_path / "imu_samples.csv", sample_line(0), end="1,1,0.0" + TORN_MARK[:3])
    assert read_raw(path)["torn_lines"] == [3]
    s = RawStore(path)
    s.append(frames(1, start=5), 2, "idle")
    s.close()
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 5] and raw["torn_lines"] == [3]


def test_a_raw_store_killed_while_writing_its_header(tmp_path):
    path = tmp_path / "imu_samples.csv"
    path.write_text(HEADER[:12], encoding="ascii")
    raw = read_raw(path)
    assert len(raw["seq"]) == 0 and raw["torn_lines"] == [1]
    s = RawStore(path)
    s.append(frames(2), 1, "soak", "s0")
    s.close()
    raw = read_raw(path)
    assert raw["seq"].tolist() == [0, 1] and raw["torn_lines"] == [1]


def test_a_file_that_is_not_raw_samples_is_refused(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("a,b,c\n1,2,3\n", encoding="ascii")
    with pytest.raises(InputError, match=r"other\.csv line 1: not a triadcal raw sample file"):
        read_raw(path)


# -- raw/events.jsonl --------------------------------------------------------------------------
def rec(kind, **fields):
    return json.dumps({"wall_time": 1.0, "kind": kind, **fields}) + "\n"


@pytest.mark.parametrize("bad, why", [
    ('{"wall_time": 1.0, "kind": "vis\n', "not a JSON record"),
    ("[1, 2]\n", "not a JSON object"),
    ('{"wall_time": 1.0}\n', "field 'kind' is missing"),
    ('{"wall_time": 1.0, "kind": 3}\n', "field 'kind' is 3"),
    ("\n", "not a JSON record"),
])
def test_a_bad_event_line_before_the_last_is_refused_naming_file_and_line(tmp_path, bad, why):
    path = tmp_path / "events.jsonl"
    path.write_text(rec("session_start", session=1) + bad + rec("visit", tag="a"), encoding="utf-8")
    with pytest.raises(InputError) as exc:
        read_events(path)
    assert str(path) in str(exc.value) and "line 2:" in str(exc.value) and why in str(exc.value)


def test_an_event_line_that_is_not_utf8_is_refused(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_bytes(rec("a").encode() + b'{"kind": "\xff"}\n' + rec("b").encode())
    with pytest.raises(InputError, match="line 2: not UTF-8"):
        read_events(path)


@pytest.mark.parametrize("tail", ['{"wall_time": 1.0, "kind": "vis', '{"wall_time": 1.0, "kind": "vis\n'])
def test_a_torn_last_event_line_is_tolerated_and_reported(tmp_path, tail):
    path = tmp_path / "events.jsonl"
    path.write_text(rec("session_start", session=1) + rec("visit", tag="a") + tail, encoding="utf-8")
    events = read_events(path)
    assert [e["kind"] for e in events] == ["session_start", "visit"]
    assert events.torn_lines == [3]


def test_a_torn_multibyte_character_at_the_end_is_a_torn_line(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_bytes(rec("a").encode() + '{"kind": "°'.encode("utf-8")[:-1])
    events = read_events(path)
    assert [e["kind"] for e in events] == ["a"] and events.torn_lines == [2]


def test_an_event_log_reopened_after_a_torn_line_names_it_and_is_read_whole(tmp_path):
    path = tmp_path / "events.jsonl"
    log = EventLog(path)
    log.write("session_start", session=1)
    log.close()
    with open(path, "a", encoding="utf-8") as fh:
        fh.write('{"wall_time": 1.0, "kind": "vis')
    log = EventLog(path)
    log.write("session_start", session=2)
    log.close()
    events = read_events(path)
    assert [e["kind"] for e in events] == ["session_start", "torn_line", "session_start"]
    assert events[1]["line"] == 2 and events.torn_lines == [2]


def test_a_missing_event_log_reads_as_no_events(tmp_path):
    events = read_events(tmp_path / "none.jsonl")
    assert list(events) == [] and events.torn_lines == []


# -- instruments on a pseudo-terminal ---------------------------------------------------------
class PtyInstrument:
    """The far end of a real pty: answers each line (split at ``term``) with ``answer(line)``
    (str, bytes, or None for no answer), in a thread."""

    def __init__(self, answer, term=b"\n"):
        self.answer, self.term = answer, term
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.received: list = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        buf = b""
        while not self._stop.is_set():
            if not select.select([self.master], [], [], 0.02)[0]:
                continue
            try:
                buf += os.read(self.master, 4096)
            except OSError:
                return
            while self.term in buf:
                line, buf = buf.split(self.term, 1)
                text = line.decode("ascii").strip()
                self.received.append(text)
                reply = self.answer(text)
                if reply is not None:
                    os.write(self.master, (reply if isinstance(reply, bytes) else reply.encode("ascii")) + self.term)

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        os.close(self.master)
        os.close(self.slave)


class FakeScpi:
    """The SCPI-style bench of docs/hardware.md, with answers a test can spoil."""

    def __init__(self):
        self.target = (0.0, 0.0)
        self.offset = (0.0, 0.0)          # where the axes stop, from the target
        self.spoil = {}                   # command -> the answer given instead
        self.received = []

    def __call__(self, cmd):
        self.received.append(cmd)
        if cmd.startswith("POS "):
            self.target = tuple(float(v) for v in cmd[4:].split(","))
            return None
        if cmd in self.spoil:
            return self.spoil[cmd]
        if cmd == "POS:TARG?":
            return "%.6f,%.6f" % self.target
        if cmd == "POS?":
            return "%.6f,%.6f" % tuple(t + o for t, o in zip(self.target, self.offset))
        return {"*IDN?": "TRIADCAL,FAKE,0,1.0", "STAT?": "1", "SYST:ERR?": '0,"No error"'}.get(cmd)


@pytest.fixture
def scpi():
    fake = FakeScpi()
    inst = PtyInstrument(fake)
    bench = ScpiBench(inst.port, timeout_s=0.2, retries=2)
    yield fake, bench
    bench.close()
    inst.close()


@pytest.mark.parametrize("answer", ["90", "90,0,1", "ninety,0", "nan,0", "", b"\xff\xfe"])
def test_a_malformed_target_answer_is_a_bench_error_naming_command_and_answer(scpi, answer):
    fake, bench = scpi
    fake.spoil["POS:TARG?"] = answer
    with pytest.raises(BenchError) as exc:
        bench.move_to(90.0, 0.0)
    text = str(exc.value)
    assert "'POS:TARG?'" in text and "answer" in text
    if isinstance(answer, str) and answer:
        assert repr(answer) in text


@pytest.mark.parametrize("answer", ["12.5", "1,2,3", "a,b", "inf,0", b"\x80,1"])
def test_a_malformed_position_answer_is_a_bench_error_naming_command_and_answer(scpi, answer):
    fake, bench = scpi
    fake.spoil["POS?"] = answer
    with pytest.raises(BenchError) as exc:
        bench.position()
    assert "'POS?'" in str(exc.value) and "answer" in str(exc.value)


def test_a_status_that_is_neither_0_nor_1_is_a_bench_error(scpi):
    fake, bench = scpi
    fake.spoil["STAT?"] = "BUSY"
    with pytest.raises(BenchError, match=r"'BUSY' to 'STAT\?'"):
        bench.in_position()


def test_scpi_in_position_needs_the_axes_at_the_target_not_only_the_status(scpi):
    fake, bench = scpi
    bench.move_to(90.0, 359.998)
    fake.offset = (0.0, 0.5)                  # STAT? says 1, axis 2 stopped half a degree short
    assert bench.in_position() is False
    assert bench.target == (90.0, 359.998)
    assert fake.received[-2:] == ["STAT?", "POS?"]
    fake.offset = (0.004, 0.004)              # within the tolerance (0.01 deg), across 360 on axis 2
    assert bench.in_position() is True
    fake.offset = (0.0, 0.0)
    fake.spoil["STAT?"] = "0"                 # moving: no need to read the position
    n = len(fake.received)
    assert bench.in_position() is False and fake.received[n:] == ["STAT?"]


def test_scpi_tolerance_is_the_shared_one(scpi):
    _, bench = scpi
    assert bench.tolerance_deg == parse_profile(TEMPLATE_DOC).tolerance_deg == 0.01
    assert within_tolerance((359.995, 10.0), (0.0, 10.009), 0.01)
    assert not within_tolerance((350.0, 10.0), (0.0, 10.0), 0.01, ("none", "none"))


TEMPLATE_DOC = {
    "axes": [{"id": "1"}, {"id": "2"}],
    "commands": {"move": "MV{axis} {value}", "position": "PA{axis}?", "done": "MD{axis}?"},
    "responses": {"position": r"^P(\S+)?$"},
    "transport": {"write_terminator": "\n", "read_terminator": "\n", "timeout_s": 0.2, "retries": 2},
}


@pytest.mark.parametrize("answer, why", [("P", "has no group 1"), ("Pnan", "is not a finite number"),
                                         ("Pabc", "is not a finite number"), ("X1", "does not match")])
def test_template_bench_position_answers_are_checked(answer, why):
    inst = PtyInstrument(lambda cmd: answer if cmd.startswith("PA") else "1")
    bench = TemplateBench(parse_profile(TEMPLATE_DOC), inst.port)
    try:
        with pytest.raises(BenchError) as exc:
            bench.position()
        assert why in str(exc.value) and repr(answer) in str(exc.value) and "'PA1?'" in str(exc.value)
    finally:
        bench.close()
        inst.close()


def test_an_event_log_with_a_bad_line_is_refused_when_reopened_not_appended_to(tmp_path):
    """A resumed capture appended its session to a log with a broken line 2; the log then could not
    be read at the next resume or report. Now the reopen refuses it, naming the line, and the
    file is left as it was."""
    path = tmp_path / "events.jsonl"
    text = rec("session_start", session=1) + "[1, 2]\n" + rec("visit", tag="a")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=r"events.jsonl line 2: not a JSON object"):
        EventLog(path)
    assert path.read_text(encoding="utf-8") == text


def test_a_hung_up_emulator_line_leaves_no_link_to_a_freed_pty(tmp_path):
    """CI, 2026-12-01: during an emulated disconnect the IMU's symlink still named the closed pty;
    its number was the next pty the other xdist worker opened (a Modbus chamber test), and the
    VectorNav driver, reconnecting through the link, wrote $VNWRG into that test's line. A hang-up
    removes the link first; the reopen makes a new pty and a new link."""
    import os

    from triadcal.hardware.chamber_emulators import WatlowEmulator
    from triadcal.hardware.emulator import _Pty

    link = tmp_path / "imu"
    p = _Pty(link)
    first = os.readlink(link)
    p.close()
    assert not link.exists() and not link.is_symlink()
    p.open()
    assert os.readlink(link) == p.name and os.path.exists(link)
    p.close()
    em = WatlowEmulator(link=str(tmp_path / "chamber")).start()
    assert os.readlink(tmp_path / "chamber") == em._path
    em.stop()
    assert not (tmp_path / "chamber").is_symlink()
    assert first.startswith("/dev/pts/")
