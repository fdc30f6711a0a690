"""Drift of a unit between two calibrations, judged against the uncertainty of both
(``triadcal compare``). The drift's uncertainty with the correlation of the two
calibrations, ISO 13528's E_n, the joint chi^2 test of the angles and the decision rule
(ISO 14253-1 guard band) are derived in docs/compare.md. Modules: rule (the decision rule),
correlation (what two calibrations share, drifts from posterior draws), results (the
comparison and its JSON), pair (:func:`compare`), sequence (:func:`compare_sequence`) and
published (a published table such as the seed paper's Table 3).
"""

from .rule import (  # noqa: F401
    EN_COVERAGE_FACTOR,
    VERDICTS,
    _TOLERANCE_ALIASES,
    _TOLERANCE_UNITS,
    check_tolerance,
    combined_covariance,
    coverage_factors,
    decide,
    decide_from_draws,
    drift_uncertainty,
    normalised_error,
    parse_tolerance,
    probability_exceeds,
    rule_text,
    verdict_from_probability,
)
from .correlation import (  # noqa: F401
    CORRELATION_TERMS,
    POSTERIOR_PAIRS,
    SharedErrors,
    POSTERIOR_MEAN_TOLERANCE,
    budget_equipment,
    check_posterior,
    derive_correlation,
    posterior_draws,
    posterior_drift,
    read_posterior,
    shared_errors,
    type_b_rows,
)
from .results import (  # noqa: F401
    ANGLES,
    BASES,
    BENCH_PARAMETERS,
    ComparisonResult,
    FORMAT,
    JointTest,
    MAX_ANGLE_ARCSEC,
    ParameterDrift,
    SEQUENCE_FORMAT,
    VERSION,
    _Fields,
    _finite,
    _load_json,
    _num,
    _opt_float,
    _save_json,
    check_verdict,
)
from .pair import (  # noqa: F401
    BENCH_MOUNTED,
    NEGATIVE_RHO_REASON,
    NOT_PASS_NOTE,
    SHAREABLE_EQUIPMENT,
    _describe,
    _is_angle,
    check_data_order,
    compare,
    joint_test,
    overall_verdict,
    same_calibration,
    same_data,
)
from .sequence import (  # noqa: F401
    SequenceComparison,
    compare_sequence,
)
from .published import (  # noqa: F401
    PublishedDrift,
    angle_name,
    judge_published,
    read_published_table,
)
