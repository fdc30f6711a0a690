"""Uncertainty budgets: the one :class:`Budget` type (:mod:`.budget`), the seed paper's eq. 4-7
tables (:mod:`.paper`, ``triadcal budget``) and the certificate's angle budget
(:mod:`.angles`). Derivations in docs/budget.md and docs/certificate.md."""

from .budget import COVERAGE_FACTOR, Budget, BudgetComponent  # noqa: F401
