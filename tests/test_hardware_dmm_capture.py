"""An analog unit read by SCPI voltmeters: `triadcal capture --instruments` with [dmm] (no [imu])
against the emulator's 34465A meters on ptys (pyvisa-py, ASRL/dev/pts/N::INSTR), end to end."""

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("pyvisa_py", reason="the voltmeter path needs pyvisa-py")

from triadcal.hardware.capture import CSV_NAME, load_instruments
from triadcal.hardware.drivers.dmm import samples_for_tau
from triadcal.hardware.emulator import EmulatorTiming, emulate
from triadcal.io.bench_csv import read_bench_csv
from triadcal.models.campaign import DEFAULT_PLAN

CLI = [sys.executable, "-m", "triadcal.cli"]
TAU_S = 30.0
FAST = ["--settle-s", "2", "--stab-window-s", "30", "--stab-hold-s", "30", "--no-progress"]


def test_sample_count_rule():
    assert samples_for_tau(30.0, 10.0, 50.0) == 150       # 30 s of 0.2 s readings
    assert samples_for_tau(30.0, 10.0, 60.0) == 180
    assert samples_for_tau(30.0, 1.0, 50.0, readings_per_sample=3) == 500
    assert samples_for_tau(0.1, 100.0, 50.0) == 2         # never fewer than 2


def test_analog_unit_through_a_dmm_instruments_file_end_to_end(tmp_path):
    timing = EmulatorTiming(time_scale=600.0, self_heating_time_constant_s=60.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], timing=timing, seed=5, dmm=True).start()
    out = tmp_path / "campaign"
    try:
        cfg = load_instruments(em.directory / "instruments.toml")
        assert "imu" not in cfg and cfg["dmm"]["resources"]["x"].startswith("ASRL/dev/")
        r = subprocess.run(CLI + ["capture", "--instruments", str(em.directory / "instruments.toml"),
                                  "--setpoints", "20", "--tau-s", str(TAU_S), "--out", str(out),
                                  "--unit", em.truth.unit] + FAST,
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    finally:
        em.stop()
    c = read_bench_csv(out / CSV_NAME)
    assert c.metadata["output_unit"] == "V"
    assert c.metadata["unit_temperature"].startswith("chamber")
    assert c.metadata["readout"].startswith("voltmeter: one 34465A per axis")
    assert list(c.position) == list(DEFAULT_PLAN)
    n = samples_for_tau(TAU_S, 10.0, 50.0)
    assert np.all(c.n_samples == n)
    np.testing.assert_allclose(c.t, 20.0, atol=0.05)      # the chamber's PV, 0.1 degC steps
    # every visit's mean against the emulator's noiseless output over the same readings
    for i, a in enumerate("xyz"):
        m = em.dmm_meters[a]
        assert m.commands[:5] == ["*IDN?", "*CLS", "CONF:VOLT:DC 10", "VOLT:DC:NPLC 10", "SYST:ERR?"]
        assert f"SAMP:COUN {n}" in m.commands
        assert len(m.windows) == c.n_visits
        true = np.array([w[2] for w in m.windows])
        np.testing.assert_allclose(c.w[:, i], np.array([w[3] for w in m.windows]), rtol=0, atol=1e-9)
        z = (c.w[:, i] - true) / (c.sd[:, i] / np.sqrt(c.n_samples))
        assert np.max(np.abs(z)) < 4.5, z
    # the sd is the white noise of one 0.2 s reading
    q = em.truth.noise.Q_V2s
    assert np.median(c.sd) == pytest.approx(np.sqrt(q / 0.2), rel=0.15)

    # the fit recovers the emulated unit
    fit_json = tmp_path / "fit.json"
    r = subprocess.run(CLI + ["fit", str(out / CSV_NAME), "--method", "joint", "--effects", "bench_tilt",
                              "--json", str(fit_json)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    result = json.loads(fit_json.read_text())
    z = {k: (p["value"] - em.truth.parameters[k]) / p["u"] for k, p in result["parameters"].items()
         if k in em.truth.parameters}
    ks = {k: v for k, v in z.items() if k.startswith("K")}
    assert ks, z
    assert max(abs(v) for v in ks.values()) < 5, z


def test_dmm_alone_needs_bench_and_chamber_ports(tmp_path):
    inst = tmp_path / "instruments.toml"
    inst.write_text('[dmm]\ndriver = "scpi"\nresources = { x = "ASRL/dev/null::INSTR", y = "a", z = "b" }\n'
                    '[bench]\ndriver = "scpi"\nport = "/dev/null"\n')
    r = subprocess.run(CLI + ["capture", "--instruments", str(inst), "--setpoints", "20", "--out",
                              str(tmp_path / "o"), "--no-progress"], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert "chamber" in r.stderr
