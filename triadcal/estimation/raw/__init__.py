"""Calibration from a raw recording of static poses without a bench (``triadcal fit-raw``).

Modules: detection (static intervals), poses (interval averages as bench visits), known
(hand-placed poses of known orientation, placement as a random effect), unknown (free poses,
the gravity-norm model), sample (their posteriors through the bench's sampler) and fit (the
entry point :func:`fit_raw`). The models, their identifiability and the measured coverage
are derived in docs/raw.md.
"""

from .detection import (  # noqa: F401
    MOTION_LABELS,
    POSE_LABELS,
    StaticDetection,
    StaticInterval,
    StaticIntervalError,
    detect_static_intervals,
    intervals_from_labels,
    intervals_from_spec,
    moving_sd,
    pose_label_of,
    robust_noise_sd,
)
from .fit import (  # noqa: F401
    RawFit,
    _fit_raw_detected,
    fit_raw,
    static_intervals_of,
)
from .known import (  # noqa: F401
    DEFAULT_PLACEMENT_SD_DEG,
    PLACEMENT_GRID_DEG,
    SENSITIVITY_NOTE_U,
    SENSITIVITY_PRIORS,
    KnownPoseProblem,
    _conditional_jacobian,
    _integrate_placement_sd,
    _known_pose_estimate,
    conditional_residuals,
    fit_known_poses,
    marginal_posterior,
    placement_sd_evidence,
    prior_sensitivity,
    sensitivity_note,
)
from .poses import (  # noqa: F401
    NORM_ANGLES,
    NORM_NAMES,
    POSE_POSITIONS,
    UNIT_NAMES,
    PoseAverages,
    bench_campaign,
    pose_averages,
)
from .sample import (  # noqa: F401
    RAW_PRIOR_CA_ARCSEC,
    RAW_PRIOR_K_REL,
    RAW_PRIOR_S_G,
    raw_priors,
    sample_known_poses,
    sample_unknown_poses,
)
from .unknown import (  # noqa: F401
    NormProblem,
    _calibrated_symbolic,
    _norm_angles,
    fit_unknown_poses,
    nominal_scale,
    norm_matrices,
    norm_residual_rms_m_s2,
    norm_start,
    result_matrices,
)
