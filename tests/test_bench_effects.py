"""The bench's effects are marked once (``Effect.bench``) and every list of bench terms is
derived from that mark: the shared parameters of a multi-unit fit, the terms a comparison
does not judge, the terms a compensation table and a unit's model leave out."""

from triadcal.estimation import multi
from triadcal.estimation.result import CalibrationResult
from triadcal.judgement.compare import results as compare_results
from triadcal.models.effects import BENCH_EFFECTS, BENCH_PARAMETERS, EFFECTS
from triadcal.models.effects.base import Effect
from triadcal.reports import compensation


def _overrides(cls, hook):
    return getattr(cls, hook) is not getattr(Effect, hook)


def test_bench_effects_are_those_that_move_gravity_or_the_bench_axes():
    # a bench term acts on the apparent gravity in the base frame or on the angle between the
    # bench's axes; no term of the unit does
    moving = {name for name, cls in EFFECTS.items() if _overrides(cls, "gravity_base") or _overrides(cls, "wobble")}
    assert set(BENCH_EFFECTS) == moving
    assert BENCH_EFFECTS == ("bench_tilt", "tilt_drift", "tilt_settling", "bench_nonorthogonality")


def test_every_list_of_bench_terms_is_derived_from_the_mark():
    # the canonical order is the order the stacked fit of several units shares them in
    assert BENCH_PARAMETERS == ("tilt_x", "tilt_y", "tilt_x_drift", "tilt_y_drift", "tilt_x_settle",
                                "tilt_y_settle", "tilt_settle_tau", "bench_nonorth")
    assert multi.BENCH_PARAMETERS == BENCH_PARAMETERS
    assert set(compare_results.BENCH_PARAMETERS) == set(BENCH_PARAMETERS) | {"tilt_delta", "tilt_beta"}
    assert compensation.BENCH_EFFECTS == BENCH_EFFECTS
    assert set(BENCH_EFFECTS) <= set(compensation.TABLE_EFFECTS)


def test_a_units_model_leaves_out_every_bench_effect():
    effects = tuple(EFFECTS)
    result = CalibrationResult(unit="u", method="joint", parameters={}, status="refused", effects=effects,
                               reference_temperature_C=25.0)
    model = result.model()
    assert not set(BENCH_EFFECTS) & set(model.effect_names)
    assert set(model.effect_names) == set(effects) - set(BENCH_EFFECTS)
