"""Diagnosis of the gap between a fitted model and the data: where, which effect, how far it
shrinks (``triadcal diagnose``). The tests and their null distributions are derived in
docs/diagnosis.md. Modules: fitting (a subset of the full model, compiled once per
campaign), slices (where: residuals by axis, pose, setpoint, branch, time), candidates
(which: score tests, refits, PSIS-LOO, cross-branch prediction), results (the Diagnosis and
its JSON), rivals (the encompassing test against the runner-up), series (the orders of one
temperature coefficient together) and run (the entry point :func:`diagnose`).
"""

from .candidates import (  # noqa: F401
    FORM_CANDIDATES,
    _cross_group,
    _effect_params,
    _fit_heavy_tails,
    _fit_position_error,
    _kurtosis_logp,
    _loglik_pointwise,
    _loglik_total,
    _loo,
    _nominal_g,
    _pe_sensitivity,
    _position_score,
    _score_mean,
)
from .fitting import (  # noqa: F401
    FitState,
    _chi2_logsf,
    _chol,
    _fit,
    _hat_q,
    _Subset,
)
from .results import (  # noqa: F401
    ALPHA,
    FORMAT,
    METHODS_TEXT,
    VERSION,
    Candidate,
    Diagnosis,
    SliceTest,
    _f,
)
from .run import (  # noqa: F401
    diagnose,
)
from .slices import (  # noqa: F401
    FAMILIES,
    SIGNATURE,
    _family_tests,
    _holm,
    _quantile_bins,
    _slice_tests,
    _slices,
)
