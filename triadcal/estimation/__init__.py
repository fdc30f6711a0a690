"""Estimators and judgements: classical (eq. 2-3), joint least squares, budget (eq. 4-7), ..."""
