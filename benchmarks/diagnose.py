"""Benchmark: the diagnosis's inner loops against the obvious alternatives, same run.

On a campaign of the diagnosis validation (420 visits, the full vocabulary's 95 parameters):

* PSIS-LOO of 200 Laplace draws x 420 visits: ours (triadcal.judgement.diagnose.psis, vectorised)
  against ``arviz.loo`` (per-visit loop); the largest difference of the pointwise elpd;
* the residuals and Jacobian of the full-vocabulary problem: ours (DenseCall, CasADi's
  FunctionBuffer into numpy) against ``numpy.asarray`` of the DM a CasADi call returns;
* the flicker floor by REML (Fisher scoring): ours (SpectralREML, eigenbasis) against the same
  ascent on the Cholesky-in-time-order pieces (reml_pieces); the largest difference of tau;
* the chi2 tail: ``special.chdtrc`` against ``stats.chi2.logsf``;

then one whole diagnosis (seconds, for the record). Each pair must agree (printed); the ratios
are the speed-ups.

    python benchmarks/diagnose.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from raw import best_of          # benchmarks/raw.py's: the best of ``repeat`` wall times, and the last output


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    import arviz as az
    from scipy import stats

    from triadcal.estimation import flicker_noise as fl
    from triadcal.estimation.joint import JointProblem
    from triadcal.judgement.diagnose import diagnose
    from triadcal.judgement.diagnose.fitting import _chi2_logsf
    from triadcal.judgement.diagnose.psis import psis_loo
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
    from triadcal.models.effects import EFFECTS
    from triadcal.models.model import Model
    from triadcal.models.simulate import Schedule, simulate_campaign

    truth, model = scenario("bias_tempco")
    campaign = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=1002)
    n = campaign.n_visits
    print(f"campaign: {n} visits, truth effects {','.join(truth.effects)}")

    # -- PSIS-LOO
    rng = np.random.default_rng(1)
    ll = (-0.5 * (rng.normal(size=(200, 3 * n)) + rng.normal(size=3 * n) * 0.3) ** 2).reshape(200, n, 3).sum(axis=2)

    def arviz_loo():
        idata = az.from_dict(posterior={"t": rng.normal(size=(1, 200))}, log_likelihood={"obs": ll[None]})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return az.loo(idata, pointwise=True)
    t_ours, ours = best_of(lambda: psis_loo(ll), args.repeat)
    t_az, ref = best_of(arviz_loo, args.repeat)
    d = float(np.max(np.abs(ours[2] - np.asarray(ref.loo_i))))
    print(f"PSIS-LOO 200 x {n}:   ours {t_ours * 1e3:8.1f} ms   arviz.loo {t_az * 1e3:8.1f} ms   "
          f"ratio {t_az / t_ours:5.1f} x   largest |loo_i difference| {d:.1e}")

    # -- the full-vocabulary Jacobian
    full = JointProblem(campaign, Model(tuple(EFFECTS)), np.ones((n, 3)))
    x = np.array([1.0 if nm.startswith("K_") else 0.0 for nm in full.names])
    mapped = full._mapped.f                               # the same CasADi map, called the DM way

    def dm_way():
        w, J = mapped(x, full.cov_matrix, full.gravity_g)
        return np.asarray(w), np.asarray(J)
    t_ours, (w1, J1) = best_of(lambda: full._mapped(x, full.cov_matrix, full.gravity_g), args.repeat * 4)
    t_dm, (w2, J2) = best_of(dm_way, args.repeat * 4)
    print(f"Jacobian {3 * n} x {len(full.names)}:   ours {t_ours * 1e3:8.2f} ms   DM -> numpy {t_dm * 1e3:8.2f} ms   "
          f"ratio {t_dm / t_ours:5.1f} x   identical {np.array_equal(J1, J2, equal_nan=True) and np.array_equal(w1, w2, equal_nan=True)}"
          f" ({int(np.isnan(J1).sum())} entries NaN at the all-nominal point, in both)")

    # -- the flicker REML
    sigma = np.ones((n, 3)) * 1e-5
    G = fl.normalised_components(campaign, sigma)
    J = rng.normal(size=(3 * n, 20))
    r = rng.normal(size=3 * n)
    groups = [[0, 1, 2]]

    def cholesky_way():
        expand = fl._expander(groups, 3)
        t, *_ = fl._fisher_ascent(np.zeros(1), lambda tg: fl.reml_pieces(r, J, G, expand(tg), campaign.time_s,
                                                                          groups) + (None,), 50)
        return expand(t)
    t_ours, tau1 = best_of(lambda: fl.reml_tau(r, J, G, campaign.time_s, groups)[0], max(1, args.repeat // 2))
    t_ch, tau2 = best_of(cholesky_way, max(1, args.repeat // 2))
    print(f"REML tau ({n} visits):  ours {t_ours * 1e3:8.1f} ms   Cholesky form {t_ch * 1e3:8.1f} ms   "
          f"ratio {t_ch / t_ours:5.1f} x   largest |tau difference| {np.max(np.abs(tau1 - tau2)):.1e}")

    # -- the chi2 tail
    S = rng.uniform(0, 80, 2000)
    t_ours, a = best_of(lambda: [_chi2_logsf(s, 12) for s in S], args.repeat)
    t_st, b = best_of(lambda: [float(stats.chi2.logsf(s, 12)) for s in S], args.repeat)
    print(f"chi2 tail x 2000:      ours {t_ours * 1e3:8.1f} ms   stats.chi2.logsf {t_st * 1e3:8.1f} ms   "
          f"ratio {t_st / t_ours:5.1f} x   largest difference {max(abs(p - q) for p, q in zip(a, b)):.1e}")

    # -- one diagnosis, whole
    t0 = time.perf_counter()
    d = diagnose(campaign, model, n_draws=200, slices_after=False, top=2, seed=1002)
    print(f"one diagnosis (bias_tempco withheld): {time.perf_counter() - t0:.1f} s, verdict {d.verdict_effect}")


if __name__ == "__main__":
    main()
