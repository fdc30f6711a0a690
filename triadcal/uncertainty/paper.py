"""Error budgets of the seed paper: eq. 4 (calibration) and eq. 5-7 (thermal drift of the axes).

One function per equation (:func:`sigma_eff_arcsec` eq. 4, :func:`thermal_drift_arcsec`,
:func:`mounting_drift_arcsec`, :func:`correction_error_arcsec` eq. 5-7), Table 1 as
``TABLE_1``, and the budget tables behind ``triadcal budget`` (:func:`budget`).
Derivation/design: docs/budget.md (Equations, Numbers); eq. 4 vs the classical SD:
docs/classical.md (How this relates to the paper's eq. 4).
"""

from __future__ import annotations

from ..errors import InputError

import math
from dataclasses import asdict, dataclass
from typing import Optional

from ..models.units import ARCSEC
from .budget import Budget, BudgetComponent

#: radians -> arcseconds (the paper's 180 * 3600 / pi)
RAD_TO_ARCSEC = 1.0 / ARCSEC

#: thermal expansion coefficients of the paper's example (1/degC)
CTE_STEEL_PER_C = 15e-6      # accelerometer body
CTE_D16_PER_C = 22.9e-6      # IMU body parts, D-16 aluminium alloy
#: tempco of the reference-plane angle used by the paper for eq. 7 (arcsec/degC)
K_CA_ARCSEC_PER_C = {"quartz": 1.5, "silicon": 6.0}


@dataclass(frozen=True)
class AccelerometerType:
    """One column of the paper's Table 1."""

    name: str
    dCa_Ta_arcsec: float          #: instability of the reference plane (+-, arcsec)
    material: str                 #: pendulum material: 'quartz' or 'silicon'
    range_g: float
    temperature_range_C: tuple


TABLE_1: tuple[AccelerometerType, ...] = (
    AccelerometerType("A-18", 60.0, "silicon", 40.0, (-50.0, 75.0)),
    AccelerometerType("AK-15", 4.0, "quartz", 20.0, (-60.0, 70.0)),
    AccelerometerType("BA-3", 20.0, "silicon", 50.0, (-55.0, 85.0)),
    AccelerometerType("A-18T", 15.0, "silicon", 40.0, (-50.0, 85.0)),
    AccelerometerType("AK-18", 15.0, "quartz", 35.0, (-55.0, 75.0)),
    AccelerometerType("AAK-02", 20.0, "quartz", 50.0, (-55.0, 85.0)),
    AccelerometerType("QA-3000", 16.5, "quartz", 60.0, (-55.0, 95.0)),
)


def accelerometer(name: str) -> AccelerometerType:
    """A unit of Table 1 by name (case-insensitive)."""
    for a in TABLE_1:
        if a.name.lower() == name.strip().lower():
            return a
    raise InputError(f"unknown accelerometer {name!r}; Table 1 lists: {', '.join(a.name for a in TABLE_1)}")


# -- eq. 4 --------------------------------------------------------------------------------
def noise_term_arcsec(K_g_per_V: float, Q_V2s: float, tau_s: float, G_g: float = 1.0) -> float:
    """Angle equivalent of the output noise averaged over tau: ``K sqrt(Q / tau) / G`` in arcsec
    (the first term under the root of eq. 4; 2.06" for the paper's example)."""
    return K_g_per_V * math.sqrt(Q_V2s / tau_s) / G_g * RAD_TO_ARCSEC


def sigma_eff_arcsec(K_g_per_V: float, Q_V2s: float, tau_s: float, sigma1_arcsec: float,
                     sigma2_arcsec: float, G_g: float = 1.0) -> float:
    """Eq. 4: the paper's error of an orientation angle, arcsec (11.52" in its example)."""
    n = noise_term_arcsec(K_g_per_V, Q_V2s, tau_s, G_g)
    return 2.0 * math.sqrt(n * n + sigma1_arcsec ** 2 + sigma2_arcsec ** 2)


# -- eq. 5-7 ------------------------------------------------------------------------------
def mounting_drift_arcsec(cte_body_per_C: float = CTE_D16_PER_C, cte_accelerometer_per_C: float = CTE_STEEL_PER_C,
                          T_max_C: float = 85.0, T0_C: float = 20.0) -> float:
    """Eq. 6: drift of the mounting surfaces from the CTE mismatch, arcsec (10.6" for steel on D-16)."""
    return 0.1 * abs(cte_body_per_C - cte_accelerometer_per_C) * (T_max_C - T0_C) * RAD_TO_ARCSEC


def correction_error_arcsec(dT_C: float, k_ca_arcsec_per_C: float) -> float:
    """Eq. 7: error of the thermal correction from the temperature error dT, arcsec."""
    return dT_C * k_ca_arcsec_per_C


def thermal_drift_arcsec(dCa_Ta_arcsec: float, dCa_Tn_arcsec: float, dCa_Tk_arcsec: float) -> float:
    """Eq. 5: total thermal drift of an axis, arcsec (root sum of squares)."""
    return math.sqrt(dCa_Ta_arcsec ** 2 + dCa_Tn_arcsec ** 2 + dCa_Tk_arcsec ** 2)


# -- budget tables ------------------------------------------------------------------------
def calibration_budget(K_g_per_V: float = 1.0, Q_V2s: float = 3e-9, tau_s: float = 30.0,
                       sigma1_arcsec: float = 5.0, sigma2_arcsec: float = 2.0, G_g: float = 1.0) -> Budget:
    """Eq. 4 as a budget table (defaults: the paper's example, 11.52").

    Contributions include eq. 4's factor 2. ``extra['classical_sd_arcsec']`` gives, for
    comparison, the standard deviation of the classical estimate of each angle for the
    default 12-position plan (docs/classical.md): eq. 4 is four times the largest of them.
    """
    from .classical_sd import classical_angle_sd_default_plan

    sens_noise = 2.0 * K_g_per_V / G_g * RAD_TO_ARCSEC
    comps = [
        BudgetComponent("output white noise averaged over tau, sqrt(Q/tau)", sens_noise * math.sqrt(Q_V2s / tau_s),
                        math.sqrt(Q_V2s / tau_s), "V", sens_noise, "arcsec/V", symbol="noise", equation="eq. 4"),
        BudgetComponent("bench positioning error sigma_1", 2.0 * sigma1_arcsec, sigma1_arcsec, "arcsec", 2.0, "1",
                        symbol="sigma_1", equation="eq. 4"),
        BudgetComponent("wobble of the bench axes sigma_2", 2.0 * sigma2_arcsec, sigma2_arcsec, "arcsec", 2.0, "1",
                        symbol="sigma_2", equation="eq. 4"),
    ]
    # the root sum of squares of these contributions is eq. 4's sigma_eff (sigma_eff_arcsec)
    sd = classical_angle_sd_default_plan(Q_V2s=Q_V2s, tau_s=tau_s, sigma_position_arcsec=sigma1_arcsec,
                                         sigma_wobble_arcsec=sigma2_arcsec, K_g_per_V=K_g_per_V, gravity_g=G_g)
    return Budget(
        "error of an orientation angle from the bench test", comps, equation="eq. 4",
        no_expanded="eq. 4 is the paper's own figure, 2 sigma_eff (four times the classical estimate's standard "
                    "deviation), not a k = 2 expanded uncertainty: no coverage probability holds for it",
        notes=["eq. 4 as printed: 2 sqrt(noise^2 + sigma_1^2 + sigma_2^2); the standard deviation of the "
               "classical estimate (default plan) is sqrt(noise^2 + sigma^2)/2 per angle, with sigma = sigma_2 "
               "for Ca_xy and sigma_1 for the other five (docs/classical.md)"],
        extra={"inputs": {"K_g_per_V": K_g_per_V, "Q_V2s": Q_V2s, "tau_s": tau_s, "sigma1_arcsec": sigma1_arcsec,
                          "sigma2_arcsec": sigma2_arcsec, "G_g": G_g},
               "noise_term_arcsec": noise_term_arcsec(K_g_per_V, Q_V2s, tau_s, G_g),
               "classical_sd_arcsec": sd})


def thermal_budget(accelerometer_name: str = "AK-18", *, k_ca_arcsec_per_C: Optional[float] = None,
                   dT_C: float = 0.2, cte_body_per_C: float = CTE_D16_PER_C,
                   cte_accelerometer_per_C: float = CTE_STEEL_PER_C, T_max_C: float = 85.0,
                   T0_C: float = 20.0) -> Budget:
    """Eq. 5-7 for a unit of Table 1 (k_ca defaults to 1.5"/degC quartz, 6"/degC silicon)."""
    acc = accelerometer(accelerometer_name)
    k_ca = K_CA_ARCSEC_PER_C[acc.material] if k_ca_arcsec_per_C is None else k_ca_arcsec_per_C
    tn = mounting_drift_arcsec(cte_body_per_C, cte_accelerometer_per_C, T_max_C, T0_C)
    tk = correction_error_arcsec(dT_C, k_ca)
    dcte = abs(cte_body_per_C - cte_accelerometer_per_C)
    comps = [
        BudgetComponent(f"reference-plane instability of the {acc.name} (Table 1, dCa_Ta)", acc.dCa_Ta_arcsec,
                        acc.dCa_Ta_arcsec, "arcsec", 1.0, "1", symbol="dCa_Ta", equation="eq. 5"),
        BudgetComponent("CTE mismatch of body and accelerometer over T_max - T0 (eq. 6, dCa_Tn)", tn,
                        dcte * (T_max_C - T0_C), "1", 0.1 * RAD_TO_ARCSEC, "arcsec", symbol="dCa_Tn", equation="eq. 6"),
        BudgetComponent("temperature error dT of the thermal correction (eq. 7, dCa_Tk)", tk, dT_C, "degC",
                        k_ca, "arcsec/degC", symbol="dCa_Tk", equation="eq. 7"),
    ]
    # the root sum of squares of these contributions is eq. 5's dCa_T (thermal_drift_arcsec)
    return Budget(
        f"thermal drift of the axes, {acc.name} ({acc.material})", comps, equation="eq. 5-7",
        no_expanded="dCa_Ta and dCa_Tn are maximum values, not standard uncertainties: the root sum of squares "
                    "is the paper's figure, and no coverage probability holds for it",
        notes=["the paper combines the three parts as independent (root sum of squares, eq. 5); dCa_Ta and "
               "dCa_Tn are maximum values, not standard uncertainties"],
        extra={"accelerometer": asdict(acc),
               "inputs": {"k_ca_arcsec_per_C": k_ca, "dT_C": dT_C, "cte_body_per_C": cte_body_per_C,
                          "cte_accelerometer_per_C": cte_accelerometer_per_C, "T_max_C": T_max_C, "T0_C": T0_C}})


def table1_thermal(**kwargs) -> list[Budget]:
    """Eq. 5 for every unit of Table 1 (same keyword arguments as :func:`thermal_budget`)."""
    return [thermal_budget(a.name, **kwargs) for a in TABLE_1]


#: what each input of :func:`budget` must be: (CLI option, lower bound, bound excluded, why)
_INPUT_RULES = {
    "K_g_per_V": ("--K", 0.0, True, "a scale factor magnitude, g/V"),
    "Q_V2s": ("--Q", 0.0, False, "a white-noise intensity, V^2 s"),
    "tau_s": ("--tau", 0.0, True, "an averaging time, s"),
    "sigma1_arcsec": ("--sigma1", 0.0, False, "a standard deviation, arcsec"),
    "sigma2_arcsec": ("--sigma2", 0.0, False, "a standard deviation, arcsec"),
    "G_g": ("--G", 0.0, True, "local gravity, g"),
    "k_ca_arcsec_per_C": ("--k-ca", 0.0, False, "a tempco magnitude, arcsec/degC"),
    "dT_C": ("--dT", 0.0, False, "a temperature error magnitude, degC"),
    "cte_body_per_C": ("--cte-body", None, False, "a thermal expansion coefficient, 1/degC"),
    "cte_accelerometer_per_C": ("--cte-accelerometer", None, False, "a thermal expansion coefficient, 1/degC"),
    "T_max_C": ("--T-max", -273.15, False, "a temperature, degC"),
    "T0_C": ("--T0", -273.15, False, "a temperature, degC"),
}
#: the largest thermal expansion coefficient of a solid, 1/degC (polymers ~2e-4): beyond it a value
#: typed in ppm/degC (an outside probe's --cte-body 22.9 gave 10 591 698 arcsec, exit 0)
MAX_CTE_PER_C = 1e-3


#: eq. 4's G: the gravity a static bench turns, g (Earth's surface 0.9952-1.0034 g, with a margin for a
#: lab that states it in another way); beyond it a value typed in m/s2
G_RANGE_G = (0.9, 1.1)

#: an angle's uncertainty beyond this (arcsec, 360 deg) says nothing about an angle
FULL_TURN_ARCSEC = 1_296_000.0


def _check_inputs(**values) -> None:
    """Refuse an input that is not a finite number of the right sign, naming the option and value
    (eq. 4 divides by tau and G and takes sqrt(Q); a negative standard deviation is no budget)."""
    for key, value in values.items():
        if value is None:
            continue
        option, low, excluded, what = _INPUT_RULES[key]
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{option} ({key}) = {value!r}: not a number; it is {what}") from None
        if not math.isfinite(v):
            raise InputError(f"{option} ({key}) = {value!r}: not finite; it is {what}")
        if low is not None and (v <= low if excluded else v < low):
            bound = f"> {low:g}" if excluded else f">= {low:g}"
            raise InputError(f"{option} ({key}) = {v:g}: must be {bound}; it is {what}")
    for key in ("cte_body_per_C", "cte_accelerometer_per_C"):
        v = values.get(key)
        if v is not None and abs(float(v)) > MAX_CTE_PER_C:
            option = _INPUT_RULES[key][0]
            raise InputError(f"{option} ({key}) = {float(v):g}: beyond any solid's expansion ({MAX_CTE_PER_C:g} "
                             f"1/degC); it is in 1/degC (22.9 ppm/degC is {option} 22.9e-6)")
    g = values.get("G_g")
    if g is not None and not G_RANGE_G[0] <= float(g) <= G_RANGE_G[1]:
        # an outside probe's --G 9.80665 (m/s2 typed) divided the noise term by 9.8, exit 0
        raise InputError(f"--G (G_g) = {float(g):g}: local gravity is in g, {G_RANGE_G[0]:g}-{G_RANGE_G[1]:g} g on "
                         "a bench" + (f" ({float(g):g} m/s2 is {float(g) / 9.80665:.5g} g)" if 9.0 < float(g) < 10.5
                                      else ""))
    if values.get("T_max_C") is not None and values.get("T0_C") is not None and values["T_max_C"] < values["T0_C"]:
        raise InputError(f"--T-max ({values['T_max_C']:g} degC) is below --T0 ({values['T0_C']:g} degC): eq. 6 "
                         "takes the maximum temperature above the normal one")


def budget(*, thermal: bool = False, accelerometer_name: Optional[str] = None, K_g_per_V: float = 1.0,
           Q_V2s: float = 3e-9, tau_s: float = 30.0, sigma1_arcsec: float = 5.0, sigma2_arcsec: float = 2.0,
           G_g: float = 1.0, k_ca_arcsec_per_C: Optional[float] = None, dT_C: float = 0.2,
           cte_body_per_C: float = CTE_D16_PER_C, cte_accelerometer_per_C: float = CTE_STEEL_PER_C,
           T_max_C: float = 85.0, T0_C: float = 20.0) -> list[Budget]:
    """``triadcal budget``: eq. 4 (default), or eq. 5-7 with ``thermal=True`` for one unit of
    Table 1 (``accelerometer_name``) or, without a name, for all of them. Returns budget tables."""
    _check_inputs(K_g_per_V=K_g_per_V, Q_V2s=Q_V2s, tau_s=tau_s, sigma1_arcsec=sigma1_arcsec,
                  sigma2_arcsec=sigma2_arcsec, G_g=G_g, k_ca_arcsec_per_C=k_ca_arcsec_per_C, dT_C=dT_C,
                  cte_body_per_C=cte_body_per_C, cte_accelerometer_per_C=cte_accelerometer_per_C,
                  T_max_C=T_max_C, T0_C=T0_C)
    try:
        if not thermal:
            if accelerometer_name is not None:
                raise InputError("an accelerometer of Table 1 is for the thermal budget: add --thermal (thermal=True)")
            tables = [calibration_budget(K_g_per_V, Q_V2s, tau_s, sigma1_arcsec, sigma2_arcsec, G_g)]
        else:
            kw = dict(k_ca_arcsec_per_C=k_ca_arcsec_per_C, dT_C=dT_C, cte_body_per_C=cte_body_per_C,
                      cte_accelerometer_per_C=cte_accelerometer_per_C, T_max_C=T_max_C, T0_C=T0_C)
            tables = table1_thermal(**kw) if accelerometer_name is None else [thermal_budget(accelerometer_name, **kw)]
        for b in tables:
            if not math.isfinite(b.total) or any(c.contribution is not None and not math.isfinite(c.contribution)
                                                 for c in b.components):
                raise OverflowError
    except OverflowError:
        # also from the root sum of squares itself (an outside probe: --sigma1 1e200, --Q 1e308, --dT 1e300
        # ended in an internal OverflowError)
        given = {"--K": K_g_per_V, "--Q": Q_V2s, "--tau": tau_s, "--sigma1": sigma1_arcsec, "--sigma2": sigma2_arcsec,
                 "--G": G_g, "--k-ca": k_ca_arcsec_per_C, "--dT": dT_C, "--T-max": T_max_C}
        big = [f"{k} {v:g}" for k, v in given.items() if v is not None and (abs(v) > 1e100 or 0 < abs(v) < 1e-100)]
        raise InputError(f"the budget overflows with these inputs ({', '.join(big) or 'their magnitudes'}): check "
                         "the magnitudes and their units") from None
    for b in tables:
        if b.unit == "arcsec" and b.total > FULL_TURN_ARCSEC:
            # --tau 1e-300 gave 2.3e151 arcsec, --thermal --T-max 1e9 1.6e8 arcsec, exit 0
            raise InputError(f"{b.equation}: the budget's total is {b.total:.3g} arcsec, beyond a full turn "
                             f"({FULL_TURN_ARCSEC:g} arcsec): no angle is measured so; check the inputs' magnitudes "
                             "and units (tau in s, Q in V^2 s, temperatures in degC)")
    return tables
