"""Accuracy by viscosity decade: median and 95th-percentile relative errors of η and ρ."""

from __future__ import annotations

import numpy as np

DECADES = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
"""Bin edges of true η in Pa·s."""


def relative_errors(pred: dict[str, np.ndarray], eta: np.ndarray, rho: np.ndarray
                    ) -> dict[str, np.ndarray]:
    """``|pred/true - 1|`` for η and ρ, each ``(n,)``."""
    return {"eta": np.abs(pred["eta"] / eta - 1), "rho": np.abs(pred["rho"] / rho - 1)}


def by_decade(err: dict[str, np.ndarray], eta: np.ndarray) -> list[dict]:
    """Rows per η decade (only decades with samples) and one for all: n, median, p95."""
    rows = []
    edges = zip(DECADES[:-1], DECADES[1:], strict=True)
    bins = [(lo, hi, f"{lo:.0e}-{hi:.0e}") for lo, hi in edges]
    for lo, hi, label in bins + [(0.0, np.inf, "all")]:
        sel = (eta >= lo) & (eta < hi)
        if sel.any():
            rows.append({"decade": label, "n": int(sel.sum()),
                         **{f"{k}_{stat}": float(fn(err[k][sel]))
                            for k in ("eta", "rho")
                            for stat, fn in (("median", np.median),
                                             ("p95", lambda x: np.percentile(x, 95)))}})
    return rows


def format_decades(name: str, rows: list[dict]) -> str:
    """A markdown table of :func:`by_decade` rows, errors in %."""
    lines = [f"**{name}**", "",
             "| η decade (Pa·s) | n | η median | η p95 | ρ median | ρ p95 |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['decade']} | {r['n']} | {100 * r['eta_median']:.2f} % | "
                     f"{100 * r['eta_p95']:.2f} % | {100 * r['rho_median']:.3f} % | "
                     f"{100 * r['rho_p95']:.3f} % |")
    return "\n".join(lines)
