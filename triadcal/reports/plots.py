"""Plots of a calibration for the certificate and for review (matplotlib, Agg backend).

Every function takes data and a result and returns PNG bytes (or a matplotlib figure);
nothing here estimates anything or re-states the physics: model values come from
:meth:`triadcal.models.model.Model.predict` / :meth:`~triadcal.models.model.Model.terms`
with the result's parameters, per-setpoint estimates from
:func:`triadcal.estimation.classical.fit_classical` (seed paper, eq. 2-3) when it is
installed, posterior draws from an arviz ``InferenceData`` whose variables are named
like the parameters in reporting units.

:func:`report_plots` collects what can be drawn from what is at hand and says, for
each plot it cannot draw, why (``skipped``).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..models.effects.hysteresis import BRANCH
from ..models.sensor import ANGLE_NAMES, AXES

#: colours of the hysteresis branches (heating red, cooling blue, none grey)
BRANCH_COLOURS = {"heating": "#c0392b", "cooling": "#2471a3", "none": "#7f8c8d"}
BRANCH_VALUE = BRANCH      # the hysteresis effect's map (models/effects/hysteresis.py), not a copy
DPI = 120


@dataclass
class Plot:
    """One rendered plot: a file-friendly ``name``, a ``title``, a ``caption`` and the PNG."""

    name: str
    title: str
    caption: str
    png: bytes


@dataclass
class PlotSet:
    plots: list = field(default_factory=list)
    #: plot name -> why it was not drawn
    skipped: dict = field(default_factory=dict)


#: the reports' text sizes (points), applied to each figure, never to matplotlib's global rcParams
STYLE = {"font.size": 9, "axes.titlesize": 10, "axes.labelsize": 9, "legend.fontsize": 8,
         "xtick.labelsize": 8, "ytick.labelsize": 8}


class _Figures:
    """The few pyplot calls the reports use, on bare :class:`matplotlib.figure.Figure` objects:
    no backend is chosen or forced (a figure renders itself to PNG with Agg when saved) and no
    global state changes; the style applies while a figure and its axes are made."""

    def __init__(self):
        import matplotlib
        from matplotlib import cm, lines

        self._mpl = matplotlib
        self.cm = cm
        self.Line2D = lines.Line2D

    def subplots(self, nrows=1, ncols=1, *, figsize=None, **kw):
        from matplotlib.figure import Figure

        with self._mpl.rc_context(STYLE):
            fig = Figure(figsize=figsize)
            axes = fig.subplots(nrows, ncols, **kw)
        return fig, axes

    def figure(self, figsize=None):
        from matplotlib.figure import Figure

        with self._mpl.rc_context(STYLE):
            return Figure(figsize=figsize)

    @staticmethod
    def close(fig) -> None:
        """Nothing to do: a bare Figure is not registered with pyplot; dropping it frees it."""


def _mpl() -> _Figures:
    return _Figures()


def styled(fn):
    """Draw ``fn``'s figure with the reports' :data:`STYLE` (a context, not a global change)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        import matplotlib

        with matplotlib.rc_context(STYLE):
            return fn(*args, **kwargs)
    return wrapper


def figure_png(fig, dpi: int = DPI) -> bytes:
    """PNG bytes of a figure; the figure is closed."""
    plt = _mpl()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


# -- the fitted model ----------------------------------------------------------------------
def model_outputs(result, campaign) -> np.ndarray:
    """Outputs (n, 3) the fitted model predicts for each visit of ``campaign`` (eq. 1)."""
    model, p = result.full_model()
    w = model.predict(p, campaign.covariates(), campaign.gravity_g)
    return np.stack([np.broadcast_to(np.asarray(c, float), (campaign.n_visits,)) for c in w], axis=1)


# -- per-setpoint estimates (classical, eq. 2-3) ---------------------------------------------
def per_setpoint_angles(campaign) -> list[dict]:
    """Per-setpoint classical estimates of the angles: a list of
    ``{"temperature_C", "direction", "Ca_xy": arcsec, ...}``.

    Taken from ``fit_classical(campaign).extra["per_setpoint"]``; raises ``ImportError``
    or ``LookupError`` with a message when that is not available.
    """
    try:
        from ..estimation.classical import fit_classical
    except ImportError as exc:
        raise ImportError(f"the classical estimator (eq. 2-3) is not installed: {exc}") from None
    res = fit_classical(campaign)
    raw = res.extra.get("per_setpoint") if hasattr(res, "extra") else None
    if not raw:
        raise LookupError("fit_classical gave no per-setpoint estimates (extra['per_setpoint'])")
    rows = raw if isinstance(raw, list) else [dict(v, key=k) for k, v in raw.items()]
    out = []
    for r in rows:
        T = next((r[k] for k in ("temperature_C", "mean_temperature_C", "t_mean_C", "T_C", "temperature", "setpoint_C") if k in r), None)
        if T is None:
            raise LookupError(f"per-setpoint estimate without a temperature: keys {sorted(r)}")
        rec = {"temperature_C": float(T), "direction": str(r.get("direction", "none"))}
        params = r.get("parameters", r)
        for ab in ANGLE_NAMES:
            v = params.get(f"Ca_{ab}")
            if v is None:
                continue
            rec[f"Ca_{ab}"] = float(v["value"] if isinstance(v, dict) else v)
            if isinstance(v, dict) and "u" in v:
                rec[f"u_Ca_{ab}"] = float(v["u"])
        out.append(rec)
    return out


# -- the plots ----------------------------------------------------------------------------------
@styled
def residuals_figure(result, campaign):
    """Residuals (observed - model, in micro output units) per bench position and axis,
    coloured by the hysteresis branch of the visit."""
    plt = _mpl()
    resid = (campaign.w - model_outputs(result, campaign)) * 1e6
    positions = list(dict.fromkeys(sorted(campaign.position.tolist())))
    xpos = {p: i for i, p in enumerate(positions)}
    x = np.array([xpos[p] for p in campaign.position], float)
    rng = np.random.default_rng(0)  # horizontal jitter only, for legibility
    jitter = rng.uniform(-0.25, 0.25, size=len(x))
    unit = campaign.output_unit
    fig, axes = plt.subplots(3, 1, figsize=(9, 5.8), sharex=True)
    for i, (ax, a) in enumerate(zip(axes, AXES)):
        for d, colour in BRANCH_COLOURS.items():
            m = campaign.direction == d
            if m.any():
                ax.plot(x[m] + jitter[m], resid[m, i], "o", ms=3.2, alpha=0.8, color=colour, label=d)
        sig = campaign.output_sigma()
        if sig is not None:
            s = float(np.median(sig[:, i])) * 1e6
            ax.axhspan(-2 * s, 2 * s, color="0.9", zorder=0, label="±2σ of a visit")
        ax.axhline(0, color="0.3", lw=0.8)
        ax.set_ylabel(f"{a.upper()}: residual (µ{unit})")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(loc="upper right", ncol=4, frameon=False)
    axes[-1].set_xticks(range(len(positions)))
    up = dict(zip(campaign.position.tolist(), campaign.up_axis().tolist()))
    axes[-1].set_xticklabels([f"{p}\n{up.get(p, '')}" for p in positions])
    axes[-1].set_xlabel("bench position (and the IMU axis pointing up)")
    fig.suptitle(f"{result.unit}: residuals of the fitted model per position and axis", fontsize=10)
    fig.tight_layout()
    return fig


@styled
def angles_temperature_figure(result, campaign=None, per_setpoint: Optional[list] = None):
    """Each orientation angle against temperature: the fitted model on the heating and the
    cooling branch (and the mid-line), with per-setpoint estimates when given."""
    plt = _mpl()
    lo, hi = result.temperature_range_C or (result.reference_temperature_C - 40, result.reference_temperature_C + 50)
    T = np.linspace(lo, hi, 101)
    has_hyst = "hysteresis" in result.effects
    curves = {b: result.angles_at(T, v) for b, v in BRANCH_VALUE.items()}
    fig, axes = plt.subplots(2, 3, figsize=(10, 5.6))
    for ax, ab in zip(axes.ravel(), ANGLE_NAMES):
        if has_hyst:
            ax.plot(T, curves["heating"][ab], color=BRANCH_COLOURS["heating"], lw=1.4, label="model, heating")
            ax.plot(T, curves["cooling"][ab], color=BRANCH_COLOURS["cooling"], lw=1.4, label="model, cooling")
        ax.plot(T, curves["none"][ab], color="0.2", lw=1.0, ls="--" if has_hyst else "-",
                label="model, mid-line" if has_hyst else "model")
        if per_setpoint:
            for d, colour in BRANCH_COLOURS.items():
                pts = [r for r in per_setpoint if r["direction"] == d and f"Ca_{ab}" in r]
                if pts:
                    t = [r["temperature_C"] for r in pts]
                    v = [r[f"Ca_{ab}"] for r in pts]
                    e = [2 * r.get(f"u_Ca_{ab}", 0.0) for r in pts]
                    ax.errorbar(t, v, yerr=e if any(e) else None, fmt="o", ms=3.5, color=colour,
                                mfc="white", capsize=2, lw=0.8, label=f"per setpoint, {d}")
        ax.axvline(result.reference_temperature_C, color="0.6", lw=0.7, ls=":")
        ax.set_title(f"Ca_{ab}")
        ax.set_xlabel("temperature (°C)")
        ax.set_ylabel("angle (arcsec)")
        ax.grid(True, alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, frameon=False)
    fig.suptitle(f"{result.unit}: orientation angles against temperature "
                 f"(reference {result.reference_temperature_C:g} °C, dotted)", fontsize=10)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    return fig


def posterior_draws(idata, names) -> dict:
    """Draws of ``names`` from an InferenceData's posterior as (chain, draw) arrays."""
    post = idata.posterior
    missing = [n for n in names if n not in post.data_vars]
    if missing:
        raise LookupError(f"the posterior has no variables {missing} (it has {sorted(post.data_vars)})")
    return {n: np.asarray(post[n].transpose("chain", "draw").values, float) for n in names}


@styled
def pair_figure(idata, names=tuple(f"Ca_{ab}" for ab in ANGLE_NAMES), max_points: int = 2000):
    """Corner plot of the posterior of ``names`` (default: the six angles), in arcsec,
    as deviations from the posterior mean so that the small spreads are legible."""
    plt = _mpl()
    draws = posterior_draws(idata, names)
    flat = {n: d.reshape(-1) for n, d in draws.items()}
    n_all = len(next(iter(flat.values())))
    idx = np.random.default_rng(0).choice(n_all, size=min(max_points, n_all), replace=False)
    k = len(names)
    fig, axes = plt.subplots(k, k, figsize=(1.2 * k + 0.8, 1.2 * k + 0.8))
    axes = np.atleast_2d(axes)
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            xa = flat[b] - flat[b].mean()
            if i == j:
                ax.hist(xa, bins=40, color="#2471a3", alpha=0.8)
                ax.set_yticks([])
            else:
                ya = flat[a] - flat[a].mean()
                ax.plot(xa[idx], ya[idx], ".", ms=1.2, alpha=0.35, color="#2471a3")
            ax.tick_params(labelsize=6)
            if i == k - 1:
                ax.set_xlabel(f"{b} − {flat[b].mean():.4g}", fontsize=7)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(f"{a} − {flat[a].mean():.4g}", fontsize=7)
            elif j > 0:
                ax.set_yticklabels([])
    fig.suptitle("posterior of the orientation angles (arcsec, around the posterior mean)", fontsize=10)
    fig.tight_layout()
    return fig


@styled
def trace_rank_figure(idata, names=tuple(f"Ca_{ab}" for ab in ANGLE_NAMES), bins: int = 20):
    """Trace (left) and rank histograms per chain (right) for ``names``; uniform rank
    histograms mean the chains explore the same distribution (Vehtari et al. 2021)."""
    plt = _mpl()
    draws = posterior_draws(idata, names)
    k = len(names)
    fig, axes = plt.subplots(k, 2, figsize=(8, 1.3 * k + 0.6), squeeze=False)
    for i, n in enumerate(names):
        d = draws[n]
        n_chain, n_draw = d.shape
        colours = plt.cm.viridis(np.linspace(0, 0.9, n_chain))
        for c in range(n_chain):
            axes[i, 0].plot(d[c], lw=0.4, alpha=0.7, color=colours[c])
        axes[i, 0].set_ylabel(f"{n} (arcsec)", fontsize=7)
        ranks = np.argsort(np.argsort(d.reshape(-1), kind="stable"), kind="stable").reshape(d.shape)
        edges = np.linspace(0, d.size, bins + 1)
        for c in range(n_chain):
            h, _ = np.histogram(ranks[c], bins=edges)
            axes[i, 1].stairs(h, edges, color=colours[c], lw=1.2, baseline=None)
        axes[i, 1].axhline(n_draw / bins, color="0.2", lw=0.8, ls="--")
        axes[i, 1].set_ylim(0, 2.0 * n_draw / bins)
        axes[i, 1].set_yticks([])
        for ax in axes[i]:
            ax.tick_params(labelsize=7)
            if i < k - 1:
                ax.set_xticklabels([])
    axes[-1, 0].set_xlabel("draw")
    axes[-1, 1].set_xlabel("rank of the draw among all chains (dashed: uniform)")
    axes[0, 0].set_title("trace per chain", fontsize=9)
    axes[0, 1].set_title("rank histogram per chain", fontsize=9)
    fig.tight_layout()
    return fig


def report_plots(result, campaign=None, idata=None) -> PlotSet:
    """Every plot that can be drawn from what is given; the others in ``skipped`` with the reason."""
    out = PlotSet()
    if campaign is not None:
        out.plots.append(Plot("residuals", "Residuals per position and axis",
                              "Observed output minus the fitted model for every visit, per bench position "
                              "(with the IMU axis pointing up) and accelerometer; colours mark the branch "
                              "of the thermal cycle.", figure_png(residuals_figure(result, campaign))))
    else:
        out.skipped["residuals"] = "no campaign data given (--data DATA.csv)"
    per_setpoint, why = None, None
    if campaign is not None:
        try:
            per_setpoint = per_setpoint_angles(campaign)
        except (ImportError, LookupError, ValueError) as exc:
            why = str(exc)
    else:
        why = "no campaign data given (--data DATA.csv)"
    caption = ("The fitted thermal model of each orientation angle on the heating and the cooling branch "
               "over the calibrated temperature range")
    caption += (", with the per-setpoint classical estimates (eq. 2-3, error bars k = 2)." if per_setpoint
                else f". Per-setpoint estimates not shown: {why}.")
    out.plots.append(Plot("angles_temperature", "Orientation angles against temperature", caption,
                          figure_png(angles_temperature_figure(result, campaign, per_setpoint))))
    if idata is None:
        out.skipped["posterior_pairs"] = out.skipped["posterior_trace_rank"] = "no posterior given (--posterior P.nc)"
    else:
        try:
            out.plots.append(Plot("posterior_pairs", "Posterior of the orientation angles",
                                  "Pairs of posterior draws of the six angles, as deviations from the posterior "
                                  "mean (axis labels give the mean).", figure_png(pair_figure(idata))))
            out.plots.append(Plot("posterior_trace_rank", "Sampler diagnostics: trace and rank plots",
                                  "Draws of each chain (left) and the rank histogram of each chain (right); "
                                  "flat rank histograms mean the chains agree.", figure_png(trace_rank_figure(idata))))
        except LookupError as exc:
            out.skipped["posterior_pairs"] = out.skipped["posterior_trace_rank"] = str(exc)
    return out


VERDICT_COLOURS = {"pass": "#1e8449", "fail": "#c0392b", "inconclusive": "#b9770e"}


@styled
def drift_figure(rows):
    """Drift of each parameter with its expanded uncertainty (k = 2), one panel per unit,
    coloured by the verdict (grey: not judged); ``rows`` are
    :class:`triadcal.reports.certificate.DriftRow`."""
    plt = _mpl()
    units = list(dict.fromkeys(r.unit for r in rows))
    heights = [max(1.2, 0.28 * sum(r.unit == u for r in rows) + 0.6) for u in units]
    fig, axes = plt.subplots(len(units), 1, figsize=(8, sum(heights) + 0.6), squeeze=False,
                             gridspec_kw={"height_ratios": heights})
    for ax, unit in zip(axes[:, 0], units):
        sub = [r for r in rows if r.unit == unit]
        y = np.arange(len(sub))[::-1]
        for yi, r in zip(y, sub):
            colour = VERDICT_COLOURS.get(r.verdict, "0.3") if getattr(r, "judged", True) else "0.55"
            ax.errorbar(r.drift_value, yi, xerr=r.U_value, fmt="o", color=colour, capsize=3, ms=4)
        ax.axvline(0, color="0.3", lw=0.8)
        ax.set_yticks(y)
        ax.set_yticklabels([r.name for r in sub], fontsize=8)
        ax.set_xlabel(f"drift, after − before ({unit}); bars: U (k = 2)")
        ax.grid(True, axis="x", alpha=0.3)
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=v) for v, c in VERDICT_COLOURS.items()]
    handles.append(plt.Line2D([], [], color="0.55", marker="o", ls="", label="not judged (no tolerance)"))
    axes[0, 0].legend(handles=handles, loc="best", fontsize=8, frameon=False)
    fig.tight_layout()
    return fig
