"""The sampling rate as an axis of the texture frontier (issue 25 §3): a ``wtml bench
texture-rate`` study's accuracy per rate (:mod:`wtml.bench.texture_rate`) beside each rate's
cost per second of signal, timed where the frontier runs. Its own module: the frontier's
texture problem (:mod:`wtml.bench.texture`) reads it, and the study imports from that."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from wtml.baselines.texture_peers import BandPowerPeer
from wtml.bench.resampling import span
from wtml.bench.timing import latency_p50, paired_ratio
from wtml.runtime.texture import windows
from wtml.scenes import load_scene

STUDY_TAG = 25_3
"""The seed's second word: this study's draws are its own, not a dataset's shards'."""

SUMMARY = "runs/texture/rate/summary.json"
"""Where :func:`wtml.bench.texture_rate.run_rate` writes its summary by default (the
texture frontier reads it)."""


class _Bound:
    """A predictor with its own arguments: ``predict()`` ignores what it is given, so two
    methods that read different records (one rate each) can be timed side by side."""

    def __init__(self, run, *args) -> None:
        self.run, self.args = run, args

    def predict(self, *_):
        return self.run(*self.args)


def frontier_lines(summary_path: str | Path = SUMMARY, *, records: int = 2) -> list[str]:
    """The sampling rate as an axis of the texture frontier (markdown lines).

    Per rate of a :func:`~wtml.bench.texture_rate.run_rate` study (``summary_path``): the
    band-power peer's accuracy on the study's paired held-out specimens and the paired
    differences, beside the rate's cost per second of signal timed here. The cost is the
    peer's features (Welch over the window and the whisk fit: the rate's whole cost; the
    boosted trees' answer is the same at every rate) on ``records`` fresh records of each
    rate's scene: p50 at one window, and each rate's time over the lowest's, side by side
    (:func:`~wtml.bench.timing.paired_ratio`). Without a study: one line saying how to
    make it."""
    path = Path(summary_path)
    if not path.is_file():
        return [f"Sampling rate: no study at `{path}` (`wtml bench texture-rate` makes it; "
                "this frontier then shows the rate as an axis).", ""]
    s = json.loads(path.read_text())
    timed = {}
    for scene_path, rate in zip(s["scenes"], s["rates_hz"], strict=True):
        scene = load_scene(scene_path)
        data = scene.simulate(records, np.random.default_rng([scene.seed, STUDY_TAG, 2]))
        (e, i), owner = windows(np.stack([data["e"], data["i"]]),
                                int(round(s["window_s"] * rate)))
        peer = BandPowerPeer(scene.calibration_hz, rate)
        timed[rate] = _Bound(peer.features, e[:1], i[:1], data["t"][owner[:1]])
    rates = list(timed)
    base = latency_p50(timed[rates[0]], None, 200) / s["window_s"]
    cost = {r: (1.0, 1.0, 1.0) if r == rates[0] else paired_ratio(timed[rates[0]], timed[r],
                                                                   None) for r in rates}
    lines = ["### Sampling rate, an axis of this frontier", "",
             f"From `wtml bench texture-rate` ({path}): the band-power peer trained on "
             f"{s['train_specimens']} specimens and scored on {s['test_specimens']} held-out "
             "ones, the same specimens at every rate (not this frontier's test shard); its cost "
             f"per second of signal timed here ({records} fresh records per rate), the higher "
             "rates side by side with the lowest.", "",
             "| rate | top band (kHz) | accuracy [95 % interval] | features' p50 / s of signal "
             "| time, side by side |", "|---|---|---|---|---|"]
    for r in s["methods"]:
        ratio = cost[r["rate_hz"]]
        lo, hi = r["interval"]
        lines.append(f"| {r['name']} | {r['top_hz'] / 1e3:.1f} | {100 * r['accuracy']:.1f} "
                     f"[{100 * lo:.1f}, {100 * hi:.1f}] | {1e3 * base * ratio[0]:.1f} ms | "
                     f"×{ratio[0]:.2f} ({ratio[1]:.2f}–{ratio[2]:.2f}) |")
    lines += ["", "| paired difference | points [95 % interval] |", "|---|---|"]
    for d in s["differences"]:
        lines.append(f"| {d['name']} | {100 * d['difference']:+.1f} "
                     f"[{span(d['interval'], signed=True)}] |")
    return lines + [""]
