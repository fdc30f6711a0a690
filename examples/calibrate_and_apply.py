"""A research script: simulate a thermal campaign, calibrate it two ways, apply the result.

    python examples/calibrate_and_apply.py

Run by the test suite (tests/test_examples.py) so it never rots.
"""

import tempfile
from pathlib import Path

import numpy as np

import triadcal.api as tc
from triadcal.estimation.result import CalibrationResult

with tempfile.TemporaryDirectory() as tmp:
    csv, truth_json, result_json = (Path(tmp) / n for n in ("campaign.csv", "truth.json", "result.json"))

    # 1. a silicon A-18-like unit on a bench tilted by 60", heating and cooling sweeps
    truth, campaign = tc.simulate(csv, truth_path=truth_json, preset="a18-silicon", seed=7)

    # 2. the paper's classical method and the joint fit, from the same file
    classical = tc.fit(csv, method="classical")
    joint = tc.fit(csv, method="joint", json_path=result_json)
    print(f"{'angle':8} {'truth':>9} {'classical':>18} {'joint':>18}   [arcsec]")
    for name in ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy"):
        c, j = classical[name], joint[name]
        print(f"{name:8} {truth.parameters[name]:9.2f} {c.value:10.2f} ± {c.u:5.2f} {j.value:10.2f} ± {j.u:5.2f}")
    print(f"hysteresis Ca_yx: truth {truth.parameters['Ca_yx_hysteresis']:.1f}\", "
          f"joint {joint['Ca_yx_hysteresis'].value:.1f} ± {joint['Ca_yx_hysteresis'].u:.1f}\" "
          "(the classical method cannot see it)")

    # 3. the saved result, loaded again and applied to raw readings at their own temperatures
    result = CalibrationResult.load(result_json)
    hot = campaign.setpoint_C == 70.0
    a = result.apply(campaign.w[hot], campaign.t[hot])
    print("|A_IMU| at +70 degC (g):", np.round(np.linalg.norm(a, axis=1), 6))
    # the residual error is the hysteresis: apply() uses the mid-line of the loop
    assert np.allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-4)
