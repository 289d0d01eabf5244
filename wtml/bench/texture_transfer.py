"""The texture bench's transfer table: its methods on each friction law alone (the laws left
out of the training mixture held out) and on each acquisition effect alone. Per row and
method: window accuracy, and for a method with a domain flag the flagged share.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from wtml.bench.transfer import Variant, acquisition_variants, member_variants
from wtml.physics.friction import LAWS
from wtml.scenes.texture import LUGRE_OVERSAMPLE


def _with_law(scene, law: str):
    """The scene with ``law`` alone (LuGre stepped at the rate its bristle needs: the records
    are decimated to the same sampling rate)."""
    step = max(scene.oversample, LUGRE_OVERSAMPLE) if law == "lugre" else scene.oversample
    return dataclasses.replace(scene, oversample=step, friction=dataclasses.replace(
        scene.friction, law={law: 1.0}))


def texture_variants(scene) -> list[Variant]:
    """The rows: the scene as trained, each friction law alone, each acquisition effect
    alone."""
    rows = [Variant("the trained scene (in family)", "in family", scene.simulate)]
    rows += member_variants(scene, LAWS, scene.friction.law, _with_law, "friction law")
    return rows + acquisition_variants(scene)


def scorer(methods: dict[str, Callable], windows: Callable[[dict], tuple]
           ) -> Callable[[dict], list[dict]]:
    """``score(records)``: the records cut into windows (``windows(records) -> (e, i,
    grade)``), then each method's ``accuracy`` and, where it answers ``in_domain``, its
    ``flagged`` share."""
    def score(records: dict) -> list[dict]:
        e, i, truth = windows(records)
        rows = []
        for name, run in methods.items():
            pred = run(e, i)
            row = {"name": name, "accuracy": float(np.mean(pred["grade"] == truth)),
                   "windows": len(truth)}
            if "in_domain" in pred:
                row["flagged"] = float(1 - np.mean(pred["in_domain"]))
            rows.append(row)
        return rows
    return score


def transfer_table(rows: list[dict]) -> list[str]:
    """Markdown lines: one row per variant, each method's accuracy (and flagged share)."""
    names = [m["name"] for m in rows[0]["methods"]]
    lines = ["| records (windows) | kind | " + " | ".join(names) + " |",
             "|---" * (2 + len(names)) + "|"]
    for r in rows:
        cells = [f"{100 * m['accuracy']:.1f} %"
                 + (f" ({100 * m['flagged']:.0f} % flagged)" if "flagged" in m else "")
                 for m in r["methods"]]
        lines.append(f"| {r['name']} ({r['records']}, {r['methods'][0]['windows']}) | "
                     f"{r['kind']} | " + " | ".join(cells) + " |")
    return lines
