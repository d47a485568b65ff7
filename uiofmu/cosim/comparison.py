"""What :func:`uiofmu.cosim.validate.validate` reports, and how it folds an FMU's outputs against their reference
into one relative difference (one scale for the whole run: see :mod:`uiofmu.cosim.validate`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Largest accepted relative difference between an FMU and its reference.
EQUALITY_RTOL = 1e-12
@dataclass
class Validation:
    """The outcome of :func:`validate`.

    ``max_abs_diff`` is the largest absolute difference between FMU and reference over the
    run (every sample, every output channel); ``scale`` is ``max(1, largest |reference
    value|)`` over the same run; ``max_rel_diff = max_abs_diff / scale``, one scale for the
    whole run, is what ``tolerance`` bounds.
    """

    path: str
    kind: str
    problems: list = field(default_factory=list)
    steps: int = 0
    max_abs_diff: float = 0.0
    max_rel_diff: float = 0.0
    tolerance: float = EQUALITY_RTOL
    scale: float = 1.0

    @property
    def ok(self) -> bool:
        """No static problem and outputs within tolerance."""
        return not self.problems and self.max_rel_diff <= self.tolerance

    def to_data(self) -> dict:
        """JSON-ready form."""
        return {"path": self.path, "kind": self.kind, "problems": self.problems, "steps": self.steps,
                "max_abs_diff": self.max_abs_diff, "max_rel_diff": self.max_rel_diff, "scale": self.scale,
                "tolerance": self.tolerance, "ok": self.ok}


def compare(report: Validation, got: np.ndarray, ref: np.ndarray) -> None:
    """Fold one sample into the run's largest difference and its one scale (see the module).

    A NaN difference counts as infinite (``max`` would drop it); the scale takes only finite
    reference values."""
    got, ref = np.asarray(got, dtype=float), np.asarray(ref, dtype=float)
    if ref.size:
        diff = np.abs(got - ref)
        report.max_abs_diff = max(report.max_abs_diff, float(np.where(np.isnan(diff), np.inf, diff).max()))
        finite = np.abs(ref[np.isfinite(ref)])
        report.scale = max(report.scale, float(finite.max()) if finite.size else 1.0)
    report.max_rel_diff = report.max_abs_diff / report.scale


__all__ = ["EQUALITY_RTOL", "Validation", "compare"]
