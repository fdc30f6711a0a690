"""A result says when the thermometers read far from the chamber or from each other
(``Campaign.thermometer_note``): the fit takes the readings as the temperature, so thermometers off by
d put every value "at T_ref" at the true T_ref - d with status ok. The files are the example campaign
with its t_* columns moved by hand (40 degC on all, 8 degC on x alone). A ramp's unit trails its
program by its lag (22 degC for 15 min at 1.5 degC/min): its offset is not noted."""

from pathlib import Path

import pytest

from triadcal import api

EXAMPLE = Path(__file__).parents[1] / "examples" / "data" / "campaign.csv"


def _shifted(tmp_path, shifts):
    lines = EXAMPLE.read_text().splitlines()
    h = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    cols = lines[h].split(",")
    out = lines[:h + 1]
    for line in lines[h + 1:]:
        r = line.split(",")
        for c, d in shifts.items():
            j = cols.index(c)
            r[j] = f"{float(r[j]) + d:.4f}"
        out.append(",".join(r))
    path = tmp_path / "shifted.csv"
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("method", ["joint", "classical"])
def test_readings_40_degc_from_the_setpoints_are_said(tmp_path, method):
    path = _shifted(tmp_path, {"t_x": 40.0, "t_y": 40.0, "t_z": 40.0})
    notes = [n for n in api.fit(path, method=method).notes if n.startswith("the accelerometers' temperatures read")]
    assert len(notes) == 1 and "+40.3, +40.3, +40.2 degC" in notes[0] and "T_ref - d" in notes[0], notes


def test_one_sensor_8_degc_from_the_others_is_said(tmp_path):
    res = api.fit(_shifted(tmp_path, {"t_x": 8.0}), method="classical")
    assert any(n.startswith("the three sensors differ by 8") for n in res.notes), res.notes


def test_the_example_and_a_moderate_self_heating_say_nothing(tmp_path):
    assert not any("thermometers" in n for n in api.fit(EXAMPLE).notes)
    res = api.fit(_shifted(tmp_path, {"t_x": 4.0, "t_y": 4.0, "t_z": 4.0}))
    assert not any("thermometers" in n for n in res.notes)
