"""Held-out physics: every method on records of physics it was, or was not, trained on
(physics.md §12, "How to judge it").

A *variant* is a way of making fresh test records: the trained scene itself (the in-family
row), one member of a model-form family alone (a contact law, a friction law; the members
left out of the training mixture marked held out), one acquisition effect alone, or records of
a second, independent simulator (:mod:`wtml.bench.independent`). The task's bench scores each
method on each variant's records with its own metrics and lays the rows side by side, so that
a decoder is robust where its held-out rows stay near its in-family row, and honest where its σ
still covers its error or its domain flag fires.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from wtml.signals.acquisition import AcquisitionEffects

EFFECT_NAMES = {"iv": "I–V converter noise", "adc": "ADC floor", "hum": "mains hum",
                "dac": "drive DAC amplitude error", "drift": "coupling's temperature drift",
                "base": "object moving with the base"}
"""How the report names each acquisition effect of :class:`AcquisitionEffects`."""


@dataclass(frozen=True)
class Variant:
    """One row's records: ``make(n, rng)`` returns ``n`` fresh records in the scene's format.

    Attributes:
        name: the row's label.
        kind: ``"in family"`` (trained on), ``"held out"`` (a family member left out of
            training), ``"acquisition"`` (one effect alone) or ``"independent"`` (another
            simulator).
    """

    name: str
    kind: str
    make: Callable[[int, np.random.Generator], dict]


def mixture_members(mixture: dict[str, float], family: tuple[str, ...]) -> tuple[list[str],
                                                                                 list[str]]:
    """The members of ``family`` that the training ``mixture`` draws (weight > 0), and those
    it leaves out (held out)."""
    trained = [m for m in family if mixture.get(m, 0) > 0]
    return trained, [m for m in family if m not in trained]


def simulated(scene, n: int, rng: np.random.Generator) -> dict:
    """``n`` records of ``scene`` (its own ``simulate``): how a variant's records are drawn
    unless a task draws them its own way."""
    return scene.simulate(n, rng)


Draw = Callable[[object, int, np.random.Generator], dict]
"""``draw(scene, n, rng)``: a variant's ``n`` records of ``scene`` (:func:`simulated`, or a
task's own way, e.g. texture's one specimen per record)."""


def member_variants(scene, family: tuple[str, ...], mixture: dict[str, float],
                    with_member: Callable[[object, str], object], label: str,
                    draw: Draw = simulated) -> list[Variant]:
    """One variant per member of a model-form ``family``: the scene with only that member
    (``with_member(scene, member)``), marked held out where the training ``mixture`` leaves it
    out. ``label`` names the family in the rows (e.g. "contact law"); ``draw`` makes a row's
    records."""
    trained, held = mixture_members(mixture, family)
    out = []
    for member in family:
        alone = with_member(scene, member)
        kind = "in family" if member in trained else "held out"
        out.append(Variant(f"{label} {member} alone" + (" (held out)" if member in held else ""),
                           kind, lambda n, rng, alone=alone: draw(alone, n, rng)))
    return out


def acquisition_variants(scene, extra: tuple[tuple[str, dict], ...] = (),
                         draw: Draw = simulated) -> list[Variant]:
    """The scene with an ideal acquisition (no effect), then with each effect alone at the
    scene's level (those the scene leaves off in training marked so; the base motion only
    through ``extra``), then each ``extra`` effect alone at the level given (``(effect,
    {field: value})``, e.g. the base motion at two levels); ``draw`` makes a row's records."""
    fx: AcquisitionEffects = scene.acquisition.effects

    def with_effects(new: AcquisitionEffects):
        return dataclasses.replace(scene, acquisition=dataclasses.replace(scene.acquisition,
                                                                           effects=new))

    def alone(name: str, **fields) -> AcquisitionEffects:
        only = fx.only(name)
        return dataclasses.replace(only, **{name: dataclasses.replace(
            getattr(only, name), **fields)}) if fields else only

    rows = [("ideal acquisition (no effect)", with_effects(fx.only()))]
    rows += [(f"{EFFECT_NAMES[name]} alone"
              + ("" if getattr(fx, name).enabled else " (not in training)"),
              with_effects(alone(name))) for name in fx.NAMES if name != "base"]
    rows += [(f"{EFFECT_NAMES[name]} alone ({_level(fields)})", with_effects(alone(name, **fields)))
             for name, fields in extra]
    return [Variant(label, "acquisition", lambda n, rng, s=s: draw(s, n, rng))
            for label, s in rows]


def _level(fields: dict) -> str:
    return ", ".join(f"{k} {v:g}" for k, v in fields.items() if k != "enabled")


def run_variants(variants: list[Variant], n: int, seed: int,
                 score: Callable[[dict], list[dict]], progress=None, *,
                 paired: bool = False) -> list[dict]:
    """Score every variant's ``n`` fresh records (drawn from ``seed`` and the row's index, so
    each row is reproducible alone; ``paired``: every row from one stream of its own, so that
    rows differing only in what the variant changes share their draws). ``score(records)``
    returns one dict per method. Returns one row per variant: ``name``, ``kind``, ``records``,
    ``simulate_s`` and ``methods``."""
    rows = []
    for k, v in enumerate(variants):
        if progress:
            progress(f"{'paired' if paired else 'transfer'}: {v.name} ({n} records)")
        t0 = time.perf_counter()
        rec = v.make(n, np.random.default_rng([seed, 9200] if paired else [seed, 9100, k]))
        made = time.perf_counter() - t0
        rows.append({"name": v.name, "kind": v.kind, "records": n, "simulate_s": made,
                     "methods": score(rec)})
    return rows
