"""The one budget type: GUM rows (input, standard uncertainty, sensitivity, contribution) and
their root-sum-of-squares combination, used by the seed paper's eq. 4-7 tables
(:mod:`.paper`) and the certificate's angle budget (:mod:`.angles`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

#: coverage factor of an expanded uncertainty U = k u_c on a certificate (about 95 %)
COVERAGE_FACTOR = 2.0


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

    def to_dict(self) -> dict:
        return {"source": self.source, "standard_uncertainty": self.u, "unit": self.unit,
                "sensitivity": self.sensitivity, "sensitivity_unit": self.sensitivity_unit,
                "contribution": self.contribution, "symbol": self.symbol, "basis": self.basis,
                "equation": self.equation, "distribution": self.distribution}


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

    def __post_init__(self):
        self.components = sorted(self.components,
                                 key=lambda c: (c.contribution is None, -abs(c.contribution or 0.0)))

    @property
    def evaluated(self) -> list:
        return [c for c in self.components if c.contribution is not None]

    @property
    def total(self) -> float:
        """Root sum of squares of the evaluated contributions, in ``unit``."""
        return math.sqrt(sum(c.contribution ** 2 for c in self.evaluated))

    combined_u = total

    @property
    def expanded_U(self) -> float:
        """U: ``k u_c`` when every component is normal (GUM); with two-point components, the
        half-width of the shortest symmetric interval that holds ``coverage_probability`` of the
        combined distribution, solved exactly (the normal part convolved with every sign
        combination of the two-point parts; JCGM 101 §5.3 on a known distribution): a
        two-point +-h is not a normal of SD h, and k u_c would overstate U."""
        two = [c.contribution for c in self.evaluated if c.distribution == "two-point" and c.contribution > 0]
        if not two:
            return self.coverage_factor * self.total
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
        return {"title": self.quantity, "equation": self.equation, "unit": self.unit,
                "combination": self.combination, "total": self.total,
                "components": [c.to_dict() for c in self.components], "notes": list(self.notes), **self.extra}
