"""``wtml bench models``: what each scene models and what that costs (issue 25 §5).

Per scene, the cheaper models it could use, their speed and the error they would make on the
task, measured against records of the scene's own (richer) model:

- radial: the beam path (the contact a rank-one update of the beam's dynamic stiffness, per
  record) against the 2×2 path (the free structure's T once per frequency, the contact as a
  tip load, :meth:`~wtml.physics.beam.BeamTransducer.contact_as_tip_load`): samples per
  second of each (one thread), the error of the Ze the 2×2 path gives (relative, and in units of the
  scene's noise), the shipped decoder's RMSE on records of each path, and the RMSE on the beam
  path's records of the polynomial in Im Ze/ref fitted on each path's records (what a method
  built on the cheaper model loses on the real one).
- onset and texture: the modal model with 1, 3, 6 and 14 modes (and the scene's own count, the
  one ``n_modes: auto`` picks and the reference): its truncation error over the scene's band
  (Ze free and clamped against every mode kept, :func:`wtml.physics.modal.truncation_errors`),
  the simulator's wall time per second of recorded signal, the current's difference from the
  reference's records (the same draws, relative RMS, beside the current noise's share) and the
  shipped decoder's error on each count's records, with the share it flags out of domain. The
  reference is the largest of these counts and the one within :data:`REFERENCE_TOLERANCE` over
  the band: never the scene's own count unless that is converged, so a decoder trained on too
  few modes shows it (texture at 14 modes flagged every record of 30).
- fluid: none; its lumped single-mode model with the sphere's tip mass is already the 2×2
  path, the cheapest model exact for a tip load.

Also the ``n_modes: auto`` table: the count :mod:`wtml.scenes.modes` picks for each time-domain
scene at its default tolerance over its band, with the errors of that count and of one fewer.
Writes ``report.md`` and ``summary.json``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from wtml.bench.extremes import strict_json
from wtml.physics.modal import ModalTransducer, truncation_errors
from wtml.runtime.predict import load_export
from wtml.scenes import SceneError, scene_from_dict
from wtml.scenes.modes import DEFAULT_TOLERANCE, AutoModes, band_omega
from wtml.scenes.texture import UNSTABLE_STEP

MODE_COUNTS = (1, 3, 6, 14)
"""The modal orders every time-domain scene is costed at."""
REFERENCE_TOLERANCE = 1e-3
"""The reference's truncation error over the scene's band (relative, Ze free and clamped): a
tenth of ``n_modes: auto``'s default."""


def radial_cost(model_dir: str | Path, *, records: int = 2000, train: int = 20000,
                threads: int = 2, seed: int = 0) -> dict:
    """The radial scene's beam path against the 2×2 path (module docstring), on ``records``
    contacts of the scene's prior (its nominal device) and polynomials fitted on ``train``."""
    from wtml.baselines.radial import PolynomialRadial
    from wtml.physics import ze_from_zm
    from wtml.physics.spread import DeviceSpread
    from wtml.signals import complex_noise

    decoder = load_export(model_dir, threads=threads)[0]
    scene = dataclasses.replace(scene_from_dict(decoder.meta.scene), spread=DeviceSpread())
    beam, omega = scene.transducer(), scene.excitation.omega
    c = scene.contact
    free = scene.free_ze(beam)

    def draw(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        return (1e-6 * rng.uniform(*c.distance_um, n),
                np.exp(rng.uniform(*np.log(c.stiffness), n)))

    def paths(d: np.ndarray, k: np.ndarray) -> dict[str, tuple[np.ndarray, float]]:
        with threadpool_limits(1):  # one BLAS thread: a loaded machine's threads thrash
            t0 = time.perf_counter()
            ze_beam = scene.ze_of(d, k, beam)
            t1 = time.perf_counter()
            ze_2x2 = ze_from_zm(beam.transduction_matrix(omega),
                                beam.contact_as_tip_load(omega, beam.length - d, k))
            t2 = time.perf_counter()
        return {"beam path": (ze_beam, len(d) / (t1 - t0)),
                "2×2 path": (ze_2x2, len(d) / (t2 - t1))}

    def noisy(ze: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        ref = np.broadcast_to(free, ze.shape)
        return (complex_noise(ze, scene.noise.ze_relative, rng),
                complex_noise(ref, scene.noise.reference_relative, rng))

    paths(*draw(16, np.random.default_rng([seed, 0])))  # warm: the beam's matrices, BLAS
    d, k = draw(records, np.random.default_rng([seed, 1]))
    test = paths(d, k)
    d_tr, k_tr = draw(train, np.random.default_rng([seed, 2]))
    fit = {name: ze for name, (ze, _) in paths(d_tr, k_tr).items()}
    beam_ze, beam_ref = noisy(test["beam path"][0], np.random.default_rng([seed, 3]))
    rows = []
    for name, (ze, rate) in test.items():
        rel = np.abs(ze / test["beam path"][0] - 1)
        effect = np.abs(test["beam path"][0] - free)
        ze_n, ref_n = noisy(ze, np.random.default_rng([seed, 3]))  # the beam path's noise
        pred = decoder.predict(ze_n, ref_n)
        poly = PolynomialRadial("imag").fit(*noisy(fit[name], np.random.default_rng([seed, 4])),
                                            d_tr)
        poly_err = poly.predict(beam_ze, beam_ref)["distance"] - d
        rows.append({"model": name, "samples_per_s": rate,
                     "ze_error_median": float(np.median(rel)),
                     "ze_error_max": float(np.max(rel)),
                     "ze_error_noise": float(np.median(rel) / scene.noise.ze_relative),
                     "ze_error_of_effect": float(np.median(np.abs(ze - test["beam path"][0])
                                                           / effect)),
                     "decoder_rmse": float(np.sqrt(np.mean((pred["distance"] - d) ** 2))),
                     "decoder_flagged": float(1 - np.mean(pred["in_domain"])),
                     "polynomial_rmse": float(np.sqrt(np.mean(poly_err**2)))})
    return {"scene": "radial", "records": records, "train": train,
            "noise": scene.noise.ze_relative, "rows": rows}


def modal_cost(model_dir: str | Path, *, records: int = 32, counts=MODE_COUNTS,
               threads: int = 2, seed: int = 0) -> dict:
    """An onset or texture scene's modal orders (module docstring), ``records`` records
    each, the same draws at every count; the reference is the largest of ``counts``, the
    scene's, auto's and :data:`REFERENCE_TOLERANCE`'s count."""
    decoder = load_export(model_dir, threads=threads)[0]
    scene = scene_from_dict(decoder.meta.scene)
    if "n_modes" not in {f.name for f in dataclasses.fields(scene)}:
        raise ValueError(f"{model_dir}: a {scene.task} scene has no modal model")
    if hasattr(scene, "one_specimen_each"):  # every grade among the records
        scene = scene.one_specimen_each(records)
    auto = AutoModes()
    n_auto, auto_errors, band = auto.count(scene)
    n_ref = AutoModes(modes_tolerance=REFERENCE_TOLERANCE).count(scene)[0]
    counts = sorted({*counts, scene.n_modes, n_auto, n_ref})
    reference = max(counts)
    beam = scene.beam()
    truncation = truncation_errors(beam, band_omega(band), reference)
    modes_hz = ModalTransducer.from_beam(beam, reference).omega_n / (2 * np.pi)
    seconds = scene.n_samples / scene.acquisition.sample_rate_hz
    made = {}
    dataclasses.replace(scene, n_modes=counts[0]).simulate(2, np.random.default_rng(seed))  # warm
    steps = {n: _stepped(dataclasses.replace(scene, n_modes=n)) for n in counts}
    for n, stepped in steps.items():
        while True:
            _progress(f"{scene.task}: {n} modes, oversample "
                      f"{getattr(stepped, 'oversample', 1)} ({records} records)")
            t0 = time.perf_counter()
            try:
                made[n] = (stepped.simulate(records, np.random.default_rng([seed, 7])),
                           time.perf_counter() - t0)
                break
            except SceneError as err:  # a drawn device the nominal's step does not hold
                if UNSTABLE_STEP not in str(err):
                    raise
                stepped = dataclasses.replace(stepped, oversample=stepped.oversample + 1
                                              ).stepped_stably()
                steps[n] = stepped
    ref_i = made[reference][0]["i"].astype(float)
    rms = np.sqrt(np.mean(ref_i**2, axis=1))
    rows = []
    for n in counts:
        rec, wall = made[n]
        diff = np.sqrt(np.mean((rec["i"].astype(float) - ref_i) ** 2, axis=1)) / rms
        rows.append({"n_modes": n, "top_mode_hz": float(modes_hz[n - 1]),
                     "truncation_error": float(truncation[n - 1]),
                     "seconds_per_signal_s": wall / (records * seconds),
                     "real_time": records * seconds / wall,
                     "current_difference": float(np.median(diff)),
                     **_decoder_score(scene, decoder, rec),
                     "oversample": getattr(steps[n], "oversample", 1),
                     "scene": n == scene.n_modes, "auto": n == n_auto})
    return {"scene": scene.task, "records": records, "band_hz": list(band),
            "reference": reference, "noise_share": float(np.median(
                scene.acquisition.i_noise_a / rms)), "rows": rows,
            "auto": {"n_modes": n_auto, "tolerance": auto.modes_tolerance,
                     "errors": auto_errors.tolist()}, "record_s": seconds}


def _stepped(scene):
    """``scene``, a texture scene stepped as finely as its friction needs at its count
    (:meth:`~wtml.scenes.texture.TextureScene.stepped_stably`: 30 modes of the macro WT need
    oversample 5); an onset scene as it is."""
    return scene.stepped_stably() if hasattr(scene, "stepped_stably") else scene


def _decoder_score(scene, decoder, rec: dict) -> dict:
    """The shipped decoder's error on ``rec`` and the share it flags: onset, the location
    RMSE (m) over the records with a wall; texture, the share of windows misclassified."""
    if scene.task == "onset":
        from wtml.bench.onset_transfer import location_scores
        from wtml.exporters.onset import record_inputs

        out = decoder.run(*record_inputs(rec))
        return {"error": location_scores(out["gap"], rec["gap"])["rmse"],
                "flagged": float(1 - np.mean(out["in_domain"]))}
    from wtml.runtime.texture import run_windows, windows

    cut, owner = windows(np.stack([rec["e"], rec["i"]]), decoder.meta.n_samples)
    out = run_windows(decoder, cut[0], cut[1], rec["t"][owner])
    wrong = np.argmax(out["probabilities"], 1) != rec["grade"][owner]
    return {"error": float(np.mean(wrong)), "flagged": float(1 - np.mean(out["in_domain"]))}


def format_radial(r: dict) -> list[str]:
    """The radial scene's table (markdown lines)."""
    lines = [f"## radial: beam path against the 2×2 path ({r['records']} contacts of the "
             f"scene's prior, nominal device; polynomials fitted on {r['train']})", "",
             "| model | samples/s, one thread | Ze error vs beam, median / max | median in noise σ "
             f"({r['noise']:g}) | of the contact's own change of Ze | decoder ONNX on its "
             "records: RMSE, flagged | polynomial Im Ze/ref fitted on its records: RMSE on the "
             "beam path's |", "|---|---|---|---|---|---|---|"]
    for x in r["rows"]:
        lines.append(f"| {x['model']} | {x['samples_per_s']:.3g} | "
                     f"{100 * x['ze_error_median']:.3g} % / {100 * x['ze_error_max']:.3g} % | "
                     f"{x['ze_error_noise']:.3g} | {100 * x['ze_error_of_effect']:.3g} % | "
                     f"{1e6 * x['decoder_rmse']:.3g} µm, {100 * x['decoder_flagged']:.0f} % | "
                     f"{1e6 * x['polynomial_rmse']:.3g} µm |")
    return lines


def format_modal(r: dict) -> list[str]:
    """An onset or texture scene's table (markdown lines)."""
    unit, scale, what = (("µm", 1e6, "location RMSE") if r["scene"] == "onset"
                         else ("%", 100.0, "windows misclassified"))
    lo, hi = r["band_hz"]
    lines = [f"## {r['scene']}: modal orders ({r['records']} records of "
             f"{r['record_s']:g} s, the same draws at every order; reference "
             f"{r['reference']} modes; band {lo:g}–{hi:g} Hz)", "",
             "| modes (oversample) | highest mode (Hz) | Ze error vs every mode, over the "
             "band | s per s of "
             f"signal | × real time | current vs {r['reference']} modes (rel. RMS; each at its "
             f"own step) | decoder "
             f"ONNX: {what} | flagged |", "|---|---|---|---|---|---|---|---|"]
    for x in r["rows"]:
        tags = [t for t, on in (("the scene's", x["scene"]), ("auto", x["auto"])) if on]
        lines.append(f"| {x['n_modes']} ({x['oversample']}"
                     f"{'; ' + ', '.join(tags) if tags else ''}) | "
                     f"{x['top_mode_hz']:.0f} | {x['truncation_error']:.2g} | "
                     f"{x['seconds_per_signal_s']:.3g} | {x['real_time']:.0f} | "
                     f"{x['current_difference']:.2g} | {scale * x['error']:.3g} {unit} | "
                     f"{100 * x['flagged']:.0f} % |")
    lines += ["", f"The current's white noise is {r['noise_share']:.2g} of its RMS (median); "
              "wall time on this machine's cores, the unrecorded lead-in included."]
    return lines


def format_auto(results: list[dict]) -> list[str]:
    """The ``n_modes: auto`` table (markdown lines)."""
    lines = ["## n_modes: auto (wtml.scenes.modes)", "",
             "| scene | band (Hz) | tolerance | picks | shipped | error at the pick | one "
             "fewer |", "|---|---|---|---|---|---|---|"]
    for r in results:
        a = r["auto"]
        errors = a["errors"]
        shipped = next(x["n_modes"] for x in r["rows"] if x["scene"])
        fewer = f"{errors[-2]:.2g}" if len(errors) > 1 else "-"
        lines.append(f"| {r['scene']} | {r['band_hz'][0]:g}–{r['band_hz'][1]:g} | "
                     f"{a['tolerance']:g} | {a['n_modes']} | {shipped} | {errors[-1]:.2g} | "
                     f"{fewer} |")
    return lines


def run_models(models: str | Path, out: str | Path, *, records: int = 32,
               radial_records: int = 2000, threads: int = 2) -> str:
    """The whole bench (module docstring); returns the report (also ``out/report.md``).

    Args:
        models: the folder of the task exports (``<models>/<task>``); a scene without its
            export is skipped, and said so.
        records: records per modal order (onset, texture).
        radial_records: contacts of the radial comparison.
        threads: onnxruntime's threads.
    """
    from wtml.tasks import TASKS

    if records < 5 or radial_records < 10:
        raise ValueError(f"records must be >= 5 and radial_records >= 10, got {records} and "
                         f"{radial_records}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    models = Path(models)
    lines = ["# wtml bench models: what each scene models and what that costs", "",
             "fluid: a lumped single-mode model cascaded with the sphere's tip mass, the 2×2 "
             "path (T once per frequency): already the cheapest model exact for a tip load.",
             "radial: the beam model (Euler–Bernoulli elements, piezo-coupled), the contact a "
             "rank-one update per record. onset and texture: the modal reduction of the beam "
             "with static correction, stepped exactly (walls switched or solved implicitly; "
             "friction once per step).", f"Default tolerance of n_modes: auto: "
             f"{DEFAULT_TOLERANCE:g}.", ""]
    summary, skipped, modal = {}, [], []
    if (models / "radial").is_dir():
        _progress(f"radial: beam and 2×2 paths ({radial_records} contacts)")
        summary["radial"] = radial_cost(models / "radial", records=radial_records,
                                        threads=threads)
        lines += format_radial(summary["radial"]) + [""]
    else:
        skipped.append(f"radial (no export at {models / 'radial'})")
    for name, task in TASKS.items():  # the scenes with a modal model
        if "n_modes" not in {f.name for f in dataclasses.fields(task.load("scene"))}:
            continue
        if not (models / name).is_dir():
            skipped.append(f"{name} (no export at {models / name})")
            continue
        summary[name] = modal_cost(models / name, records=records, threads=threads)
        modal.append(summary[name])
        lines += format_modal(summary[name]) + [""]
    if modal:
        lines += format_auto(modal)
    if skipped:
        lines += ["", "Skipped: " + "; ".join(skipped) + "."]
    report = "\n".join(lines) + "\n"
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(json.dumps(strict_json(
        {"scenes": summary, "skipped": skipped}), indent=1, allow_nan=False))
    return report


def _progress(text: str) -> None:
    print(f"bench models: {text}", file=sys.stderr, flush=True)
