"""Regenerate docs/img/hysteresis_forms.png and docs/img/thermal_orders.png (docs/model.md,
"Hysteresis forms" and "Quadratic and cubic tempcos"): one campaign per form, made by
tests/independent_bench.py (a backlash state machine, a Horner polynomial; no code of
triadcal.models), fitted by ``fit --thermal-order auto --hysteresis-form auto``, and the
model's curve drawn over the data's partial residuals.

    .venv/bin/python docs/plot_thermal_forms.py

The partial residual of Ca_xy at a visit whose X sensor feels gravity along IMU Y
(``|G_y| = 1``, 4 of the 12 positions) is ``(W_x - W_x(model without the term)) K_x / G_y`` in
arcsec: the term the model fitted, plus the noise (about 2"). Matplotlib's Figure API only (no
pyplot state).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from independent_bench import simulate_campaign  # noqa: E402
from test_thermal_forms_statistics import SCENARIOS, TILT, NOISE, _truth  # noqa: E402

from triadcal.estimation.hysteresis_form import fit_hysteresis_form  # noqa: E402
from triadcal.estimation.thermal_order import choose_thermal_order  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402
from triadcal.models.campaign import nominal_gravity  # noqa: E402
from triadcal.models.units import ARCSEC  # noqa: E402

BASE = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
PANELS = {"offset": "quartz-linear-offset", "play": "quartz-linear-play", "pi": "silicon-cubic-pi"}


def fitted(name: str, seed: int, tmp: Path):
    preset, order, hyst, setpoints = SCENARIOS[name]
    text, truth = simulate_campaign(np.random.default_rng(seed), truth=_truth(preset, order), setpoints_C=setpoints,
                                    tilt_arcsec=TILT, hysteresis=hyst, unit=f"SN-{name}", **NOISE)
    path = tmp / f"{name}.csv"
    path.write_text(text, encoding="utf-8")
    c = read_bench_csv(path)
    effects, _ = choose_thermal_order(c, BASE, "auto")
    res, problem, sol, used = fit_hysteresis_form(c, effects, "auto")
    if used is not c:                     # as triadcal.api.fit: the order again on the form's branches
        again, _ = choose_thermal_order(used, BASE, "auto")
        if again != effects:
            res, problem, sol, used = fit_hysteresis_form(c, again, "auto")
    return truth, c, res, problem, sol, used


def partial(problem, sol, c, zero):
    """Partial residual of Ca_xy (arcsec) with the parameters in ``zero`` set to 0, at the visits
    with |G_y| = 1."""
    x = sol.x.copy()
    for n in zero:
        if n in problem.index:
            x[problem.index[n]] = 0.0
    w0 = problem.predict(x)
    G = nominal_gravity(c.axis1_deg, c.axis2_deg)
    sel = np.abs(G[:, 1]) > 0.99
    K = sol.x[problem.index["K_x"]]
    return sel, (c.w[:, 0] - w0[:, 0]) * K / G[:, 1] / ARCSEC


def main(out=ROOT / "docs" / "img"):
    import tempfile

    tmp = Path(tempfile.mkdtemp())
    fig = Figure(figsize=(13.5, 4.2))
    for k, (form, name) in enumerate(PANELS.items()):
        truth, c, res, problem, sol, used = fitted(name, 1, tmp)
        sel, pr = partial(problem, sol, c, ["Ca_xy_hysteresis"])
        order = np.argsort(c.time_s)
        T = c.t.mean(axis=1)
        h = res.parameters["Ca_xy_hysteresis"]
        ax = fig.add_subplot(1, 3, k + 1)
        ax.plot(T[sel], pr[sel], ".", color="0.55", ms=4, label="data (partial residual)")
        curve = h.value * used.branch[order]
        ax.plot(T[order], curve, "-", color="C3", lw=1.5, label=f"fitted: {res.fit['hysteresis']['form']}")
        ax.set_title(f"{form} data: chose {res.fit['hysteresis']['form']}; h_xy = {h.value:.1f} ± {h.u:.1f}\" "
                     f"(true {truth['Ca_xy_hysteresis']:g})", fontsize=9)
        ax.set_xlabel("temperature (°C)")
        ax.set_ylabel("Ca_xy hysteresis term (arcsec)")
        ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    FigureCanvasAgg(fig).print_png(out / "hysteresis_forms.png")

    fig = Figure(figsize=(10.5, 4.4))
    for k, name in enumerate(("silicon-quadratic-play", "silicon-cubic-pi")):
        truth, c, res, problem, sol, used = fitted(name, 1, tmp)
        nonlin = [n for n in problem.names if n.startswith("Ca_xy_tempco") and n != "Ca_xy_tempco"]
        sel, pr = partial(problem, sol, c, nonlin)
        T = c.t[:, 0] - 20.0
        grid = np.linspace(T.min(), T.max(), 200)
        c2 = res.parameters.get("Ca_xy_tempco2")
        c3 = res.parameters.get("Ca_xy_tempco3")
        fit_curve = (c2.value if c2 else 0.0) * grid ** 2 + (c3.value if c3 else 0.0) * grid ** 3
        true_curve = truth.get("Ca_xy_tempco2", 0.0) * grid ** 2 + truth.get("Ca_xy_tempco3", 0.0) * grid ** 3
        ax = fig.add_subplot(1, 2, k + 1)
        ax.plot(T[sel] + 20, pr[sel], ".", color="0.55", ms=4, label="data (partial residual)")
        ax.plot(grid + 20, fit_curve, "-", color="C0", lw=1.5, label=f"fitted (angles' order {3 if c3 else 2})")
        ax.plot(grid + 20, true_curve, "--", color="k", lw=1, label="true")
        ax.set_title(f"{name} (true {truth.get('Ca_xy_tempco2', 0):g}\"/°C², {truth.get('Ca_xy_tempco3', 0):g}\"/°C³)\n"
                     f"Ca_xy_tempco2 = {c2.value:.4f} ± {c2.u:.4f}\"/°C²"
                     + (f", tempco3 = {c3.value:.2e} ± {c3.u:.1e}\"/°C³" if c3 else ""), fontsize=8)
        ax.set_xlabel("temperature of the X sensor (°C)")
        ax.set_ylabel("Ca_xy beyond linear (arcsec)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    FigureCanvasAgg(fig).print_png(out / "thermal_orders.png")


if __name__ == "__main__":
    main()
