"""The onset bench's transfer table: its methods on each contact law alone (the laws left out of
the training mixture held out), with the wall's tangential friction (held out where the scene
trains without it), on each acquisition effect alone, on an object moving with the base, and on
records of the independent simulator (:mod:`wtml.bench.independent`); and its device-spread
table (issue 21 §1): the same methods on the nominal device, on devices drawn from the trained
spread and from the issue's, and from each class of the issue's spread alone
(:func:`device_variants`), every record with its own device's calibration.

Per row and method: location RMSE and max |error| over the records with a wall (and how many
got no location), F1 of onsets at ±1 ms, and for a method with σ and a domain flag (the
decoder) the flagged share, the RMSE of the in-domain answers and the share of those within
2σ of the truth.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from wtml.bench.independent import simulate_onset
from wtml.bench.transfer import Variant, acquisition_variants, member_variants
from wtml.exporters.onset import record_inputs
from wtml.physics.contact import LAWS
from wtml.physics.spread import CLASSES, DeviceSpread

BASE_LEVELS = (("base", {"enabled": True, "rms_m": 1e-8}),
               ("base", {"enabled": True, "rms_m": 0.8e-6}))
"""The object moving with the base: an isolated optical table (~10 nm rms) and a floor at
50 µm/s rms near 10 Hz (0.8 µm; physics.md §12). Neither is in the shipped scenes' training."""


FRICTION_RANGE = (0.1, 0.5)
"""μ of the wall's friction in its row where the scene trains without it: a tip sliding along
a wall, μ ≈ 0.1–0.5 (physics.md §12)."""


ISSUE_SPREAD = DeviceSpread(length=0.005, thickness=0.005, modulus=0.03, loss_factor=0.25,
                            tan_delta=0.25, coupling=0.03)
"""Issue 21's tolerances (uniform half-widths): lengths and thicknesses ±0.5 %, moduli ±3 %,
the structural loss factor and tanδ ±25 %, the piezo coupling ±3 %."""


def device_variants(scene) -> list[Variant]:
    """The device-spread table's rows: the nominal device (the preset), the trained spread
    (the scene's ``spread`` block), the issue's (:data:`ISSUE_SPREAD`, where it differs) and
    each class of the issue's alone (kind ``"one class"``). Records from the scene's own
    simulator with the scene's nuisance, each with its device's calibration."""
    def row(name: str, kind: str, device: DeviceSpread) -> Variant:
        alone = dataclasses.replace(scene, spread=dataclasses.replace(
            device, devices=scene.spread.devices))
        return Variant(name, kind, lambda n, rng: alone.simulate(n, rng))

    rows = [row("nominal device", "nominal", DeviceSpread())]
    if not scene.spread.none:
        rows.append(row("trained spread", "spread", scene.spread))
    if dataclasses.replace(scene.spread, devices=ISSUE_SPREAD.devices) != ISSUE_SPREAD:
        rows.append(row("issue 21 spread", "spread", ISSUE_SPREAD))
    return rows + [row(f"{c} ±{100 * getattr(ISSUE_SPREAD, c):g} % alone", "one class",
                       DeviceSpread(**{c: getattr(ISSUE_SPREAD, c)})) for c in CLASSES]


def spread_summary(rows: list[dict]) -> dict:
    """The decoder's figures over the spread against the nominal device's: ``nominal`` and
    ``spread`` (its scores on those rows: the trained spread, else the issue's), ``ratio``
    (location RMSE over the spread / nominal; the issue's target ≤ 1.5) and ``limit``, the
    class whose row alone has the largest RMSE (what a user must measure better)."""
    dec = {r["name"]: r["methods"][0] for r in rows}
    nominal = dec["nominal device"]
    spread = next(r for r in rows if r["kind"] == "spread")
    alone = [r for r in rows if r["kind"] == "one class"]
    limit = max(alone, key=lambda r: dec[r["name"]]["rmse"]) if alone else None
    return {"nominal": nominal, "spread_name": spread["name"], "spread": dec[spread["name"]],
            "ratio": dec[spread["name"]]["rmse"] / nominal["rmse"],
            "limit": None if limit is None else limit["name"],
            "limit_rmse": None if limit is None else dec[limit["name"]]["rmse"]}


def _with_law(scene, law: str):
    return dataclasses.replace(scene, wall=dataclasses.replace(scene.wall, law={law: 1.0}))


def independent_records(scene, n: int, rng: np.random.Generator) -> dict:
    """``n`` records of the independent simulator with the scene's nuisance drawn as the scene
    draws it (g, k, c, the coupling's calibration error; the linear wall) and the scene's white
    noise (not its acquisition effects)."""
    lo, hi = scene.gap_range_m()
    w = scene.wall
    gaps = rng.uniform(lo, hi, n)
    k = np.exp(rng.uniform(*np.log(w.stiffness), n))
    c = rng.uniform(*w.damping, n)
    coupling = 1 + scene.calibration_error * rng.standard_normal(n)
    return simulate_onset(scene, gaps, k, c, coupling, rng=rng)


def onset_variants(scene) -> list[Variant]:
    """The rows of the table made by the scene's own simulator: the scene as trained, each
    contact law alone, each acquisition effect alone (and the base motion at
    :data:`BASE_LEVELS`)."""
    rows = [Variant("the trained scene (in family)", "in family", scene.simulate)]
    rows += member_variants(scene, LAWS, scene.wall.law, _with_law, "contact law")
    rows.append(friction_variant(scene))
    return rows + acquisition_variants(scene, BASE_LEVELS)


def friction_variant(scene) -> Variant:
    """The trained scene (its law mixture) with the wall's tangential friction on: μ over the
    scene's own range where it trains with friction (in family), else over
    :data:`FRICTION_RANGE` (held out)."""
    trained = scene.wall.friction[1] > 0
    mu = scene.wall.friction if trained else FRICTION_RANGE
    alone = dataclasses.replace(scene, wall=dataclasses.replace(scene.wall, friction=tuple(mu)))
    return Variant(f"wall friction μ {mu[0]:g}–{mu[1]:g}" + ("" if trained else " (held out)"),
                   "in family" if trained else "held out",
                   lambda n, rng: alone.simulate(n, rng))


def independent_variant(scene) -> Variant:
    """The row of the independent simulator (:func:`independent_records`)."""
    return Variant("independent simulator (linear wall, white noise)", "independent",
                   lambda n, rng: independent_records(scene, n, rng))


def location_scores(gap: np.ndarray, truth: np.ndarray, sigma: np.ndarray | None = None,
                    in_domain: np.ndarray | None = None) -> dict:
    """Location scores over the records with a wall (``truth`` finite), m: ``rmse``, ``max``,
    ``missed`` (no location given); with ``sigma`` and ``in_domain`` (the decoder's) also
    ``flagged`` (share out of domain), ``rmse_in_domain`` and ``within_2sigma`` (share of the
    in-domain answers with |error| <= 2σ), and ``sigma_median``."""
    wall = np.isfinite(truth)
    err = (gap - truth)[wall]
    found = np.isfinite(err)
    out = {"rmse": _rms(err[found]), "missed": int((~found).sum()),
           "max": float(np.max(np.abs(err[found]))) if found.any() else float("nan")}
    if sigma is not None and in_domain is not None:
        ok = in_domain[wall] & found
        sd = sigma[wall]
        out |= {"flagged": float(1 - np.mean(in_domain[wall])),
                "rmse_in_domain": _rms(err[ok]),
                "within_2sigma": float(np.mean(np.abs(err[ok]) <= 2 * sd[ok]))
                if ok.any() else float("nan"),
                "sigma_median": float(np.median(sd[ok])) if ok.any() else float("nan")}
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")


def scorer(methods: dict[str, Callable], events: Callable[[dict, np.ndarray, np.ndarray], dict]
           ) -> Callable[[dict], list[dict]]:
    """``score(records)`` for :func:`~wtml.bench.transfer.run_variants`: each method
    (``run(e, i, t_re, t_im, hue0) -> (gap, onset, detachment, outputs or None)``, the
    records' own calibration after ``e, i``: ``wtml.exporters.onset.record_inputs``) scored by
    :func:`location_scores` and ``events`` (F1 and timing of the contacts)."""
    def score(records: dict) -> list[dict]:
        rows = []
        for name, run in methods.items():
            gap, on, off, out = run(*record_inputs(records))
            answers = out if out is not None and {"sigma", "in_domain"} <= set(out) else None
            extra = (answers["sigma"], answers["in_domain"].astype(bool)) if answers else ()
            rows.append({"name": name, **location_scores(gap, records["gap"], *extra),
                         **events(records, on, off)})
        return rows
    return score


def transfer_table(rows: list[dict]) -> list[str]:
    """Markdown lines: one row per variant, the decoder's columns first (RMSE / max µm, F1,
    flagged, in-domain RMSE, within 2σ), then each other method's RMSE and F1."""
    names = [m["name"] for m in rows[0]["methods"]]
    head = ("| records | kind | " + f"{names[0]}: RMSE / max µm | F1 ±1 ms | flagged | "
            "in-domain RMSE µm | within 2σ | "
            + " | ".join(f"{n}: RMSE µm, F1" for n in names[1:]) + " |")
    lines = [head, "|---" * (7 + len(names[1:])) + "|"]
    for r in rows:
        d, others = r["methods"][0], r["methods"][1:]
        miss = f" ({d['missed']} missed)" if d["missed"] else ""
        lines.append(
            f"| {r['name']} ({r['records']}) | {r['kind']} | {1e6 * d['rmse']:.3f} / "
            f"{1e6 * d['max']:.2f}{miss} | {d['f1']:.3f} | "
            f"{100 * d.get('flagged', np.nan):.0f} % | "
            f"{1e6 * d.get('rmse_in_domain', np.nan):.3f} | "
            f"{100 * d.get('within_2sigma', np.nan):.0f} % | "
            + " | ".join(f"{1e6 * m['rmse']:.3f}, {m['f1']:.2f}" for m in others) + " |")
    return lines
