"""The smaller readers take numbers through the same parser: interval files of fit-raw and the
bench plan of capture refuse what is not a number in range, naming the file and the place."""

import json

import pytest

from triadcal.hardware.capture import plan_from_csv
from triadcal.io.raw import RawRecordingError, read_intervals


@pytest.mark.parametrize("entry, needle", [({"start": None, "end": 10}, "a.start"),
                                           ({"start": "x", "end": 10}, "a.start"),
                                           ({"start": 1.5, "end": 10}, "not an integer"),
                                           ({"start": -1, "end": 10}, "outside"),
                                           ({"start": 0, "end": 1e300}, "outside")])
def test_interval_json_values(tmp_path, entry, needle):
    p = tmp_path / "i.json"
    p.write_text(json.dumps({"a": entry}))
    with pytest.raises(RawRecordingError, match=needle) as e:
        read_intervals(p)
    assert str(p) in str(e.value)


@pytest.mark.parametrize("text, needle", [("start,end\n0,100\nnan,200\n", ":3"), ("0,100\n1_0,200\n", ":2"),
                                          ("0,100\n5,inf\n", ":2"), ("0,100\n-5,20\n", "outside")])
def test_interval_csv_values(tmp_path, text, needle):
    p = tmp_path / "i.csv"
    p.write_text(text)
    with pytest.raises(RawRecordingError, match=needle):
        read_intervals(p)


@pytest.mark.parametrize("row, needle", [("P01,0,400", "axis2_deg 400 outside"), ("P01,abc,0", "not a number"),
                                         ("P01,nan,0", "not a finite"), ("P01,0", "expected a label"),
                                         ("P00,0,0", "appears twice")])
def test_plan_values(tmp_path, row, needle):
    p = tmp_path / "plan.csv"
    p.write_text("position,axis1_deg,axis2_deg\nP00,0,0\n" + row + "\n")
    with pytest.raises(ValueError, match=needle) as e:
        plan_from_csv(p)
    assert f"{p}:3" in str(e.value)


def test_fit_given_a_raw_recording_points_to_fit_raw(tmp_path):
    """A newcomer's probe: `fit` on a raw recording said only "column 'unit' is missing"."""
    from triadcal.io.bench_csv import BenchCSVError, read_bench_csv

    p = tmp_path / "raw.csv"
    p.write_text("ax,ay,az\n0.1,0.2,9.8\n0.1,0.2,9.8\n", encoding="utf-8")
    with pytest.raises(BenchCSVError, match=r"raw recording of static poses\? `triadcal fit-raw"):
        read_bench_csv(p)
