"""The one budget type: GUM rows (input, standard uncertainty, sensitivity, contribution) and
their root-sum-of-squares combination, used by the seed paper's eq. 4-7 tables
(:mod:`.paper`), the certificate's angle budget (:mod:`.angles`) and every parameter's budget
in the results JSON (:mod:`.typeb`).

Expanded uncertainty (JCGM 100 / JCGM 101):

- every row normal: ``U = k u_c`` with ``k = t_p(nu_eff)`` (Student's t at coverage ``p``,
  95.45 %, for the Welch-Satterthwaite effective degrees of freedom; ``k = 2`` for
  ``nu_eff = inf``);
- normal and two-point rows: the exact coverage interval of the convolution;
- a rectangular or arcsine row: a JCGM 101 Monte Carlo (``MC_DRAWS`` draws, a seed fixed
  by the quantity's name, so the same budget gives the same U), the probabilistically
  symmetric interval of the sum."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from typing import Optional

#: coverage factor of an expanded uncertainty U = k u_c on a certificate (about 95 %)
COVERAGE_FACTOR = 2.0
#: draws of the JCGM 101 Monte Carlo (the 95 % half-width to about 0.3 %, JCGM 101 7.9)
MC_DRAWS = 200_000
#: distributions a row may have; the row's ``contribution`` is always its standard deviation
DISTRIBUTIONS = ("normal", "two-point", "rectangular", "arcsine")


@dataclass
class BudgetComponent:
    """One row: the standard uncertainty ``u`` of an input (in ``unit``), its sensitivity
    coefficient (in ``sensitivity_unit``) and its ``contribution`` ``|c| u`` in the budget's
    unit (None when it could not be evaluated), with how it was obtained (``basis``), the
    equation it comes from and the paper's symbol of the term (dCa_Ta, sigma_1, ...)."""

    source: str
    contribution: Optional[float]
    u: Optional[float] = None
    unit: str = "arcsec"
    sensitivity: Optional[float] = 1.0
    sensitivity_unit: str = "1"
    basis: str = ""
    equation: str = ""
    symbol: str = ""
    #: "normal", or "two-point": the error is +-contribution with probability 1/2 each (a reading
    #: on one branch of a hysteresis loop stated on its mid-line); its SD is the contribution
    distribution: str = "normal"
    #: degrees of freedom of ``u`` (None: infinite, a Type B value taken as exact, JCGM 100 G.4.2)
    dof: Optional[float] = None
    #: "A" (evaluated from the data's scatter) or "B" (from the lab's statements)
    type: str = "B"

    def to_dict(self) -> dict:
        return {"source": self.source, "type": self.type, "standard_uncertainty": self.u, "unit": self.unit,
                "sensitivity": self.sensitivity, "sensitivity_unit": self.sensitivity_unit,
                "contribution": self.contribution, "symbol": self.symbol, "basis": self.basis,
                "equation": self.equation, "distribution": self.distribution, "dof": self.dof}


@dataclass
class Budget:
    """Components sorted by contribution (largest first, not evaluated last) and their
    combination: ``total`` is the root sum of squares of the evaluated contributions
    (independent inputs), ``expanded_U`` that times ``coverage_factor``."""

    quantity: str
    components: list
    unit: str = "arcsec"
    equation: str = ""
    combination: str = "root sum of squares"
    coverage_factor: float = COVERAGE_FACTOR
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    #: why no expanded uncertainty is stated (the paper's eq. 4 and eq. 5-7 combine bounds and a
    #: factor 2 of their own: no coverage probability holds for them), or None when U is stated
    no_expanded: Optional[str] = None

    def __post_init__(self):
        self.components = sorted(self.components,
                                 key=lambda c: (c.contribution is None, -abs(c.contribution or 0.0)))
        for c in self.components:
            if c.distribution not in DISTRIBUTIONS:
                raise ValueError(f"{self.quantity}: {c.source}: distribution {c.distribution!r} is not one of "
                                 f"{', '.join(DISTRIBUTIONS)}")
        self._U = None

    @property
    def evaluated(self) -> list:
        return [c for c in self.components if c.contribution is not None]

    @property
    def total(self) -> float:
        """Root sum of squares of the evaluated contributions, in ``unit``."""
        return math.sqrt(sum(c.contribution ** 2 for c in self.evaluated))

    combined_u = total

    @property
    def dof_eff(self) -> float:
        """Welch-Satterthwaite effective degrees of freedom (JCGM 100 G.4.1):
        ``u_c^4 / sum(u_i^4 / nu_i)``; ``inf`` when every evaluated row has infinite dof."""
        den = sum(c.contribution ** 4 / c.dof for c in self.evaluated
                  if c.dof is not None and c.dof > 0 and c.contribution)
        return self.total ** 4 / den if den > 0 else math.inf

    @property
    def method(self) -> str:
        """How U was obtained: "GUM" (k from nu_eff), "exact" (two-point rows), "Monte Carlo"."""
        kinds = {c.distribution for c in self.evaluated if c.contribution}
        if kinds & {"rectangular", "arcsine"}:
            return "Monte Carlo"
        return "exact" if "two-point" in kinds else "GUM"

    @property
    def expanded_U(self) -> float:
        """U at :attr:`coverage_probability` (cached: the Monte Carlo runs once per budget)."""
        if self._U is None:
            self._U = self._expanded()
        return self._U

    def monte_carlo_U(self, draws: int = MC_DRAWS, seed: Optional[int] = None) -> float:
        """JCGM 101: the half-width of the probabilistically symmetric coverage interval of the sum
        of every row drawn from its distribution (normal, or scaled t with ``dof``; two-point
        +-s; rectangular of SD s; arcsine of SD s), ``draws`` draws, seed from the quantity."""
        import numpy as np

        rng = np.random.default_rng(zlib.crc32(self.quantity.encode()) if seed is None else seed)
        total = np.zeros(draws)
        for c in self.evaluated:
            s = float(c.contribution)
            if s == 0:
                continue
            if c.distribution == "rectangular":
                total += rng.uniform(-math.sqrt(3.0) * s, math.sqrt(3.0) * s, draws)
            elif c.distribution == "arcsine":
                total += math.sqrt(2.0) * s * np.sin(2.0 * math.pi * rng.random(draws))
            elif c.distribution == "two-point":
                total += s * rng.choice((-1.0, 1.0), draws)
            elif c.dof is not None and c.dof > 2:
                # JCGM 101 6.4.9: a Type A value of nu dof is s * t_nu (its SD then s sqrt(nu/(nu-2)))
                total += s * rng.standard_t(c.dof, draws)
            else:
                total += rng.normal(0.0, s, draws)
        p = self.coverage_probability
        lo, hi = np.quantile(total, [(1.0 - p) / 2.0, (1.0 + p) / 2.0])
        return float((hi - lo) / 2.0)

    def _expanded(self) -> float:
        """U: ``t_p(nu_eff) u_c`` when every component is normal (GUM); with two-point components, the
        half-width of the shortest symmetric interval that holds ``coverage_probability`` of the
        combined distribution, solved exactly (the normal part convolved with every sign
        combination of the two-point parts; JCGM 101 §5.3 on a known distribution): a
        two-point +-h is not a normal of SD h, and k u_c would overstate U."""
        if self.method == "Monte Carlo":
            return self.monte_carlo_U()
        two = [c.contribution for c in self.evaluated if c.distribution == "two-point" and c.contribution > 0]
        if not two:
            nu = self.dof_eff
            if math.isinf(nu) or self.coverage_factor != COVERAGE_FACTOR:
                return self.coverage_factor * self.total
            from scipy import stats

            return float(stats.t.ppf((1.0 + self.coverage_probability) / 2.0, nu)) * self.total
        import itertools

        from scipy import optimize, special

        s = math.sqrt(sum(c.contribution ** 2 for c in self.evaluated if c.distribution != "two-point"))
        offsets = [sum(sg * h for sg, h in zip(signs, two)) for signs in itertools.product((-1.0, 1.0), repeat=len(two))]
        if s <= 1e-12 * max(two):
            return max(abs(o) for o in offsets)

        def coverage(U):
            return sum(special.ndtr((U - o) / s) - special.ndtr((-U - o) / s) for o in offsets) / len(offsets)

        hi = max(abs(o) for o in offsets) + 10.0 * s
        return float(optimize.brentq(lambda U: coverage(U) - self.coverage_probability, 0.0, hi, xtol=1e-12))

    @property
    def coverage_probability(self) -> float:
        """The coverage probability U stands for: that of k = 2 for a normal distribution
        (95.45 %), so a budget with and without two-point parts means the same by U."""
        return float(math.erf(self.coverage_factor / math.sqrt(2.0)))

    @property
    def effective_k(self) -> float:
        """U / u_c: 2 for a normal budget, less where a two-point part dominates."""
        return self.expanded_U / self.total if self.total > 0 else self.coverage_factor

    def share(self, c: BudgetComponent) -> Optional[float]:
        """Fraction of the combined variance from ``c``."""
        total = sum(x.contribution ** 2 for x in self.evaluated)
        return None if c.contribution is None or total == 0 else c.contribution ** 2 / total

    def to_dict(self) -> dict:
        stated = self.no_expanded is None
        return {"title": self.quantity, "equation": self.equation, "unit": self.unit,
                "combination": self.combination, "total": self.total, "U": self.expanded_U if stated else None,
                "k": self.effective_k if stated else None,
                "coverage_probability": self.coverage_probability if stated else None,
                "dof_eff": None if math.isinf(self.dof_eff) else self.dof_eff,
                "U_method": self.method if stated else f"none: {self.no_expanded}",
                "components": [c.to_dict() for c in self.components], "notes": list(self.notes), **self.extra}
