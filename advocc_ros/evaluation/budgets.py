"""The budget-to-failure rule of the paper's Table II: the smallest budget reaching a PSR."""

from __future__ import annotations

THRESHOLDS = (0.8, 0.6, 0.4, 0.2, 0.0)
"""PSR thresholds of the budget-to-failure question (the paper's Table II), as fractions."""


def minimal_budgets(psr: dict[str, list[float]], thresholds=THRESHOLDS
                    ) -> dict[str, dict[str, int | None]]:
    """Per threshold (key ``str(threshold)``, e.g. ``'0.2'``) and planner: the smallest m whose
    PSR (``psr[planner][m]``, a fraction; None = not measured) is <= the threshold, or None
    when no measured m reaches it. The first crossing counts even if a later m is higher."""
    out: dict[str, dict[str, int | None]] = {}
    for threshold in thresholds:
        row = {}
        for planner, curve in psr.items():
            row[planner] = next((m for m, value in enumerate(curve)
                                 if value is not None and value <= threshold + 1e-9), None)
        out[str(threshold)] = row
    return out
