"""The fuzz corpus: mutated inputs generated from the built-in example campaign, a real raw
recording (tests/data/real/mikoff_imu0.log) and a real result of the example, each with the
outcome the issue requires (not the one the code happens to give).

A :class:`Case` is a name, the files it writes (name -> bytes), the CLI arguments (with
``{dir}`` for the case's folder) and the expected outcome:

- ``"refused"``: exit code 1 (one line on stderr naming the file and, in ``where``, the line
  or field);
- ``"not_ok"``: the command ran and said the answer is not ok (exit 3) — or refused it;
- ``"any"``: a benign mutation (the input may still be valid): any of 0, 1, 3.

Every case must end without a traceback and without an internal error (exit 70). The
generator is deterministic (seeded numpy RNG) and produces well over 300 cases.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from triadcal.api import example_path

HERE = Path(__file__).parent
MIKOFF = HERE / "data" / "real" / "mikoff_imu0.log"


@dataclass
class Case:
    name: str
    files: dict
    argv: list
    expected: str                      # refused | not_ok | any
    where: list = field(default_factory=list)   # text the refusal must contain (line, column, field)
    main_file: Optional[str] = None    # the file whose name the refusal must contain


# -- bench CSV --------------------------------------------------------------------------
def _bench_parts():
    lines = example_path().read_text().splitlines()
    n_meta = sum(1 for ln in lines if ln.startswith("#"))
    return lines[:n_meta], lines[n_meta].split(","), [ln.split(",") for ln in lines[n_meta + 1:]]


def _bench_text(meta, header, rows) -> bytes:
    return ("\n".join(meta + [",".join(header)] + [",".join(r) for r in rows]) + "\n").encode()


def _fit_case(name, data: bytes, expected, where=(), method="classical"):
    argv = ["fit", "{dir}/c.csv", "--method", method]
    return Case(name, {"c.csv": data}, argv, expected, list(where), "c.csv")


NUMERIC = ["setpoint_C", "time_s", "axis1_deg", "axis2_deg", "tau_s", "w_x", "w_y", "w_z", "t_x", "t_y", "t_z",
           "sd_x", "sd_y", "sd_z"]
BAD_NUMBERS = ["abc", "", "nan", "inf", "-inf", "1e300", "-1e300", "0x1F", "1.2.3", "--5", "1e", "NaN", "Infinity",
               "1_000", "\u0661"]


def bench_cases(rng) -> list:
    meta, header, rows = _bench_parts()
    n_meta = len(meta)
    out = []
    # 1. a bad number in a random row and numeric column: refused naming the line and column
    for k in range(120):
        col = NUMERIC[k % len(NUMERIC)]
        bad = BAD_NUMBERS[k % len(BAD_NUMBERS)]
        if bad in ("\u0661",) and k % 2:       # Arabic-Indic digit one: float() reads it, a range may not
            continue
        i = int(rng.integers(len(rows)))
        r2 = copy.deepcopy(rows)
        r2[i][header.index(col)] = bad
        line = n_meta + 2 + i
        if bad == "\u0661":
            out.append(_fit_case(f"bench-number-{k}-{col}-arabic-one", _bench_text(meta, header, r2), "any"))
            continue
        out.append(_fit_case(f"bench-number-{k}-{col}-{bad or 'empty'}", _bench_text(meta, header, r2), "refused",
                             [f":{line}", f"'{col}'"]))
    # 2. out-of-range values
    for k, (col, val) in enumerate([("axis1_deg", "400"), ("axis2_deg", "-720"), ("tau_s", "0"), ("tau_s", "-3"),
                                    ("tau_s", "1e9"), ("t_x", "-300"), ("setpoint_C", "5000"), ("sd_y", "-0.1"),
                                    ("w_z", "3e11"), ("n_samples", "0"), ("n_samples", "1.5"), ("cycle", "-1")]):
        for rep in range(3):
            i = int(rng.integers(len(rows)))
            r2 = copy.deepcopy(rows)
            r2[i][header.index(col)] = val
            out.append(_fit_case(f"bench-range-{col}-{val}-{rep}", _bench_text(meta, header, r2), "refused",
                                 [f":{n_meta + 2 + i}", f"'{col}'"]))
    # 3. header damage
    for col in header[:14]:
        h2 = [c for c in header if c != col]
        r2 = [[v for c, v in zip(header, r) if c != col] for r in rows]
        out.append(_fit_case(f"bench-missing-{col}", _bench_text(meta, h2, r2), "refused", [f":{n_meta + 1}", col]))
    for col in ("w_x", "unit", "tau_s"):
        h2 = header + [col]
        r2 = [r + [r[header.index(col)]] for r in rows]
        out.append(_fit_case(f"bench-duplicate-column-{col}", _bench_text(meta, h2, r2), "refused",
                             ["appears twice"]))
    # 4. metadata
    for key, val, expected in [("Q_V2s", "abc", "refused"), ("Q_V2s", "-1e-9", "refused"), ("Q_V2s", "nan", "refused"),
                               ("Q_V2s", "", "refused"), ("local_g_m_s2", "1.0", "refused"),
                               ("local_g_m_s2", "9.9", "refused"), ("local_g_m_s2", "abc", "refused"),
                               ("local_g_m_s2", "inf", "refused"), ("output_unit", "m/s2", "refused"),
                               ("output_unit", "g", "any"), ("output_unit", "mg", "refused"),
                               ("output_unit", "counts", "any"), ("output_unit", "furlongs", "any")]:
        m2 = [f"# {key} = {val}" if ln.startswith(f"# {key}") else ln for ln in meta]
        line = next(j for j, ln in enumerate(m2) if ln.startswith(f"# {key}")) + 1
        out.append(_fit_case(f"bench-meta-{key}-{val or 'empty'}", _bench_text(m2, header, rows), expected,
                             [key] + ([f":{line}"] if key != "output_unit" else [])))
    # 5. whole-file physics mutations
    for method in ("classical", "joint"):
        for a, b in (("w_x", "w_y"), ("w_y", "w_z"), ("w_x", "w_z")):
            ia, ib = header.index(a), header.index(b)
            r2 = copy.deepcopy(rows)
            for r in r2:
                r[ia], r[ib] = r[ib], r[ia]
            out.append(_fit_case(f"bench-swap-{a}-{b}-{method}", _bench_text(meta, header, r2), "not_ok",
                                 method=method))
        for a in ("w_x", "w_y", "w_z"):
            ia = header.index(a)
            r2 = copy.deepcopy(rows)
            for r in r2:
                r[ia] = repr(-float(r[ia]))
            out.append(_fit_case(f"bench-flip-{a}-{method}", _bench_text(meta, header, r2), "not_ok", method=method))
            r2 = copy.deepcopy(rows)
            for r in r2:
                r[ia] = "0.25"
            out.append(_fit_case(f"bench-stuck-{a}-{method}", _bench_text(meta, header, r2), "not_ok", method=method))
        # kelvin
        r2 = copy.deepcopy(rows)
        for r in r2:
            for c in ("t_x", "t_y", "t_z", "setpoint_C"):
                r[header.index(c)] = repr(float(r[header.index(c)]) + 273.15)
        out.append(_fit_case(f"bench-kelvin-{method}", _bench_text(meta, header, r2), "refused", ["kelvin"],
                             method=method))
        # x1000 declared m/s2
        m2 = [("# output_unit = m/s2" if ln.startswith("# output_unit") else ln) for ln in meta]
        r2 = copy.deepcopy(rows)
        for r in r2:
            for c in ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z"):
                r[header.index(c)] = repr(float(r[header.index(c)]) * 9806.65)
        out.append(_fit_case(f"bench-x1000-m_s2-{method}", _bench_text(m2, header, r2), "refused",
                             ["output_unit = m/s2"], method=method))
        # only the first 8 rows
        out.append(_fit_case(f"bench-8-rows-{method}", _bench_text(meta, header, rows[:8]), "not_ok", method=method))
        # tau 1e4 s without sd columns: the noise it implies is far below the scatter
        keep = [c for c in header if c not in ("sd_x", "sd_y", "sd_z", "n_samples")]
        r2 = [[r[header.index(c)] for c in keep] for r in rows]
        for r in r2:
            r[keep.index("tau_s")] = "80000"
        out.append(_fit_case(f"bench-huge-tau-{method}", _bench_text(meta, keep, r2),
                             "not_ok" if method == "joint" else "any", method=method))
    # 6. structure
    text = _bench_text(meta, header, rows)
    for k in range(15):
        cut = int(rng.integers(len(text) // 2, len(text) - 1))
        out.append(_fit_case(f"bench-truncated-{k}", text[:cut], "any"))
    for k in range(10):
        i = int(rng.integers(len(rows)))
        r2 = copy.deepcopy(rows)
        r2[i] = r2[i] + ["extra"] if k % 2 else r2[i][:-3]
        out.append(_fit_case(f"bench-field-count-{k}", _bench_text(meta, header, r2), "refused",
                             [f":{n_meta + 2 + i}", "fields"]))
    for k in range(5):
        i = int(rng.integers(len(rows)))
        r2 = copy.deepcopy(rows)
        r2[i][header.index("direction")] = ["Heating", "up", "", "cooling ", "HEATING"][k]
        expected = "any" if k == 3 else "refused"       # surrounding whitespace is stripped
        out.append(_fit_case(f"bench-direction-{k}", _bench_text(meta, header, r2), expected,
                             [f":{n_meta + 2 + i}", "direction"] if expected == "refused" else []))
    for k in range(5):
        i = int(rng.integers(1, len(rows)))
        r2 = copy.deepcopy(rows)
        r2.insert(i, list(r2[i - 1]))
        out.append(_fit_case(f"bench-duplicate-row-{k}", _bench_text(meta, header, r2), "refused",
                             [f":{n_meta + 2 + i}", "time_s"]))
    garbage = [b"", b"\n\n", b"# only = comments\n", ",".join(header).encode() + b"\n",
               b"\xff\xfe\x00garbage", bytes(rng.integers(0, 256, 2000, dtype=np.uint8)), text[:200] + b"\xc3\x28\n",
               b"unit;setpoint_C;direction\nX;20;none\n", b"\x00" * 100]
    for k, g in enumerate(garbage):
        out.append(_fit_case(f"bench-garbage-{k}", g, "refused"))
    for k in range(6):
        drop = sorted(rng.choice(len(rows), size=int(rng.integers(1, 20)), replace=False))
        r2 = [r for j, r in enumerate(rows) if j not in set(drop)]
        out.append(_fit_case(f"bench-drop-rows-{k}", _bench_text(meta, header, r2), "any"))
    return out


# -- raw recordings -----------------------------------------------------------------------
def _raw_lines():
    a = np.loadtxt(MIKOFF)[:, :3]
    counts = np.round(a * 2048 / 9.81).astype(int)
    return ["ax,ay,az"] + [f"{x},{y},{z}" for x, y, z in counts]


def _raw_case(name, lines, expected, where=(), extra=()):
    data = ("\n".join(lines) + "\n").encode() if isinstance(lines, list) else lines
    argv = ["fit-raw", "{dir}/r.csv", "--rate", "100", "--poses", "unknown", "--local-g", "9.81",
            "--json", "{dir}/out.json", *extra]
    return Case(name, {"r.csv": data}, argv, expected, list(where), "r.csv")


def raw_cases(rng) -> list:
    lines = _raw_lines()
    out = [_raw_case("raw-valid", lines, "any"),
           _raw_case("raw-offset-binary", ["ax,ay,az"] + [",".join(str(int(v) + 32768) for v in ln.split(","))
                                                           for ln in lines[1:]], "any")]
    # a bad number is refused wherever it stands: these cases mutate the first 2000 rows of the
    # recording (not all of its ~16000, which the reader parses at ~0.2 s a case before it refuses)
    short = lines[:2001]
    for k in range(40):
        i = int(rng.integers(1, len(short)))
        col = int(rng.integers(3))
        bad = ["abc", "nan", "inf", "1e300", "", "-1e300", "0x10", "1,2"][k % 8]
        l2 = list(short)
        f = l2[i].split(",")
        f[col] = bad
        l2[i] = ",".join(f)
        where = [f":{i + 1}"] + ([f"'{'ax ay az'.split()[col]}'"] if bad != "1,2" else [])
        out.append(_raw_case(f"raw-number-{k}-{bad or 'empty'}", l2, "refused", where))
    for k, g in enumerate([b"", b"ax,ay,az\n", b"x;y;z\n1;2;3\n", b"\xff\xfe\x00", b"ax,ay\n1,2\n3,4\n"]):
        out.append(_raw_case(f"raw-garbage-{k}", g, "refused"))
    out.append(_raw_case("raw-constant", ["ax,ay,az"] + ["100,200,300"] * 3000, "refused"))
    out.append(_raw_case("raw-declared-g", lines, "refused", [], extra=("--unit", "g")))
    out.append(_raw_case("raw-declared-m_s2", lines, "refused", [], extra=("--unit", "m/s2")))
    return out


# -- result JSON, compare and certificate inputs --------------------------------------------
def _j(d) -> bytes:
    return json.dumps(d, indent=1).encode()


def result_cases(rng, good: dict) -> list:
    out = []
    names = list(good["parameters"])

    def cert(name, data, expected, where=()):
        return Case(name, {"r.json": data}, ["certificate", "{dir}/r.json", "--html", "{dir}/c.html"], expected,
                    list(where), "r.json")

    def comp(name, data, expected, where=(), side=0):
        files = {"good.json": _j(good), "bad.json": data}
        pair = ["{dir}/bad.json", "{dir}/good.json"] if side == 0 else ["{dir}/good.json", "{dir}/bad.json"]
        return Case(name, files, ["compare", *pair], expected, list(where), "bad.json")

    muts = []
    for k in range(30):
        n = names[int(rng.integers(len(names)))]
        key = ["value", "u"][k % 2]
        val = [None, "1.0", True, [], {}, -1.0, 1e308 * 10][k % 7] if key == "u" else \
            [None, "x", False, [1], {"a": 1}][k % 5]
        if key == "u" and val == -1.0 or (key == "u" and isinstance(val, float)):
            where = [n]
        else:
            where = [n]
        d = copy.deepcopy(good)
        d["parameters"][n][key] = val
        if isinstance(val, float) and not np.isfinite(val):
            muts.append((f"param-{k}-{n}-{key}-inf", _j(d).replace(b"Infinity", b"1e400"), where))
        else:
            muts.append((f"param-{k}-{n}-{key}-{type(val).__name__}", _j(d), where))
    for key in ("status", "parameters", "format", "version", "unit", "method"):
        d = copy.deepcopy(good)
        d.pop(key)
        muts.append((f"missing-{key}", _j(d), [key] if key not in ("format", "version") else []))
    for key, val in (("parameters", []), ("status", 3), ("version", 2), ("format", "triadcal.other"),
                     ("reference_temperature_C", None), ("reference_temperature_C", 1e6), ("status", "great"),
                     ("correlation", {"names": ["K_x"], "matrix": [[1, 2]]}), ("notes", "a note"),
                     ("effects", "bench_tilt")):
        d = copy.deepcopy(good)
        d[key] = val
        muts.append((f"field-{key}-{json.dumps(val)[:20]}", _j(d), [key] if key not in ("format", "version") else []))
    for n, v in (("Ca_xy", 1e7), ("K_x", -0.9), ("K_y", 0.0), ("K_z", 5e4)):
        d = copy.deepcopy(good)
        d["parameters"][n]["value"] = v
        muts.append((f"gate-{n}-{v:g}", _j(d), [n]))
    d = copy.deepcopy(good)
    d["parameters"] = {}
    muts.append(("empty-parameters", _j(d), ["no parameters"]))
    text = _j(good)
    for k in range(8):
        cut = int(rng.integers(10, len(text) - 2))
        muts.append((f"truncated-{k}", text[:cut], [":"]))
    muts += [("nan-token", text.replace(b'"u": ' + json.dumps(good["parameters"]["K_x"]["u"]).encode(),
                                        b'"u": NaN', 1), ["NaN"]),
             ("not-utf8", b"\xff\xfe" + text, ["UTF-8"]), ("a-list", b"[1, 2, 3]", []), ("a-number", b"3", []),
             ("deep", b"[" * 50000 + b"]" * 50000, []), ("empty", b"", [])]
    for name, data, where in muts:
        out.append(cert(f"certificate-{name}", data, "refused" if name != "notes-ok" else "any", where))
    for k, (name, data, where) in enumerate(muts):
        out.append(comp(f"compare-{name}", data, "refused", where, side=k % 2))
    for st in ("not_converged", "model_mismatch", "unidentifiable"):
        d = copy.deepcopy(good)
        d["status"] = st
        out.append(cert(f"certificate-status-{st}", _j(d), "not_ok"))
        out.append(comp(f"compare-status-{st}", _j(d), "refused", [st]))
    d = copy.deepcopy(good)
    d["extra_key_from_another_tool"] = {"x": 1}
    out.append(comp("compare-unknown-key", _j(d), "any"))
    return out


def comparison_cases(rng, comparison: dict) -> list:
    out = []
    name = next(iter(comparison["parameters"]))
    for key, val in (("drift", None), ("drift", "x"), ("u", -1.0), ("u", None), ("verdict", "great"), ("En", "x"),
                     ("unit", 3)):
        d = copy.deepcopy(comparison)
        d["parameters"][name][key] = val
        out.append(Case(f"drift-report-{key}-{val}", {"c.json": _j(d)},
                        ["certificate", "{dir}/c.json", "--html", "{dir}/d.html"], "refused", [key], "c.json"))
    for key in ("parameters", "rule", "overall"):
        d = copy.deepcopy(comparison)
        d.pop(key)
        out.append(Case(f"drift-report-missing-{key}", {"c.json": _j(d)},
                        ["certificate", "{dir}/c.json", "--html", "{dir}/d.html"], "refused", [], "c.json"))
    for row, where in (("e1,s,xy,1e300,2", "drift_arcsec"), ("e1,s,xy,nan,2", "row 1"), ("e1,s,xy,3,-1", "u_arcsec"),
                       ("e1,s,xy,abc,2", "row 1"), ("e1,s,zz,3,2", "angle"), ("e1,s,xy,3,2,9", "row 1"),
                       ("e1,,xy,,2", "drift_arcsec")):
        data = ("exposure,sensor,angle,drift_arcsec,u_arcsec\n" + row + "\n").encode()
        out.append(Case(f"published-{row}", {"p.csv": data}, ["compare", "--published", "{dir}/p.csv"], "refused",
                        [where], "p.csv"))
    return out


def generate(good_result: dict, comparison: dict, seed: int = 20261124) -> list:
    rng = np.random.default_rng(seed)
    return bench_cases(rng) + raw_cases(rng) + result_cases(rng, good_result) + comparison_cases(rng, comparison)
