"""The command line as a shell user meets it: piped into head, warnings, internal errors, the
same output flags on every command."""

import argparse
import os
import shlex
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from triadcal.cli import build_parser, main

CLI = [sys.executable, "-m", "triadcal.cli"]
EXAMPLE_CSV = Path(__file__).resolve().parents[1] / "triadcal" / "data" / "example_campaign.csv"


def _subcommands() -> dict:
    """Every subcommand the parser registers, name -> its parser (never a list kept by hand)."""
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def _minimal_argv(p: argparse.ArgumentParser) -> list:
    """The fewest arguments the parser accepts: each required option and positional, with a value of
    the right type (the first choice where there are choices)."""
    argv, positionals = [], []
    for a in p._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        if a.option_strings and not a.required:
            continue
        if not a.option_strings and a.nargs in ("?", "*"):
            continue
        value = str(a.choices[0] if a.choices else 1 if a.type in (int, float) else "x")
        if a.option_strings:
            argv += [a.option_strings[-1]] + ([] if a.nargs == 0 else [value])
        else:
            positionals.append(value)
    return argv + positionals


def test_piped_into_head_ends_quietly(tmp_path):
    """`triadcal budget | head -1`: the reader closes the pipe; no 'Broken pipe', exit 0."""
    p = subprocess.Popen(CLI + ["budget"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = p.stdout.readline()
    p.stdout.close()                      # what head does after its line
    err = p.stderr.read().decode()
    assert p.wait() == 0 and first and "Broken pipe" not in err and "Traceback" not in err


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


def test_an_unknown_preset_is_an_input_error_with_exit_1(tmp_path, capsys):
    """Once exit 2 (an argparse usage error, docs/model.md listed it as a known issue); an unknown
    preset is bad input like a missing file: exit 1, the presets named."""
    assert main(["simulate", "-o", str(tmp_path / "x.csv"), "--preset", "UNKNOWN"]) == 1
    err = capsys.readouterr().err
    assert "unknown preset 'UNKNOWN'" in err and "ak18-quartz" in err
    assert not (tmp_path / "x.csv").exists()


# -- the same output flags on every command (issue 22, item 6) -----------------------------

@pytest.mark.parametrize("name", sorted(_subcommands()))
def test_every_command_takes_no_progress_and_quiet(name):
    """Every registered command (the long ones and the others, so that a script need not know which
    is which) accepts --no-progress and --quiet, with the same meaning (cli/_common.py)."""
    from triadcal.cli._common import output

    parser = build_parser()
    minimal = _minimal_argv(_subcommands()[name])
    plain = parser.parse_args([name, *minimal])
    assert not plain.no_progress and not plain.quiet
    args = parser.parse_args([name, *minimal, "--no-progress", "--quiet"])
    assert args.no_progress and args.quiet
    quiet = output(parser.parse_args([name, *minimal, "--quiet"]))
    assert quiet.quiet and not quiet.progress                 # --quiet implies --no-progress


def test_a_progress_bar_only_on_a_terminal(monkeypatch):
    from triadcal.cli._common import output

    class Terminal:
        def isatty(self):
            return True

        def write(self, text):
            return len(text)

        def flush(self):
            pass

    parser = build_parser()
    args = parser.parse_args(["fit", "--example"])
    assert not output(args).progress                          # stderr is not a terminal here
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert output(args).progress
    assert not output(parser.parse_args(["fit", "--example", "--no-progress"])).progress
    assert not output(parser.parse_args(["fit", "--example", "--quiet"])).progress


def test_quiet_prints_nothing_on_stdout(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["fit", "--example", "--method", "joint", "--quiet", "--json", str(out)]) == 0
    assert capsys.readouterr().out == ""
    assert out.stat().st_size > 0                             # what it was asked to write, it wrote
    assert main(["fit", "--example", "--method", "joint"]) == 0
    assert "Ca_xy" in capsys.readouterr().out                 # and without --quiet, the summary


def _published_table(tmp_path) -> Path:
    path = tmp_path / "table3.csv"
    rows = ["exposure,sensor,angle,drift_arcsec"]
    for e, values in {"shock 20g": (8.03, 0.89, -0.51), "vib 20g": (-33.38, 17.76, 22.09)}.items():
        rows += [f"{e},gyro,{a},{v}" for a, v in zip(("xY", "xZ", "yZ"), values)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


PIPED = {
    "budget": ["budget"],
    "budget --thermal": ["budget", "--thermal"],
    "fit --example": ["fit", "--example"],
    # one candidate and 100 draws: the pipe meets the same report lines (2/3 of the CPU time of the
    # whole vocabulary's scores and refits, which test_diagnose.py tests)
    "diagnose": ["diagnose", str(EXAMPLE_CSV), "--candidates", "bias_drift", "--draws", "100", "--json",
                 "{tmp}/d.json"],
    "compare --published": ["compare", "--published", "{table}", "--u-arcsec", "12"],
}


@pytest.mark.parametrize("reader", ["head -1", "true"])
@pytest.mark.parametrize("command", sorted(PIPED))
def test_piped_into_a_reader_that_stops_early_ends_cleanly(command, reader, tmp_path):
    """`triadcal ... | head -1` in a shell: exit 0, no 'Broken pipe', no traceback. `true` closes the
    pipe before the command writes anything, so that the last flush of stdout meets a closed pipe
    every time (with `head -1` that depends on timing); stdout block-buffered, as in a terminal
    session (no PYTHONUNBUFFERED)."""
    exe = Path(sys.executable).with_name("triadcal")
    prefix = [str(exe)] if exe.exists() else CLI
    argv = [a.format(tmp=tmp_path, table=_published_table(tmp_path)) for a in PIPED[command]]
    err = tmp_path / "err.txt"
    script = f"{shlex.join(prefix + argv)} 2>{shlex.quote(str(err))} | {reader} >/dev/null; exit ${{PIPESTATUS[0]}}"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    env.update(MPLBACKEND="Agg", XDG_CACHE_HOME=str(tmp_path / "xdg"))
    rc = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env).returncode
    text = err.read_text()
    assert rc == 0 and "Broken pipe" not in text and "Traceback" not in text, (rc, text)


@pytest.mark.parametrize("argv, says", [
    (["fit", str(EXAMPLE_CSV), "--jsn", "x.json"], "triadcal fit: error: unrecognized arguments: --jsn x.json "
                                                   "(did you mean: --jsn -> --json?)"),
    (["budget", "--tua", "3"], "triadcal budget: error: unrecognized arguments: --tua 3 (did you mean: --tua -> --tau?)"),
    (["fit", "a.csv", "b.csv"], "triadcal fit: error: unrecognized arguments: b.csv"),
])
def test_a_mistyped_option_gets_the_commands_usage_and_the_likely_option(argv, says, capsys):
    """A newcomer's typo printed the top level's usage ("triadcal [-h] [--version] COMMAND ...")
    and no hint; now the command's usage, its name in the error, and the closest option."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert says in err and f"usage: triadcal {argv[0]}" in err


def test_an_unknown_top_level_option_keeps_the_top_level_usage(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--bogus"])
    assert exc.value.code == 2 and "triadcal: error: unrecognized arguments: --bogus" in capsys.readouterr().err


def test_capture_emulate_refuses_port_options_it_would_ignore(tmp_path, capsys):
    """`capture --emulate --imu-port /dev/x --chamber-slave 7` exited 0 with both ignored (a
    newcomer's probe): the emulator makes its own ports. Refused before anything starts."""
    rc = main(["capture", "--emulate", "--imu-port", "/dev/does-not-exist", "--chamber-slave", "7",
               "--setpoints", "20", "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1 and "--imu-port, --chamber-slave would be ignored" in err, err
    assert not (tmp_path / "run").exists()
