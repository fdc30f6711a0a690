"""A classical line whose scatter the Birge ratio took into u states it on the line's dof: k from
Student's t on n_setpoints - 2 (JCGM 100 G.3), per parameter. An outside probe (2026-12-02): one
setpoint block of five relabelled by 40 degC, every line widened up to x159 on 3 dof, and the summary
said "U (k=2.09)" for all (the residuals' dof)."""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import simulate_campaign  # noqa: E402

from triadcal.estimation.classical import fit_classical  # noqa: E402
from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.reports.summary import summary_text  # noqa: E402


def test_a_birge_widened_line_has_k_from_its_own_dof():
    text, _ = simulate_campaign(np.random.default_rng(6), setpoints_C=(-40, -10, 20, 50, 80))
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("unit,"))
    cols = lines[i].split(",")
    sp, tcols = cols.index("setpoint_C"), [cols.index(c) for c in ("t_x", "t_y", "t_z")]
    out = lines[: i + 1]
    for ln in lines[i + 1:]:                       # the 50 degC block relabelled as 90 degC
        f = ln.split(",")
        if float(f[sp]) == 50.0:
            f[sp] = "90.0"
            for j in tcols:
                f[j] = repr(float(f[j]) + 40.0)
        out.append(",".join(f))
    r = fit_classical(parse_bench_csv("\n".join(out) + "\n"))
    ratios = r.fit["chi2_dof_by_parameter"]
    widened = [n for n, q in ratios.items() if q > 1.0]
    assert len(widened) >= 3, ratios
    k3 = stats.t.ppf(stats.norm.cdf(2.0), 3)          # 95.45 % on 5 - 2 dof: 3.307
    assert k3 == pytest.approx(3.307, abs=1e-3)
    for n, p in r.parameters.items():
        base = n[:-len("_tempco")] if n.endswith("_tempco") else n
        if base in widened:
            assert p.uncertainty["k"] == pytest.approx(k3, rel=1e-6) and p.uncertainty["dof_eff"] == 3.0, n
            assert p.U == pytest.approx(k3 * p.u, rel=1e-9)
        else:
            assert p.uncertainty["k"] < k3, n
    s = summary_text(r)
    assert " 3.31  " in s and "U (k=" not in s, s
