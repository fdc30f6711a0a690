"""The fleet summary of a batch: one row per unit and state (``fleet.csv``, ``fleet.parquet``),
units outside a tolerance file, the fleet's outliers against its own spread, and an HTML page
with the distribution of every parameter (``fleet.html``, self-contained)."""

from __future__ import annotations

import base64
import csv
import fnmatch
import html
import io
import math
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import InputError
from ..models.units import canonical_scale_unit

#: the outlier rule: |x - median| > OUTLIER_K * max(1.4826 * MAD, u) over the units whose status is
#: ok, for every parameter with at least OUTLIER_MIN_UNITS such units (u: the unit's own standard
#: uncertainty of x, so that a fleet tighter than its measurements does not flag a unit by its noise)
OUTLIER_K = 5.0
MAD_TO_SD = 1.4826
OUTLIER_MIN_UNITS = 5

BASE_COLUMNS = ("unit", "state", "input", "action", "status", "chi2_dof", "n_obs", "out_of_tolerance",
                "outliers", "error")


# -- tolerances --------------------------------------------------------------------------------

def load_tolerances(path) -> list[tuple]:
    """A tolerance file (TOML)::

        [tolerances]
        "Ca_*" = 120            # |value| <= 120 (the parameter's unit: arcsec)
        K_x = [0.99, 1.01]      # 0.99 <= value <= 1.01
        K_y = {range = [0.99, 1.01], unit = "g/V"}     # only values in g/V are comparable
        "S_*" = {limit = 0.01, unit = "g"}

    Names may hold ``*``/``?`` wildcards. Returns ``[(pattern, low, high, unit or None)]``. With a
    unit, a value in another unit is flagged (not comparable); without one, the limit is in the
    parameter's own unit, and a fleet holding the parameter in two units is refused by
    :func:`check_tolerance_units` (a K of 0.99-1.01 g/V says nothing of a K in g/counts)."""
    path = Path(path)
    from ..io.atomic import read_toml

    data = read_toml(path, "a tolerance file")
    extra = [k for k in data if k != "tolerances"]
    if extra or not isinstance(data.get("tolerances"), dict):
        raise InputError(f"{path}: a tolerance file has one section [tolerances] (NAME = limit or [low, high])"
                         + (f"; unknown: {', '.join(extra)}" if extra else ""))

    def num(x):
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    def bounds(v):
        if num(v) and v >= 0:
            return -float(v), float(v)
        if isinstance(v, list) and len(v) == 2 and all(num(x) for x in v) and v[0] <= v[1]:
            return float(v[0]), float(v[1])
        return None

    out = []
    for name, v in data["tolerances"].items():
        unit = None
        if isinstance(v, dict):
            keys = set(v)
            unit = v.get("unit")
            if not (keys in ({"limit", "unit"}, {"range", "unit"}) and isinstance(unit, str) and unit.strip()):
                raise InputError(f"{path}: [tolerances] {name} = {v!r}: a table holds unit = \"...\" and either "
                                 "limit = L (|value| <= L) or range = [low, high]")
            v = v.get("limit", v.get("range"))
        b = bounds(v)
        if b is None:
            raise InputError(f"{path}: [tolerances] {name} = {v!r}: give a limit >= 0 (|value| <= limit) or "
                             "[low, high] with low <= high")
        out.append((name, b[0], b[1], unit))
    return out


def _tolerance_of(name: str, tolerances):
    for tol in tolerances or ():
        if fnmatch.fnmatchcase(name, tol[0]):
            return tol
    return None


def out_of_tolerance(params: dict, tolerances) -> list[str]:
    """Names of the parameters of ``params`` (name -> {"value", "unit", ...}) outside their
    tolerance; a value in another unit than its tolerance's is outside, written ``name (unit)``."""
    bad = []
    for name, p in params.items():
        tol = _tolerance_of(name, tolerances)
        if tol is None:
            continue
        _, low, high, unit = (*tol, None)[:4]
        x = p.get("value")
        if unit is not None and canonical_scale_unit(p.get("unit", "")) != canonical_scale_unit(unit):
            bad.append(f"{name} (in {p.get('unit')}, tolerance in {unit})")
        elif x is None or not (low <= x <= high):
            bad.append(name)
    return bad


def check_tolerance_units(records, tolerances) -> None:
    """Refuse a tolerance without a unit that meets one parameter in several units over the fleet
    (values in g/V and in g/counts: one limit cannot hold for both), naming them."""
    seen: dict = {}
    for r in records:
        for name, p in ((r.get("result") or {}).get("parameters") or {}).items():
            tol = _tolerance_of(name, tolerances)
            if tol is not None and (tol[3] if len(tol) > 3 else None) is None:
                seen.setdefault((tol[0], name), set()).add(canonical_scale_unit(str(p.get("unit"))))
    mixed = {k: u for k, u in seen.items() if len(u) > 1}
    if mixed:
        txt = "; ".join(f"{name} in {', '.join(sorted(u))} (tolerance {pat!r})" for (pat, name), u in sorted(mixed.items()))
        raise InputError(f"the fleet holds a parameter in several units and its tolerance states none: {txt}; give "
                         "the unit in the tolerance file (NAME = {range = [low, high], unit = \"g/V\"}), one per unit")


def check_tolerances_match(records, tolerances) -> list[str]:
    """Refuse a tolerance name without wildcards that matches no parameter of any fitted result: a
    typo (``Ca_xyy``) checked nothing, and the units came out "ok" with Ca_xy 15 times its limit (an
    outside probe). A pattern (``*``, ``?``) that matches nothing is returned, for a warning: a shared
    tolerance file may hold ``"*_hysteresis"`` for a fleet fitted without hysteresis. A fleet with no
    fitted result has nothing to match against."""
    names = {n for r in records for n in ((r.get("result") or {}).get("parameters") or {})}
    if not names or not tolerances:
        return []
    unmatched = [t[0] for t in tolerances if not any(fnmatch.fnmatchcase(n, t[0]) for n in names)]
    exact = [u for u in unmatched if not any(c in u for c in "*?[")]
    if exact:
        raise InputError(f"tolerance {', '.join(repr(u) for u in exact)} matches no parameter of the fleet's "
                         f"results ({', '.join(sorted(names))}): no unit was checked against it (a typo?); the "
                         "results are saved, so the same command with the tolerance corrected refits nothing")
    return [f"tolerance pattern {u!r} matches no parameter of the fleet's results: nothing was checked against it"
            for u in unmatched]


# -- outliers ----------------------------------------------------------------------------------

def robust_outliers(values, u=None, k: float = OUTLIER_K) -> np.ndarray:
    """Boolean mask of the values with |x - median| > k * max(1.4826 * MAD, u_i) (NaN: never an
    outlier). ``u``: each value's own standard uncertainty (None or NaN: not known). The fleet's
    spread 1.4826 MAD estimates the SD of a normal fleet (one wild unit cannot mask it); a unit's
    own u floors it, so that a fleet whose units differ less than their measurement does (a MAD
    below the u) does not flag a unit by its measurement noise, nor a poorly measured unit by a
    deviation within its own u. No flag when fewer than OUTLIER_MIN_UNITS values are finite, nor
    where the scale is 0 (a MAD of 0 and no u)."""
    x = np.asarray(values, float)
    uu = np.full(len(x), np.nan) if u is None else np.asarray(u, float)
    if uu.shape != x.shape:
        raise ValueError(f"u has shape {uu.shape}, values {x.shape}")
    ok = np.isfinite(x)
    flags = np.zeros(len(x), bool)
    if ok.sum() < OUTLIER_MIN_UNITS:
        return flags
    med = np.median(x[ok])
    spread = MAD_TO_SD * np.median(np.abs(x[ok] - med))
    scale = np.fmax(spread, np.where(np.isfinite(uu) & (uu >= 0), uu, np.nan))   # fmax: NaN u -> spread
    flags[ok] = (scale[ok] > 0) & (np.abs(x[ok] - med) > k * scale[ok])
    return flags


#: normal fleets drawn to measure the rule's false-alarm rate (:func:`outlier_false_alarm`)
FALSE_ALARM_FLEETS = 20000


def outlier_false_alarm(n_units: int, k: float = OUTLIER_K, fleets: int = FALSE_ALARM_FLEETS) -> float:
    """The fraction of normal fleets of ``n_units`` (no outlier, no u floor) in which
    :func:`robust_outliers` flags at least one unit of a parameter: Monte Carlo, fixed seed. The MAD of
    a few values is itself uncertain, so the "5 sigma" rule is far looser there than 5 sigma: an
    outside probe measured 11 % at 5 units, 7.4 % at 7, 3.7 % at 10, where a 5 sigma rule with a known
    sigma flags 3e-6. Said with every flag (batch's output, the HTML summary)."""
    if n_units < OUTLIER_MIN_UNITS:
        return 0.0
    x = np.random.default_rng(20261201).standard_normal((fleets, n_units))
    med = np.median(x, axis=1, keepdims=True)
    spread = MAD_TO_SD * np.median(np.abs(x - med), axis=1, keepdims=True)
    return float(np.mean(np.any(np.abs(x - med) > k * spread, axis=1)))


def false_alarm_words(n_units: int) -> str:
    """What a fleet-outlier flag is worth with ``n_units`` units, in one sentence."""
    rate = outlier_false_alarm(n_units)
    return (f"with {n_units} units a normal fleet has a flagged unit in {100 * rate:.2g} % of parameters "
            f"(Monte Carlo, {FALSE_ALARM_FLEETS} fleets): the MAD of few values is uncertain, and a flag is a lead "
            "to check, not a finding")


def fleets_by_state(rows) -> dict:
    """``{state: [row indices whose status is ok]}``, states in the order first met. A fleet is the
    units of one state: one unit's initial, after-shock and after-vibration calibrations are one
    unit three times, not three units (an outside probe: a unit in three states of one truth set the
    median, the MAD came out about 0, and the two other units were flagged on 24 and 23 of 24
    parameters, "with 5 units", exit 0)."""
    out: dict = {}
    for i, row in enumerate(rows):
        if row["unit"]:
            out.setdefault(row["state"], [])
            if row["status"] == "ok":
                out[row["state"]].append(i)
    return out


def fleet_words(rows) -> str:
    """What the fleet-outlier flags of these rows are worth, per state's fleet, in words."""
    parts = []
    for state, idx in fleets_by_state(rows).items():
        n = len(idx)
        parts.append(f"{state!r}: " + (false_alarm_words(n) if n >= OUTLIER_MIN_UNITS else
                                       f"{n} unit(s) with status ok, too few for the rule (at least "
                                       f"{OUTLIER_MIN_UNITS}): none flagged"))
    return "a fleet per state; " + "; ".join(parts)


# -- the table -----------------------------------------------------------------------------------

def parameter_names(records) -> list[str]:
    names = []
    for r in records:
        for n in (r.get("result") or {}).get("parameters", {}):
            if n not in names:
                names.append(n)
    return names


def table(records, tolerances=None):
    """(columns, rows as dicts) of the fleet: BASE_COLUMNS then ``<p>``, ``<p>_u``, ``<p>_unit`` per
    parameter. Outliers are sought per parameter and unit (never over values of different units)."""
    names = parameter_names(records)
    rows = []
    for r in records:
        res = r.get("result") or {}
        params = res.get("parameters", {})
        fit = res.get("fit", {})
        row = {"unit": r["unit"], "state": r["state"], "input": r["input"], "action": r["action"],
               "status": res.get("status", r.get("status", "refused")), "chi2_dof": fit.get("chi2_dof"),
               "n_obs": fit.get("n_obs"), "out_of_tolerance": ";".join(out_of_tolerance(params, tolerances)),
               "outliers": "", "error": r.get("error", "")}
        for n in names:
            p = params.get(n) or {}
            row[n] = p.get("value")
            row[n + "_u"] = p.get("u")
            # one spelling of a unit (g/counts and g/count, written before and after 2026-11-30, are one)
            row[n + "_unit"] = canonical_scale_unit(p.get("unit", "")) if n in params else ""
        rows.append(row)
    flagged = {i: [] for i in range(len(rows))}
    fleets = fleets_by_state(rows)
    for n in names:
        # values of different units (g/V and g/counts) are never pooled: the rule runs per unit, and per
        # state (fleets_by_state: a unit in three states is one unit of each state's fleet)
        for unit in units_of(rows, n):
            for idx in fleets.values():
                mine = set(idx)
                x = np.array([row[n] if (i in mine and row[n] is not None and row[n + "_unit"] == unit) else np.nan
                              for i, row in enumerate(rows)], float)
                u = np.array([row[n + "_u"] if row[n + "_u"] is not None else np.nan for row in rows], float)
                for i in np.flatnonzero(robust_outliers(x, u)):
                    flagged[int(i)].append(n)
    for i, row in enumerate(rows):
        row["outliers"] = ";".join(flagged[i])
    columns = list(BASE_COLUMNS) + [c for n in names for c in (n, n + "_u", n + "_unit")]
    return columns, rows, names


def units_of(rows, name: str) -> list[str]:
    """The units of parameter ``name`` over the rows whose status is ok and that hold it, most
    frequent first (the fleet's values of one name in different units are never pooled)."""
    count: dict = {}
    for r in rows:
        if r["status"] == "ok" and r.get(name) is not None:
            u = r.get(name + "_unit", "")
            count[u] = count.get(u, 0) + 1
    return sorted(count, key=lambda u: (-count[u], u))


def write_summary(records, out_dir, tolerances=None, html_page: bool = True) -> tuple[dict, dict]:
    """Write fleet.csv, fleet.parquet and fleet.html into ``out_dir``; return (files, flags)
    with flags = {"out_of_tolerance": {unit/state: [names]}, "outliers": {unit/state: [names]}, "outlier_worth":
    what the outlier flags are worth per state (:func:`fleet_words`),
    "tolerances_unmatched": [warnings of patterns that matched nothing]}."""
    from ..io.atomic import atomic_path, atomic_write, atomic_write_text

    out_dir = Path(out_dir)
    unmatched = check_tolerances_match(records, tolerances)
    check_tolerance_units(records, tolerances)
    columns, rows, names = table(records, tolerances)
    files = {"csv": out_dir / "fleet.csv", "parquet": out_dir / "fleet.parquet"}
    if html_page:
        files["html"] = out_dir / "fleet.html"
    with atomic_write(files["csv"], "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if v is None else (repr(v) if isinstance(v, float) else v)) for k, v in row.items()})
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {}
    for c in columns:
        vals = [row[c] for row in rows]
        if c in ("unit", "state", "input", "action", "status", "out_of_tolerance", "outliers", "error") \
                or c.endswith("_unit"):
            arrays[c] = pa.array([str(v) for v in vals], pa.string())
        elif c == "n_obs":
            arrays[c] = pa.array([None if v is None else int(v) for v in vals], pa.int64())
        else:
            arrays[c] = pa.array([None if v is None else float(v) for v in vals], pa.float64())
    with atomic_path(files["parquet"], suffix=".parquet") as tmp:
        pq.write_table(pa.table(arrays), tmp)
    worth = fleet_words(rows)
    if html_page:
        atomic_write_text(files["html"], render_html(rows, names, tolerances, worth))
    flags = {"out_of_tolerance": {f"{r['unit']}/{r['state']}": r["out_of_tolerance"].split(";")
                                  for r in rows if r["out_of_tolerance"]},
             "outliers": {f"{r['unit']}/{r['state']}": r["outliers"].split(";") for r in rows if r["outliers"]},
             "tolerances_unmatched": unmatched, "outlier_worth": worth}
    return files, flags


# -- the HTML page -------------------------------------------------------------------------------

def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def render_html(rows, names, tolerances=None, worth: Optional[str] = None) -> str:
    """A self-contained page: counts, flagged units, one histogram per parameter (units whose
    status is ok; outliers in red, tolerance limits dashed) as inline PNG, and the table."""
    from matplotlib.figure import Figure     # a Figure renders without choosing a backend

    esc = html.escape
    ok = [r for r in rows if r["status"] == "ok"]
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>triadcal fleet summary</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;font-size:12px}"
             "td,th{border:1px solid #ccc;padding:2px 6px}.bad{background:#fdd}.fig{display:inline-block;margin:4px}"
             "</style></head><body><h1>Fleet summary</h1>",
             f"<p>{sum(1 for r in rows if r['unit'])} unit/state pairs, {len(ok)} with status ok"
             + (f", {sum(1 for r in rows if not r['unit'])} input(s) refused whole (their units not read)"
                if any(not r["unit"] for r in rows) else "")
             + ". Outliers: |x &minus; median| &gt; "
             f"{OUTLIER_K:g} &times; max({MAD_TO_SD} &times; MAD, u) over the units whose status is ok (at least "
             f"{OUTLIER_MIN_UNITS}; u: the unit's own standard uncertainty), per parameter and state; "
             + esc(worth if worth is not None else fleet_words(rows)) + "."
             + (" Tolerances: " + esc(", ".join(f"{t[0]} in [{t[1]:g}, {t[2]:g}]" + (f" {t[3]}" if len(t) > 3 and t[3] else "")
                                          for t in tolerances))
                if tolerances else " No tolerance file.") + "</p>"]
    flagged = [r for r in rows if r["status"] != "ok" or r["out_of_tolerance"] or r["outliers"]]
    parts.append("<h2>Flagged units</h2>")
    if flagged:
        parts.append("<table><tr><th>unit</th><th>state</th><th>input</th><th>status</th><th>outside tolerance</th>"
                     "<th>fleet outlier in</th><th>why refused</th></tr>")
        for r in flagged:      # a refused input has no unit: its file and reason say what it was
            parts.append(f"<tr class='bad'><td>{esc(r['unit'])}</td><td>{esc(r['state'])}</td><td>{esc(str(r['input']))}"
                         f"</td><td>{esc(r['status'])}</td><td>{esc(r['out_of_tolerance'])}</td><td>{esc(r['outliers'])}"
                         f"</td><td>{esc(str(r.get('error') or ''))}</td></tr>")
        parts.append("</table>")
    else:
        parts.append("<p>none</p>")
    parts.append("<h2>Distributions</h2>")
    mixed = [(n, units_of(rows, n)) for n in names if len(units_of(rows, n)) > 1]
    if mixed:
        parts.append("<p>Values in different units are never pooled: one histogram, and one outlier rule, per "
                     "parameter and unit (" + esc("; ".join(
                         f"{n}: " + ", ".join(f"{u or 'no unit'} ({sum(1 for r in ok if r[n] is not None and r[n + '_unit'] == u)})"
                                             for u in us) for n, us in mixed)) + ").</p>")
    for n, unit in [(n, u) for n in names for u in units_of(rows, n)]:
        sel = [r for r in ok if r[n] is not None and r[n + "_unit"] == unit]
        x = np.array([r[n] for r in sel], float)
        if not len(x):
            continue
        out = np.array([n in r["outliers"].split(";") for r in sel], bool)
        fig = Figure(figsize=(3.6, 2.4))
        ax = fig.add_axes((0.16, 0.14, 0.8, 0.74))
        ax.hist(x[~out] if (~out).any() else x, bins=min(30, max(5, len(x) // 5)), color="#4a7ab0")
        for v in x[out]:
            ax.axvline(v, color="red", lw=1)
        tol = _tolerance_of(n, tolerances)
        if tol is not None and (len(tol) < 4 or tol[3] in (None, unit)):    # limits only in their own unit
            for v in tol[1:3]:
                ax.axvline(v, color="k", ls="--", lw=0.8)
        title = f"{n} ({unit})" if unit else n
        n_units, n_states = len({r["unit"] for r in sel}), len({r["state"] for r in sel})
        ax.set_title(f"{title}, {n_units} units" + (f" in {n_states} states ({len(x)} calibrations)"
                                                     if n_states > 1 else ""), fontsize=9)
        ax.tick_params(labelsize=7)
        parts.append(f"<div class='fig'><img alt='{esc(title)}' title='{esc(title)}' "
                     f"src='data:image/png;base64,{_png(fig)}'></div>")
    parts.append("<h2>Table</h2><table><tr><th>unit</th><th>state</th><th>status</th><th>chi2/dof</th>"
                 "<th>input</th></tr>")
    for r in rows:
        chi = "" if r["chi2_dof"] is None else f"{r['chi2_dof']:.3f}"
        parts.append(f"<tr><td>{esc(r['unit'])}</td><td>{esc(r['state'])}</td><td>{esc(r['status'])}</td>"
                     f"<td>{chi}</td><td>{esc(r['input'])}</td></tr>")
    parts.append("</table><p>Every value, its u and unit (columns NAME, NAME_u, NAME_unit): fleet.csv, fleet.parquet "
                 "and results/.</p></body></html>\n")
    return "".join(parts)
