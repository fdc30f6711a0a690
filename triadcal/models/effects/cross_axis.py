"""Third-order scale nonlinearity and the cross-axis terms of IEEE Std 1293 (transfer effects).

IEEE Std 1293-1998 (*IEEE Standard Specification Format Guide and Test Procedure for Linear,
Single-Axis, Nongyroscopic Accelerometers*), its model equation: with ``a_i`` the acceleration along the input axis and ``a_p``, ``a_o`` those along
the pendulous and output axes,

    E/K1 = K0 + a_i + K2 a_i^2 + K3 a_i^3 + ... + K_ip a_i a_p + K_io a_i a_o + ...

Here each output ``a`` of the triad responds to the components ``a_b`` of the acceleration along
the three sensing axes (the sensed acceleration ``a_b = Ca_b . G`` of eq. 1; along a sensing axis
within arcminutes of the IMU axis, so a product with the IMU-frame component differs by a
second-order term). All three effects act on the ``transfer`` hook, after ``scale_nonlinearity``
and ``scale_asymmetry``, on the sensed components as they come in (the products use the
components before this effect, so the three outputs are updated together):

- ``scale_cubic`` (K3): ``a_a <- a_a + K3_a a_a^3`` (``K3_a`` in ug/g3);
- ``cross_coupling`` (IEEE 1293's ``K_ip``, ``K_io``): ``a_a <- a_a + Σ_{b != a} Kc_ab a_a a_b``
  (``Kc_ab`` in ug/g2; six coefficients ``Kc_xy, Kc_xz, Kc_yx, Kc_yz, Kc_zx, Kc_zy``, the names and
  the definition of the raw diagnosis's candidate, ``estimation/raw/terms.cross_coupling``);
- ``g_dependent_misalignment``: the angle of sensing axis ``a`` toward ``b`` grows with the square
  of the acceleration along the axis, ``Ca_ab(a) = Ca_ab + m_ab a_a^2``, so output ``a`` gains
  ``m_ab a_a^2 a_b`` (``Ca_ab_g2`` = m in arcsec/g2; ``estimation/raw/terms.g_dependent_misalignment``).
  A misalignment linear in ``a_a`` would add ``m a_a a_b``, which *is* the cross-coupling term
  (the pendulum deflected by the input acceleration tilts its axis: the physical origin of K_ip),
  so the one term that is a separate candidate is the even one: it does not change sign when the
  axis turns over.

On a plan whose every pose has one sensing axis along gravity (the 12 positions of bench CSV v1)
``a^3 = a`` (K3 is K1) and every product ``a_a a_b`` vanishes: these terms need oblique poses
(``triadcal plan --positions 18|24``), and :func:`triadcal.estimation.joint.identifiability_problems`
holds them otherwise (docs/model.md, "Nonlinear and cross-axis terms").
"""

from __future__ import annotations

from ..parameters import per_angle, per_axis
from ..sensor import ANGLE_NAMES, AXES
from .base import Effect

#: sensing-axis index pairs (output a, other axis b) in the order of ANGLE_NAMES
PAIRS = tuple((AXES.index(ab[0]), AXES.index(ab[1])) for ab in ANGLE_NAMES)
#: fixed-point iterations of the inverse transfers (error O(k^(n+1)) for coefficients k)
INVERSE_ITERATIONS = 3


def third_order(a, k3):
    """``a + K3 a^3`` (IEEE 1293 model equation, K3 term; ``k3`` in 1/g^2)."""
    return a + k3 * a * a * a


def cross_coupled(sensed, coefficients):
    """``a_a + Σ_{b != a} k_ab a_a a_b`` for each output ``a`` (IEEE 1293 cross-coupling, K_ip a_i a_p);
    ``coefficients`` maps ``'xy'`` ... ``'zy'`` to ``k_ab`` in 1/g."""
    out = list(sensed)
    for ab, (i, j) in zip(ANGLE_NAMES, PAIRS):
        out[i] = out[i] + coefficients[ab] * sensed[i] * sensed[j]
    return tuple(out)


def g_dependent_misaligned(sensed, coefficients):
    """``a_a + Σ_{b != a} m_ab a_a^2 a_b``: the angle of axis ``a`` toward ``b`` is
    ``Ca_ab + m_ab a_a^2`` (``coefficients`` maps ``'xy'`` ... to ``m_ab`` in rad/g^2)."""
    out = list(sensed)
    for ab, (i, j) in zip(ANGLE_NAMES, PAIRS):
        out[i] = out[i] + coefficients[ab] * sensed[i] * sensed[i] * sensed[j]
    return tuple(out)


def _fixed_point(forward_increment, responded):
    """Solve ``a + f(a) = m`` for ``a`` by ``a <- m - f(a)`` from ``a = m`` (a contraction for
    |f'| << 1: after n steps the error is O(k^(n+1)), 1e-15 g for k = 1e-3 and n = 3)."""
    a = tuple(responded)
    for _ in range(INVERSE_ITERATIONS):
        inc = forward_increment(a)
        a = tuple(m - d for m, d in zip(responded, inc))
    return a


class ScaleCubic(Effect):
    name = "scale_cubic"
    description = "third-order scale nonlinearity K3 (ug/g^3)"

    def parameters(self):
        return per_axis("K3_{a}", "ug/g3", 50.0, "third-order nonlinearity of the {a} accelerometer", self.name)

    def transfer(self, p, cov, sensed):
        return tuple(third_order(sensed[i], p[f"K3_{a}"]) for i, a in enumerate(AXES))

    def inverse_transfer(self, p, cov, responded):
        """``a = m - K3 a^3`` by fixed-point iteration (:func:`_fixed_point`)."""
        return _fixed_point(lambda a: tuple(p[f"K3_{x}"] * a[i] * a[i] * a[i] for i, x in enumerate(AXES)),
                            responded)


class CrossCoupling(Effect):
    name = "cross_coupling"
    description = "cross-axis nonlinearity: output a gains Kc_ab a_a a_b (ug/g^2)"

    def parameters(self):
        return per_angle("Kc_{ab}", "ug/g2", 100.0,
                         "cross-coupling of the {a} accelerometer: its output gains Kc a_{a} a_{b}", self.name)

    def _k(self, p):
        return {ab: p[f"Kc_{ab}"] for ab in ANGLE_NAMES}

    def transfer(self, p, cov, sensed):
        return cross_coupled(sensed, self._k(p))

    def inverse_transfer(self, p, cov, responded):
        """``a = m - Kc a a'`` by fixed-point iteration (:func:`_fixed_point`)."""
        k = self._k(p)
        return _fixed_point(lambda a: tuple(v - w for v, w in zip(cross_coupled(a, k), a)), responded)


class GDependentMisalignment(Effect):
    name = "g_dependent_misalignment"
    description = "misalignment growing with the square of the acceleration along the axis (arcsec/g^2)"

    def parameters(self):
        return per_angle("Ca_{ab}_g2", "arcsec/g2", 20.0,
                         "g-dependent misalignment: the tilt of the {a} sensing axis toward IMU {b} grows by "
                         "Ca_{ab}_g2 a_{a}^2", self.name)

    def _m(self, p):
        return {ab: p[f"Ca_{ab}_g2"] for ab in ANGLE_NAMES}

    def transfer(self, p, cov, sensed):
        return g_dependent_misaligned(sensed, self._m(p))

    def inverse_transfer(self, p, cov, responded):
        """``a = m - m_ab a_a^2 a_b`` by fixed-point iteration (:func:`_fixed_point`)."""
        m = self._m(p)
        return _fixed_point(lambda a: tuple(v - w for v, w in zip(g_dependent_misaligned(a, m), a)), responded)
