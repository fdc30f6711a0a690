"""Raw recordings in a batch through a manifest (issue 21, item 2): fitted with fit-raw beside
the bench campaigns, one result per serial and state, resumable, every manifest key checked."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from triadcal.errors import InputError
from triadcal.estimation.raw import fit_raw
from triadcal.fleet.batch import batch
from triadcal.fleet.manifest import read_manifest

ROOT = Path(__file__).resolve().parents[1]
RECORDING = ROOT / "examples" / "data" / "mikoff_imu0.csv"


def _manifest(tmp_path, extra=""):
    rec = tmp_path / "imu0.csv"
    rec.write_bytes(RECORDING.read_bytes())
    m = tmp_path / "raw.toml"
    m.write_text('[[recording]]\npath = "imu0.csv"\nserial = "MPU-0"\nrate_hz = 100.0\nunit = "m/s2"\n'
                 'poses = "unknown"\n' + extra)
    return m


def test_a_manifest_is_batched_like_a_campaign_and_resumes(tmp_path):
    m = _manifest(tmp_path)
    out = tmp_path / "fleet"
    rep = batch([m, ROOT / "examples" / "data" / "campaign.csv"], out, workers=1, processes=False, html=False)
    assert rep.n_fitted == 2 and rep.n_errors == 0
    doc = json.loads((out / "results" / "MPU-0__initial.json").read_text())
    alone = fit_raw(str(RECORDING), 100.0, unit="m/s2", poses="unknown", serial="MPU-0").result.to_dict()
    for name, p in alone["parameters"].items():
        assert doc["parameters"][name]["value"] == p["value"], name        # the same numbers as fit-raw
    assert "MPU-0" in (out / "fleet.csv").read_text()
    again = batch([m], out, workers=1, processes=False, html=False)
    assert again.n_skipped == 1 and again.n_fitted == 0


@pytest.mark.parametrize("extra, message", [
    ('colour = "red"\n', "unknown key 'colour'"),
    ('columns = ["ax", "ay"]\n', "three column names"),
    ("local_g_m_s2 = 1.0\n", r"local_g_m_s2 = 1 m/s2 is outside 9.76-9.84 m/s2"),
])
def test_bad_manifests_are_refused_naming_the_entry(tmp_path, extra, message):
    with pytest.raises(InputError, match=f"recording 1: .*{message}"):
        read_manifest(_manifest(tmp_path, extra))


def test_a_missing_recording_is_refused(tmp_path):
    m = tmp_path / "raw.toml"
    m.write_text('[[recording]]\npath = "nope.csv"\nserial = "A"\nrate_hz = 100.0\nunit = "g"\nposes = "known"\n')
    with pytest.raises(InputError, match="no such file"):
        read_manifest(m)


@pytest.mark.parametrize("key", ["serial", "state", "path"])
def test_an_empty_serial_state_or_path_is_refused(tmp_path, key):
    """serial = "" was fitted under the recording's file name while the summary said unit ''
    (an outside probe); state = "" became a state of its own."""
    (tmp_path / "imu0.csv").write_bytes(RECORDING.read_bytes())
    entry = {"path": '"imu0.csv"', "serial": '"MPU-0"', "state": '"initial"', "rate_hz": "100.0", "unit": '"m/s2"',
             "poses": '"unknown"', key: '""'}
    m = tmp_path / "raw.toml"
    m.write_text("[[recording]]\n" + "".join(f"{k} = {v}\n" for k, v in entry.items()))
    with pytest.raises(InputError, match=f"recording 1: {key} is empty"):
        read_manifest(m)
