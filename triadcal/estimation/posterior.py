"""Posterior of the joint model by MCMC (emcee), with arviz diagnostics that gate the result.

``sample`` (the library function of ``triadcal sample``):

1. the joint least-squares fit (:func:`triadcal.estimation.joint.fit_joint`) gives the
   least-squares intervals and start values of the parameters it can determine;
2. the full model (every parameter, also those the least-squares fit had to hold, e.g.
   hysteresis from a heating sweep alone) with the priors of
   :mod:`triadcal.estimation.priors` is maximised (Gauss-Newton on the data residuals of
   eq. 1 plus the prior residuals), and its Laplace approximation ``N(x_map, C)``,
   ``C = (J^T J + P)^-1``, whitens the coordinates: ``x = x_map + L z``, ``L L^T = C``;
3. the log-posterior of eq. 1 with Gaussian noise, ``-1/2 sum r^2 + log prior``, is one
   CasADi function of ``z``: the per-visit model (:meth:`Model.predict` on SX symbols)
   mapped over the visits, mapped again over a block of walkers, compiled to C once per
   model and campaign size (falls back to CasADi's virtual machine without a compiler);
   emcee calls it with every walker at once (``vectorize=True``);
4. the moves are a mixture of differential evolution (``DEMove``), snooker
   (``DESnookerMove``) and an independence proposal from the Laplace approximation
   (:class:`LaplaceMove`); walkers start from draws of the Laplace approximation;
5. the run stops when, after discarding a burn-in of ``5 tau``, the chain is at least
   ``50 tau`` long (emcee's integrated autocorrelation time, the maximum over parameters)
   and arviz's bulk and tail ESS reach the request and split R-hat < 1.01 for every
   parameter; at ``max_steps`` it stops anyway and says ``status: not_converged``.

Why these moves (measured on the standard campaign, see docs/posterior.md and
``benchmarks/sample.py``): in the 32 dimensions of the default model the stretch move
has tau >= 660 steps (still growing after 58 000 steps), DE + snooker ~ 110 (15 000
steps, 70 s to the stop rule), the mixture with the Laplace independence proposal ~ 1.4
(100-170 steps, ~ 1.1 s end to end). DE and snooker keep the chain mixing where the
posterior is not Gaussian (the independence proposal alone would stick in a heavy tail).

Walkers as chains (R-hat, ESS): emcee's walkers are coupled through the ensemble moves,
so they are not independent chains in the strict sense of R-hat. Each walker is a
Markov chain with the posterior as its stationary law, the start is over-dispersed
(draws of the Laplace approximation, inflated), and most proposals here (the
independence move) do not depend on the other walkers, so the cross-walker correlation
is small: R-hat over walkers detects walkers that have not mixed, and ESS over walkers
is the ESS of the ensemble. This is arviz's own convention for emcee
(``from_emcee``). The simulation-based calibration (:mod:`.validation`) checks the
whole procedure, stop rule included.

Reported value: the posterior **mean**, ``u`` = posterior standard deviation (JCGM 101
takes the expectation and standard deviation of the output distribution as the
estimate and its standard uncertainty), with the 95 % central and HDI intervals.
"""

from __future__ import annotations

from ..errors import UnknownName

import math
import os
import tempfile
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence, Union

import casadi as ca
import numpy as np

from ..models.campaign import Campaign
from ..models.effects import DEFAULT_EFFECTS
from ..models.kinematics import tilt_polar
from ..models.model import Covariates, Model
from ..models.units import ARCSEC, DEG
from .gates import DEFAULT_CONFIG, FitEvidence, GateConfig, GateOutcome, apply_gates
from .joint import (COVARIATES, JointProblem, fit_joint, levenberg_marquardt, noise_of, parameter_unit,
                    scaled_covariance)
from .priors import Prior, default_priors, prior_arrays
from .result import Z95, CalibrationResult, ParameterValue

#: posterior SD / prior SD above which a parameter is reported as prior-dominated
PRIOR_DOMINATED_RATIO = 0.5
#: an end of the 95 % central interval that differs from the least-squares one by more
#: than this fraction of the least-squares half-width flags the posterior as non-Gaussian
NON_GAUSSIAN_TOLERANCE = 0.15
LEVEL = 0.95
MOVES = ("de-snooker-laplace", "de-snooker", "stretch")


# -- the compiled log-posterior -----------------------------------------------------------

_COMPILED: dict = {}


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "triadcal" / "casadi"


def _compile(key, build: Callable[[], ca.Function]) -> tuple[ca.Function, bool]:
    """Build a CasADi function and compile its generated C code (cached per process, and on
    disk by a hash of the code under ``$XDG_CACHE_HOME/triadcal/casadi``, so a model is
    compiled once per machine). Without a working C compiler the function runs on CasADi's
    virtual machine: the same numbers, slower."""
    if key in _COMPILED:
        return _COMPILED[key]
    f = build()
    try:
        import hashlib
        import shutil
        import subprocess

        cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
        if cc is None:
            raise RuntimeError("no C compiler")
        folder = _cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
            cg.add(f)
            cg.generate(tmp + os.sep)
            src = Path(tmp) / f"{f.name()}.c"
            digest = hashlib.sha256(src.read_bytes() + cc.encode()).hexdigest()[:20]
            lib = folder / f"{f.name()}_{digest}.so"
            if not lib.exists():
                out = Path(tmp) / "f.so"
                subprocess.run([cc, "-O3", "-fPIC", "-shared", str(src), "-o", str(out), "-lm"],
                               check=True, capture_output=True)
                os.replace(out, lib)
        compiled_f = ca.external(f.name(), str(lib))
        result = (compiled_f, True)
    except Exception:  # no compiler or a failed build: the virtual machine
        result = (f, False)
    _COMPILED[key] = result
    return result


def _visit_functions(model: Model):
    """Per-visit pointwise ``-1/2 r^2`` (3 axes) of eq. 1, symbolic in the parameters
    (reporting units) and the visit's covariates, observation and inverse sigma."""
    npar = len(model.names)
    x = ca.SX.sym("x", npar)
    c = ca.SX.sym("c", len(COVARIATES))
    g = ca.SX.sym("g")
    wo = ca.SX.sym("w_obs", 3)
    isg = ca.SX.sym("inv_sigma", 3)
    p = {s.name: x[i] * s.to_internal for i, s in enumerate(model.parameters)}
    cov = Covariates(axis1=c[0], axis2=c[1], temp=(c[2], c[3], c[4]), temp_rate=(c[5], c[6], c[7]),
                     branch=c[8], time_s=c[9])
    w = ca.vertcat(*model.predict(p, cov, g))
    r = (wo - w) * isg
    return ca.Function("visit_loglik", [x, c, g, wo, isg], [-0.5 * r * r])


class LogPosterior:
    """``log p(z | data)`` up to a constant, in whitened coordinates ``x = x0 + L z``.

    ``__call__`` takes an (m, d) array of walkers and returns (m,) log-posteriors;
    :meth:`pointwise` gives the pointwise log-likelihood per visit and axis (with the
    Gaussian normalisation), for LOO.
    """

    def __init__(self, campaign: Campaign, model: Model, sigma: np.ndarray, priors: Mapping[str, Prior],
                 x0: np.ndarray, L: np.ndarray, block: int):
        self.model = model
        self.names = model.names
        self.d = len(self.names)
        self.n = campaign.n_visits
        self.block = int(block)
        self.x0 = np.asarray(x0, float)
        self.L = np.asarray(L, float)
        mu, sd, self.low, self.high = prior_arrays(priors, self.names)
        rate = campaign.temperature_rate()
        C = np.vstack([np.radians(campaign.axis1_deg), np.radians(campaign.axis2_deg), campaign.t.T,
                       rate.T, campaign.branch, campaign.time_s])
        self.sigma = np.asarray(sigma, float)
        self.args = [ca.DM(self.x0), ca.DM(self.L), ca.DM(C), campaign.gravity_g, ca.DM(campaign.w.T),
                     ca.DM(1.0 / self.sigma.T), ca.DM(mu), ca.DM(1.0 / sd)]
        self.log_norm = -np.log(self.sigma * math.sqrt(2 * math.pi))    # (n, 3)
        key = (model.effect_names, model.reference_temperature_C, self.n, self.block)
        self.f_lp, self.compiled = _compile(("lp",) + key, self._build_lp)
        self._f_pw = None
        self.evaluations = 0

    def _symbols(self):
        d, n, m = self.d, self.n, self.block
        Z = ca.MX.sym("z", d, m)
        syms = [ca.MX.sym("x0", d), ca.MX.sym("L", d, d), ca.MX.sym("cov", len(COVARIATES), n), ca.MX.sym("g"),
                ca.MX.sym("w_obs", 3, n), ca.MX.sym("inv_sigma", 3, n), ca.MX.sym("mu", d), ca.MX.sym("inv_sd", d)]
        return Z, syms

    def _build_lp(self) -> ca.Function:
        visit = _visit_functions(self.model)
        Z, (x0, L, C, g, W, IS, mu, isd) = self._symbols()
        xs = ca.MX.sym("x", self.d)
        ll = ca.sum2(ca.sum1(visit.map(self.n, "serial")(xs, C, g, W, IS)))
        lprior = -0.5 * ca.sumsqr((xs - mu) * isd)
        walker = ca.Function("walker_logpost", [xs, C, g, W, IS, mu, isd], [ll + lprior])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        out = walker.map(self.block, "serial")(X, C, g, W, IS, mu, isd)
        return ca.Function("triadcal_logpost", [Z, x0, L, C, g, W, IS, mu, isd], [out])

    def _build_pw(self) -> ca.Function:
        visit = _visit_functions(self.model)
        Z, (x0, L, C, g, W, IS, mu, isd) = self._symbols()
        xs = ca.MX.sym("x", self.d)
        pw = ca.vec(visit.map(self.n, "serial")(xs, C, g, W, IS))    # visit-major: 3 per visit
        walker = ca.Function("walker_pointwise", [xs, C, g, W, IS], [pw])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        out = walker.map(self.block, "serial")(X, C, g, W, IS)
        return ca.Function("triadcal_pointwise", [Z, x0, L, C, g, W, IS, mu, isd], [out])

    def to_x(self, z: np.ndarray) -> np.ndarray:
        """Whitened -> reporting units; ``z`` (..., d)."""
        return self.x0 + np.asarray(z) @ self.L.T

    def _blocks(self, f, z: np.ndarray, args: Optional[Sequence] = None) -> np.ndarray:
        """``f`` (mapped over ``block`` columns) on the rows of ``z`` in blocks, the last one
        padded; ``args`` after the block (default: the target's data)."""
        args = self.args if args is None else args
        z = np.atleast_2d(np.asarray(z, float))
        m = len(z)
        out = []
        for k in range(0, m, self.block):
            chunk = z[k:k + self.block]
            pad = self.block - len(chunk)
            if pad:
                chunk = np.vstack([chunk, np.repeat(chunk[-1:], pad, axis=0)])
            v = np.asarray(f(chunk.T, *args))
            out.append(v[:, :self.block - pad] if pad else v)
        return np.hstack(out)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.atleast_2d(z)
        self.evaluations += len(z)
        lp = self._blocks(self.f_lp, z)[0]
        x = self.to_x(z)
        inside = np.all((x > self.low) & (x < self.high), axis=1)
        lp = np.where(inside & np.isfinite(lp), lp, -np.inf)
        return lp

    def pointwise(self, z: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood ``log N(w_obs | w_model, sigma)`` per draw, visit and axis:
        shape (m, n, 3)."""
        if self._f_pw is None:
            key = (self.model.effect_names, self.model.reference_temperature_C, self.n, self.block)
            self._f_pw, _ = _compile(("pw",) + key, self._build_pw)
        v = self._blocks(self._f_pw, z)              # (3 n, m)
        return v.T.reshape(-1, self.n, 3) + self.log_norm[None]


# -- moves -----------------------------------------------------------------------------------

def _emcee():
    import emcee
    return emcee


def laplace_move(scale: float = 1.0):
    """Independence Metropolis proposal ``z' ~ N(0, scale^2 I)`` in the whitened coordinates,
    i.e. from the (inflated) Laplace approximation of the posterior; the Hastings factor
    ``log q(z) - log q(z')`` keeps the posterior exact whatever its shape."""
    emcee = _emcee()

    class LaplaceMove(emcee.moves.MHMove):
        def __init__(self):
            self.scale = float(scale)
            super().__init__(self._propose)

        def _propose(self, coords, random):
            new = random.standard_normal(coords.shape) * self.scale
            factor = 0.5 * (np.sum(new * new, axis=1) - np.sum(coords * coords, axis=1)) / self.scale ** 2
            return new, factor

    return LaplaceMove()


def make_moves(kind: str = "de-snooker-laplace"):
    """The emcee move mixture by name (see the module docstring for the measured choice)."""
    emcee = _emcee()
    if kind == "de-snooker-laplace":
        return [(emcee.moves.DEMove(), 0.15), (emcee.moves.DESnookerMove(), 0.05), (laplace_move(1.0), 0.8)]
    if kind == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    if kind == "stretch":
        return [(emcee.moves.StretchMove(), 1.0)]
    raise ValueError(f"unknown moves {kind!r}; choose one of {', '.join(MOVES)}")


# -- the maximum a posteriori and its Laplace approximation ----------------------------------

def laplace_approximation(problem: JointProblem, priors: Mapping[str, Prior], x_start: np.ndarray,
                          max_iter: int = 50):
    """Gauss-Newton (damped) on ``[r(x); (x - mu)/sd]``: MAP ``x`` and covariance
    ``(J^T J + diag(1/sd^2))^-1`` in reporting units. Bounds are not active at the MAP of
    any sensible campaign; a step that leaves them is shortened."""
    mu, sd, low, high = prior_arrays(priors, problem.names)
    # start strictly inside the bounds (an LS value may sit beyond a physical bound)
    margin = 1e-3 * sd
    x = np.clip(np.array(x_start, float), low + margin, high - margin)

    def cost_of(x):
        r, J = problem.residuals_and_jacobian(x)
        rp = (x - mu) / sd
        return float(r @ r + rp @ rp), r, J

    cost, r, J = cost_of(x)
    lam = 1e-6
    for _ in range(max_iter):
        A = J.T @ J + np.diag(1.0 / sd ** 2)
        # J = d r / dx; the Gauss-Newton step solves (J^T J + P) dx = -J^T r - P (x - mu)
        g = -(J.T @ r) - (x - mu) / sd ** 2
        D = np.sqrt(np.diag(A))
        improved = False
        while lam < 1e12:
            As = A / np.outer(D, D) + lam * np.eye(len(x))
            step = np.linalg.solve(As, g / D) / D
            x_new = x + step
            if np.all((x_new > low) & (x_new < high)):
                c_new, r_new, J_new = cost_of(x_new)
                if np.isfinite(c_new) and c_new <= cost:
                    improved = True
                    break
            lam *= 10
        if not improved:
            break
        done = cost - c_new <= 1e-10 * max(cost, 1.0)
        x, cost, r, J = x_new, c_new, r_new, J_new
        lam = max(lam / 10, 1e-9)
        if done:
            break
    A = J.T @ J + np.diag(1.0 / sd ** 2)
    D = np.sqrt(np.diag(A))
    C = np.linalg.inv(A / np.outer(D, D)) / np.outer(D, D)
    C = 0.5 * (C + C.T)
    return x, C


# -- diagnostics ----------------------------------------------------------------------------

def _arviz():
    """arviz, imported on first use (it is slow to import). Where arviz keeps its cache is
    the entry point's choice (``XDG_CACHE_HOME``), never the library's."""
    import arviz as az
    return az


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """emcee's integrated autocorrelation time of a (steps, walkers, d) chain, vectorised.

    The estimator of ``emcee.autocorr.integrated_time`` (Goodman & Weare; Sokal's
    automatic window with ``c = 5``): the normalised autocorrelation of each walker (FFT),
    averaged over walkers, summed up to the first lag ``M >= c tau(M)``. One FFT over
    all walkers and parameters instead of a Python loop; same numbers.
    """
    emcee = _emcee()
    chain = np.asarray(chain, float)
    n, _, d = chain.shape
    nfft = 2 * emcee.autocorr.next_pow_two(n)
    # parameters in groups, so that a long chain does not need gigabytes of FFT buffers
    group = max(1, int(2e7 // (nfft * chain.shape[1])))
    out = np.empty(d)
    for k0 in range(0, d, group):
        x = chain[:, :, k0:k0 + group]
        x = x - x.mean(axis=0, keepdims=True)
        f = np.fft.rfft(x, n=nfft, axis=0)
        acf = np.fft.irfft(f * np.conj(f), n=nfft, axis=0)[:n]
        with np.errstate(invalid="ignore", divide="ignore"):
            acf = acf / acf[0:1]
        rho = np.nan_to_num(acf).mean(axis=1)              # (n, group)
        taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
        for j in range(taus.shape[1]):
            out[k0 + j] = taus[emcee.autocorr.auto_window(taus[:, j], c), j]
    return out


def split_rhat_quick(chain: np.ndarray) -> np.ndarray:
    """Classic split R-hat (Gelman et al. BDA3, walkers as chains), vectorised: a cheap
    screen before arviz's rank-normalised R-hat."""
    n = chain.shape[0] // 2
    parts = np.concatenate([chain[:n], chain[-n:]], axis=1)       # (n, 2W, d)
    w = parts.var(axis=0, ddof=1).mean(axis=0)
    b = n * parts.mean(axis=0).var(axis=0, ddof=1)
    return np.sqrt(((n - 1) / n * w + b / n) / w)


def diagnostics(chain: np.ndarray, names: Sequence[str], tau: Optional[np.ndarray] = None) -> dict:
    """ESS (bulk, tail), rank-normalised split R-hat (walkers as chains, arviz) and emcee's
    integrated autocorrelation time of a (steps, walkers, d) chain."""
    az = _arviz()
    tau = integrated_time(chain) if tau is None else tau
    draws = np.swapaxes(chain, 0, 1)      # (chain=walker, draw, d)
    with warnings.catch_warnings():       # short runs: arviz warns of more chains than draws
        warnings.simplefilter("ignore", UserWarning)
        ds = az.convert_to_dataset({n: draws[:, :, i] for i, n in enumerate(names)})
        ess_b = az.ess(ds, method="bulk")
        ess_t = az.ess(ds, method="tail")
        rhat = az.rhat(ds)
    return {"tau": np.asarray(tau, float),
            "ess_bulk": np.array([float(ess_b[n]) for n in names]),
            "ess_tail": np.array([float(ess_t[n]) for n in names]),
            "rhat": np.array([float(rhat[n]) for n in names])}


@dataclass
class PosteriorRun:
    """What the sampler produced: the whole chain in whitened coordinates and how it stopped."""

    names: tuple
    units: tuple
    chain_z: np.ndarray            # (steps, walkers, d)
    log_prob: np.ndarray           # (steps, walkers)
    burn: int
    converged: bool
    diagnostics: dict
    target: LogPosterior
    seconds: float
    acceptance: float
    moves: str
    checks: list = field(default_factory=list)

    @property
    def kept_z(self) -> np.ndarray:
        return self.chain_z[self.burn:]

    def draws(self) -> np.ndarray:
        """Kept draws in reporting units, (steps, walkers, d)."""
        return self.target.to_x(self.kept_z)

    def flat(self) -> np.ndarray:
        return self.draws().reshape(-1, len(self.names))


def run_sampler(target: LogPosterior, n_walkers: int, *, ess: float = 2000, rhat_max: float = 1.01,
                tau_factor: float = 50.0, max_steps: int = 20000, seed: int = 0,
                moves: str = "de-snooker-laplace", start_scale: float = 1.2,
                progress: Union[bool, Callable, None] = None, first_check: int = 100,
                progress_every: int = 50, max_seconds: Optional[float] = None) -> PosteriorRun:
    """Run emcee until the stop rule holds (module docstring), ``max_steps`` or ``max_seconds``.

    ``target`` is a :class:`LogPosterior` (or any object with its ``d``, ``names``, ``model``,
    ``to_x`` and vectorised ``__call__``)."""
    emcee = _emcee()
    d = target.d
    rng = np.random.default_rng(seed)
    z0 = rng.standard_normal((n_walkers, d)) * start_scale
    for _ in range(100):                  # every walker starts where the posterior is positive
        bad = ~np.isfinite(target(z0))
        if not bad.any():
            break
        z0[bad] = rng.standard_normal((int(bad.sum()), d)) * start_scale * 0.5
    else:
        raise ValueError("cannot place the walkers inside the bounds of the priors around the MAP; "
                         "check the priors (a bound at the estimate?) or the data")
    sampler = emcee.EnsembleSampler(n_walkers, d, target, vectorize=True, moves=make_moves(moves))
    sampler.random_state = np.random.RandomState(seed).get_state()
    bar = None
    if progress is True:
        from tqdm.auto import tqdm
        bar = tqdm(total=max_steps, desc="sampling", unit="step")
        callback = None
    else:
        callback = progress if callable(progress) else None
    t0 = time.perf_counter()
    state = z0
    steps = 0
    target_steps = min(first_check, max_steps)
    checks = []
    converged = False
    diag = None
    burn = 0
    tau_last = 4.0
    while True:
        while steps < target_steps:
            n_run = min(progress_every, target_steps - steps)
            state = sampler.run_mcmc(state, n_run, progress=False)
            steps += n_run
            if bar is not None:
                bar.update(n_run)
            if callback is not None and steps < target_steps:
                callback(steps, max_steps, None)
        # diagnostics of the reported parameters (x), not of the walkers' coordinates
        chain = target.to_x(sampler.get_chain())
        # burn-in: 5 tau of the previous look (the start is already near the posterior)
        burn = int(min(math.ceil(5 * tau_last), steps // 2))
        kept = steps - burn
        tau_vec = integrated_time(chain[burn:])
        tau = tau_last = float(np.max(tau_vec))
        ess_guess = n_walkers * kept / tau
        rhat_guess = float(np.max(split_rhat_quick(chain[burn:])))
        check = {"steps": steps, "burn": burn, "tau_max": tau, "ess_estimate": ess_guess,
                 "rhat_classic_max": rhat_guess}
        # arviz (rank-normalised, slower) only once the cheap screens pass
        if kept >= tau_factor * tau and ess_guess >= ess and rhat_guess < rhat_max:
            diag = diagnostics(chain[burn:], target.names, tau=tau_vec)
            check.update({"ess_bulk_min": float(diag["ess_bulk"].min()),
                          "ess_tail_min": float(diag["ess_tail"].min()), "rhat_max": float(diag["rhat"].max())})
            if (min(check["ess_bulk_min"], check["ess_tail_min"]) >= ess and check["rhat_max"] < rhat_max
                    ):
                converged = True
        checks.append(check)
        if bar is not None:
            bar.set_postfix(tau=f"{tau:.1f}", ess=f"{ess_guess:.0f}", rhat=f"{rhat_guess:.3f}")
        if callback is not None:
            callback(steps, max_steps, check)
        out_of_time = max_seconds is not None and time.perf_counter() - t0 >= max_seconds
        if converged or steps >= max_steps or out_of_time:
            if diag is None or "ess_bulk_min" not in check:
                diag = diagnostics(chain[burn:], target.names, tau=tau_vec)
            break
        # next look: long enough for the length rule at the current tau, the ESS, and R-hat
        # (split R-hat - 1 ~ (tau - 1) / steps for walkers as chains)
        need = max(burn + 1.1 * tau_factor * tau, burn + 1.1 * kept * ess / max(ess_guess, 1.0),
                   burn + 1.1 * kept * (rhat_guess - 1.0) / (0.8 * (rhat_max - 1.0)))
        target_steps = int(min(max_steps, max(need, steps + 25)))
        if max_seconds is not None:
            per_step = (time.perf_counter() - t0) / steps
            left = max(max_seconds - (time.perf_counter() - t0), 0.0)
            target_steps = int(min(target_steps, steps + max(25, left / per_step)))
    if bar is not None:
        bar.close()
    units = (tuple(target.units) if getattr(target, "units", None) is not None
             else tuple(target.model.spec[n].unit for n in target.names))
    return PosteriorRun(names=target.names, units=units,
                        chain_z=sampler.get_chain(), log_prob=sampler.get_log_prob(), burn=burn,
                        converged=converged, diagnostics=diag, target=target,
                        seconds=time.perf_counter() - t0,
                        acceptance=float(np.mean(sampler.acceptance_fraction)), moves=moves, checks=checks)


# -- the library function of ``triadcal sample`` ------------------------------------------------

def _load(data) -> Campaign:
    if isinstance(data, Campaign):
        return data
    from ..io.bench_csv import read_bench_csv
    return read_bench_csv(data)


def sample(data, effects: Sequence[str] = DEFAULT_EFFECTS, *, reference_temperature_C: float = 20.0,
           ess: float = 2000, rhat_max: float = 1.01, tau_factor: float = 50.0, max_steps: int = 20000,
           n_walkers: Optional[int] = None, seed: int = 0, priors: Optional[Mapping[str, Prior]] = None,
           moves: str = "de-snooker-laplace", progress: Union[bool, Callable, None] = None,
           json_path=None, posterior_path=None, max_saved_draws: int = 4000,
           return_run: bool = False, least_squares: Optional[tuple] = None,
           gates: Optional[GateConfig] = None):
    """Posterior of every parameter of the joint model (``triadcal sample``).

    ``data``: a bench CSV v1 path or a :class:`Campaign`. ``ess``: requested bulk and
    tail ESS of every parameter; ``max_steps``: the cap after which the result says
    ``status: not_converged``. ``progress``: True for a tqdm bar (stderr), or a callable
    ``f(steps, max_steps, check)`` called every 50 steps (``check`` is None between
    convergence checks, else the dict of the check). ``priors``: overrides
    of :func:`default_priors` by name. Writes results-json v1 to ``json_path`` and an
    arviz InferenceData netCDF to ``posterior_path`` when given. Returns the
    :class:`CalibrationResult` (method ``posterior``), or ``(result, run)`` with
    ``return_run``. ``least_squares``: the output of ``fit_joint(campaign, effects,
    return_problem=True)`` when the caller already has it (it is computed otherwise).
    ``gates``: the answer gates' thresholds (:class:`~triadcal.estimation.gates.GateConfig`).
    """
    gates = gates or DEFAULT_CONFIG
    if moves not in MOVES:
        raise ValueError(f"unknown moves {moves!r}; choose one of {', '.join(MOVES)}")
    campaign = _load(data)
    t_start = time.perf_counter()
    if least_squares is None:
        least_squares = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                  return_problem=True, gates=gates)
    ls, ls_problem, ls_sol = least_squares
    model = Model(effects, reference_temperature_C)
    pri = default_priors(model, overrides=priors)
    noise = noise_of(campaign)
    sigma = noise.sigma
    notes = []
    if not noise.known:
        chi2_dof = ls.fit.get("chi2_dof")
        if not (chi2_dof and np.isfinite(chi2_dof)):
            raise ValueError(f"{campaign.source or 'campaign'}: the noise of the outputs is not in the data "
                             "(no sd_* columns, no Q_V2s metadata) and cannot be estimated from the fit")
        sigma = sigma * math.sqrt(chi2_dof)
        notes.append(f"output noise not in the data: held at its least-squares estimate ({noise.description}, "
                     f"chi2/dof = {chi2_dof:.3g}); the posterior does not include the uncertainty of the noise level")
    problem = JointProblem(campaign, model, sigma)
    ls_values = dict(zip(ls_problem.names, ls_sol.x))
    x_start = np.array([ls_values.get(n, pri[n].mean) for n in model.names])
    x_map, C = laplace_approximation(problem, pri, x_start)
    Lc = np.linalg.cholesky(C)
    d = len(model.names)
    W = int(n_walkers or 2 * d)
    W += W % 2
    target = LogPosterior(campaign, model, sigma, pri, x_map, Lc, block=W // 2)
    run = run_sampler(target, W, ess=ess, rhat_max=rhat_max, tau_factor=tau_factor, max_steps=max_steps,
                      seed=seed, moves=moves, progress=progress)
    total_seconds = time.perf_counter() - t_start
    result = _result(campaign, model, problem, pri, ls, run, notes, total_seconds, ess, rhat_max, tau_factor, max_steps,
                     gates)
    if json_path is not None:
        result.save(json_path)
    if posterior_path is not None:
        write_inference_data(posterior_path, campaign, run, result, max_saved_draws=max_saved_draws)
    return (result, run) if return_run else result


def posterior_summary(names: Sequence[str], units: Sequence[str], run: PosteriorRun, pri: Mapping[str, Prior],
                      ls_intervals: Mapping[str, tuple]):
    """Value (posterior mean), ``u`` (posterior SD), the 95 % central and HDI intervals beside the
    least-squares ones (``ls_intervals``: name -> (low, high)), and the flags of every parameter.
    Returns ``(params, intervals, non_gaussian, prior_dominated)``. Shared by the bench and the
    generic residual target."""
    az = _arviz()
    draws = run.flat()
    mean = draws.mean(axis=0)
    sd = draws.std(axis=0, ddof=1)
    lo, hi = np.quantile(draws, [(1 - LEVEL) / 2, (1 + LEVEL) / 2], axis=0)
    params, intervals = {}, {}
    non_gaussian, prior_dominated = [], []
    kept = run.draws()
    for i, n in enumerate(names):
        params[n] = ParameterValue(float(mean[i]), float(sd[i]), units[i])
        h = az.hdi(kept[:, :, i].ravel(), hdi_prob=LEVEL)
        iv = {"level": LEVEL, "low": float(lo[i]), "high": float(hi[i]),
              "hdi_low": float(h[0]), "hdi_high": float(h[1]), "ls_low": None, "ls_high": None}
        ratio = float(sd[i] / pri[n].sd)
        iv["prior_sd_ratio"] = ratio
        if n in ls_intervals:
            iv["ls_low"], iv["ls_high"] = (float(v) for v in ls_intervals[n])
            half = 0.5 * (iv["ls_high"] - iv["ls_low"])
            dev = max(abs(iv["low"] - iv["ls_low"]), abs(iv["high"] - iv["ls_high"]))
            iv["non_gaussian"] = bool(half > 0 and dev > NON_GAUSSIAN_TOLERANCE * half) or not half > 0
        else:
            iv["non_gaussian"] = True     # the least-squares fit could not determine it: no Gaussian interval
        iv["prior_dominated"] = ratio > PRIOR_DOMINATED_RATIO
        if iv["non_gaussian"]:
            non_gaussian.append(n)
        if iv["prior_dominated"]:
            prior_dominated.append(n)
        intervals[n] = iv
    return params, intervals, non_gaussian, prior_dominated


def posterior_notes(intervals: Mapping[str, dict], non_gaussian, prior_dominated, ls_names, run: PosteriorRun,
                    ess, rhat_max, tau_factor, max_steps, notes: Optional[list] = None) -> list:
    """The notes of the flags and of a run that did not converge (appended to ``notes``)."""
    notes = [] if notes is None else notes
    for n in prior_dominated:
        notes.append(f"{n}: prior-dominated (posterior SD / prior SD = {intervals[n]['prior_sd_ratio']:.2f} > "
                     f"{PRIOR_DOMINATED_RATIO}): the data do not measure it; its value is the prior's, not a measurement")
    for n in non_gaussian:
        if n in prior_dominated:
            continue
        if n in ls_names:
            notes.append(f"{n}: the 95% posterior interval differs from the least-squares one by more than "
                         f"{NON_GAUSSIAN_TOLERANCE:.0%} of its half-width: the least-squares interval does not hold "
                         "(a non-Gaussian posterior, or parameters the least-squares fit held fixed); "
                         "use the posterior interval")
        else:
            notes.append(f"{n}: the least-squares fit could not determine it; only the posterior interval exists")
    if not run.converged:
        notes.insert(0, f"not converged within {max_steps} steps: the stop rule (chain >= {tau_factor:g} tau, "
                        f"ESS >= {ess:g}, R-hat < {rhat_max}) did not hold; do not use these intervals")
    return notes


def sampler_info(run: PosteriorRun, names: Sequence[str], total_seconds, ess, rhat_max, tau_factor,
                 max_steps) -> dict:
    """The ``sampler`` block of a posterior result (moves, stop rule, diagnostics per parameter)."""
    diag = run.diagnostics
    return {
        "library": "emcee", "moves": run.moves, "walkers": int(run.chain_z.shape[1]),
        "steps": int(run.chain_z.shape[0]), "burn": int(run.burn), "acceptance": run.acceptance,
        "tau_max": float(diag["tau"].max()), "ess_bulk_min": float(diag["ess_bulk"].min()),
        "ess_tail_min": float(diag["ess_tail"].min()), "rhat_max": float(diag["rhat"].max()),
        "stop_rule": {"tau_factor": tau_factor, "ess": ess, "rhat_max": rhat_max, "max_steps": max_steps,
                      "chains": "walkers as chains (see docs/posterior.md)"},
        "compiled": bool(run.target.compiled), "sampling_seconds": run.seconds, "total_seconds": total_seconds,
        "per_parameter": {n: {"tau": float(diag["tau"][k]), "ess_bulk": float(diag["ess_bulk"][k]),
                              "ess_tail": float(diag["ess_tail"][k]), "rhat": float(diag["rhat"][k])}
                          for k, n in enumerate(names)},
    }


def _flags_block(non_gaussian, prior_dominated) -> dict:
    return {"non_gaussian": non_gaussian, "prior_dominated": prior_dominated,
            "criteria": {"non_gaussian": f"an end of the 95% central interval differs from the "
                                         f"least-squares interval by > {NON_GAUSSIAN_TOLERANCE} x its "
                                         "half-width, or no least-squares interval exists",
                         "prior_dominated": f"posterior SD / prior SD > {PRIOR_DOMINATED_RATIO}"}}


def _result(campaign, model, problem, pri, ls, run: PosteriorRun, notes, total_seconds, ess, rhat_max, tau_factor,
            max_steps, gates: GateConfig = DEFAULT_CONFIG) -> CalibrationResult:
    names = list(model.names)
    z = Z95
    ls_intervals = {n: (p.value - z * p.u, p.value + z * p.u) for n, p in ls.parameters.items()}
    params, intervals, non_gaussian, prior_dominated = posterior_summary(
        names, [parameter_unit(model, n, campaign.output_unit) for n in names], run, pri, ls_intervals)
    draws = run.flat()
    if "tilt_x" in names and "tilt_y" in names:
        i, j = names.index("tilt_x"), names.index("tilt_y")
        delta, beta = tilt_polar(draws[:, i] * ARCSEC, draws[:, j] * ARCSEC)
        delta = np.asarray(delta) / ARCSEC
        beta_mean = math.atan2(np.mean(np.sin(beta)), np.mean(np.cos(beta)))
        dev = np.angle(np.exp(1j * (np.asarray(beta) - beta_mean)))
        params["tilt_delta"] = ParameterValue(float(delta.mean()), float(delta.std(ddof=1)), "arcsec")
        params["tilt_beta"] = ParameterValue(beta_mean / DEG, float(dev.std(ddof=1)) / DEG, "deg")
    posterior_notes(intervals, non_gaussian, prior_dominated, ls.parameters, run, ess, rhat_max, tau_factor,
                    max_steps, notes)
    corr = np.corrcoef(draws, rowvar=False)
    x_mean = draws.mean(axis=0)
    chi2 = float(np.sum(problem.residuals(x_mean) ** 2))
    n_obs = 3 * campaign.n_visits
    T = campaign.t
    fit = {"chi2_dof": chi2 / (n_obs - len(names)) if n_obs > len(names) else None, "n_obs": n_obs,
           "n_params": len(names), "value": "posterior mean", "u": "posterior standard deviation",
           "least_squares": {"status": ls.status, "chi2_dof": ls.fit.get("chi2_dof")}}
    result = CalibrationResult(
        unit=ls.unit, method="posterior", parameters=params, effects=tuple(model.effect_names),
        reference_temperature_C=model.reference_temperature_C,
        temperature_range_C=(float(T.min()), float(T.max())), intervals=intervals, fit=fit,
        correlation_names=tuple(names), correlation=corr, notes=notes + list(ls.notes),
        extra={"priors": {n: p.to_dict() for n, p in pri.items()},
               "flags": _flags_block(non_gaussian, prior_dominated),
               "sampler": sampler_info(run, names, total_seconds, ess, rhat_max, tau_factor, max_steps),
               "output_unit": campaign.output_unit,
               "local_g_m_s2": campaign.local_g_m_s2, "source": campaign.source})
    # the least-squares answer's own gates (fit, rank, physics) carry over: a posterior of a
    # model that does not fit the data is no better an answer than its least-squares fit
    ls_gate = GateOutcome("least_squares", ls.status in ("ok", "not_converged"),
                          ls.status if ls.status != "ok" else "model_mismatch",
                          f"the least-squares fit under the same model has status {ls.status!r}")
    noise_known = noise_of(campaign).known
    apply_gates(result, FitEvidence(converged=run.converged, n_obs=n_obs, n_free=len(names), chi2=chi2,
                                    dof=n_obs - len(names), noise_known=noise_known, extra=[ls_gate]),
                config=gates)
    return result


# -- arviz InferenceData ----------------------------------------------------------------------

def _thinned(run: PosteriorRun, max_saved_draws: int):
    """Kept draws thinned to at most ``max_saved_draws``: ``(idx, z, x, thin)``, ``z`` and ``x``
    (draw, chain, d) in whitened and reporting units."""
    kept_z = run.kept_z
    steps, W, _ = kept_z.shape
    thin = max(1, math.ceil(steps * W / max_saved_draws))
    idx = np.arange(steps - 1, -1, -thin)[::-1]
    z = kept_z[idx]                                   # (draw, chain, d)
    return idx, z, run.target.to_x(z), thin


def _posterior_variables(run: PosteriorRun, x: np.ndarray) -> dict:
    """One (chain, draw) variable per parameter, named as the parameter, with its unit."""
    return {name: (("chain", "draw"), x[:, :, i].T, {"units": unit})
            for i, (name, unit) in enumerate(zip(run.names, run.units))}


def _posterior_datasets(run: PosteriorRun, post: dict, idx: np.ndarray, attrs: dict):
    """The ``posterior`` and ``sample_stats`` (``lp``) groups, walkers as ``chain``."""
    import xarray as xr

    W = run.chain_z.shape[1]
    coords = {"chain": np.arange(W), "draw": np.arange(len(idx))}
    posterior = xr.Dataset(post, coords=coords, attrs=attrs)
    lp = run.log_prob[run.burn:][idx]
    sample_stats = xr.Dataset({"lp": (("chain", "draw"), lp.T)}, coords=coords)
    return posterior, sample_stats

def inference_data(campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                   max_saved_draws: int = 4000):
    """arviz ``InferenceData``: posterior (parameters by name, reporting units; walkers as
    ``chain``), sample_stats (``lp``), observed_data and the pointwise log-likelihood
    (``w`` per ``visit`` and ``axis``, with ``position``, ``setpoint_C``, ``direction``
    coordinates), thinned to at most ``max_saved_draws`` draws."""
    az = _arviz()
    import xarray as xr

    idx, z, x, thin = _thinned(run, max_saved_draws)
    W, d = z.shape[1], z.shape[2]
    n = campaign.n_visits
    draws = np.arange(len(idx))
    chains = np.arange(W)
    post = _posterior_variables(run, x)
    if "tilt_x" in run.names and "tilt_y" in run.names:
        i, j = run.names.index("tilt_x"), run.names.index("tilt_y")
        delta, beta = tilt_polar(x[:, :, i].T * ARCSEC, x[:, :, j].T * ARCSEC)
        post["tilt_delta"] = (("chain", "draw"), np.asarray(delta) / ARCSEC, {"units": "arcsec"})
        post["tilt_beta"] = (("chain", "draw"), np.asarray(beta) / DEG, {"units": "deg"})
    attrs = {"inference_library": "emcee", "created_by": "triadcal sample", "moves": run.moves,
             "thinning": int(thin), "burn": int(run.burn), "chains": "emcee walkers"}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status, "effects": ",".join(result.effects)})
    posterior, sample_stats = _posterior_datasets(run, post, idx, attrs)
    visit_coords = {"visit": np.arange(n), "axis": ["x", "y", "z"],
                    "position": ("visit", campaign.position.astype(str)),
                    "setpoint_C": ("visit", campaign.setpoint_C.astype(float), {"units": "degC"}),
                    "direction": ("visit", campaign.direction.astype(str))}
    observed = xr.Dataset({"w": (("visit", "axis"), campaign.w, {"units": campaign.output_unit})},
                          coords=visit_coords)
    pw = run.target.pointwise(z.reshape(-1, d)).reshape(len(idx), W, n, 3).transpose(1, 0, 2, 3)
    loglik = xr.Dataset({"w": (("chain", "draw", "visit", "axis"), pw)},
                        coords={"chain": chains, "draw": draws, **visit_coords})
    return az.InferenceData(posterior=posterior, sample_stats=sample_stats, observed_data=observed,
                            log_likelihood=loglik)


def write_inference_data(path, campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                         max_saved_draws: int = 4000) -> None:
    idata = inference_data(campaign, run, result, max_saved_draws)
    from ..io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")


# -- a generic target: any CasADi residual function of the parameter vector ---------------------

@dataclass
class ResidualTarget:
    """A posterior target defined by normalised residuals, for models other than the bench's eq. 1
    (e.g. the gravity-norm model of :mod:`triadcal.estimation.raw`).

    ``residual``: a CasADi function ``r = f(x, *data)`` of the parameter vector ``x`` (reporting
    units, order of ``names``) and numeric ``data`` arguments, giving the column of residuals
    divided by their standard deviations (``sigma``, in the observations' unit), so that the
    log-likelihood is ``-1/2 r^T r`` (Gaussian noise, known ``sigma``). ``priors``: a
    :class:`Prior` per name. ``x_ls``, ``cov_ls``: the least-squares optimum (start of the MAP
    search, then of the walkers through the Laplace approximation) and its covariance (the
    least-squares intervals, unless ``ls_intervals`` gives them, e.g. Student-t ones).
    ``obs_dim``/``obs_name``: names of the observation axis and of the log-likelihood variable in
    the InferenceData; ``observed``: optional ``{name: (dims, array, attrs)}`` for its
    ``observed_data`` group, with ``obs_coords``.

    ``transform`` (optional): a CasADi function ``x = T(y)`` from the coordinates the walkers
    move in to the parameters, with a constant Jacobian determinant (e.g. a shear
    ``x = (y_1 + m(y_2), y_2)``), and ``inverse`` its inverse. Priors, bounds, residuals and
    the reported draws are in ``x``; the MAP, the Laplace approximation, the whitening and the
    moves are in ``y``. A constant determinant leaves the density unchanged up to a constant,
    so the posterior is exact; a good ``T`` straightens a curved posterior (a "banana") that
    the Laplace proposal and the differential-evolution moves cannot follow.
    """

    name: str
    residual: ca.Function
    data: tuple
    names: tuple
    units: tuple
    priors: Mapping[str, Prior]
    x_ls: np.ndarray
    cov_ls: np.ndarray
    sigma: np.ndarray
    ls_intervals: Optional[Mapping[str, tuple]] = None
    obs_dim: str = "obs"
    obs_name: str = "r"
    observed: Optional[dict] = None
    obs_coords: Optional[dict] = None
    unit_serial: str = ""
    transform: Optional[ca.Function] = None
    inverse: Optional[ca.Function] = None

    def __post_init__(self):
        if (self.transform is None) != (self.inverse is None):
            raise ValueError("a transform needs its inverse (and the inverse its transform)")
        self.names = tuple(self.names)
        self.units = tuple(self.units)
        self.x_ls = np.asarray(self.x_ls, float)
        self.cov_ls = np.asarray(self.cov_ls, float)
        self.sigma = np.asarray(self.sigma, float).reshape(-1)
        missing = [n for n in self.names if n not in self.priors]
        if missing:
            raise UnknownName(f"no prior for {', '.join(missing)}")
        if self.ls_intervals is None:
            z = Z95
            u = np.sqrt(np.maximum(np.diag(self.cov_ls), 0.0))
            self.ls_intervals = {n: (v - z * s, v + z * s) for n, v, s in zip(self.names, self.x_ls, u)}

    @property
    def n_obs(self) -> int:
        return len(self.sigma)


class ResidualProblem:
    """``residuals_and_jacobian`` of a :class:`ResidualTarget` (CasADi exact Jacobian), the
    interface :func:`laplace_approximation` uses. With a ``transform`` the variables are the
    walkers' coordinates ``y`` and the priors (Gaussian, on ``x = T(y)``) are residual rows
    ``(x - mean) / sd`` after the data's, so the MAP and Laplace approximation are in ``y``."""

    def __init__(self, target: ResidualTarget):
        self.names = target.names
        self.n_obs = target.n_obs
        data = [ca.DM(np.asarray(a, float)) if not np.isscalar(a) else a for a in target.data]
        v = ca.MX.sym("v", len(target.names))
        if target.transform is None:
            r = target.residual(v, *data)
        else:
            mu, sd, _, _ = prior_arrays(target.priors, target.names)
            x = target.transform(v)
            r = ca.vertcat(target.residual(x, *data), (x - ca.DM(mu)) / ca.DM(sd))
        self._f = ca.Function("residual_jac", [v], [r, ca.jacobian(r, v)])

    def residuals_and_jacobian(self, x: np.ndarray):
        r, J = self._f(np.asarray(x, float))
        return np.asarray(r).reshape(-1), np.asarray(J)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x)[0]


def conditional_shear(residual: ca.Function, data: Sequence, priors: Mapping[str, Prior], names: Sequence[str],
                      x_hat: np.ndarray, slow: Sequence[int], steps: int = 2):
    """A transform for :class:`ResidualTarget`: the shear ``x_fast = m(x_slow) + u``,
    ``x_slow = y_slow``, with ``m`` the conditional optimum of the other ("fast") parameters
    given the ``slow`` ones (indices). ``m`` is ``steps`` Gauss-Newton steps from ``x_hat`` on
    the data rows ``residual(x, *data)`` and the fast parameters' prior rows
    ``(x - mean) / sd``, each with its own exact Jacobian (CasADi, column-scaled at ``x_hat``).
    Returns ``(transform, inverse)``.

    Use: a posterior whose ridge is a curve along a few poorly determined parameters (the slow
    ones, e.g. prior-dominated nuisances), the others following them nonlinearly. In ``y`` the
    fast part is the residual about the ridge, nearly Gaussian and independent of the slow
    part, so the Laplace proposal and the DE moves work again. The Jacobian determinant of a
    shear is 1 whatever ``m`` is, so the density is unchanged and the posterior exact."""
    d = len(names)
    slow = [int(i) for i in slow]
    fast = [i for i in range(d) if i not in slow]
    mu, sd, _, _ = prior_arrays(priors, names)
    dat = [ca.DM(np.asarray(a, float)) if not np.isscalar(a) else a for a in data]
    xf, xs = ca.MX.sym("x_fast", len(fast)), ca.MX.sym("x_slow", len(slow))
    full = [None] * d
    for k, i in enumerate(fast):
        full[i] = xf[k]
    for k, i in enumerate(slow):
        full[i] = xs[k]
    x = ca.vertcat(*full)
    rows = ca.vertcat(residual(x, *dat), (xf - ca.DM(mu[fast])) / ca.DM(sd[fast]))
    rj = ca.Function("conditional_rows", [xf, xs], [rows, ca.jacobian(rows, xf)])
    _, J0 = rj(x_hat[fast], x_hat[slow])
    D = np.linalg.norm(np.asarray(J0), axis=0)
    D[D == 0] = 1.0
    Dm = ca.DM(D)
    m = ca.DM(x_hat[fast])
    for _ in range(steps):
        r, J = rj(m, xs)
        Js = J / ca.repmat(Dm.T, J.size1(), 1)
        m = m - ca.solve(ca.mtimes(Js.T, Js), ca.mtimes(Js.T, r)) / Dm
    m_of = ca.Function("conditional_optimum", [xs], [m])

    def assemble(y, sign):
        out = [None] * d
        mf = m_of(ca.vertcat(*[y[i] for i in slow]))
        for k, i in enumerate(fast):
            out[i] = y[i] + sign * mf[k]
        for i in slow:
            out[i] = y[i]
        return ca.vertcat(*out)

    y = ca.MX.sym("y", d)
    return (ca.Function("shear", [y], [assemble(y, 1.0)]), ca.Function("shear_inverse", [y], [assemble(y, -1.0)]))


def _transformed_laplace(problem: ResidualProblem, y_start: np.ndarray):
    """MAP and Laplace covariance in the walkers' coordinates of a transformed target (the priors
    are rows of ``problem``): Levenberg-Marquardt, then ``(J^T J)^-1`` (column-scaled)."""
    sol = levenberg_marquardt(problem, np.asarray(y_start, float))
    C = scaled_covariance(sol.J)
    return sol.x, 0.5 * (C + C.T)


class ResidualLogPosterior(LogPosterior):
    """``log p(z | data)`` of a :class:`ResidualTarget` in whitened coordinates ``x = x0 + L z``:
    ``-1/2 r^T r`` plus the Gaussian log-prior, mapped over a block of walkers and compiled like
    :class:`LogPosterior` (same ``__call__``, ``pointwise``, ``to_x``, bounds in numpy)."""

    def __init__(self, target: ResidualTarget, x0: np.ndarray, L: np.ndarray, block: int):
        import hashlib

        self.spec = target
        self.names = target.names
        self.units = target.units
        self.d = len(self.names)
        self.n = target.n_obs
        self.block = int(block)
        self.x0 = np.asarray(x0, float)
        self.L = np.asarray(L, float)
        mu, sd, self.low, self.high = prior_arrays(target.priors, self.names)
        self.sigma = target.sigma
        self._data = [ca.DM(np.asarray(a, float)) for a in target.data]
        self.args = [ca.DM(self.x0), ca.DM(self.L), *self._data, ca.DM(mu), ca.DM(1.0 / sd)]
        self.log_norm = -np.log(self.sigma * math.sqrt(2 * math.pi))    # (n,)
        code = hashlib.sha256((target.residual.serialize() + (target.transform.serialize() if target.transform
                                                                 is not None else "")).encode()).hexdigest()[:16]
        self._key = (target.name, code, tuple(a.shape for a in self._data), self.block)
        self.f_lp, self.compiled = _compile(("residual-lp",) + self._key, self._build_lp)
        self._f_pw = None
        self._f_x = None
        self.evaluations = 0

    def _symbols(self):
        Z = ca.MX.sym("z", self.d, self.block)
        data = [ca.MX.sym(f"data{i}", *a.shape) for i, a in enumerate(self._data)]
        return Z, ca.MX.sym("x0", self.d), ca.MX.sym("L", self.d, self.d), data, \
            ca.MX.sym("mu", self.d), ca.MX.sym("inv_sd", self.d)

    def _build(self, pointwise: bool) -> ca.Function:
        """Log-posterior (row 0) and, with a transform, the parameters ``x`` (rows 1..d) of a
        block of walkers; or the pointwise log-likelihood."""
        Z, x0, L, data, mu, isd = self._symbols()
        ys = ca.MX.sym("y", self.d)
        xs = ys if self.spec.transform is None else self.spec.transform(ys)
        r = self.spec.residual(xs, *data)
        out = -0.5 * r * r if pointwise else -0.5 * ca.sumsqr(r) - 0.5 * ca.sumsqr((xs - mu) * isd)
        if self.spec.transform is not None and not pointwise:
            out = ca.vertcat(out, xs)
        walker = ca.Function("walker", [ys, *data, mu, isd], [out])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        res = walker.map(self.block, "serial")(X, *data, mu, isd)
        name = f"triadcal_{self.spec.name}_{'pointwise' if pointwise else 'logpost'}"
        return ca.Function(name, [Z, x0, L, *data, mu, isd], [res])

    def _build_lp(self) -> ca.Function:
        return self._build(False)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        if self.spec.transform is None:
            return super().__call__(z)
        z = np.atleast_2d(z)
        self.evaluations += len(z)
        out = self._blocks(self.f_lp, z)
        lp, x = out[0], out[1:].T
        inside = np.all((x > self.low) & (x < self.high), axis=1)
        return np.where(inside & np.isfinite(lp), lp, -np.inf)

    def to_x(self, z: np.ndarray) -> np.ndarray:
        """Whitened -> reporting units (through the transform, if any); ``z`` (..., d)."""
        y = self.x0 + np.asarray(z) @ self.L.T
        if self.spec.transform is None:
            return y
        if self._f_x is None:
            self._f_x = self.spec.transform.map(self.block, "serial")
        return self._blocks(self._f_x, y.reshape(-1, self.d), args=()).T.reshape(y.shape)

    def pointwise(self, z: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood ``log N(obs | model, sigma)`` per draw and observation: (m, n)."""
        if self._f_pw is None:
            self._f_pw, _ = _compile(("residual-pw",) + self._key, lambda: self._build(True))
        return self._blocks(self._f_pw, z).T + self.log_norm[None]


def sample_target(target: ResidualTarget, *, ess: float = 2000, rhat_max: float = 1.01, tau_factor: float = 50.0,
                  max_steps: int = 20000, n_walkers: Optional[int] = None, seed: int = 0,
                  moves: str = "de-snooker-laplace", progress: Union[bool, Callable, None] = None,
                  posterior_path=None, max_saved_draws: int = 4000, notes: Sequence[str] = ()):
    """Posterior of a :class:`ResidualTarget` through the bench's path: MAP and Laplace
    approximation from the least-squares optimum (:func:`laplace_approximation`), whitened
    coordinates, the same emcee moves and stop rule (:func:`run_sampler`), the same value,
    intervals and flags (:func:`posterior_summary`). Returns ``(CalibrationResult, PosteriorRun)``
    (method ``posterior``); writes the InferenceData to ``posterior_path`` when given."""
    if moves not in MOVES:
        raise ValueError(f"unknown moves {moves!r}; choose one of {', '.join(MOVES)}")
    t_start = time.perf_counter()
    problem = ResidualProblem(target)
    if target.transform is None:
        x_map, C = laplace_approximation(problem, target.priors, target.x_ls)
    else:
        y_map, C = _transformed_laplace(problem, np.asarray(target.inverse(target.x_ls)).reshape(-1))
    # Cholesky of the column-scaled covariance (parameters differ by 10 orders of magnitude)
    D = np.sqrt(np.diag(C))
    Lc = np.linalg.cholesky(C / np.outer(D, D)) * D[:, None]
    d = len(target.names)
    W = int(n_walkers or 2 * d)
    W += W % 2
    lp = ResidualLogPosterior(target, x_map if target.transform is None else y_map, Lc, block=W // 2)
    if target.transform is not None:
        x_map = np.asarray(target.transform(y_map)).reshape(-1)
    run = run_sampler(lp, W, ess=ess, rhat_max=rhat_max, tau_factor=tau_factor, max_steps=max_steps,
                      seed=seed, moves=moves, progress=progress)
    total_seconds = time.perf_counter() - t_start
    names = list(target.names)
    params, intervals, non_gaussian, prior_dominated = posterior_summary(names, target.units, run, target.priors,
                                                                         target.ls_intervals)
    out_notes = posterior_notes(intervals, non_gaussian, prior_dominated, target.ls_intervals, run, ess, rhat_max,
                                tau_factor, max_steps, list(notes))
    # prior-influenced: the least-squares (data-only) uncertainty is comparable to the prior's,
    # so the prior, not the data, sets the posterior's width (weaker than prior-dominated)
    prior_influenced = []
    for n in names:
        if n in target.ls_intervals:
            lo_, hi_ = target.ls_intervals[n]
            ratio = float((hi_ - lo_) / (2 * Z95) / target.priors[n].sd)
            intervals[n]["ls_prior_sd_ratio"] = ratio
            if ratio > PRIOR_DOMINATED_RATIO and n not in prior_dominated:
                prior_influenced.append(n)
                out_notes.append(f"{n}: prior-influenced (least-squares SD / prior SD = {ratio:.2f} > "
                                 f"{PRIOR_DOMINATED_RATIO}): the data alone determine it poorly; the prior "
                                 f"narrows its interval (posterior SD / prior SD = {intervals[n]['prior_sd_ratio']:.2f})")
    draws = run.flat()
    x_mean = draws.mean(axis=0)
    chi2 = float(np.sum(ResidualProblem(replace(target, transform=None, inverse=None)).residuals(x_mean) ** 2))
    n_obs = target.n_obs
    fit = {"chi2_dof": chi2 / (n_obs - d) if n_obs > d else None, "n_obs": n_obs, "n_params": d,
           "value": "posterior mean", "u": "posterior standard deviation",
           "map": dict(zip(names, map(float, x_map)))}
    result = CalibrationResult(
        unit=target.unit_serial, method="posterior", parameters=params,
        status="ok" if run.converged else "not_converged", intervals=intervals, fit=fit,
        correlation_names=tuple(names), correlation=np.corrcoef(draws, rowvar=False), notes=out_notes,
        extra={"priors": {n: target.priors[n].to_dict() for n in names},
               "flags": {**_flags_block(non_gaussian, prior_dominated), "prior_influenced": prior_influenced},
               "sampler": sampler_info(run, names, total_seconds, ess, rhat_max, tau_factor, max_steps)})
    result.extra["flags"]["criteria"]["prior_influenced"] = (f"least-squares SD / prior SD > {PRIOR_DOMINATED_RATIO} "
                                                             "(and not prior-dominated)")
    if posterior_path is not None:
        write_target_inference_data(posterior_path, target, run, result, max_saved_draws=max_saved_draws)
    return result, run


def target_inference_data(target: ResidualTarget, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                          max_saved_draws: int = 4000):
    """arviz ``InferenceData`` of a :class:`ResidualTarget` run: posterior (by name, reporting
    units), sample_stats (``lp``), observed_data (when the target gives it) and the pointwise
    log-likelihood ``obs_name`` over ``(chain, draw, obs_dim)``."""
    az = _arviz()
    import xarray as xr

    idx, z, x, thin = _thinned(run, max_saved_draws)
    W, d = z.shape[1], z.shape[2]
    attrs = {"inference_library": "emcee", "created_by": f"triadcal ({target.name})", "moves": run.moves,
             "thinning": int(thin), "burn": int(run.burn), "chains": "emcee walkers"}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status})
    posterior, sample_stats = _posterior_datasets(run, _posterior_variables(run, x), idx, attrs)
    n = target.n_obs
    coords = {target.obs_dim: np.arange(n), **(target.obs_coords or {})}
    groups = {"posterior": posterior, "sample_stats": sample_stats}
    if target.observed:
        groups["observed_data"] = xr.Dataset(target.observed, coords=coords)
    pw = run.target.pointwise(z.reshape(-1, d)).reshape(len(idx), W, n).transpose(1, 0, 2)
    loglik_coords = {"chain": np.arange(W), "draw": np.arange(len(idx)), target.obs_dim: np.arange(n)}
    groups["log_likelihood"] = xr.Dataset({target.obs_name: (("chain", "draw", target.obs_dim), pw)},
                                          coords=loglik_coords)
    return az.InferenceData(**groups)


def write_target_inference_data(path, target: ResidualTarget, run: PosteriorRun,
                                result: Optional[CalibrationResult] = None, max_saved_draws: int = 4000) -> None:
    idata = target_inference_data(target, run, result, max_saved_draws)
    from ..io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")
