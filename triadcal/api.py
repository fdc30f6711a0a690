"""Library functions behind the ``triadcal`` commands, one per command, same names.

A research script calls these exactly as the command line does.
"""

from __future__ import annotations

from .errors import InputError

from typing import Optional, Sequence

from .io.bench_csv import write_bench_csv
from .models.effects import DEFAULT_EFFECTS, NOISE_EFFECTS
from .models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign


def simulate(output=None, *, truth_path=None, preset: str = "ak18-quartz",
             effects: Sequence[str] = DEFAULT_EFFECTS, parameters: Optional[dict] = None,
             schedule: Optional[Schedule] = None, Q_V2s: float = 3e-9,
             sigma_position_arcsec: Optional[float] = None, sigma_wobble_arcsec: Optional[float] = None,
             heavy_tails_dof: Optional[float] = None, unit: str = "SN-SIM-0001", seed: int = 0,
             plan=None, flicker_Bf: Optional[float] = None, quantisation_lsb: Optional[float] = None,
             metadata: Optional[dict] = None):
    """Simulate a campaign (``triadcal simulate``); returns ``(truth, campaign)``. ``metadata``: header
    lines added to the campaign (``planned_effects`` of ``simulate --plan``).

    ``effects`` may include the noise effects ``position_error`` (defaults sigma_1 = 5",
    sigma_2 = 2" as in the paper's eq. 4 example), ``heavy_tails`` (Student-t, 3 dof) and
    ``flicker_noise`` (1/f noise of Allan floor ``flicker_Bf``, output unit; default 3e-6 V, about
    3 ug for the presets). ``quantisation`` rounds every sample to the LSB ``quantisation_lsb``
    (output unit; default 2.5 sqrt(Q f_s), f_s = 100 Hz): the visit means get the expected rounding
    error (:class:`~triadcal.models.simulate.NoiseModel`, docs/model.md).
    """
    effects = list(effects)
    pos = "position_error" in effects
    noise = NoiseModel(
        Q_V2s=Q_V2s,
        sigma_position_arcsec=sigma_position_arcsec if sigma_position_arcsec is not None else (5.0 if pos else 0.0),
        sigma_wobble_arcsec=sigma_wobble_arcsec if sigma_wobble_arcsec is not None else (2.0 if pos else 0.0),
        heavy_tails_dof=heavy_tails_dof if heavy_tails_dof is not None else (3.0 if "heavy_tails" in effects else None),
        flicker_Bf=flicker_Bf if flicker_Bf is not None else (3e-6 if "flicker_noise" in effects else 0.0),
        # quantisation: an LSB q (output unit); default 2.5 sample SDs sqrt(Q f_s), where the rounding
        # error is 2 visit SDs (docs/model.md, Quantisation of a digital output)
        quantisation_lsb=quantisation_lsb if quantisation_lsb is not None else (
            2.5 * (Q_V2s * 100.0) ** 0.5 if "quantisation" in effects else None))
    effects = [e for e in effects if e != "quantisation"]
    truth = preset_truth(preset, [e for e in effects if e not in NOISE_EFFECTS], noise=noise, unit=unit,
                         **(parameters or {}))
    campaign = simulate_campaign(truth, plan=plan, schedule=schedule, seed=seed)
    if metadata:
        campaign.metadata.update(metadata)
    if output is not None:
        write_bench_csv(campaign, output)
    if truth_path is not None:
        truth.save(truth_path)
    return truth, campaign


def example_path():
    """Path of the built-in example campaign (bench CSV v1, simulated ak18-quartz unit)."""
    from importlib.resources import files

    return files("triadcal") / "data" / "example_campaign.csv"


def _output_variances(campaign, effects, kwargs) -> Optional[list]:
    """The outputs' relative noise variances from a base fit with one noise level per output
    (:func:`~triadcal.estimation.noise_model.per_output_scale`), or None: the noise is in the data,
    the loss is robust, or the base fit cannot be made (the form's own fit then says why)."""
    from .estimation.joint import fit_joint, noise_of

    if noise_of(campaign).known or kwargs.get("loss", "l2") != "l2" or kwargs.get("whitening") is not None:
        return None
    try:
        base = fit_joint(campaign, effects, noise_per_output=True,
                         **{k: v for k, v in kwargs.items() if k not in ("return_problem", "output_variances")})
    except InputError:
        return None
    q = base.fit.get("Q_estimate_per_output")
    return [3.0 * float(v) / float(sum(q)) for v in q] if q else None


def fit(data, *, method: str = "joint", effects: Optional[Sequence[str]] = None, json_path=None, **kwargs):
    """Calibrate from a campaign (``triadcal fit``): :func:`_fit` (which documents every argument) with
    ``effects`` None taken from the data's ``# planned_effects`` (the plan the campaign follows),
    else :data:`~triadcal.models.effects.DEFAULT_EFFECTS`; a note says where they came from, or how
    given effects differ from the plan's (:mod:`triadcal.estimation.planned_effects`)."""
    from .estimation.planned_effects import resolve
    from .io.bench_csv import read_bench_csv
    from .models.campaign import Campaign

    campaign = data if isinstance(data, Campaign) else read_bench_csv(example_path() if data is None else data)
    effects, note = resolve(effects, campaign, method)
    result = _fit(campaign, method=method, effects=effects, json_path=None, **kwargs)
    if note:
        result.notes.append(note)
    if json_path is not None:
        result.save(json_path)
    return result


def _fit(data, *, method: str = "joint", effects: Sequence[str] = DEFAULT_EFFECTS,
        reference_temperature_C: float = 20.0, loss: str = "l2", strict: bool = False,
        json_path=None, netcdf_path=None, angle_bound_arcsec: float = 3600.0, lab=None,
        hysteresis_form: str = "offset", hysteresis_half_width_C: Optional[float] = None,
        bench_errors_from_replicates: bool = False, thermal_order: str = "1", thermal_lag_form: str = "rate",
        quantisation_lsb: Optional[float] = None, bridge_gaps: bool = False):
    """Calibrate from a campaign (``triadcal fit``): ``data`` is a bench CSV path, a
    :class:`~triadcal.models.campaign.Campaign`, or None for the built-in example.
    ``angle_bound_arcsec``: the answer gates' bound on an orientation angle (arcsec).
    ``lab``: a lab file (path or :class:`~triadcal.io.lab.LabConfig`) whose bench errors
    (``[bench] sigma_position_arcsec, sigma_wobble_arcsec``, arcsec) enter the joint fit as
    variance components and whose systematic errors (encoder zeros, axes non-orthogonality,
    fixture, g, thermometers, voltmeter) are propagated to every parameter as Type B
    (:mod:`triadcal.uncertainty.typeb`); without it the joint fit's uncertainties are Type A only.
    ``bench_errors_from_replicates``: estimate the bench's random errors from the plan's
    replicated visits (:func:`triadcal.estimation.joint.bench_errors_from_replicates`) instead of
    taking them from the lab file (the result's ``fit.bench_errors.source`` says which).
    ``thermal_order``: ``1`` (the effects as given), ``2`` (every linear tempco's quadratic term
    added), ``3`` (quadratic and cubic terms added) or ``auto`` (the order 1-3 the data support per
    family, :mod:`triadcal.estimation.thermal_order`).
    ``effects`` may name the noise effects: ``position_error`` (the bench's random errors estimated
    from the residuals as a variance component) and ``heavy_tails`` (the Student-t likelihood);
    :mod:`triadcal.estimation.noise_effects`.
    ``thermal_lag_form``: ``rate`` (the ``thermal_lag`` effect as listed: ``T - tau dT/dt``, for
    short lags), ``housing`` or ``air`` (the element's lag estimated from the temperature history,
    the thermometer on the housing or in the chamber air;
    :func:`triadcal.estimation.thermal_lag_form.fit_thermal_lag`), or ``history`` (the location
    chosen by the data on a continuous record, by the rule of the diagnosis's ``thermal_lag_history``;
    a stepped record with gaps is refused until the location is stated: ``fit_thermal_lag_history``);
    ``bridge_gaps`` (with ``housing`` or ``air``)
    fills the record's gaps, the soaks of a stepped campaign, with a first-order approach profiled
    with the lags (docs/model.md).
    ``hysteresis_form``: ``offset`` (the branches a constant offset apart), ``play`` (a play
    hysteresis of half-width ``hysteresis_half_width_C`` degC, profiled when None), ``pi`` (a
    Prandtl-Ishlinskii sum of two plays, profiled) or ``auto`` (chosen by the data;
    :mod:`triadcal.estimation.hysteresis_form`).
    ``effects`` may name the diagnosis's form candidates (:mod:`triadcal.estimation.form_names`):
    ``hysteresis_play`` and ``hysteresis_pi`` are ``hysteresis`` with that ``hysteresis_form``,
    ``thermal_lag_history`` is ``thermal_lag`` with ``thermal_lag_form="history"``.
    ``effects`` may name ``quantisation`` (a digital output rounded to an LSB q, one for the three
    outputs, in the output unit): q is ``quantisation_lsb`` when given (which implies the term), else
    profiled; :mod:`triadcal.estimation.quantisation_form`, ``fit.quantisation`` in the result.
    Returns a :class:`~triadcal.estimation.result.CalibrationResult` whose ``status`` is
    ``ok`` only when every answer gate passed (docs/statuses.md)."""
    from .estimation.gates import GateConfig
    from .io.bench_csv import read_bench_csv
    from .models.campaign import Campaign

    gates = GateConfig(angle_bound_arcsec=angle_bound_arcsec)

    from .estimation.form_names import resolve_form_names

    campaign = data if isinstance(data, Campaign) else read_bench_csv(example_path() if data is None else data)
    effects, hysteresis_form, thermal_lag_form = resolve_form_names(effects, hysteresis_form, thermal_lag_form)
    quantised = "quantisation" in effects or quantisation_lsb is not None
    effects = [e for e in effects if e != "quantisation"]
    if quantised and (method != "joint" or thermal_lag_form != "rate" or hysteresis_form != "offset"
                      or hysteresis_half_width_C is not None):
        raise InputError("quantisation is fitted by the joint method with the offset hysteresis and the rate-form "
                         "lag (not with --method classical, --hysteresis-form, --hysteresis-width or "
                         "--thermal-lag-form)")
    if method == "classical":
        from .estimation.classical import fit_classical

        # the paper's eq. 2 per setpoint and its linear thermal correction: nothing of the joint model
        # applies; what would be ignored is refused by name
        ignored = [what for what, given in (
            (f"--effects {','.join(effects)}", list(effects) != list(DEFAULT_EFFECTS)),
            (f"--loss {loss}", loss != "l2"), ("--strict", strict),
            (f"--hysteresis-form {hysteresis_form}", hysteresis_form != "offset"),
            ("--hysteresis-width", hysteresis_half_width_C is not None),
            ("--bench-errors-from-replicates", bench_errors_from_replicates),
            (f"--thermal-order {thermal_order}", thermal_order != "1"),
            (f"--thermal-lag-form {thermal_lag_form}", thermal_lag_form != "rate"), ("--bridge-gaps", bridge_gaps),
            ("--netcdf", netcdf_path is not None)) if given]
        if ignored:
            raise InputError(f"--method classical is the paper's eq. 2 per setpoint with a linear thermal "
                             f"correction: {', '.join(ignored)} would be ignored; use --method joint for them")

        if lab is not None:
            from .io.lab import LabConfig, load_lab, with_lab_gravity

            lab = lab if isinstance(lab, LabConfig) else load_lab(lab)
            # the lab's measured g when the data state none (K takes g one to one): the classical branch
            # ignored it, K_x 464 ppm off at a site of 9.8112 with status ok (an outside probe)
            campaign = with_lab_gravity(campaign, lab)
        result = fit_classical(campaign, reference_temperature_C=reference_temperature_C, gates=gates)
        if lab is not None:
            from .estimation.classical_typeb import bench_at_one_setpoint, propagate_classical
            from .uncertainty.typeb import systematic_sources

            result = bench_at_one_setpoint(result, campaign, lab.sigma_position_arcsec, lab.sigma_wobble_arcsec)
            result = propagate_classical(
                result, campaign, systematic_sources(lab, campaign.output_unit),
                lambda changed: fit_classical(changed, reference_temperature_C=reference_temperature_C, gates=gates,
                                              values_only=True))
    elif method == "joint":
        from .estimation.joint import fit_joint

        from .io.lab import LabConfig, bench_errors_of, load_lab
        from .uncertainty.typeb import effects_with_lab, systematic_sources

        if lab is not None and not isinstance(lab, LabConfig):
            lab = load_lab(lab)
        from .io.lab import with_lab_gravity

        campaign = with_lab_gravity(campaign, lab)
        systematics = systematic_sources(lab, campaign.output_unit)
        effects, added = effects_with_lab(effects, systematics)
        bench = bench_errors_of(lab) if lab is not None else None
        if bench_errors_from_replicates:
            from .estimation.joint import bench_errors_from_replicates as from_replicates
            from .models.model import Model

            bench = from_replicates(campaign, Model(effects, reference_temperature_C))
        from .estimation.noise_effects import resolve_noise_effects

        qmap = {}
        if quantised:
            from .estimation.quantisation_form import noise_effects_map

            qmap = noise_effects_map(campaign, effects, quantisation_lsb)
        noise_fx = resolve_noise_effects(campaign, effects, bench_errors=bench, loss=loss,
                                         reference_temperature_C=reference_temperature_C, gates=gates, **qmap)
        effects = noise_fx["effects"]
        kwargs = dict(reference_temperature_C=reference_temperature_C, loss=noise_fx["loss"], nu=noise_fx["nu"],
                      unidentifiable="refuse" if strict else "fix", return_problem=True, gates=gates,
                      bench_errors=noise_fx["bench_errors"], systematics=systematics)
        if noise_fx.get("whitening") is not None:      # flicker_noise: GLS on the fitted covariance
            kwargs["whitening"] = noise_fx["whitening"]
        order_block = None
        initial_effects = effects
        if thermal_order != "1" or thermal_lag_form != "rate" or quantised or hysteresis_form != "offset" \
                or hysteresis_half_width_C is not None:
            # the forms compare the chi^2 of several fits, which must share their weights: one noise
            # level per output, from a base fit, for all of them (as the plain fit has its own)
            kwargs["output_variances"] = _output_variances(campaign, effects, kwargs)
        if thermal_order != "1":
            from .estimation.thermal_order import choose_thermal_order

            effects, order_block = choose_thermal_order(
                campaign, effects, thermal_order, **{k: v for k, v in kwargs.items() if k != "return_problem"})
        if thermal_lag_form not in ("rate", "housing", "air", "history"):
            raise InputError(f"unknown thermal lag form {thermal_lag_form!r}: choose rate, housing, air or history")
        if bridge_gaps and thermal_lag_form == "rate":
            raise InputError("--bridge-gaps fills the temperature record's gaps for the history form: use it with "
                             "--thermal-lag-form housing, air or history")
        if thermal_lag_form != "rate":
            if hysteresis_form != "offset" or hysteresis_half_width_C is not None or thermal_order != "1" \
                    or netcdf_path is not None:
                raise InputError(f"--thermal-lag-form {thermal_lag_form} is fitted with the offset hysteresis, "
                                 "linear tempcos and no --netcdf (not combined with --hysteresis-form, "
                                 "--hysteresis-width, --thermal-order or --netcdf)")
            from .estimation.thermal_lag_form import fit_thermal_lag, fit_thermal_lag_history

            kwargs.pop("return_problem")
            if thermal_lag_form == "history":           # the location chosen by the data, or refused
                result = fit_thermal_lag_history(campaign, effects, **kwargs)
            else:
                result = fit_thermal_lag(campaign, effects, thermal_lag_form, bridge_gaps=bridge_gaps, **kwargs)
            result.notes.extend(noise_fx["notes"] + ([added] if added else []))
            result.extra.update(noise_fx["extra"])
            if json_path is not None:
                result.save(json_path)
            return result
        if quantised:
            from .estimation.quantisation_form import fit_quantisation

            result, problem, solution = fit_quantisation(campaign, effects, quantisation_lsb, **{
                k: v for k, v in kwargs.items() if k != "return_problem"})
        elif hysteresis_form == "offset" and hysteresis_half_width_C is None:
            # one noise level per output when the data hold none (joint.per_output_scale)
            result, problem, solution = fit_joint(campaign, effects, noise_per_output=True, **kwargs)
            from .estimation.lag_validity import judge_ramp_form

            judge_ramp_form(campaign, result, effects, kwargs)     # a rate-form lag on a ramp
        else:
            from .estimation.hysteresis_form import fit_hysteresis_form

            kwargs.pop("return_problem")
            given, form_used = campaign, "play" if hysteresis_form == "offset" else hysteresis_form
            result, problem, solution, campaign = fit_hysteresis_form(
                given, effects, form_used, hysteresis_half_width_C, **kwargs)
            if order_block is not None and order_block["order"] == "auto" and campaign is not given:
                # the order was chosen with the offset form; chosen again on the form's branches
                # (an unmodelled play or PI must not be taken up by a higher tempco), then the form
                again, block = choose_thermal_order(campaign, initial_effects, "auto", **kwargs)
                if again != effects:
                    effects, order_block = again, dict(block, rechosen_with_hysteresis_form=True)
                    result, problem, solution, campaign = fit_hysteresis_form(
                        given, effects, form_used, hysteresis_half_width_C, **kwargs)
        if added:
            result.notes.append(added)
        result.notes.extend(noise_fx["notes"])
        result.extra.update(noise_fx["extra"])
        if order_block is not None:
            result.fit["thermal_order"] = order_block
            result.notes.append("thermal order: " + (", ".join(order_block["added"]) or "linear") + " ("
                                + "; ".join(f"{t['term']}: {t['why']}" for t in order_block.get("tried", []))
                                + (")" if order_block.get("tried") else order_block["criterion"] + ")"))
        if netcdf_path is not None:
            from .io.netcdf import write_fit_netcdf

            write_fit_netcdf(netcdf_path, campaign, problem, solution, result)
    else:
        raise InputError(f"unknown method {method!r}: choose classical or joint")
    if json_path is not None:
        result.save(json_path)
    return result


#: commands whose library function lives in a module that is slow to import (CasADi, arviz,
#: reportlab, pyserial): ``triadcal.api.NAME`` is that very function (its own signature, units
#: and docstring), imported on first use (PEP 562)
_LAZY = {
    "capture": ("triadcal.hardware.capture", "capture"),
    "emulate": ("triadcal.hardware.emulator", "emulate"),
    "certificate": ("triadcal.reports.certificate", "certificate"),
    "compare": ("triadcal.judgement.compare", "compare"),
    "budget": ("triadcal.uncertainty.paper", "budget"),
    "fit_raw": ("triadcal.estimation.raw", "fit_raw"),
    "diagnose": ("triadcal.judgement.diagnose", "diagnose"),
    "validate_diagnosis": ("triadcal.judgement.diagnosis_validation", "validate"),
    "sample": ("triadcal.estimation.posterior", "sample"),
    "batch": ("triadcal.fleet.batch", "batch"),
    "export_compensation": ("triadcal.reports.compensation", "export_compensation"),
    "thermal_cycle": ("triadcal.estimation.thermal_cycle", "thermal_cycle"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        fn = getattr(importlib.import_module(module), attr)
        globals()[name] = fn
        return fn
    raise AttributeError(f"module 'triadcal.api' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))


def validate(n_campaigns: int = 200, effects: Sequence[str] = DEFAULT_EFFECTS, *, n_ranks: int = 99,
             seed: int = 0, processes: int = 2, ess: float = 400, json_path=None, plot_path=None,
             progress=None):
    """Simulation-based calibration of the least-squares and posterior intervals
    (``triadcal validate``): :func:`triadcal.judgement.validation.sbc`, then its summary as
    JSON (``json_path``) and the rank histograms as PNG (``plot_path``). Returns the
    :class:`~triadcal.judgement.validation.SBCResult`."""
    from .judgement.validation import sbc
    from .io.atomic import atomic_write_json

    result = sbc(n_campaigns, effects, n_ranks=n_ranks, seed=seed, processes=processes, ess=ess,
                 progress=progress)
    if json_path is not None:
        atomic_write_json(json_path, result.summary())
    if plot_path is not None:
        from .reports.sbc import plot_rank_histograms

        plot_rank_histograms(result, plot_path)
    return result
