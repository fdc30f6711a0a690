"""Estimators: classical (the paper's eq. 2-3), joint least squares (CasADi), posterior
(emcee), raw recordings without a bench (raw/); the result they write (result), the priors
and the answer gates every estimator passes before status "ok" (gates)."""
