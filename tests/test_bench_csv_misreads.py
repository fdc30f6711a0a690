"""Bench CSV files that an outside tester found read silently into a confident wrong calibration
(status ok), now refused with the file, the line and the field (docs/bench-csv.md):

1. a metadata key mistyped (``# local_g = 9.78``, ``# Local_G_m_s2 = 9.78``, ``# output_units = mV``)
   or written with ':' (``# local_g_m_s2: 9.78``): it was dropped and the default used;
2. t_x t_y t_z in degF (68 at a 20 degC setpoint);
3. heating and cooling swapped: every hysteresis term changed sign.

Each mutated file is made from a valid one -- the example campaign, or a campaign of
tests/independent_bench.py (made without the package's model code) -- and the valid file itself
is read too.
"""

import csv
import io

import numpy as np
import pytest
from independent_bench import RampProgram, StepProgram, simulate_campaign, simulate_lag_campaign

from triadcal.api import example_path
from triadcal.io.bench_csv import BenchCSVError, read_bench_csv

SWAP = {"heating": "cooling", "cooling": "heating", "none": "none"}


class Table:
    """A bench CSV split into its comment lines, header and rows, mutated and written back."""

    def __init__(self, text: str):
        lines = text.splitlines()
        k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
        self.comments = lines[:k]
        self.header = next(csv.reader([lines[k]]))
        self.rows = [r for r in csv.reader(lines[k + 1:]) if r]

    def line_of_row(self, i: int) -> int:
        """1-based line of data row ``i`` in the written file (comments, then the header)."""
        return len(self.comments) + 2 + i

    def line_of_comment(self, start: str) -> int:
        return next(j for j, ln in enumerate(self.comments) if ln.startswith(start)) + 1

    def col(self, name):
        j = self.header.index(name)
        return [r[j] for r in self.rows]

    def map(self, name, f):
        j = self.header.index(name)
        for r in self.rows:
            r[j] = f(r[j])

    def write(self, path):
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.header)
        w.writerows(self.rows)
        path.write_text("\n".join(self.comments) + ("\n" if self.comments else "") + buf.getvalue())
        return path


def example_table() -> Table:
    return Table(example_path().read_text())


def independent_table(**kw) -> Table:
    kw.setdefault("setpoints_C", (20.0, 50.0, 80.0, 50.0, 20.0, -10.0, -40.0, -10.0, 20.0))
    text, _ = simulate_campaign(np.random.default_rng(7), **kw)
    return Table(text)


def lag_table(program=None) -> Table:
    text, _ = simulate_lag_campaign(np.random.default_rng(3), program=program, dt_s=2.0)
    return Table(text)


def refused(path) -> BenchCSVError:
    with pytest.raises(BenchCSVError) as info:
        read_bench_csv(path)
    err = info.value
    assert err.path == str(path) and str(err).startswith(f"{path}:{err.line}:")
    return err


def fahrenheit(s: str) -> str:
    return repr(float(s) * 1.8 + 32.0)


@pytest.fixture(params=["example", "independent"])
def valid(request):
    return example_table() if request.param == "example" else independent_table()


def test_the_valid_files_read(tmp_path, valid):
    c = read_bench_csv(valid.write(tmp_path / "valid.csv"))
    assert c.n_visits == len(valid.rows)


# -- 1. metadata keys ---------------------------------------------------------------------------

@pytest.mark.parametrize("line, key, known", [
    ("# local_g = 9.78", "local_g", "local_g_m_s2"),
    ("# Local_G_m_s2 = 9.78", "Local_G_m_s2", "local_g_m_s2"),
    ("# local_g_ms2 = 9.78", "local_g_ms2", "local_g_m_s2"),
    ("# local g m s2 = 9.78", "local g m s2", "local_g_m_s2"),
    ("# q_v2s = 3e-9", "q_v2s", "Q_V2s"),
    ("# power_on = 0", "power_on", "power_on_s"),
])
def test_a_mistyped_local_g_or_other_known_key_is_refused(tmp_path, valid, line, key, known):
    table = valid
    table.comments = [ln for ln in table.comments if not ln.startswith(("# local_g_m_s2", "# Q_V2s", "# power_on_s"))]
    table.comments.insert(1, line)
    err = refused(table.write(tmp_path / "typo.csv"))
    assert err.line == 2 and err.column is None            # a metadata line: the key is named
    assert f"metadata key '{key}'" in err.problem and f"did you mean '{known}'" in err.problem


def test_output_units_mv_is_refused_not_read_as_volts(tmp_path, valid):
    table = valid
    line = table.line_of_comment("# output_unit")
    table.comments[line - 1] = "# output_units = mV"
    err = refused(table.write(tmp_path / "units.csv"))
    assert err.line == line and "'output_units'" in err.problem and "did you mean 'output_unit'" in err.problem


@pytest.mark.parametrize("line, known", [("# local_g_m_s2: 9.78", "local_g_m_s2"),
                                         ("# output_unit: mV", "output_unit"),
                                         ("# Local_G_m_s2 : 9.78", "local_g_m_s2")])
def test_a_metadata_line_with_a_colon_is_refused(tmp_path, valid, line, known):
    table = valid
    j = table.line_of_comment(f"# {known}")
    table.comments[j - 1] = line
    err = refused(table.write(tmp_path / "colon.csv"))
    assert err.line == j and "':'" in err.problem and f"'# {known} = " in err.problem


def test_free_keys_and_prose_comments_still_read(tmp_path, valid):
    table = valid
    table.comments += ["# a free comment without a key", "# Note: K is in g/V, see the lab book",
                       "# note = a = b", "# operator=J. Doe", "# input_unit = V", "# temperature = placeholder",
                       "# bench_id = 7", "# output = analog", "# power = 5 W", "# the local g: measured in 2024",
                       "# ramp_rate = 1", "", "# t_override = false"]
    c = read_bench_csv(table.write(tmp_path / "free.csv"))
    assert c.metadata["note"] == "a = b" and c.metadata["bench_id"] == "7" and c.metadata["output"] == "analog"
    assert "Note: K is in g/V, see the lab book" not in c.metadata and c.output_unit == "V"


# -- 2. temperatures in degF ---------------------------------------------------------------------

def test_temperatures_in_fahrenheit_are_refused(tmp_path, valid):
    table = valid
    for col in ("t_x", "t_y", "t_z"):
        table.map(col, fahrenheit)
    err = refused(table.write(tmp_path / "degF.csv"))
    assert err.column == "t_x" and "degF" in err.problem and "(t - 32)/1.8" in err.problem
    assert "1.8 setpoint_C" in err.problem                 # the slope over the setpoints
    sp, t = np.array(table.col("setpoint_C"), float), np.array(table.col("t_x"), float)
    first = int(np.flatnonzero(np.abs(t - sp) >= 10.0)[0])  # the first row that shows it
    assert err.line == table.line_of_row(first)


def test_a_file_wholly_in_fahrenheit_is_refused_by_its_setpoints(tmp_path, valid):
    """An outside probe converted setpoint_C and every t_* of the example campaign to degF: the t_*
    check compares the two columns, which agree, and the fit said ok with K_x 400 ppm (300 u) and
    Ca_xy 80 u off. The setpoints are the degF of multiples of 5 degC: refused, with the override."""
    table = valid
    for col in ("setpoint_C", "t_x", "t_y", "t_z"):
        table.map(col, fahrenheit)
    err = refused(table.write(tmp_path / "all_degF.csv"))
    sp = np.array(table.col("setpoint_C"), float)
    first = int(np.flatnonzero(np.abs(sp / 5 - np.round(sp / 5)) > 0.01)[0])
    assert err.column == "setpoint_C" and err.line == table.line_of_row(first)
    assert "are the degF of" in err.problem and "(x - 32)/1.8" in err.problem
    table.comments.append("# t_override = true")
    assert read_bench_csv(table.write(tmp_path / "override.csv")).n_visits == len(table.rows)


def test_one_column_in_fahrenheit_is_named(tmp_path):
    table = independent_table()
    table.map("t_y", fahrenheit)
    err = refused(table.write(tmp_path / "degF_y.csv"))
    assert err.column == "t_y" and err.line == table.line_of_row(0)     # 20 degC -> 68


def test_a_cold_campaign_in_fahrenheit_is_refused(tmp_path):
    table = independent_table(setpoints_C=(-40.0, -25.0, -10.0))       # degF and degC meet at -40
    for col in ("t_x", "t_y", "t_z"):
        table.map(col, fahrenheit)
    err = refused(table.write(tmp_path / "cold.csv"))
    assert err.column == "t_x" and err.line == table.line_of_row(12)    # the first row at -25 degC


def test_one_setpoint_in_fahrenheit_is_refused_and_the_override_reads_it(tmp_path):
    table = independent_table(setpoints_C=(20.0,))
    for col in ("t_x", "t_y", "t_z"):
        table.map(col, fahrenheit)
    err = refused(table.write(tmp_path / "one.csv"))
    assert err.column == "t_x" and err.line == table.line_of_row(0) and "t_override" in err.problem
    table.comments.append("# t_override = true")                   # an oven-controlled unit at 68 degC
    assert read_bench_csv(table.write(tmp_path / "oven.csv")).t[0, 0] > 60.0


def test_a_ramp_in_fahrenheit_is_refused(tmp_path):
    table = lag_table()                 # setpoint_C: the target of each leg, so t is far from it
    read_bench_csv(table.write(tmp_path / "ramp.csv"))
    for col in ("t_x", "t_y", "t_z"):
        table.map(col, fahrenheit)
    err = refused(table.write(tmp_path / "ramp_degF.csv"))
    t, hi = np.array(table.col("t_x"), float), max(float(v) for v in table.col("setpoint_C"))
    assert err.column == "t_x" and err.line == table.line_of_row(int(np.flatnonzero(t > hi + 20.0)[0]))
    assert "above the highest setpoint" in err.problem


@pytest.mark.parametrize("col", ["t_x", "t_z"])
def test_a_stuck_thermometer_is_refused(tmp_path, valid, col):
    """An outside probe: t_z = 20.35 on every visit of a -20...60 degC campaign crashed the classical
    fit (a singular matrix, exit 70) and made the joint one hold K_z, S_z and its angles at nominal
    and blame a missing effect. Now the reader names the column; with the override the classical fit
    refuses with the reason instead of crashing."""
    valid.map(col, lambda v: "20.35")
    err = refused(valid.write(tmp_path / "stuck.csv"))
    assert err.column == col and err.line == valid.line_of_row(0)
    assert "stuck or disconnected thermometer" in err.problem and "t_override" in err.problem
    valid.comments.append("# t_override = true")
    from triadcal.errors import InputError
    from triadcal.estimation.classical import fit_classical

    c = read_bench_csv(valid.write(tmp_path / "override.csv"))
    with pytest.raises(InputError, match=f"the {col[-1]} accelerometer's sensor is 20.35 degC at every setpoint"):
        fit_classical(c)


def test_one_setpoint_with_one_thermometer_steady_reads(tmp_path):
    """At one setpoint every sensor may hold its value: nothing spans 1 degC, nothing is stuck."""
    table = independent_table(setpoints_C=(20.0,))
    table.map("t_z", lambda v: "20.35")
    assert read_bench_csv(table.write(tmp_path / "one.csv")).t[0, 2] == 20.35


@pytest.mark.parametrize("case", ["self-heating 8 degC", "oven-controlled", "lagging", "cold", "hot", "ramp"])
def test_legitimate_temperatures_still_read(tmp_path, case):
    if case == "self-heating 8 degC":
        table = independent_table()
        table.map("t_x", lambda s: repr(float(s) + 8.0))
    elif case == "oven-controlled":                       # the sensors read the oven, not the chamber
        table = independent_table(setpoints_C=(-40.0, -10.0, 20.0))
        for col in ("t_x", "t_y", "t_z"):
            table.map(col, lambda s: repr(65.0 + 0.01 * float(s)))
    elif case == "lagging":                                # visits before the unit has settled
        table = lag_table(StepProgram(soak_min=15.0))
    elif case == "cold":
        table = independent_table(setpoints_C=(-45.0, -40.0, -35.0))
    elif case == "hot":                                    # a downhole tool's range
        table = independent_table(setpoints_C=(20.0, 85.0, 150.0, 175.0))
    else:
        table = lag_table(RampProgram(points_C=(20.0, -40.0, 85.0, 20.0), rate_C_per_min=2.0, hold_min=20.0))
    read_bench_csv(table.write(tmp_path / "ok.csv"))


# -- 3. heating and cooling swapped --------------------------------------------------------------

def test_swapped_directions_are_refused(tmp_path, valid):
    table = valid
    table.map("direction", SWAP.get)
    err = refused(table.write(tmp_path / "swapped.csv"))
    sp, d = table.col("setpoint_C"), table.col("direction")
    first = next(i for i in range(1, len(sp)) if sp[i] != sp[i - 1])     # the second setpoint block
    assert err.column == "direction" and err.line == table.line_of_row(first)
    want = "heating" if float(sp[first]) > float(sp[first - 1]) else "cooling"
    assert (f"the setpoint went from {float(sp[first - 1]):g} degC (line {table.line_of_row(first - 1)}) to "
            f"{float(sp[first]):g} degC: that is {want}, not {d[first]}") in err.problem


def test_a_slow_marked_ramp_swapped_is_refused_by_most_of_its_labels(tmp_path):
    table = lag_table(RampProgram(points_C=(20.0, 5.0, 35.0), rate_C_per_min=0.1))
    table.comments.append("# ramp = 20:5:35 degC at 0.1 degC/min")
    read_bench_csv(table.write(tmp_path / "slow.csv"))
    table.map("direction", SWAP.get)
    err = refused(table.write(tmp_path / "slow_swapped.csv"))
    assert err.column == "direction" and "are against their rate" in err.problem


def test_one_block_against_the_sequence_reads_but_most_blocks_are_refused(tmp_path):
    """One block whose label contradicts the setpoint sequence is what a unit taken past the next
    setpoint without a logged visit gives (a preconditioning excursion: 70 -> 85 unlogged -> 55
    'heating'), which an outside tester's legitimate files did: it reads. Most of the blocks
    against their labels is a swapped file: refused, naming the first."""
    table = example_table()             # 20 none, 35 55 70 heating, 55 cooling, ...
    rows = [i for i, (s, d) in enumerate(zip(table.col("setpoint_C"), table.col("direction")))
            if s == "55.0" and d == "cooling"]
    for i in rows:
        table.rows[i][table.header.index("direction")] = "heating"
    read_bench_csv(table.write(tmp_path / "one_block.csv"))
    table = example_table()
    table.map("direction", SWAP.get)         # every block against its label
    err = refused(table.write(tmp_path / "swapped.csv"))
    assert err.column == "direction" and "setpoint changes checked contradict" in err.problem


def test_swapped_ramp_directions_are_refused(tmp_path):
    table = lag_table()                 # direction: the sign of the unit's rate; setpoint_C: the leg's target
    read_bench_csv(table.write(tmp_path / "ramp.csv"))
    table.map("direction", SWAP.get)
    err = refused(table.write(tmp_path / "ramp_swapped.csv"))
    assert err.column == "direction" and "that is heating, not cooling" in err.problem
    # a file that says it is a ramp: the label against the rate of the temperature readings
    table.comments.append("# ramp = 20:-40:70:20 degC at 1 degC/min")
    err = refused(table.write(tmp_path / "ramp_marked.csv"))
    assert err.column == "direction" and "falls at" in err.problem
    i = err.line - table.line_of_row(0)
    t = [np.mean([float(r[table.header.index(c)]) for c in ("t_x", "t_y", "t_z")]) for r in table.rows]
    assert table.col("direction")[i] == "heating" and t[i + 1] < t[i - 1]


@pytest.mark.parametrize("case", ["none", "repeated setpoint", "1 degC steps", "measured setpoint", "ramp",
                                  "ramp with holds", "ramp marked", "two units", "after shock"])
def test_legitimate_directions_still_read(tmp_path, case):
    if case == "1 degC steps":
        table = independent_table(setpoints_C=(20.0, 21.0, 22.0, 23.0, 22.0, 21.0))
    elif case == "measured setpoint":   # the chamber's reading written as setpoint_C: an overshoot settling
        table = independent_table(setpoints_C=(20.0, 35.8, 35.5, 35.2, 35.0, 20.0))
        j = table.header.index("direction")
        for r in table.rows[12:60]:
            r[j] = "heating"
    elif case == "none":                # a setpoint reached with no known history
        table = example_table()
        j = table.header.index("direction")
        for r in table.rows[24:36]:
            r[j] = "none"
    elif case == "repeated setpoint":   # keeps the previous direction (docs/model.md)
        table = independent_table(setpoints_C=(20.0, 20.0, 50.0, 50.0, 20.0))
    elif case in ("ramp", "ramp marked"):   # the unit keeps its direction for a while after the program turns
        table = lag_table()
        if case == "ramp marked":
            table.comments.append("# ramp = 20:-40:70:20 degC at 1 degC/min")
    elif case == "ramp with holds":
        table = lag_table(RampProgram(points_C=(20.0, 60.0, 30.0, 70.0), rate_C_per_min=0.5, hold_min=30.0))
    elif case == "two units":           # interleaved in time, each with its own history
        a, b = independent_table(unit="SN-A"), independent_table(unit="SN-B", setpoints_C=(80.0, 20.0, -40.0))
        jt = a.header.index("time_s")
        for r in b.rows:
            r[jt] = repr(float(r[jt]) + 25.0)
        table = a
        table.rows = sorted(a.rows + b.rows, key=lambda r: float(r[jt]))
    else:                               # a second state starts its own history
        a, b = independent_table(), independent_table(setpoints_C=(80.0, 20.0))
        jt, js, jd = a.header.index("time_s"), a.header.index("state"), a.header.index("direction")
        for r in b.rows:
            r[jt], r[js] = repr(float(r[jt]) + 1e6), "after-shock"
        for r in b.rows[:12]:           # the lab knows it came from a hot shock test
            r[jd] = "cooling"
        table = a
        table.rows = a.rows + b.rows
    read_bench_csv(table.write(tmp_path / "ok.csv"))


@pytest.mark.parametrize("line, refused_", [
    ("# Power on 07:55", False), ("# Override: none", False), ("# Ramps: 1 degC/min between setpoints", False),
    ("# Quantisation: none (DMM)", False), ("# Power on: 08:00 local time", False), ("# Date: see log book", False),
    ("# Bench: two-axis rate table", False), ("# Operator: J. Smith", False), ("# Local gravity measured 2025", False),
    ("# local_g_m_s2: 9.78", True), ("# Q_V2s: 3e-9", True), ("# output_unit: mV", True),
    ("# Local gravity = 9.8123", True), ("# local_g = 9.78", True), ("# Local_G_m_s2 = 9.78", True)])
def test_prose_comments_read_and_metadata_meant_as_such_is_refused(tmp_path, line, refused_):
    """An outside tester's prose comments ('# Power on: 08:00 local time', '# Override: none') were
    refused as near-miss metadata, with suggested fixes that did not parse; '# Local gravity =
    9.8123' was ignored (standard gravity taken). A ':' line is refused only for a key the model
    reads with a value of its kind."""
    from triadcal.api import example_path

    text = example_path().read_text().replace("# Q_V2s = 3e-09\n", "# Q_V2s = 3e-09\n" + line + "\n")
    (tmp_path / "m.csv").write_text(text)
    if refused_:
        with pytest.raises(BenchCSVError):
            read_bench_csv(tmp_path / "m.csv")
    else:
        read_bench_csv(tmp_path / "m.csv")


# -- one visit written twice ----------------------------------------------------------------------
def test_every_visit_written_twice_is_refused(tmp_path, valid):
    """An outside probe wrote every visit twice, the copy 1 s later (windows overlapping, readings
    equal to the last digit): status ok, every u 0.707 of the single file's. Refused at the copy,
    naming the line it repeats."""
    rows, t = [], valid.header.index("time_s")
    for r in valid.rows:
        copy = list(r)
        copy[t] = repr(float(r[t]) + 1.0)
        rows += [r, copy]
    valid.rows = rows
    err = refused(valid.write(tmp_path / "twice.csv"))
    assert err.line == valid.line_of_row(1) and err.column == "w_x"
    assert f"repeat line {valid.line_of_row(0)}'s to the last digit" in str(err) and "windows overlap" in str(err)


def test_equal_readings_far_apart_are_refused_with_noise_and_read_without(tmp_path):
    """Hand-made: row 40 given row 3's readings, a day later. With sd_* above 0 two averages are never
    equal: refused. Without noise columns but with the file's `# Q_V2s` the visits are noisy averages
    too: refused (an outside probe wrote every visit twice with Q_V2s and no sd_*: status ok in 6 of
    12, every u 0.71 times; 2026-12-02). With no noise stated at all, means written to 10 significant
    digits or more are averages no two of which are equal by chance: refused; written to a coarse step
    (a quantised quiet output visiting one position twice reads equal) they are read."""
    tab = independent_table()
    cols = [tab.header.index(c) for c in ("w_x", "w_y", "w_z")]
    for j in cols:
        tab.rows[40][j] = tab.rows[3][j]
    err = refused(tab.write(tmp_path / "noisy.csv"))
    assert err.line == tab.line_of_row(40) and "never equal" in str(err)
    keep = [i for i, h in enumerate(tab.header) if h not in ("sd_x", "sd_y", "sd_z", "n_samples")]
    tab.header = [tab.header[i] for i in keep]
    tab.rows = [[r[i] for i in keep] for r in tab.rows]
    tab.comments.append("# Q_V2s = 2.5e-07")
    err = refused(tab.write(tmp_path / "q.csv"))
    assert err.line == tab.line_of_row(40) and "the file's Q_V2s" in str(err)
    tab.comments.pop()
    err = refused(tab.write(tmp_path / "digits.csv"))
    assert err.line == tab.line_of_row(40) and "written to 10 significant digits" in str(err)
    for name in ("w_x", "w_y", "w_z"):
        tab.map(name, lambda v: f"{float(v):.4f}")
    assert read_bench_csv(tab.write(tmp_path / "quiet.csv")).n_visits == 108


def test_means_rounded_coarser_than_their_noise_may_repeat_and_weigh_their_rounding(tmp_path):
    """An outside probe's visit means written to 4 decimals of V (a spreadsheet export) with a
    standard error of 1e-5 V: two visits of one pose at setpoints 30 degC apart read equal, and the
    reader refused them as "the same visit twice ... two such averages are never equal" (the advice,
    remove the copy, would delete a real visit). Rounded to 1e-4 V (11 standard errors) equal means
    are no evidence of a copy: read. The rounding is noise of the means the sd_* do not hold: q^2/12
    joins each visit's variance (GUM F.2.2.1) where it does not exceed the stated noise (1e-5 V: the
    fit ok, every |z| < 4). Where it dominates it is said, not added: one pose's means round alike,
    and weights calling that independent gave status ok with a parameter 5.6 u off; the stated noise
    alone leaves the goodness-of-fit gate to refuse (1e-4 V: model_mismatch). The file printed in
    full is refused as before (test above)."""
    from triadcal import api
    from triadcal.estimation.noise_model import noise_of
    from triadcal.io.bench_checks import written_resolution

    assert written_resolution([0.1235, -0.7062, 1.0]) == pytest.approx(1e-4)
    assert written_resolution([0.123456789012345, 1.0]) == 0.0
    se = 0.0005 / np.sqrt(3000) * np.sqrt(2999 / 2997)
    effects = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
    for decimals, q in ((4, 1e-4), (5, 1e-5)):
        tab = independent_table()
        truth = simulate_campaign(np.random.default_rng(7), setpoints_C=(20.0, 50.0, 80.0, 50.0, 20.0, -10.0, -40.0,
                                                                          -10.0, 20.0))[1]
        for name in ("w_x", "w_y", "w_z"):
            tab.map(name, lambda v, d=decimals: f"{float(v):.{d}f}")
        path = tab.write(tmp_path / f"rounded{decimals}.csv")
        noise = noise_of(read_bench_csv(path))
        fit = api.fit(path, effects=effects)
        if decimals == 4:
            assert "exceeds their stated noise (x q 0.0001" in noise.description and np.allclose(noise.sigma, se)
            assert fit.status == "model_mismatch"
            # and the fit says the rounding may be what fails it (before: only "the model misses something")
            said = [n for n in fit.notes if n.startswith("the means are written to a step whose rounding exceeds")]
            assert len(said) == 1 and "x q 0.0001 V (q/sqrt(12) 3.16 times the median stated SD)" in said[0], fit.notes  # 1e-4/sqrt(12)/se
            classical = api.fit(path, method="classical")
            assert any(n.startswith("the means are written to a step whose rounding") for n in classical.notes)
            cols = [tab.header.index(c) for c in ("w_x", "w_y", "w_z")]
            for j in cols:
                tab.rows[40][j] = tab.rows[3][j]
            assert read_bench_csv(tab.write(tmp_path / "equal.csv")).n_visits == 108
        else:
            assert "rounding of the means as written" in noise.description and "x 1e-05" in noise.description
            assert np.allclose(noise.sigma, np.sqrt(se ** 2 + q ** 2 / 12), rtol=1e-6)
            assert not any("rounding exceeds" in n for n in fit.notes)
            z = [abs(fit.parameters[n].value - v) / fit.parameters[n].u for n, v in truth.items() if n in fit.parameters]
            assert fit.status == "ok" and max(z) < 4.0, (fit.status, max(z))


@pytest.mark.parametrize("k_true", [1.0007, 2.0])
def test_millivolts_declared_as_volts_are_refused_by_their_magnitude(tmp_path, k_true):
    """An outside probe: a unit of about 1 V/g recorded in mV and declared V was certified with K
    1000 times too small in 5 of 10 seeds (the plausible band of a V output reached 1000 V/g, and
    K = 0.0010007 g/V lay inside it). The band now ends at 100 V/g (no voltage input reads beyond
    +-100 V on a +-1 g tumble): refused naming the implied K; the same file in V is read."""
    from triadcal.estimation.gates import SCALE_BAND_G_PER_UNIT

    assert SCALE_BAND_G_PER_UNIT["V"][0] == 1e-2
    text, _ = simulate_campaign(np.random.default_rng(4), setpoints_C=(20,))
    (tmp_path / "V.csv").write_text(text, encoding="utf-8")
    assert read_bench_csv(tmp_path / "V.csv").output_unit == "V"
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("unit,"))
    cols = lines[i].split(",")
    idx = [cols.index(c) for c in ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z")]
    out = lines[: i + 1]
    for ln in lines[i + 1:]:
        f = ln.split(",")
        for j in idx:
            f[j] = repr(float(f[j]) * 1000.0 / k_true)       # about 1000/k_true "V" per g
        out.append(",".join(f))
    p = tmp_path / "mV_as_V.csv"
    p.write_text("\n".join(out) + "\n", encoding="utf-8")
    with pytest.raises(BenchCSVError, match=r"implies K = 0\.00\d+ g/V, below the plausible 0\.01-20000 g/V"):
        read_bench_csv(p)
