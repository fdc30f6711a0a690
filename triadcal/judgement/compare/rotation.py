"""A drift of the angles that is a rigid rotation of the whole triad.

The six angles are the sensing axes' directions in the IMU frame that the bench realises. Turning
the whole triad by a small rotation vector ``w`` (arcsec, about the IMU's x, y, z) moves each axis
``s_a -> s_a + w x s_a``, so (eq. 1's rows near the unit vectors)::

    d Ca_xy = +w_z   d Ca_xz = -w_y   d Ca_yx = -w_z   d Ca_yz = +w_x   d Ca_zx = +w_y   d Ca_zy = -w_x

A bench whose axis 1 was re-zeroed between the calibrations turns the unit about its y axis in
that frame (docs/lab.md: one to one into Ca_xz and Ca_zx), a unit re-seated in its fixture turns it
about any axis, and so does a sensor block that turned in its case -- only the last is a drift of
the unit. An outside probe's bench with axis 1 re-zeroed by 15 arcsec, the unit unchanged: "fail"
5 of 5 (Ca_xz -16 sigma, Ca_zx +16 sigma, D2 500-575), with a lab file stating the encoder zeros
"pass", and nothing said of the pattern.

The rotation is fitted to the drifts by generalised least squares with the drifts' covariance:
``w = (A' C^-1 A)^-1 A' C^-1 d``, its chi2 ``w' (A' C^-1 A) w`` on 3 dof, and what is left,
``(d - A w)' C^-1 (d - A w)`` on 3 dof. Where the rotation is significant and the rest is not, and
neither calibration's u holds the bench's systematic errors (no lab file: Type A only), the data
cannot tell the unit from its bench: the overall verdict is held back as inconclusive with a note;
with a lab file stating them, u(d) holds the bench's part and the verdict stands, with the note."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from scipy import stats

#: d Ca_ab per unit of w (x, y, z), in the order of the results' angles
ROTATION_ROWS = {"Ca_xy": (0, 0, 1), "Ca_xz": (0, -1, 0), "Ca_yx": (0, 0, -1),
                 "Ca_yz": (1, 0, 0), "Ca_zx": (0, 1, 0), "Ca_zy": (-1, 0, 0)}


def rigid_rotation(drift: np.ndarray, cov: np.ndarray, names: Sequence[str]) -> Optional[dict]:
    """The rotation's fit (module docstring) to the six angle drifts ``drift`` (arcsec) with their
    covariance ``cov``: ``{"w_arcsec", "u_arcsec", "p_rotation", "p_rest"}``, or None without the six
    angles or with a singular covariance."""
    if sorted(names) != sorted(ROTATION_ROWS):
        return None
    d = np.asarray(drift, float)
    A = np.array([ROTATION_ROWS[n] for n in names], float)
    try:
        Ci = np.linalg.inv(np.asarray(cov, float))
        F = A.T @ Ci @ A
        Fi = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(Ci)) and np.all(np.isfinite(Fi))):
        return None
    w = Fi @ (A.T @ Ci @ d)
    rest = d - A @ w
    chi_rot, chi_rest = float(w @ F @ w), float(rest @ Ci @ rest)
    u_w = np.sqrt(np.diag(Fi))
    z_d = d / np.sqrt(np.diag(cov))
    return {"w_arcsec": [float(x) for x in w], "u_arcsec": [float(x) for x in u_w],
            "chi2_rotation": chi_rot, "p_rotation": float(stats.chi2.sf(chi_rot, 3)),
            "chi2_rest": chi_rest, "p_rest": float(stats.chi2.sf(chi_rest, 3)),
            "z_w": [float(x) for x in w / u_w],
            # per component, the z of each of its two angles' drifts in the direction the rotation moves them
            "z_pairs": [[float(A[j, i] * z_d[j]) for j in range(len(names)) if A[j, i] != 0] for i in range(3)]}


def _supported(rot: dict, level: float) -> bool:
    """Every component of the rotation that is significant moves both of its angles significantly, each
    the way a rotation does (beyond :data:`SUPPORT_Z`), the components tested at the level Bonferroni-
    corrected over the three (a single
    angle's change, Ca_xy +4 arcsec alone, has a significant w_z and a rest whose test at these sizes has
    little power: 2 of 6 of an outside probe's were read as turns, one with Ca_yx at -1.97 sigma by
    chance)."""
    zc = float(stats.norm.isf((1 - level) / 6))        # two-sided, Bonferroni over the three components
    sig = [i for i in range(3) if abs(rot["z_w"][i]) > zc]
    return bool(sig) and all(min(s * np.sign(rot["z_w"][i]) for s in rot["z_pairs"][i]) > SUPPORT_Z for i in sig)


#: each angle of a significant component must have moved beyond this many sigma the way the turn moves
#: it: an angle that did not move gets there by chance once in a thousand (one-sided), so a single
#: angle's change is read as a turn that rarely (the compare test's 4 u(d) shift of Ca_xy: 1 % at the
#: component's level alone, which cost the rule's detection 4 % in the test's 1000 pairs)
SUPPORT_Z = float(stats.norm.isf(0.001))


def rotation_note(rot: Optional[dict], level: float, bench_in_u: bool) -> Optional[str]:
    """The note of a drift that is a rigid rotation, or None (not significant, or more than a rotation)."""
    if rot is None or not (rot["p_rotation"] < 1 - level <= rot["p_rest"]) or not _supported(rot, level):
        return None
    w = ", ".join(f"{a} {v:+.3g} +- {u:.2g}" for a, v, u in zip("xyz", rot["w_arcsec"], rot["u_arcsec"]))
    text = (f"the angles' drift is a rigid rotation of the whole triad (arcsec about the IMU's {w}; p "
            f"{rot['p_rotation']:.2g}), and what is left after it is not significant (p {rot['p_rest']:.2g}): the "
            "unit turned as a whole in the frame the bench defines -- the bench's axis 1 re-zeroed (a turn about y), "
            "the unit re-seated in its fixture, or its sensor block turned in its case; only the last is a drift of "
            "the unit")
    if bench_in_u:
        return text + " (u(d) holds the lab's stated encoder zeros and fixture)"
    return (text + "; neither calibration's u holds the bench's systematic errors (no lab file), so the data "
            "cannot tell them apart: give the lab file (--lab, [bench] encoder_zero_u_arcsec, [fixture]) to both fits")


def rotation_verdict(d, cov, angles, level: float, before, after, shared_equipment, overall: str, held_back: bool,
                     notes: list) -> tuple:
    """``(overall, held_back)`` after the rotation's test (module docstring); its note first in
    ``notes``. A fail the rotation explains is held back as inconclusive where u(d) holds no bench
    error of either calibration (no lab file, or the bench's shared and so cancelled)."""
    from .correlation import budget_equipment
    from .guards import BENCH_MOUNTED, NOT_PASS_NOTE

    eq = set(budget_equipment(before)) | set(budget_equipment(after))
    in_u = bool(eq & set(BENCH_MOUNTED)) and not (set(shared_equipment or ()) & set(BENCH_MOUNTED))
    note = rotation_note(rigid_rotation(d, cov, angles), level, in_u)
    if note is None:
        return overall, held_back
    if held_back:                   # already held back (the bench check against the sharing): its note stays first
        notes.append(note)
        return overall, held_back
    if overall == "fail" and not in_u:
        notes.insert(0, NOT_PASS_NOTE + note)
        return "inconclusive", True
    notes.insert(0, note)
    return overall, held_back
