"""The command line as a shell user meets it: piped into head, warnings, internal errors."""

import os
import subprocess
import sys
import warnings

from triadcal.cli import main

CLI = [sys.executable, "-m", "triadcal.cli"]


def test_piped_into_head_ends_quietly(tmp_path):
    """`triadcal budget | head -1`: the reader closes the pipe; no 'Broken pipe', exit 0."""
    p = subprocess.Popen(CLI + ["budget"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = p.stdout.readline()
    p.stdout.close()                      # what head does after its line
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 0 and first and "Broken pipe" not in err and "Traceback" not in err


def test_a_warning_is_one_line_without_paths(capsys, monkeypatch):
    import triadcal.cli.budget as budget_cli

    real = budget_cli.run

    def noisy(args):
        warnings.warn("overflow encountered in square", RuntimeWarning)
        return real(args)

    monkeypatch.setattr(budget_cli, "run", noisy)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["budget"]) == 0
    err = capsys.readouterr().err
    assert "triadcal: warning: overflow encountered in square" in err
    assert os.sep + "triadcal" + os.sep not in err          # no source path of the library


def test_an_internal_error_is_one_line_with_exit_70(capsys, monkeypatch):
    import triadcal.cli.budget as budget_cli

    def broken(args):
        raise TypeError("unsupported operand")

    monkeypatch.setattr(budget_cli, "run", broken)
    monkeypatch.delenv("TRIADCAL_DEBUG", raising=False)
    assert main(["budget"]) == 70
    err = capsys.readouterr().err
    assert "internal error: TypeError: unsupported operand" in err and "Traceback" not in err


def test_a_missing_file_is_named_in_a_sentence(tmp_path, capsys):
    missing = tmp_path / "nope.csv"
    assert main(["fit", str(missing)]) == 1
    err = capsys.readouterr().err
    assert f"{missing}: no such file or directory" in err and "[Errno" not in err
