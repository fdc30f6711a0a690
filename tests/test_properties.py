"""Property-based tests (hypothesis) of the readers: whatever the input, a bench CSV read gives
a Campaign or a BenchCSVError, a result read gives a CalibrationResult or a ValueError — never
another exception — and what is written is read back exactly."""

import json

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from triadcal.api import example_path
from triadcal.estimation.result import CalibrationResult
from triadcal.io.bench_csv import BenchCSVError, RANGES, format_bench_csv, parse_bench_csv

TEXT = example_path().read_text()
LINES = TEXT.splitlines()
N_META = sum(1 for ln in LINES if ln.startswith("#"))
HEADER = LINES[N_META].split(",")
CAMPAIGN = parse_bench_csv(TEXT, "example.csv")
SETTINGS = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])

JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
                    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=5), children,
                                                                                       max_size=4),
                    max_leaves=12)


@SETTINGS
@given(row=st.integers(0, len(LINES) - N_META - 2), line=st.text(max_size=60))
def test_any_line_gives_a_campaign_or_a_located_refusal(row, line):
    lines = list(LINES)
    lines[N_META + 1 + row] = line
    try:
        parse_bench_csv("\n".join(lines), "p.csv")
    except BenchCSVError as exc:
        assert str(exc).startswith("p.csv:")


@SETTINGS
@given(row=st.integers(0, len(LINES) - N_META - 2), col=st.sampled_from(sorted(RANGES)),
       data=st.data())
def test_any_value_in_range_is_read_back_exactly(row, col, data):
    low, high, low_open = RANGES[col]
    if col in ("t_x", "t_y", "t_z", "setpoint_C"):
        high = 150.0                            # a median >= 200 degC is refused as kelvin
    value = data.draw(st.floats(low, high, allow_nan=False, allow_infinity=False, exclude_min=low_open))
    lines = list(LINES)
    f = lines[N_META + 1 + row].split(",")
    f[HEADER.index(col)] = repr(value)
    lines[N_META + 1 + row] = ",".join(f)
    try:
        c = parse_bench_csv("\n".join(lines), "p.csv")
    except BenchCSVError as exc:
        # a value may be valid alone and still make the file inconsistent (a duplicate time,
        # readings whose magnitude contradicts the unit): refused with the place, never lost
        assert str(exc).startswith("p.csv:")
        return
    got = {"w_x": c.w[row, 0], "w_y": c.w[row, 1], "w_z": c.w[row, 2], "t_x": c.t[row, 0], "t_y": c.t[row, 1],
           "t_z": c.t[row, 2], "sd_x": c.sd[row, 0], "sd_y": c.sd[row, 1], "sd_z": c.sd[row, 2]}.get(col)
    if got is None:
        got = getattr(c, col)[row]
    assert got == value


def test_write_then_read_is_exact():
    again = parse_bench_csv(format_bench_csv(CAMPAIGN), "again.csv")
    for name in ("w", "t", "sd", "axis1_deg", "axis2_deg", "tau_s", "time_s", "setpoint_C"):
        assert np.array_equal(getattr(again, name), getattr(CAMPAIGN, name)), name
    assert format_bench_csv(again) == format_bench_csv(CAMPAIGN)


GOOD = None


def _good():
    global GOOD
    if GOOD is None:
        from triadcal.estimation.classical import fit_classical

        GOOD = fit_classical(CAMPAIGN).to_dict()
        GOOD = json.loads(json.dumps(GOOD))
    return GOOD


@SETTINGS
@given(tree=JSON)
def test_any_json_tree_gives_a_result_or_a_value_error(tree):
    try:
        CalibrationResult.from_dict(tree, "t.json")
    except ValueError:
        pass


@SETTINGS
@given(path=st.lists(st.sampled_from(["parameters", "K_x", "value", "u", "unit", "status", "correlation",
                                      "names", "matrix", "fit", "notes", "effects", "reference_temperature_C",
                                      "temperature_range_C", 0, 1]), min_size=1, max_size=3), value=JSON)
def test_any_field_replaced_gives_a_result_or_a_value_error(path, value):
    d = json.loads(json.dumps(_good()))
    node = d
    for key in path[:-1]:
        if isinstance(node, dict) and key in node:
            node = node[key]
        elif isinstance(node, list) and isinstance(key, int) and key < len(node):
            node = node[key]
        else:
            return
    last = path[-1]
    if isinstance(node, dict) and isinstance(last, str):
        node[last] = value
    elif isinstance(node, list) and isinstance(last, int) and last < len(node):
        node[last] = value
    else:
        return
    try:
        r = CalibrationResult.from_dict(d, "t.json")
    except ValueError:
        return
    # what was read is what the gates then judge: no exception either
    from triadcal.estimation.gates import result_problems

    result_problems(r)
