"""Judgements of calibrations: drift between two calibrations (compare), what a model misses
(diagnose), and whether the procedures hold what they claim (validation: simulation-based
calibration of the posterior; diagnosis_validation: withheld effects)."""
