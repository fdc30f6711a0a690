"""One atomic writer: nothing torn, nothing left behind, no NaN in JSON; the capture folder lock."""

import json
import math
import subprocess
import sys
import threading

import numpy as np
import pytest

from triadcal.hardware.storage import FolderLocked, folder_lock
from triadcal.io.atomic import atomic_path, atomic_write, atomic_write_json, atomic_write_text


def _listing(d):
    return sorted(p.name for p in d.iterdir())


@pytest.mark.parametrize("exc", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_an_error_mid_write_leaves_the_old_file_and_no_temporary(tmp_path, exc):
    target = tmp_path / "r.json"
    target.write_text("old")
    with pytest.raises(type(exc)):
        with atomic_write(target) as fh:
            fh.write("half of the new conte")
            raise exc
    assert target.read_text() == "old"
    assert _listing(tmp_path) == ["r.json"]


def test_an_error_in_a_library_writing_by_path_leaves_nothing(tmp_path):
    with pytest.raises(ValueError):
        with atomic_path(tmp_path / "p.nc") as tmp:
            tmp.write_bytes(b"partial")
            raise ValueError("h5 failed")
    assert _listing(tmp_path) == []


def test_json_never_holds_nan_or_infinity(tmp_path):
    p = tmp_path / "d.json"
    atomic_write_json(p, {"k": float("nan"), "a": np.array([1.0, np.inf]), "n": np.float32(2.5), "i": np.int64(3),
                          "b": np.bool_(True), "nested": [{"x": -math.inf}]})
    text = p.read_text()
    assert "NaN" not in text and "Infinity" not in text
    d = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert d == {"k": None, "a": [1.0, None], "n": 2.5, "i": 3, "b": True, "nested": [{"x": None}]}


def test_an_object_that_cannot_be_written_leaves_nothing(tmp_path):
    with pytest.raises(TypeError):
        atomic_write_json(tmp_path / "x.json", {"f": object()})
    assert _listing(tmp_path) == []


def test_concurrent_writers_leave_one_whole_file(tmp_path):
    p = tmp_path / "c.txt"
    texts = [str(i) * 100_000 for i in range(8)]
    threads = [threading.Thread(target=atomic_write_text, args=(p, t)) for t in texts]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert p.read_text() in texts
    assert _listing(tmp_path) == ["c.txt"]


def test_fit_leaves_no_temporary_files(tmp_path, capsys):
    from triadcal.cli import main

    assert main(["fit", "--example", "--json", str(tmp_path / "r.json"), "--netcdf", str(tmp_path / "r.nc")]) == 0
    assert _listing(tmp_path) == ["r.json", "r.nc"]


def test_a_second_holder_is_refused_naming_the_first(tmp_path):
    with folder_lock(tmp_path / "out", "capture"):
        with pytest.raises(FolderLocked, match=r"capture pid \d+ on host"):
            with folder_lock(tmp_path / "out", "capture"):
                pass
    with folder_lock(tmp_path / "out", "capture"):    # released: free again
        pass


def test_capture_into_a_locked_folder_is_refused_at_once(tmp_path):
    from triadcal.hardware.capture import CaptureError, CaptureSettings, capture

    with folder_lock(tmp_path, "capture"):
        with pytest.raises(CaptureError, match="in use by another capture"):
            capture(tmp_path, plan={"P01": (0.0, 0.0)}, setpoints_C=[20.0], imu=None, bench=None, chamber=None,
                    settings=CaptureSettings(unit="X"))


def test_the_lock_of_a_killed_process_does_not_block(tmp_path):
    code = ("import sys; from triadcal.hardware.storage import folder_lock\n"
            f"with folder_lock({str(tmp_path)!r}, 'capture'):\n"
            "    print('locked', flush=True); sys.stdin.read()\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLocked, match=f"pid {proc.pid}"):
            with folder_lock(tmp_path, "capture"):
                pass
    finally:
        proc.kill()
        proc.wait()
    with folder_lock(tmp_path, "capture"):        # the kernel released it with the process
        pass


def test_written_files_get_the_mode_of_an_ordinary_open(tmp_path):
    """mkstemp creates 0600; what triadcal writes is readable as any file the user writes."""
    import os
    import stat

    from triadcal.io.atomic import atomic_write_text

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        (tmp_path / "b.txt").write_text("x")
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "a.txt").stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "b.txt").stat().st_mode) == 0o644


def test_an_event_log_torn_by_a_kill_is_ended_and_the_next_session_starts_on_its_own_line(tmp_path):
    from triadcal.hardware.storage import EventLog, read_events
    path = tmp_path / "events.jsonl"
    log = EventLog(path)
    log.write("session_start", session=1)
    log.close()
    with open(path, "a", encoding="utf-8") as fh:     # what a SIGKILL in the middle of a write leaves
        fh.write('{"wall_time": 1.0, "kind": "vis')
    log = EventLog(path)
    log.write("session_start", session=2)
    log.close()
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[1] == '{"wall_time": 1.0, "kind": "vis'           # the torn line is kept, ended
    kinds = [e["kind"] for e in read_events(path)]
    assert kinds == ["session_start", "torn_line", "session_start"]
    torn = read_events(path)[1]
    assert torn["line"] == 2 and torn["n_bytes"] == len('{"wall_time": 1.0, "kind": "vis')


def test_every_toml_reader_says_utf16_and_skips_a_bom(tmp_path):
    """An outside probe: a lab file saved as UTF-16 ended in "internal error: UnicodeDecodeError";
    one with a UTF-8 byte-order mark was "Invalid statement (line 1, column 1)". The lab file, the
    instruments and capture config files, bench profiles, tolerance files and manifests are read by
    one reader (io.atomic.read_toml)."""
    from triadcal.errors import InputError
    from triadcal.fleet.manifest import read_manifest
    from triadcal.fleet.summary import load_tolerances
    from triadcal.hardware.instrument_config import load_instruments
    from triadcal.io.lab import load_lab

    cases = [(load_lab, "[fixture]\nmounting_u_arcsec = 3.0\n", lambda r: r.mounting_u_arcsec == 3.0),
             (load_tolerances, "[tolerances]\nK_x = 1.0\n", lambda r: r == [("K_x", -1.0, 1.0, None)]),
             (load_instruments, "[chamber]\ndriver = \"espec\"\nport = \"loop://\"\n",
              lambda r: r["chamber"]["driver"] == "espec"),
             (read_manifest, "[[recording]]\n", None)]
    for i, (reader, text, ok) in enumerate(cases):
        p = tmp_path / f"f{i}.toml"
        p.write_bytes(text.encode("utf-16"))
        with pytest.raises(InputError, match=r"f\d.toml: not UTF-8 text \(byte 0; it is UTF-16\)"):
            reader(p)
        if ok is not None:
            p.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
            assert ok(reader(p))
        p.write_text("[oops\n", encoding="utf-8")
        with pytest.raises(InputError, match=r"not valid TOML \(a"):
            reader(p)
