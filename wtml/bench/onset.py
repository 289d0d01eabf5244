"""``wtml bench onset``: every onset method on the held-out test shard, in one run.

Methods: our decoder (``model.onnx``), the thesis's pipeline (``classical.onnx``), and the
ruptures change-point peer (PELT on the pipeline's |Zm| per probe frame). For each: location
RMSE and max error (µm) by range of g, onset and detachment time error (ms, median absolute,
over contacts matched within 50 ms), detection F1 of onsets at ±1 ms, false positives on free
whisking (``free_records`` records without a wall, and the test shard's own): every reported
wall and every contact interval counts, per second of free whisking (:func:`free_positives`),
p50 latency at batch 1 per second of signal and throughput. A reference row: the true onsets
read through the calibrated model (the free tip's reach on the probe peak where each contact
starts, averaged over a record's contacts): what a perfect detector gets that does not
infer the device's own coupling (the calibration error is its floor). And the best
achievable: the Cramér–Rao bound on g for each test record under the scene's own model
(:func:`cramer_rao_bound`). The streaming decoder (``stream.onnx``, chunk by chunk): its
agreement with the offline graph and its detection delay (from each true onset to
the end of the chunk in which its contact probability first passes 0.5). Also: the decoder's
domain flag on variants it was not trained on (another whisking amplitude, another probe
level), the thesis's Figure 5.22 (15 positions × ``repeats``, measured against actual location,
with R²), the transfer table (held-out physics), the device-spread table (every method on the
nominal device, on devices of the trained spread and on each class of issue 21's spread alone,
each record with its own device's calibration: :func:`wtml.bench.onset_transfer.device_variants`),
the modal model's convergence table, and the simulator's speed. Every method gets each record's
calibration (T at the probe, HUE(0)); the Cramér–Rao bound is the nominal device's.
Writes ``report.md``, ``summary.json`` and PNGs.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from wtml.baselines.onset_classical import ruptures_contacts
from wtml.bench.frontier import Method, Problem, open_graph
from wtml.bench.onset_transfer import (
    device_variants,
    independent_variant,
    onset_variants,
    spread_summary,
    transfer_table,
)
from wtml.bench.onset_transfer import scorer as transfer_scorer
from wtml.bench.resampling import statistic_interval
from wtml.bench.transfer import run_variants
from wtml.cores import available_cores
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.exporters.onset import record_inputs, thesis_pipeline
from wtml.physics.modal import Wall, convergence_table
from wtml.runtime.contacts import Timing, contacts_from
from wtml.runtime.onset import stream_record
from wtml.runtime.predict import OnnxModel, load_export

TOLERANCE_S = 1e-3
MATCH_S = 50e-3


def match_events(true: np.ndarray, found: np.ndarray, tol: float) -> tuple[int, int, int,
                                                                          np.ndarray]:
    """Greedy one-to-one matching of event times per record within ``tol`` s: true
    positives, false positives, false negatives, and the matched errors (s)."""
    tp = fp = fn = 0
    errors = []
    for t_row, f_row in zip(true, found, strict=True):
        t_ev = list(t_row[np.isfinite(t_row)])
        f_ev = f_row[np.isfinite(f_row)]
        for f in f_ev:
            if t_ev:
                k = int(np.argmin(np.abs(np.subtract(t_ev, f))))
                if abs(t_ev[k] - f) <= tol:
                    errors.append(f - t_ev.pop(k))
                    tp += 1
                    continue
            fp += 1
        fn += len(t_ev)
    return tp, fp, fn, np.array(errors)


def event_metrics(labels: dict, onset: np.ndarray, detach: np.ndarray) -> dict:
    tp, fp, fn, _ = match_events(labels["onset"], onset, TOLERANCE_S)
    f1 = 2 * tp / max(2 * tp + fp + fn, 1)
    _, _, _, on_err = match_events(labels["onset"], onset, MATCH_S)
    _, _, _, off_err = match_events(labels["detachment"], detach, MATCH_S)
    return {"f1": f1, "onset_ms": _median_ms(on_err), "detach_ms": _median_ms(off_err)}


def _median_ms(errors: np.ndarray) -> float:
    return float(np.median(np.abs(errors))) * 1e3 if len(errors) else float("nan")


def location_rows(err: np.ndarray, frac: np.ndarray) -> list[dict]:
    """RMSE and max |error| (m) by range of g as a fraction of the whisking amplitude."""
    rows = []
    for lo, hi in ((0.0, 0.37), (0.37, 0.63), (0.63, 1.0), (0.0, 1.0)):
        sel = (frac >= lo) & (frac <= hi) & np.isfinite(err)
        miss = int(np.sum((frac >= lo) & (frac <= hi) & ~np.isfinite(err)))
        rows.append({"range": "all" if (lo, hi) == (0.0, 1.0) else f"{lo:.2f}-{hi:.2f}",
                     "rmse": float(np.sqrt(np.mean(err[sel] ** 2))) if sel.any() else np.nan,
                     "max": float(np.abs(err[sel]).max()) if sel.any() else np.nan,
                     "missed": miss})
    return rows


def free_positives(gap: np.ndarray, onset: np.ndarray, seconds: float) -> dict:
    """False positives of one method on records of free whisking (no wall): ``walls``, the
    records that report a wall (finite ``gap``, ``(n,)`` m), ``contacts``, the contact
    intervals found (finite ``onset``, ``(n, max_contacts)`` s), and both together per second
    of the records' total duration ``seconds``."""
    walls, contacts = int(np.isfinite(gap).sum()), int(np.isfinite(onset).sum())
    return {"walls": walls, "contacts": contacts, "seconds": float(seconds),
            "per_s": (walls + contacts) / seconds}


def _timed(fn, *args, repeats: int = 5) -> float:
    fn(*args)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


class RupturesPeer:
    """The change-point peer on the thesis pipeline's |Zm| (mean per probe frame)."""

    name = "ruptures PELT on |Zm|"

    def __init__(self, scene) -> None:
        self.pipe = thesis_pipeline(scene).eval()
        self.period = int(round(scene.acquisition.sample_rate_hz / scene.drive.probe_hz))
        self.frame_s = self.period / scene.acquisition.sample_rate_hz
        self.merge = scene.merge_periods / scene.drive.probe_hz
        self.threshold = self.pipe.threshold
        self.max_contacts = scene.max_contacts

    @torch.no_grad()
    def run(self, e: np.ndarray, i: np.ndarray, *calibration: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """On records ``e, i`` and their devices' calibration (``t_re, t_im, hue0``)."""
        from wtml.runtime.contacts import intervals

        u, zm = self.pipe.bands(*(torch.tensor(x) for x in (e, i, *calibration)))
        n_fr = zm.shape[1] // self.period
        zf = zm[:, :n_fr * self.period].reshape(len(e), n_fr, -1).mean(-1).numpy()
        uf = u[:, :n_fr * self.period].reshape(len(e), n_fr, -1).mean(-1).numpy()
        pad = int(np.ceil(self.pipe.pad / self.period))
        gaps, states = [], []
        for z, uu in zip(zf, uf, strict=True):
            z = z[pad:-pad]
            noise = np.median(np.abs(np.diff(z))) / 0.95 + 1e-12
            g, st = ruptures_contacts(z / noise, uu[pad:-pad], self.threshold / noise,
                                      penalty=10.0 * np.log(len(z)))
            gaps.append(g)
            states.append(np.concatenate([np.zeros(pad, bool), st, np.zeros(pad, bool)]))
        on, off = intervals(np.array(states), 1 / self.frame_s, self.merge, self.max_contacts)
        return np.array(gaps), on + self.frame_s / 2, off - self.frame_s / 2


def cramer_rao_bound(scene, labels: dict, *, upsample: int = 4, step_m: float = 20e-9,
                     chunk: int = 4) -> np.ndarray:
    """The Cramér–Rao bound on the std of any unbiased estimate of g (m, ``(n,)``; NaN for a
    record without a wall), for each record's own parameters under the scene's model and its
    acquisition.

    The unknowns are g and the nuisances the scene draws per record: contact stiffness k,
    damping c and the device's coupling s, and, where the scene's acquisition adds mains hum,
    the amplitude and phase of each of its harmonics (two linear nuisances each). The drive
    is the scene's known waveform (the recorded e measures its DAC error to ~1e-8). The
    current's noise is Gaussian with the one-sided density :func:`current_noise_density`:
    the scene's white noise and the ADC's step (``LSB²/12``), and, where its acquisition has
    them, the I–V converter's coloured noise and the ADC floor. The Fisher information is the
    Whittle sum over the record's frequencies (:func:`whittle_fisher`; for white noise exactly
    ``Σ_t ∂i/∂θ ∂i/∂θᵀ / σ²``), the derivatives by central differences (g ± ``step_m``,
    k ± 1 %, c ± 2 %, s ± 1e-4), simulated at ``upsample`` × the sampling rate so that a
    contact's start moves by less than a sample (the bound changes by < 2× over steps of
    5-80 nm and upsampling 1-8), ``chunk`` records at a time (memory: ~8 · chunk records at
    ``upsample`` × the rate, float64). It ignores the noise on e, which only makes it lower:
    a floor, not a promise; and it holds the device known but for s (its geometry, moduli
    and losses as the nominal device's).
    """
    acq = scene.acquisition
    fine = dataclasses.replace(scene, acquisition=dataclasses.replace(
        acq, sample_rate_hz=upsample * acq.sample_rate_hz))
    e, de = fine.drive_voltage(lead=True)
    n_lead = len(e) - fine.n_samples
    model = scene.transducer()
    theta = np.stack([labels["gap"], labels["stiffness"], labels["damping"],
                      labels["coupling"]], 1)
    walled = np.isfinite(theta[:, 0])
    rate, n_samples = acq.sample_rate_hz, scene.n_samples
    fx = acq.effects
    nuisance = np.zeros((0, n_samples))
    if fx.hum.enabled:  # each harmonic's cos and sin: linear nuisances, the same per record
        t = np.arange(n_samples) / rate
        hum = 2 * np.pi * fx.hum.mains_hz * np.arange(1, len(fx.hum.amplitudes()) + 1)
        nuisance = np.concatenate([np.cos(hum[:, None] * t), np.sin(hum[:, None] * t)])
    density = current_noise_density(scene, np.fft.rfftfreq(n_samples, 1 / rate),
                                    model.capacitance)
    out = np.full(len(walled), np.nan)
    rows = np.flatnonzero(walled)
    for start in range(0, len(rows), chunk):  # 8 simulations of ~upsample·n_samples each
        part = theta[rows[start:start + chunk]]
        h = np.stack([np.full(len(part), step_m), 0.01 * part[:, 1], 0.02 * part[:, 2],
                      np.full(len(part), 1e-4)], 1)
        shifted = part[:, None, None, :] + np.array([1.0, -1.0])[None, :, None, None] * (
            h[:, None, :, None] * np.eye(4))  # (n, ±, which, θ)
        p = shifted.reshape(-1, 4)
        cur = model.simulate(
            e, 1 / fine.acquisition.sample_rate_hz, Wall(p[:, 0], p[:, 1], p[:, 2]),
            drive_rate=de, coupling_scale=p[:, 3], record=("i",), dtype=np.float64,
            tones=[(w, x) for w, x, _ in fine.drive_tones(lead=True)])["i"]
        cur = cur[:, n_lead::upsample].reshape(len(part), 2, 4, -1)
        grad = (cur[:, 0] - cur[:, 1]) / (2 * h[:, :, None])  # (n, 4, n_samples)
        grad = np.concatenate([grad, np.broadcast_to(nuisance, (len(grad), *nuisance.shape))],
                              1)
        fisher = whittle_fisher(grad, density, rate)
        out[rows[start:start + chunk]] = np.sqrt(np.linalg.inv(fisher)[:, 0, 0])
    return out


def current_noise_density(scene, f: np.ndarray, capacitance: float) -> np.ndarray:
    """The one-sided density (A²/Hz) of the noise on the recorded current at ``f`` (Hz,
    ``(n_f,)``, ``f[0]`` may be 0) under the scene's acquisition: its white noise and the
    ADC's step (``LSB²/12``) at every f, and where the acquisition has them, the ADC floor
    (white) and the I–V converter's density for the device's capacitance (F; none at f = 0,
    as :func:`wtml.signals.acquisition.coloured_noise` draws it)."""
    acq, fx = scene.acquisition, scene.acquisition.effects
    lsb = 2 * acq.i_full_scale_a / 2**acq.adc_bits
    white = acq.i_noise_a**2 + lsb**2 / 12
    if fx.adc.enabled:
        white += fx.adc.rms(acq.i_full_scale_a) ** 2
    density = np.full(np.shape(f), 2 * white / acq.sample_rate_hz)
    if fx.iv.enabled:
        positive = np.asarray(f) > 0
        density[positive] += fx.iv.density(np.asarray(f)[positive], capacitance)
    return density


def whittle_fisher(grad: np.ndarray, density: np.ndarray, rate: float) -> np.ndarray:
    """The Fisher information of parameters whose derivatives of a record's mean are ``grad``
    (``(n, n_params, n_samples)``, per unit of each parameter) under stationary Gaussian noise
    of one-sided density ``density`` (``(n_samples // 2 + 1,)``, on ``numpy.fft.rfftfreq``'s
    frequencies, unit²/Hz) sampled at ``rate`` (Hz): Whittle's ``Σ_f 2 Re(G_j G_k*) / v_f``
    over the interior frequencies (``v_f = N S(f) rate / 2``, the variance of a noise bin)
    and ``G_j G_k / v_f`` at 0 and Nyquist, with ``G = rfft(grad)``. For white noise of
    variance σ² it is exactly ``Σ_t g_j g_k / σ²`` (Parseval). Returns ``(n, n_params,
    n_params)``."""
    n_samples = grad.shape[-1]
    g = np.fft.rfft(grad, axis=-1)
    weight = np.full(g.shape[-1], 2.0)
    weight[0] = 1.0
    if n_samples % 2 == 0:
        weight[-1] = 1.0
    scale = weight / (n_samples * np.asarray(density) * rate / 2)
    return np.einsum("njf,nkf,f->njk", g, g.conj(), scale).real


def calibrated_reference(scene, labels: dict) -> np.ndarray:
    """The wall location (m, ``(n,)``) that the true onsets give through the calibrated model:
    the mean over each record's contacts of the free tip's reach ``u_L + |u_H|`` on the probe
    peak where the contact starts (interpolated between the frames' centres)."""
    from wtml.decoders.onset import OnsetDecoder, frame_period

    net = OnsetDecoder()._make(scene, torch.stack([torch.zeros(5), torch.ones(5)]))
    x = [torch.tensor(v) for v in record_inputs(labels)]
    with torch.no_grad():
        reach = net.reach(net.frames(*x), net.reach_per_volt(*x[2:4])).double().numpy()
    frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
    centres = (np.arange(reach.shape[1]) + 0.5) * frame_s
    out = np.full(len(reach), np.nan)
    for r, (row, onsets) in enumerate(zip(reach, labels["onset"], strict=True)):
        onsets = onsets[np.isfinite(onsets)]
        if len(onsets):
            out[r] = np.interp(onsets, centres, row).mean()
    return out


def stream_metrics(stream: OnnxModel, offline: dict, labels: dict, frame_s: float) -> dict:
    """The streaming graph against the offline one on the same records, and its detection
    delay (ms; median and 95th percentile over true contacts, and the fraction detected)."""
    streamed = stream_record(stream, *record_inputs(labels))
    prob = streamed["contact"]
    chunk_s = json.loads(stream.metadata["chunk_samples"]) / json.loads(
        stream.metadata["sample_rate_hz"])
    frames_per_chunk = max(1, int(round(chunk_s / frame_s)))
    delays = []
    for row, onsets in zip(prob, labels["onset"], strict=True):
        for t in onsets[np.isfinite(onsets)]:
            hit = np.flatnonzero(row[int(t // frame_s):] > 0.5)
            if len(hit):  # ready at the end of the chunk that holds the first such frame
                k = int(t // frame_s) + hit[0]
                delays.append((k // frames_per_chunk + 1) * chunk_s - t)
            else:
                delays.append(np.nan)
    delays = np.array(delays)
    found = delays[np.isfinite(delays)]
    gap_diff = np.abs(streamed["gap"] - offline["gap"])
    return {"chunk_ms": 1e3 * chunk_s,
            "contact_max_diff": float(np.max(np.abs(prob - offline["contact"]))),
            "gap_max_diff_m": float(np.nanmax(gap_diff)) if np.isfinite(gap_diff).any()
            else 0.0,
            "score_max_diff": float(np.max(np.abs(streamed["domain_score"]
                                                  - offline["domain_score"]))),
            "delay_ms_p50": float(np.median(found)) * 1e3 if len(found) else float("nan"),
            "delay_ms_p95": float(np.percentile(found, 95)) * 1e3 if len(found)
            else float("nan"),
            "detected": float(len(found) / max(len(delays), 1))}


def _methods(model_dir: Path, scene):
    decoder, classical = load_export(model_dir)
    peer = RupturesPeer(scene)

    def onnx_run(model):
        def run(*inputs):
            out = model.run(*inputs)
            on, off = contacts_from(out, Timing.of(model.meta))
            return out["gap"], on, off, out
        return run

    return {"decoder (ONNX)": onnx_run(decoder), "thesis pipeline (ONNX)": onnx_run(classical),
            peer.name: lambda *inputs: (*peer.run(*inputs), None)}, decoder


def simulator_speed(scene, records: int = 64, modes=(None, 6), repeats: int = 3) -> list[dict]:
    """Samples·steps per second and the real-time factor of the onset scene's simulator on
    this machine: ``records`` walls across the reach over the scene's whole record, for each
    number of ``modes`` (None: the scene's) on one thread and on every core, side by side in
    one run, the median of ``repeats``. ``per_core`` is the real-time factor over the threads."""
    rate = scene.acquisition.sample_rate_hz
    e, de = scene.drive_voltage(lead=True)
    tones = [(w, x) for w, x, _ in scene.drive_tones(lead=True)]
    lo, hi = scene.gap_range_m()
    wall = Wall(np.random.default_rng(0).uniform(lo, hi, records), 5.0, 1e-4)
    cores = available_cores()
    rows = []
    for n in modes:
        model = (scene if n is None else dataclasses.replace(scene, n_modes=n)).transducer()
        for threads in sorted({1, cores}):
            def run(model=model, threads=threads):
                model.simulate(e, 1 / rate, wall, drive_rate=de, record=("i",),
                               threads=threads, tones=tones)
            wall_s = _timed(run, repeats=repeats)
            factor = records * len(e) / rate / wall_s
            rows.append({"modes": model.n_modes, "threads": threads, "records": records,
                         "seconds": len(e) / rate, "repeats": repeats,
                         "sample_steps_per_s": records * len(e) / wall_s,
                         "real_time_factor": factor, "per_core": factor / threads})
    return rows


def run_bench(data_dir, model_dir, out, *, free_records: int = 50, variant_records: int = 16,
              repeats: int = 3, transfer_records: int = 32, independent_records: int = 8,
              device_records: int = 32) -> str:
    """The whole bench; returns the markdown report (also written to ``out/report.md``).
    ``transfer_records`` fresh records per row of the transfer table made by the scene's own
    simulator, ``independent_records`` for the independent simulator's row (0: none),
    ``device_records`` per row of the device-spread table (0: none)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model_dir = Path(model_dir)
    scene = dataset_scene(data_dir)
    split = split_shards(read_manifest(data_dir)["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    methods, decoder = _methods(model_dir, scene)
    amp = scene.whisk_amplitude_m()
    frac = test["gap"] / amp
    rng = np.random.default_rng([scene.seed, 777])
    free_scene = dataclasses.replace(scene, wall=dataclasses.replace(scene.wall,
                                                                     free_fraction=1.0))
    free = free_scene.simulate(free_records, rng)
    own = np.isnan(test["gap"])  # the test shard's free records
    free = {key: np.concatenate([free[key], test[key][own]])
            for key in ("e", "i", "t_probe", "hue0")}
    free_s = len(free["e"]) * scene.n_samples / scene.acquisition.sample_rate_hz
    positions = np.repeat(np.linspace(*scene.gap_range_m(), 15), repeats)
    fig = scene.simulate(len(positions), rng, gaps=positions)
    results = []
    for name, run in methods.items():
        x = record_inputs(test)
        gap, on, off, _ = run(*x)
        err = gap - test["gap"]
        ev = event_metrics(test, on, off)
        f_gap, f_on, _, f_out = run(*record_inputs(free))
        false = free_positives(f_gap, f_on, free_s)
        if f_out is not None:
            false["flagged"] = float(1 - f_out["in_domain"].mean())
        g_fig, _, _, _ = run(*record_inputs(fig))
        ok = np.isfinite(g_fig)
        r2 = 1 - np.sum((g_fig[ok] - positions[ok]) ** 2) / np.sum(
            (positions[ok] - positions[ok].mean()) ** 2)
        lat = _timed(run, *(v[:1] for v in x), repeats=repeats)
        thr = len(test["e"]) / _timed(run, *x, repeats=1)
        results.append({"name": name, "rows": location_rows(err, frac), **ev,
                        "false_per_s": false["per_s"], "free": false,
                        "fig522_r2": float(r2),
                        "fig522": g_fig.tolist(), "err": err.tolist(),
                        "latency_ms_per_s": 1e3 * lat * scene.acquisition.sample_rate_hz
                        / scene.n_samples, "records_per_s": thr})
    score = transfer_scorer(methods, event_metrics)
    transfer = run_variants(onset_variants(scene), transfer_records, scene.seed, score, _progress)
    if independent_records:
        transfer += run_variants([independent_variant(scene)], independent_records,
                                 scene.seed + 1, score, _progress)
    spread = (run_variants(device_variants(scene), device_records, scene.seed + 2, score,
                           _progress) if device_records else [])
    flags = {}
    for label, drive in (("whisk 7.5 V", {"whisk_v": 7.5}), ("probe 40 mV", {"probe_v": 0.04})):
        var = dataclasses.replace(scene, drive=dataclasses.replace(scene.drive, **drive))
        rec = var.simulate(variant_records, rng)
        flags[label] = float(1 - decoder.run(*record_inputs(rec))["in_domain"].mean())
    offline = decoder.run(*record_inputs(test))
    held_in = float(1 - offline["in_domain"].mean())
    frame_s = json.loads(decoder.metadata["frame_s"])
    streaming = stream_metrics(load_export(model_dir, stream=True)[2], offline, test, frame_s)
    ref = calibrated_reference(scene, test) - test["gap"]
    reference = [{"name": "reference: true onsets through the calibrated model",
                  "rows": location_rows(ref, frac)},
                 {"name": "Cramér–Rao bound (the scene's model and acquisition; g, k, c, s "
                          "and the hum unknown)",
                  "rows": location_rows(cramer_rao_bound(scene, test), frac)}]
    band = 2 * np.pi * np.linspace(0.9, 1.1, 41) * scene.drive.probe_hz
    conv = convergence_table(scene.beam(), band)
    speed = simulator_speed(scene)
    report = _report(results, reference, streaming, flags, held_in, conv, speed, scene,
                     len(test["e"]), free_s, transfer, spread)
    (out / "report.md").write_text(report)
    summary = {"task": "onset", "n_test": len(test["e"]),
               "methods": [{k: v for k, v in r.items() if k not in ("err", "fig522")}
                           for r in results], "domain_flag": flags,
               "reference": reference, "streaming": streaming,
               "false_alarm_held_out": held_in, "convergence": conv, "simulator": speed,
               "transfer": transfer, "device_spread": spread,
               "device_summary": spread_summary(spread) if spread else None}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plots(results, test, fig, positions, amp, scene, methods, out)
    return report


def _progress(text: str) -> None:
    print(f"bench onset: {text}", file=sys.stderr, flush=True)


def _report(results, reference, streaming, flags, held_in, conv, speed, scene, n_test,
            free_s, transfer, spread) -> str:
    rows = results[0]["rows"]
    lines = [f"# wtml bench onset ({n_test} held-out records of "
             f"{scene.n_samples / scene.acquisition.sample_rate_hz:g} s; "
             f"{free_s:g} s of free whisking)", "",
             "Location RMSE / max |error| in µm by g as a fraction of the whisking amplitude "
             f"({1e6 * scene.whisk_amplitude_m():.2f} µm):", "",
             "| method | " + " | ".join(r["range"] for r in rows)
             + " | onset err (ms) | detach err (ms) | F1 ±1 ms | free: walls + contacts "
               "(per s) | Fig 5.22 R² | p50 ms per s of signal | records/s |",
             "|---|" + "---|" * (len(rows) + 7)]
    for r in results:
        cells = [f"{1e6 * x['rmse']:.3f} / {1e6 * x['max']:.2f}"
                 + (f" ({x['missed']} missed)" if x["missed"] else "") for x in r["rows"]]
        lines.append(f"| {r['name']} | " + " | ".join(cells)
                     + f" | {r['onset_ms']:.2f} | {r['detach_ms']:.2f} | {r['f1']:.3f} | "
                       f"{r['free']['walls']} + {r['free']['contacts']} "
                       f"({r['false_per_s']:.3f}) | {r['fig522_r2']:.5f} | "
                       f"{r['latency_ms_per_s']:.2f} | {r['records_per_s']:.1f} |")
    for ref in reference:
        cells = [f"{1e6 * x['rmse']:.3g} / {1e6 * x['max']:.3g}" for x in ref["rows"]]
        lines.append(f"| {ref['name']} | " + " | ".join(cells) + " |" + " |" * 7)
    st = streaming
    lines += ["", f"Streaming decoder (`stream.onnx`, chunks of {st['chunk_ms']:.2f} ms, state "
              f"carried): against the offline graph, contact probability max |diff| "
              f"{st['contact_max_diff']:.1e}, gap {1e6 * st['gap_max_diff_m']:.1e} µm, domain "
              f"score {st['score_max_diff']:.1e}; detection delay p50 {st['delay_ms_p50']:.2f} "
              f"ms, p95 {st['delay_ms_p95']:.2f} ms ({100 * st['detected']:.1f} % of contacts "
              "detected)."]
    lines += ["", "## Transfer: held-out physics", "",
              "Fresh records per row: the trained scene, each contact law alone (a law the "
              "training mixture leaves out is held out), an ideal acquisition, each "
              "acquisition effect alone, the object moving with the base (never trained), and "
              "records of the independent simulator (wtml.bench.independent: its own modal "
              "reduction, TR-BDF2 with touch and release located in the step). The decoder's "
              "columns: location over the records with a wall, F1 of onsets at ±1 ms, the share "
              "flagged out of domain, the in-domain answers' RMSE and the share of them within "
              "2σ.", ""]
    lines += transfer_table(transfer)
    if spread:
        sm = spread_summary(spread)
        lines += ["", "## Device spread", "",
                  f"Fresh records per row from devices drawn around the preset "
                  f"(uniform within ±half-width; {scene.spread.devices} devices per simulated "
                  "batch), every record with its own device's calibration (T at the probe and "
                  "HUE(0), the graphs' inputs t_re, t_im, hue0); the coupling's calibration "
                  f"error ({100 * scene.calibration_error:g} %) stays unknown on top. Columns as "
                  "the transfer table's.", ""]
        lines += transfer_table(spread)
        lines += ["", f"Decoder over the {sm['spread_name']}: location RMSE "
                  f"{sm['ratio']:.2f}× the nominal device's (target ≤ 1.5×: "
                  f"{'met' if sm['ratio'] <= 1.5 else 'MISSED'}); the class that limits it "
                  f"alone: {sm['limit']} ({1e6 * sm['limit_rmse']:.3f} µm)."]
    lines += ["", "Decoder's domain flag (fraction of records flagged out of domain): "
              f"held-out test {held_in:.3f}; free whisking {results[0]['free']['flagged']:.3f}; "
              + "; ".join(f"{k} {v:.3f}" for k, v in flags.items()), "",
              f"Modal T(ω) over {0.9 * scene.drive.probe_hz:g}-{1.1 * scene.drive.probe_hz:g} "
              "Hz: max relative error of any element", "",
              "| modes | vs all modes (truncation) | vs beam (+ damping model) | HUE(0) |",
              "|---|---|---|---|"]
    lines += [f"| {c['n_modes']} | {c['vs_all_modes']:.2e} | {c['vs_beam']:.2e} | "
              f"{c['hue0']:.1e} |" for c in conv]
    lines += ["", f"Simulator: {speed[0]['records']} walls over {speed[0]['seconds']:g} s "
              f"records (median of {speed[0]['repeats']}, side by side in one run):", "",
              "| modes | threads | samples·steps/s | × real time | × real time per core |",
              "|---|---|---|---|---|"]
    lines += [f"| {r['modes']} | {r['threads']} | {r['sample_steps_per_s']:.3g} | "
              f"{r['real_time_factor']:.0f} | {r['per_core']:.0f} |" for r in speed]
    return "\n".join(lines) + "\n"


def _plots(results, test, fig, positions, amp, scene, methods, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, ax, name: str) -> None:
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / name, dpi=120)
        plt.close(fig)

    f, ax = plt.subplots(figsize=(6, 4))
    for r in results:
        ax.plot(test["gap"] * 1e6, np.abs(r["err"]) * 1e6, ".", label=r["name"])
    ax.set(xlabel="wall location g (µm)", ylabel="|error| (µm)", yscale="log",
           title="location error vs g")
    save(f, ax, "error_vs_g.png")
    f, ax = plt.subplots(figsize=(5, 4))
    for r in results:
        ax.plot(r["latency_ms_per_s"], 1e6 * r["rows"][-1]["rmse"], "o", label=r["name"])
    ax.set(xlabel="p50 latency, ms per s of signal", ylabel="location RMSE (µm)",
           xscale="log", yscale="log", title="error vs latency")
    save(f, ax, "error_vs_latency.png")
    f, ax = plt.subplots(figsize=(5, 5))
    for r in results:
        ax.plot(positions * 1e6, np.array(r["fig522"]) * 1e6, "o", ms=3,
                label=f"{r['name']} (R² {r['fig522_r2']:.4f})")
    ax.plot(positions * 1e6, positions * 1e6, "k-", lw=0.5)
    ax.set(xlabel="actual location (µm)", ylabel="measured location (µm)",
           title=f"Figure 5.22: 15 positions × {len(positions) // 15} repeats")
    save(f, ax, "fig5_22.png")
    pipe = thesis_pipeline(scene).eval()
    first = [v[:1] for v in record_inputs(test)]
    with torch.no_grad():
        u, zm = pipe.bands(*(torch.tensor(v) for v in first))
    t = np.arange(scene.n_samples) / scene.acquisition.sample_rate_hz
    f, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    axes[0].plot(t, test["e"][0], lw=0.5)
    axes[0].set_ylabel("e (V)")
    axes[1].plot(t, test["i"][0] * 1e9, lw=0.5)
    axes[1].set_ylabel("i (nA)")
    axes[2].plot(t, zm[0].numpy() * 1e3, lw=0.7, label="|Zm(t)| (thesis pipeline)")
    for k, (name, run) in enumerate(methods.items()):
        _, on, off, _ = run(*first)
        for a, b in zip(on[0], off[0], strict=True):
            if np.isfinite(a):
                axes[2].axvspan(a, b if np.isfinite(b) else t[-1], ymin=0.05 + 0.1 * k,
                                ymax=0.12 + 0.1 * k, color=f"C{k + 1}", label=name)
    for a, b in zip(test["onset"][0], test["detachment"][0], strict=True):
        if np.isfinite(a):
            axes[2].axvspan(a, b, ymin=0.9, ymax=1.0, color="k", alpha=0.4, label="true")
    axes[2].set(ylabel="|Zm| (mN·s/m)", xlabel="t (s)")
    handles, labels = axes[2].get_legend_handles_labels()
    keep = dict(zip(labels, handles, strict=True))
    axes[2].legend(keep.values(), keep.keys(), fontsize=6)
    f.tight_layout()
    f.savefig(out / "example_record.png", dpi=120)
    plt.close(f)


class _Peer:
    """:class:`RupturesPeer` behind the frontier's predictor interface."""

    def __init__(self, peer: RupturesPeer) -> None:
        self.peer, self.name = peer, peer.name

    def predict(self, *inputs: np.ndarray) -> dict:
        gap, onsets, detachments = self.peer.run(*inputs)
        return {"gap": gap, "onsets": onsets, "detachments": detachments}


def frontier_problem(data_dir: str | Path, model_dir: str | Path, *, threads: int = 2
                     ) -> Problem:
    """The onset task for :mod:`wtml.bench.frontier`: the RMSE of the wall's location g (µm)
    over the test shard's records with a wall (each record with its own calibration), costs
    per second of signal; beside it each method's onset F1 (±1 ms), median onset error and
    walls missed. The thesis pipeline (``model_dir``'s classical graph), the ruptures peer,
    the true onsets read through the calibrated model (a reference without a cost) and the
    Cramér–Rao bound, as rows."""
    scene = dataset_scene(data_dir)
    split = split_shards(read_manifest(data_dir)["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    inputs = record_inputs(test)
    wall = np.isfinite(test["gap"])
    calibration = record_inputs(load_shards(data_dir, split["train"][:1]))

    def rms(values):
        return np.sqrt(np.mean(values**2, -1))

    def location(err: np.ndarray) -> tuple[float, float, float]:
        err = 1e6 * err[wall & np.isfinite(err)]
        return float(rms(err)), *statistic_interval(err, rms)

    def score(pred: dict) -> tuple[float, float, float, str]:
        ev = event_metrics(test, pred["onsets"], pred["detachments"])
        missed = int(np.sum(wall & ~np.isfinite(pred["gap"])))
        return (*location(pred["gap"] - test["gap"]),
                f"onset F1 {ev['f1']:.3f}, onset error {ev['onset_ms']:.2f} ms, "
                f"walls missed {missed} of {int(wall.sum())}")

    bound = cramer_rao_bound(scene, test)
    drawn = bound * np.random.default_rng(0).standard_normal(len(bound))
    classical = Path(model_dir) / "classical.onnx"
    methods = [
        Method("thesis pipeline ONNX", "classical", open_graph(classical, "records", threads),
               classical),
        Method(RupturesPeer.name, "peer", _Peer(RupturesPeer(scene))),
        Method("true onsets through the calibrated model", "reference",
               score=location(calibrated_reference(scene, test) - test["gap"]),
               note="a perfect detector that does not infer the device's coupling"),
        Method("Cramér–Rao bound", "bound", score=location(drawn),
               note="RMS of one error drawn from each record's bound (g, k, c, s unknown)"),
    ]
    seconds = scene.n_samples / scene.acquisition.sample_rate_hz
    return Problem(
        "onset", "RMSE of the wall's location g", "µm", False, "s of signal", seconds, inputs,
        score, "records", 16, calibration, methods,
        data=f"`{data_dir}` test shard {split['test']}, {len(wall)} records of {seconds:g} s "
             f"({int(wall.sum())} with a wall)")
