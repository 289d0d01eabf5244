"""Accuracy by viscosity decade: median and 95th-percentile relative errors of η and ρ."""

from __future__ import annotations

import numpy as np

DECADES = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
"""Bin edges of true η in Pa·s."""


def relative_errors(pred: dict[str, np.ndarray], eta: np.ndarray, rho: np.ndarray
                    ) -> dict[str, np.ndarray]:
    """``|pred/true - 1|`` for η and ρ, each ``(n,)``."""
    return {"eta": np.abs(pred["eta"] / eta - 1), "rho": np.abs(pred["rho"] / rho - 1)}


def sampled_errors(std: dict[str, np.ndarray], eta: np.ndarray, draws: int = 200,
                   seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Errors as a bound allows them, for tables made like the methods' rows: each sample's
    relative error drawn ``draws`` times from a Gaussian of its own std, pooled.

    Args:
        std: relative standard deviations per sample, ``{"eta": (n,), "rho": (n,)}``.
        eta: true η per sample (Pa·s), for the decade bins.

    Returns:
        ``{"eta": (n·draws,), "rho": (n·draws,)}`` absolute relative errors, and η repeated
        to match. Percentiles of these are the bound's percentiles, like the methods'.
    """
    rng = np.random.default_rng(seed)
    err = {k: np.abs(v[:, None] * rng.standard_normal((len(v), draws))).ravel()
           for k, v in std.items()}
    return err, np.repeat(eta, draws)


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
