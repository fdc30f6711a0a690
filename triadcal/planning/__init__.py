"""Planning a calibration campaign for a target uncertainty (``triadcal plan``, docs/plan.md)."""

from .plan import (DEFAULT_Q_V2S, HOURS_CAP, POSITION_SETS, Plan, design, example_plan,  # noqa: F401
                   predict)
from .search import CRITERION, parse_targets, prediction_document, search  # noqa: F401
