"""``compare_sequence``: a unit's calibrations after successive exposures, each against the
first and against the previous one.
"""

from __future__ import annotations
from ...errors import InputError
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence
from ...io.formats import require_format
from ...estimation.result import CalibrationResult
from .results import ComparisonResult, SEQUENCE_FORMAT, VERSION, _load_json, _save_json
from .pair import check_data_order, compare


@dataclass
class SequenceComparison:
    """A sequence of exposures compared step by step and against the first state.

    ``steps[i]`` compares state i with state i+1; ``cumulative[i]`` state 0 with state i+1.
    A published table carries only one kind (``kind``: what the table's drifts are).
    """

    labels: list
    steps: list
    cumulative: list
    kind: str = "results"
    rule: str = ""
    notes: list = field(default_factory=list)

    @property
    def overall(self) -> str:
        verdicts = [c.overall for c in self.steps + self.cumulative]
        if "fail" in verdicts:
            return "fail"
        return "pass" if verdicts and all(v == "pass" for v in verdicts) else "inconclusive"

    def to_dict(self) -> dict:
        return {"format": SEQUENCE_FORMAT, "version": VERSION, "kind": self.kind, "labels": list(self.labels),
                "rule": self.rule, "steps": [c.to_dict() for c in self.steps],
                "cumulative": [c.to_dict() for c in self.cumulative], "overall": self.overall,
                "notes": list(self.notes)}

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "SequenceComparison":
        require_format(d, SEQUENCE_FORMAT, VERSION, source, "a comparison sequence", "sequence")
        for key in ("labels", "steps", "cumulative"):
            if not isinstance(d.get(key), list):
                raise InputError(f"{source}: {key} is missing or not a list")
        return cls(labels=list(d["labels"]), steps=[ComparisonResult.from_dict(c, source) for c in d["steps"]],
                   cumulative=[ComparisonResult.from_dict(c, source) for c in d["cumulative"]],
                   kind=d.get("kind", "results"), rule=d.get("rule", ""), notes=list(d.get("notes", [])))

    def save(self, path) -> None:
        _save_json(self.to_dict(), path)

    @classmethod
    def load(cls, path) -> "SequenceComparison":
        return cls.from_dict(_load_json(path), str(path))

    def table(self, which: str = "step", names: Optional[Sequence[str]] = None, digits: int = 2) -> str:
        """The drifts as a text table like the paper's Table 3: a row per parameter, a column
        per exposure; each cell ``drift(u)`` and a mark: ``F`` fail, ``?`` inconclusive."""
        comps = self.comparisons(which)
        if not comps:
            return "(no comparisons)"
        if names is None:
            names = [n for n in comps[0].parameters if comps[0].parameters[n].judged]
        cols = [c.label or f"#{i + 1}" for i, c in enumerate(comps)]
        width = max(17, *(len(c) + 2 for c in cols))
        head = f"{'parameter':<16}" + "".join(f"{c:>{width}}" for c in cols)
        lines = [head]
        for n in names:
            cells = []
            for c in comps:
                p = c.parameters.get(n)
                if p is None:
                    cells.append(f"{'-':>{width}}")
                    continue
                mark = {"fail": " F", "inconclusive": " ?", "pass": "  "}[p.verdict] if p.judged else "  "
                cells.append(f"{p.drift:+.{digits}f}({p.u:.{max(digits - 1, 0)}f}){mark}".rjust(width))
            lines.append(f"{n:<16}" + "".join(cells))
        lines.append(f"{'joint p (chi2)':<16}" + "".join(
            (f"{c.joint.p_value:.3g}" if c.joint is not None else "-").rjust(width) for c in comps))
        lines.append(f"{'overall':<16}" + "".join(f"{c.overall:>{width}}" for c in comps))
        return "\n".join(lines)

    def comparisons(self, which: str) -> list:
        if which not in ("step", "cumulative"):
            raise InputError(f"which must be 'step' or 'cumulative', got {which!r}")
        return self.steps if which == "step" else self.cumulative


def compare_sequence(results: Sequence[CalibrationResult], labels: Optional[Sequence[str]] = None,
                     **kwargs) -> SequenceComparison:
    """Compare a sequence of calibrations (initial, after exposure 1, ...) step by step and
    against the initial one; ``kwargs`` as :func:`compare` (posteriors: a list per state as
    ``posteriors=[...]``)."""
    if len(results) < 2:
        raise InputError("a sequence needs at least two calibrations (the initial state and one exposure)")
    labels = list(labels) if labels is not None else [f"state {i}" for i in range(len(results))]
    if len(labels) != len(results):
        raise InputError(f"{len(labels)} labels for {len(results)} calibrations")
    # the states in the order their data were taken (when the results state it): reversed, every drift
    # would have the wrong sign
    check_data_order(results, labels)
    posteriors = kwargs.pop("posteriors", None) or [None] * len(results)
    if len(posteriors) != len(results):
        raise InputError(f"{len(posteriors)} posteriors for {len(results)} calibrations")
    steps, cumulative = [], []
    for i in range(1, len(results)):
        steps.append(compare(results[i - 1], results[i], posterior_before=posteriors[i - 1],
                             posterior_after=posteriors[i], label=f"{labels[i - 1]} -> {labels[i]}",
                             files=(labels[i - 1], labels[i]), **kwargs))
        cumulative.append(compare(results[0], results[i], posterior_before=posteriors[0],
                                  posterior_after=posteriors[i], label=f"{labels[0]} -> {labels[i]}",
                                  files=(labels[0], labels[i]), **kwargs))
    notes = ["consecutive steps share a calibration, so their drifts are negatively correlated "
             "(each comparison is right on its own; do not add step drifts and their u in quadrature)"]
    return SequenceComparison(labels=labels, steps=steps, cumulative=cumulative, kind="results",
                              rule=steps[0].rule, notes=notes)
