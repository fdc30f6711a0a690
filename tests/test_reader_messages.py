"""Messages of the readers on inputs an outside fuzz probe found read with a misleading reason:
each now says what is wrong (2026-12-01)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.io.bench_csv import read_bench_csv
from triadcal.io.raw import read_raw_csv

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "data" / "campaign.csv"


def test_a_utf16_recording_is_said_to_be_utf16(tmp_path):
    p = tmp_path / "u16.csv"
    p.write_bytes((ROOT / "examples" / "data" / "mikoff_imu0.csv").read_text().encode("utf-16"))
    with pytest.raises(InputError, match="not UTF-8 text"):          # was: "no header line naming the columns"
        read_raw_csv(p, 100.0)


@pytest.mark.parametrize("sep, name", [("\t", "tabs"), (";", "semicolons")])
def test_a_bench_csv_in_tabs_or_semicolons_is_said_to_be(tmp_path, sep, name):
    lines = EXAMPLE.read_text().splitlines()
    p = tmp_path / "t.csv"
    p.write_text("\n".join(ln if ln.startswith("#") else ln.replace(",", sep) for ln in lines) + "\n")
    with pytest.raises(InputError, match=f"separated by {name}.*bench CSV v1 is comma-separated"):
        read_bench_csv(p)


def test_the_scale_band_message_does_not_round_the_value_into_the_band(tmp_path):
    """Readings just below the band of a V output (0.01 g/V since 2026-12-02, 0.001 before): K just
    below it was printed "K = 0.001 g/V, outside the plausible 0.001-20000"."""
    from triadcal.estimation.gates import SCALE_BAND_G_PER_UNIT

    lo, _ = SCALE_BAND_G_PER_UNIT["V"]
    lines = EXAMPLE.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[head].split(",")
    w = [cols.index(c) for c in ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z")]
    out = lines[:head + 1]
    for ln in lines[head + 1:]:
        f = ln.split(",")
        for j in w:
            f[j] = repr(float(f[j]) * 1.0001 / lo)          # K = lo / 1.0001, just below the band
        out.append(",".join(f))
    p = tmp_path / "mv.csv"
    p.write_text("\n".join(out) + "\n")
    assert lo == 0.01
    with pytest.raises(InputError, match=r"implies K = 0\.00999\d* g/V, below the plausible 0\.01-"):
        read_bench_csv(p)


def test_a_posterior_with_a_nan_draw_is_said_to_hold_one():
    from triadcal import api
    from triadcal.judgement.compare.correlation import check_posterior_moments

    r = api.fit(EXAMPLE)
    draws = {n: (np.full(100, p.value) + p.u * np.random.default_rng(1).normal(size=100), p.unit)
             for n, p in r.parameters.items()}
    check_posterior_moments(draws, r, "post.nc")                     # the result's own: accepted
    draws["Ca_xy"][0][5] = np.nan
    with pytest.raises(InputError, match=r"post.nc: its draws of Ca_xy hold a value that is not a finite number"):
        check_posterior_moments(draws, r, "post.nc")
