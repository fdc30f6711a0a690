"""Report of a diagnosis (HTML with embedded plots) and the plots of its validation.

Nothing here estimates anything: the numbers come from
:class:`triadcal.judgement.diagnose.Diagnosis` and
:class:`triadcal.judgement.diagnosis_validation.ValidationResult`.
"""

from __future__ import annotations

import base64
import html
import math

import numpy as np

from .plots import BRANCH_COLOURS, _mpl, figure_png, styled

FAMILY_COLOURS = {"axis": "#34495e", "up": "#8e44ad", "setpoint": "#d35400", "direction": "#c0392b",
                  "time": "#16a085", "since_change": "#2980b9"}


@styled
def residuals_figure(diagnosis, campaign):
    """Normalised residuals of the base fit against time, per output, coloured by branch."""
    plt = _mpl()
    r = diagnosis.residuals
    fig, axes = plt.subplots(3, 1, figsize=(8.0, 6.0), sharex=True)
    t_h = (campaign.time_s - campaign.time_s.min()) / 3600.0
    for i, ax in enumerate(axes):
        for d, col in BRANCH_COLOURS.items():
            m = campaign.direction == d
            if m.any():
                ax.plot(t_h[m], r[m, i], ".", ms=3, color=col, label=d)
        ax.axhline(0, color="k", lw=0.6)
        for y in (-3, 3):
            ax.axhline(y, color="k", lw=0.4, ls=":")
        ax.set_ylabel(f"r_{'xyz'[i]} / sigma")
    axes[0].legend(loc="upper right", ncol=3)
    axes[0].set_title(f"normalised residuals of the model {', '.join(diagnosis.model) or '(core)'}")
    axes[-1].set_xlabel("time in campaign (h)")
    return fig


@styled
def slices_figure(diagnosis, n: int = 15):
    """The most significant slices: -log10 of the Holm-adjusted p-value, coloured by family."""
    plt = _mpl()
    sl = diagnosis.slices[:n]
    fig, ax = plt.subplots(figsize=(8.0, 0.3 * max(len(sl), 3) + 1.0))
    vals = [-s.log10_p for s in sl]
    labels = [f"{s.slice} [{s.axis}] {s.test}" for s in sl]
    ax.barh(range(len(sl)), vals, color=[FAMILY_COLOURS.get(s.family, "grey") for s in sl])
    ax.axvline(-math.log10(diagnosis.alpha), color="k", ls="--", lw=0.8, label=f"alpha = {diagnosis.alpha:g}")
    ax.set_yticks(range(len(sl)))
    ax.set_yticklabels(labels)
    ax.invert_yaxis()
    ax.set_xscale("symlog")
    ax.set_xlabel("-log10 p (unadjusted; the line is alpha)")
    ax.set_ylabel("slice [output] test")
    ax.set_title("where: residual slices ranked")
    ax.legend(loc="lower right")
    return fig


@styled
def candidates_figure(diagnosis):
    """Score test (-log10 p) of every testable candidate and delta elpd of the refitted ones."""
    plt = _mpl()
    cs = [c for c in sorted(diagnosis.candidates, key=lambda c: c.rank) if c.testable]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9.0, 0.35 * max(len(cs), 3) + 1.2), sharey=True)
    y = np.arange(len(cs))
    a1.barh(y, [min(-c.score_logp / math.log(10), 1e4) for c in cs], color="#2471a3")
    a1.set_xscale("symlog")
    a1.set_yticks(y)
    a1.set_yticklabels([c.effect for c in cs])
    a1.invert_yaxis()
    a1.set_xlabel("score test -log10 p")
    a1.axvline(-math.log10(diagnosis.alpha), color="k", ls="--", lw=0.8)
    d = [c.refit["delta_elpd"] if c.refit else np.nan for c in cs]
    e = [c.refit["delta_elpd_se"] if c.refit else 0.0 for c in cs]
    a2.barh(y, d, xerr=e, color="#27ae60")
    a2.set_xscale("symlog")
    a2.set_xlabel("delta elpd (PSIS-LOO) +- SE")
    a2.axvline(0, color="k", lw=0.6)
    fig.suptitle("which: candidate effects")
    return fig


def _confusion_panel(ax, M, labels, conditions, title):
    R = M / np.maximum(M.sum(axis=1, keepdims=True), 1)
    im = ax.imshow(R, cmap="Blues", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=45, ha="right")
    ax.set_yticks(range(len(conditions)))
    ax.set_yticklabels(conditions)
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            if M[i, j]:
                ax.text(j, i, f"{int(M[i, j])}", ha="center", va="center",
                        color="white" if R[i, j] > 0.5 else "black", fontsize=8)
    ax.set_xlabel("verdict of the diagnosis")
    ax.set_ylabel("effect withheld from the fit")
    ax.set_title(title)
    return im


@styled
def confusion_figure(validation):
    """Confusion matrix of a validation (rows: withheld effect, columns: verdict), as rates; with
    the left-out mode a second panel: the verdicts with the effect's group left out of the
    candidates (right verdict: 'unexplained')."""
    plt = _mpl()
    left_out = bool(getattr(validation, "left_out", False)) and bool(validation.left_out_conditions)
    n_rows = len(validation.conditions)
    height = max(6.5, 0.22 * n_rows + 3.0)
    if left_out:
        fig, axes = plt.subplots(1, 2, figsize=(18.0, height))
    else:
        fig, ax = plt.subplots(figsize=(9.0, height))
        axes = [ax]
    im = _confusion_panel(axes[0], validation.confusion().astype(float), validation.labels, validation.conditions,
                          f"in vocabulary: {validation.seeds} seeds per row")
    if left_out:
        _confusion_panel(axes[1], validation.confusion(left_out=True).astype(float), validation.labels,
                         validation.left_out_conditions,
                         f"left out (effect and its group not candidates): {validation.seeds} seeds per row")
    fig.suptitle("diagnosis validation")
    fig.colorbar(im, ax=axes, fraction=0.03, label="rate")
    return fig


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}"/>'


def _chi2_after(gap_after: dict, noise_known: bool = True) -> str:
    """How far a refit shrank the gap: its chi2/dof, or with the noise estimated (no chi2 level)
    the ratio of chi2/dof after to before (none for a noise model, which reweights), said so."""
    a = gap_after or {}
    if a.get("chi2_dof") is not None or noise_known:
        return f"chi2/dof after {_num(a.get('chi2_dof'))}"
    if a.get("chi2_dof_ratio") is None:
        return "chi2/dof after: none (noise estimated, and a noise model reweights the residuals)"
    return f"chi2/dof x {_num(a['chi2_dof_ratio'])} of the base fit's (noise estimated: no chi2 level)"


def _gap_chi2(d) -> str:
    """The gap's chi2/dof, or with the noise estimated what it was estimated from."""
    g = d.gap
    if g.get("chi2_dof") is None and not d.noise_known:
        return f"chi2/dof: none, the noise was {d.noise} ({_count(g.get('dof'))} dof)"
    return f"chi2/dof = {_num(g['chi2_dof'])} ({_count(g.get('dof'))} dof)"


def _num(v, fmt="{:.3g}") -> str:
    """A number, or why there is none (never a bare dash that reads like a value)."""
    if v is None:
        return "not computed"
    if isinstance(v, float) and not math.isfinite(v):
        return "not finite"
    return fmt.format(v)


def _p(p, log10_p=None) -> str:
    """A p-value as a reader takes it: never a bare "0" when it underflowed (then its order of
    magnitude from ``log10_p`` when known, else an honest bound)."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "not computed"
    if p > 0:
        return f"{p:.3g}"
    if log10_p is not None and math.isfinite(log10_p):
        exponent = math.floor(log10_p)
        mantissa = 10.0 ** (log10_p - exponent)
        return f"{mantissa:.3g}e{exponent:d}"
    return "< 1e-300"


def _p_is(p, log10_p=None) -> str:
    """``"= 0.003"`` or ``"< 1e-300"``: a p-value after its name ("LR p = 0.003", "LR p < 1e-300")."""
    txt = _p(p, log10_p)
    return txt if txt.startswith("<") else f"= {txt}"


def _ppc_p(p) -> str:
    """A posterior-predictive p (a share of draws): 0 means no draw was as extreme."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "not computed"
    return "no draw as extreme" if p == 0 else f"{p:.3g}"


def _yes_no(flag) -> str:
    return "not computed" if flag is None else ("yes" if flag else "no")


def _count(n) -> str:
    return "not computed" if n is None else f"{int(n)}"


def _verdict_text(d) -> tuple[str, str]:
    """The verdict's headline and its evidence in words (p-values from the candidate itself, so
    that an underflowed p never reads "p = 0"), and what the design cannot tell from it."""
    headline, evidence = _verdict_words(d)
    if d.verdict.get("caveat"):
        evidence += f"; caution: {d.verdict['caveat']}"
    return headline, evidence


#: the generic families of an unexplained gap's shape (verdict.shape), in words
SHAPE_WORDS = {"temperature": "temperature", "time": "time", "orientation_even": "orientation (even in g)",
               "orientation_odd": "orientation (odd in g)", "direction": "the direction of the temperature change",
               "heading": "the pose's rotation about the vertical (no function of gravity: a field fixed in the "
                          "room, a bearing's run-out)",
               "variance": "the scatter (variance)",
               "tilt": "the bench's tilt, soak by soak (a base that moves between soaks)",
               "scale": "the scale factors, soak by soak (a scale that wanders in time)",
               "correlated": "time: residuals alike when close in time (a noise that wanders, or a pattern "
                             "of the mean no smooth family holds)",
               "level": "nothing but the level of the scatter (no pattern: the declared noise may be too small)",
               "tails": "nothing but the tails of the scatter (outliers with no pattern)"}


def _verdict_words(d) -> tuple[str, str]:
    v = d.verdict
    effect = v.get("effect")
    if effect is None:
        return "no missing effect named", str(v.get("reason") or "")
    if effect == "unexplained":
        where = "; ".join(f"{w.get('family')} {w.get('slice')} ({w.get('axis')}, {w.get('test')})"
                          for w in v.get("where") or [])
        shape = ", ".join(f"{SHAPE_WORDS.get(x['family'], x['family'])} (p(Holm) {_p_is(x.get('p_holm'))})"
                          for x in v.get("shape") or [])
        if shape:
            where = (where + "; " if where else "no single slice; ") + f"shape against {shape}"
        if v.get("ambiguous_with"):
            return (f"unexplained: {v.get('best_partial')} closes the gap but the data cannot tell it from "
                    + ", ".join(str(x) for x in v["ambiguous_with"]),
                    str(v.get("reason") or "") + (f"; where: {where}" if where else ""))
        return ("unexplained: a structured gap no candidate effect closes",
                str(v.get("reason") or "") + (f"; where: {where}" if where else ""))
    if v.get("effects"):            # a series of one temperature coefficient: its own evidence
        return (" + ".join(v["effects"]) + " (the orders of one temperature coefficient, together)",
                str(v.get("evidence") or "") + (f"; {v['remaining']}" if v.get("remaining") else ""))
    cand = next((c for c in d.candidates if c.effect == effect), None)
    if cand is None or not cand.refit:
        return str(effect), str(v.get("evidence") or v.get("reason") or "")
    r = cand.refit
    if cand.refit_only:
        # a form candidate has no score test (its score p is no p-value): the verdict's own words
        evidence = str(v.get("evidence") or "")
    else:
        evidence = (f"score p {_p_is(cand.score_p, cand.score_logp / math.log(10))}, "
                    f"LR p {_p_is(r.get('lr_p_value'))}, delta elpd = {_num(r.get('delta_elpd'), '{:.1f}')} "
                    f"+- {_num(r.get('delta_elpd_se'), '{:.1f}')}")
    if v.get("remaining"):
        evidence += f"; {v['remaining']}"
    if v.get("runner_up"):
        evidence += f"; runner-up {v['runner_up']}"
        dd = v.get("delta_elpd_to_runner_up")
        if isinstance(dd, (int, float)) and dd >= 0:
            evidence += f" ({_num(dd, '{:.1f}')} elpd behind)"
        elif isinstance(dd, (int, float)):
            evidence += f" ({_num(-dd, '{:.1f}')} elpd ahead, but {_why_not_named(d, v['runner_up'])})"
    cr = v.get("closest_rival")
    if cr:
        evidence += (f"; beats its closest rival, {cr['rival']}, by the encompassing test (S = "
                     f"{_num(cr.get('S'), '{:.3g}')} on {cr.get('k')} dof, p {_p_is(cr.get('p_value'))})")
    return str(effect), evidence


def _why_not_named(d, effect) -> str:
    """Why a runner-up ahead in elpd was not named, from its refit: an outside probe's
    thermal_lag_history (no structure left, but not beating the rate form by its nested test) was
    said to be "a noise effect" that "keeps structure"."""
    from ..models.effects import NOISE_EFFECTS

    c = next((c for c in d.candidates if c.effect == effect), None)
    r = (c.refit or {}) if c is not None else {}
    form = r.get("form") or {}
    if form and not form.get("beats_simpler", True):
        return (f"a form is named only when it beats its simpler form ({form.get('simpler_form')}) by the nested "
                f"likelihood-ratio test ({form.get('criterion')}), and it does not")
    if r.get("time_constant_refused"):
        return "its time constant is one the fit's answer gate refuses"
    lr = r.get("lr_p_value")
    if isinstance(lr, (int, float)) and lr >= d.alpha:
        return f"its likelihood ratio is not significant (p {_p_is(lr)})"
    if effect in NOISE_EFFECTS:
        return "a noise effect cannot be named while slices or generic families keep structure after its refit"
    return "the verdict's rules (its reason) put the named effect first"


def html_report(diagnosis, campaign=None) -> str:
    """A self-contained HTML report of a diagnosis (plots embedded as PNG)."""
    d = diagnosis
    e = html.escape
    g = d.gap
    headline, evidence = _verdict_text(d)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>triadcal diagnosis</title>",
        "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}th{background:#eee}</style></head><body>",
        f"<h1>Diagnosis of the model-data gap</h1><p>data: {e(str(d.source))}; model: "
        f"{e(', '.join(d.model) or '(core only)')}; noise: {e(d.noise)}</p>",
        "<h2>Gap</h2>",
        f"<p>{e(_gap_chi2(d))}, residual RMS "
        f"{_num(g['residual_rms_ug'])} ug against a noise floor of {_num(g['noise_floor_ug'])} ug"
        f"{'' if d.noise_known else ' (estimated from these residuals)'}; "
        f"significant: <b>{_yes_no(g.get('significant'))}</b> (Holm at alpha = {d.alpha:g}). "
        f"{e(str(g.get('testable', '')))}.</p>",
        "<h2>Verdict</h2>",
        f"<p><b>{e(headline)}</b>" + (f" &mdash; {e(evidence)}" if evidence else "") + "</p>",
    ]
    lim = d.verdict.get("detection_limits")
    if lim and lim.get("candidates"):
        parts.append(f"<p>What this campaign could not have seen: the size of each parameter (the others at zero) "
                     f"that its candidate's own score test finds with probability {lim['power']:g} at Holm's first "
                     f"level {lim['level']:.2g}; smaller effects may be there.</p>"
                     "<table><tr><th>candidate</th><th>parameter</th><th>limit</th></tr>")
        for c in lim["candidates"]:
            tc = c.get("time_constant") or {}
            for n, p in c["parameters"].items():
                if n == tc.get("parameter"):
                    continue            # the grid's own parameter: its limits are per value of it
                if n in tc.get("limits", {}):
                    val = "; ".join(f"{'not seen' if v is None else _num(v)} at {_num(t)} {e(tc['unit'])}"
                                    for t, v in zip(tc["grid"], tc["limits"][n])) + f" ({e(p['unit'])})"
                else:
                    val = ("not seen apart from the model" if p["value"] is None
                           else f"{_num(p['value'])} {e(p['unit'])}")
                parts.append(f"<tr><td>{e(c['effect'])}</td><td>{e(n)}</td><td>{val}</td></tr>")
        parts.append("</table>")
    if campaign is not None and d.residuals is not None:
        parts.append(_img(figure_png(residuals_figure(d, campaign)), "residuals"))
    parts.append("<h2>Where</h2>")
    if d.slices:
        parts.append(_img(figure_png(slices_figure(d)), "slices"))
    rows = d.where[:25] or d.slices[:10]
    parts.append("<table><tr><th>slice</th><th>output</th><th>test</th><th>n</th><th>size</th>"
                 "<th>p</th><th>p (Holm)</th><th>PPC p</th></tr>")
    for s in rows:
        parts.append(f"<tr><td>{e(s.slice)}</td><td>{e(s.axis)}</td><td>{e(s.test)}</td><td>{s.n}</td>"
                     f"<td>{_num(s.size)} {e(s.unit)}</td><td>{_p(s.p_value, s.log10_p)}</td>"
                     f"<td>{_p(s.p_adjusted)}</td><td>{_ppc_p(s.ppc_p)}</td></tr>")
    parts.append("</table>")
    if not d.where:
        parts.append("<p>No slice disagrees significantly; the most extreme are listed.</p>")
    elif len(d.where) > len(rows):
        parts.append(f"<p>{len(d.where)} slices disagree significantly; the {len(rows)} with the smallest p "
                     "are listed, every one is in the JSON (where).</p>")
    if d.families:
        parts.append("<p>Families of slices, by how much of the misfit their offsets explain "
                     "(chi2 of the projection, after the fitted model):</p><table><tr><th>family</th>"
                     "<th>slices</th><th>dof</th><th>chi2/dof</th><th>log10 p</th></tr>")
        for f in d.families:
            parts.append(f"<tr><td>{e(str(f['family']))}</td><td>{_count(f.get('slices'))}</td>"
                         f"<td>{_count(f.get('dof'))}</td>"
                         f"<td>{_num(f['chi2_per_dof'])}</td><td>{_num(f['log10_p'], '{:.1f}')}</td></tr>")
        parts.append("</table>")
    parts.append("<h2>Which</h2>")
    if any(c.testable for c in d.candidates):
        parts.append(_img(figure_png(candidates_figure(d)), "candidates"))
    parts.append("<table><tr><th>rank</th><th>effect</th><th>score (dof)</th><th>log10 p</th><th>delta loglik</th>"
                 "<th>LR p</th><th>delta elpd +- SE</th><th>cross-branch delta lpd</th><th>chi2/dof after</th>"
                 "<th>RMS after (ug)</th><th>largest shift</th></tr>")
    for c in sorted(d.candidates, key=lambda c: c.rank):
        if not c.testable:
            parts.append(f"<tr><td>{c.rank}</td><td>{e(c.effect)}</td><td colspan='9'>not testable: "
                         f"{e(c.reason)}</td></tr>")
            continue
        r = c.refit or {}
        ls = r.get("largest_shift") or {}
        parts.append(
            f"<tr><td>{c.rank}</td><td>{e(c.effect)}</td><td>{_num(c.score)} ({c.k})</td>"
            f"<td>{_num(c.score_logp / math.log(10), '{:.1f}')}</td><td>{_num(r.get('delta_loglik'), '{:.1f}')}</td>"
            f"<td>{_p(r.get('lr_p_value'))}</td>"
            f"<td>{_num(r.get('delta_elpd'), '{:.1f}')} +- {_num(r.get('delta_elpd_se'), '{:.1f}')}</td>"
            f"<td>{_num(r.get('cross_branch_delta_lpd'), '{:.1f}')}</td>"
            f"<td>{e(_chi2_after(r.get('gap_after'), d.noise_known).replace('chi2/dof after ', ''))}</td>"
            f"<td>{_num((r.get('gap_after') or {}).get('residual_rms_ug'))}</td>"
            + (f"<td>{e(str(ls['parameter']))} {_num(ls.get('in_u'), '{:.1f}')} u</td></tr>" if ls.get("parameter")
               else "<td>not computed</td></tr>"))
    parts.append("</table>")
    parts.append("<h2>How far it shrinks</h2>")
    for c in sorted(d.candidates, key=lambda c: c.rank):
        if not c.refit:
            continue
        r = c.refit
        b, a = r["gap_before"], r["gap_after"]
        moved = sorted(((n, s) for n, s in r["parameter_shifts"].items() if s.get("in_u") is not None),
                       key=lambda t: -abs(t[1]["in_u"]))[:6]
        parts.append(
            f"<h3>{e(c.effect)}</h3><p>"
            + (f"chi2/dof {_num(b['chi2_dof'])} &rarr; {_num(a['chi2_dof'])}" if a.get("chi2_dof") is not None
               or d.noise_known else e(_chi2_after(a, False)))
            + "; residual RMS "
            f"{_num(b['residual_rms_ug'])} &rarr; {_num(a['residual_rms_ug'])} ug (noise floor "
            f"{_num(a['noise_floor_ug'])} ug); elpd {_num(b['elpd_loo'], '{:.1f}')} &rarr; "
            f"{_num(a['elpd_loo'], '{:.1f}')}; significant slices {_count(b.get('significant_slices'))} &rarr; "
            f"{_count(a.get('significant_slices'))}; "
            + (("smooth structure left (generic families, Holm p): " + e(", ".join(
                f"{f} {_num(a['generic'][f].get('p_holm'), '{:.2g}')}" for f in a.get("generic_structure") or [])))
               if a.get("generic_structure") else "no generic family significant after it"
               if a.get("generic") else "generic families not tested")
            + ".</p>"
            "<p>New parameters: " + e(", ".join(
                f"{n} = {_num(p['value'])}" + (f" +- {_num(p['u'])}" if p.get('u') is not None else "")
                + f" {p.get('unit', '')}"
                for n, p in r["new_parameters"].items())) + "</p>"
            "<p>Calibration parameters that move most (shift in units of their u before): " + e(", ".join(
                f"{n} {_num(s['shift'])} {s['unit']} ({_num(s['in_u'], '{:+.1f}')} u)" for n, s in moved)) + "</p>")
    if d.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{e(n)}</li>" for n in d.notes) + "</ul>")
    parts.append("<h2>Methods</h2><ul>" + "".join(
        f"<li><b>{e(str(k))}</b>: {e(str(t))}</li>" for k, t in d.to_dict()["methods"].items()) + "</ul>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_html_report(diagnosis, path, campaign=None) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(html_report(diagnosis, campaign))


def write_validation(validation, out_dir) -> dict:
    """Write the validation's table (text), confusion matrix (PNG) and rows (JSON) into ``out_dir``;
    with the left-out mode the table and the plot hold both blocks and the JSON both matrices
    (``confusion``, ``confusion_left_out``)."""
    import os

    os.makedirs(out_dir, exist_ok=True)
    paths = {"table": os.path.join(out_dir, "confusion.txt"), "plot": os.path.join(out_dir, "confusion.png"),
             "json": os.path.join(out_dir, "validation.json")}
    from ..io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text

    atomic_write_text(paths["table"], validation.table() + "\n")
    atomic_write_bytes(paths["plot"], figure_png(confusion_figure(validation)))
    atomic_write_json(paths["json"], validation.to_dict())
    return paths


def summary_text(diagnosis) -> str:
    """A few lines for the terminal: gap, verdict, top slices and candidates."""
    d = diagnosis
    g = d.gap
    lines = [f"model: {', '.join(d.model) or '(core only)'}",
             f"gap: {_gap_chi2(d)}, RMS {_num(g['residual_rms_ug'])} ug vs noise "
             f"{_num(g['noise_floor_ug'])} ug{'' if d.noise_known else ' (estimated from these residuals)'}; "
             f"significant: {_yes_no(g.get('significant'))}",
             "verdict: {}  ({})".format(*_verdict_text(d))]
    if d.families and d.families[0]["log10_p"] < math.log10(d.alpha):
        f = d.families[0]
        lines.append(f"  localised in: {f['family']} (chi2/dof {f['chi2_per_dof']:.3g}, log10 p {f['log10_p']:.1f})")
    for s in d.where[:5]:
        lines.append(f"  where: {s.slice} [{s.axis}] {s.test}: {_num(s.size)} {s.unit}, p(Holm) {_p_is(s.p_adjusted)}")
    for c in sorted(d.candidates, key=lambda c: c.rank)[:5]:
        if not c.testable:
            continue
        r = c.refit or {}
        head = ("refit-only form (no score test)" if c.refit_only else
                f"score log10 p = {c.score_logp / math.log(10):.1f}")
        lines.append(f"  {c.rank}. {c.effect}: {head}"
                     + (f", delta elpd = {r['delta_elpd']:.1f} +- {r['delta_elpd_se']:.1f}, "
                        + _chi2_after(r.get("gap_after"), d.noise_known) if r else ""))
    return "\n".join(lines)
