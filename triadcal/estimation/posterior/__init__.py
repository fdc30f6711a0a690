"""Posterior of the joint model by MCMC (emcee), with arviz diagnostics that gate the result.

The derivation, the choice of moves and the stop rule are in docs/posterior.md. Modules:
compile (CasADi code generation, cached), targets (log-posteriors), moves (emcee move
mixtures), laplace (MAP and Laplace approximation), diagnostics (tau, R-hat, ESS), run (the
sampler loop and its stop rule), summary (intervals, flags, the CalibrationResult), export
(arviz InferenceData) and sample (the entry points ``sample`` and ``sample_target``).
"""

from .compile import (  # noqa: F401
    _COMPILED,
    _cache_dir,
    _compile,
)
from .diagnostics import (  # noqa: F401
    _arviz,
    diagnostics,
    integrated_time,
    split_rhat_quick,
)
from .export import (  # noqa: F401
    _posterior_datasets,
    _posterior_variables,
    MAX_LOGLIK_DRAWS,
    _loglik_subset,
    verdict_attrs,
    inference_data,
    target_inference_data,
    write_inference_data,
    write_target_inference_data,
)
from .laplace import (  # noqa: F401
    _transformed_laplace,
    laplace_approximation,
)
from .moves import (  # noqa: F401
    MOVES,
    _emcee,
    laplace_move,
    make_moves,
)
from .run import (  # noqa: F401
    MAX_SAVED_DRAWS,
    PosteriorRun,
    run_sampler,
)
from .sample import (  # noqa: F401
    _load,
    sample,
    sample_target,
)
from .summary import (  # noqa: F401
    LEVEL,
    NON_GAUSSIAN_TOLERANCE,
    PRIOR_DOMINATED_RATIO,
    _flags_block,
    _result,
    posterior_notes,
    posterior_summary,
    sampler_info,
)
from .targets import (  # noqa: F401
    LogPosterior,
    ResidualLogPosterior,
    ResidualProblem,
    ResidualTarget,
    _visit_functions,
    conditional_shear,
)
