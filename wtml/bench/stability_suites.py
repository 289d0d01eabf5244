"""The conditions and methods of ``wtml bench stability`` (:mod:`wtml.bench.stability`; the
machinery: :mod:`wtml.bench.extremes`), one suite per task, each built from the task's export
folder: the scene is the one its decoder was trained on (the graph's metadata), the methods
are the export's graphs beside the task's classical paths in float64.

- fluid: the prior's lowest, middle and highest viscosity decades; water at 60–95 °C and
  glycerol at 0–10 °C, below and above the prior; the sphere in air (a free tip, at the
  transducer's resonance) and held by a paste of 1e6 Pa·s (clamped). Methods: the closed form
  in numpy and ONNX, the decoder (ONNX) and the Bayes posterior mean; metric: η's median
  relative error.
- radial: contacts in the middle, at both ends of the trained range of d and beyond the far
  end; contacts far softer (their antiresonance in the band) and far stiffer (rigid) than
  trained; no contact at all. Methods: the decoder (ONNX), the thesis's 2-10-1 net where its
  export exists beside it, the polynomial in Im Ze/ref in numpy and ONNX, the physics
  inversion; metric: RMSE of d.
- onset: walls in the middle of the gap range, at both of its ends and beyond them; walls
  softer and far stiffer than trained; free whisking. Methods: the decoder and the thesis's
  pipeline (ONNX); metric: location RMSE over the records with a wall that were located.
- texture: the whisk's amplitude, its frequency and the normal force each at both ends of its
  trained range (the others in the middle fifth of theirs), the amplitude beyond it. Methods:
  the decoder and the thesis's cues (ONNX); metric: the share of windows misclassified.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np

from wtml.bench.extremes import Condition, Method, Suite
from wtml.runtime.predict import load_export
from wtml.scenes import scene_from_dict

AIR = (1.81e-5, 1.20)
"""Air at 20 °C: η (Pa·s), ρ (kg/m³) (CRC Handbook): the sphere's load with the tip free."""
CLAMPING_PASTE = (1e6, 1000.0)
"""η (Pa·s), ρ of a load that holds the sphere: ``|Zm| = 6πRη`` ≈ 3.6e4 N·s/m for R =
1.9 mm, 1e7 times the fluid transducer's own mechanical impedance near resonance."""
MIDDLE = (0.4, 0.6)
EDGE = 0.1
"""A condition at the end of a trained range draws from its last tenth."""


def fluid(model_dir: Path, threads: int) -> Suite:
    """The fluid task's suite (module docstring)."""
    from wtml.baselines import ClassicalFluid
    from wtml.baselines.fluid_bayes import BayesFluid
    from wtml.bench.accuracy import relative_errors
    from wtml.bench.fluid import BAYES_GRID
    from wtml.scenes.fluid import FluidRange

    decoder, classical = load_export(model_dir, threads=threads)
    scene = scene_from_dict(decoder.meta.scene)
    eta_lo, eta_hi = (scene.output_ranges()["eta"].low, scene.output_ranges()["eta"].high)

    def decade(lo: float, hi: float):
        def make(n: int, rng: np.random.Generator) -> dict:
            kept, total = [], 0
            for _ in range(50):  # the prior's highest decade holds ~1 % of its records
                rec = scene.simulate(max(4000, 20 * n), rng)
                sel = (rec["eta"] >= lo) & (rec["eta"] < hi)
                kept.append({k: v[sel] for k, v in rec.items()})
                total += int(sel.sum())
                if total >= n:
                    break
            else:
                raise ValueError(f"fluid: the prior holds too few records with η in "
                                 f"[{lo:g}, {hi:g}) Pa·s")
            return {k: np.concatenate([p[k] for p in kept])[:n] for k in kept[0]}
        return make

    def fluid_range(fraction, temperature):
        variant = dataclasses.replace(scene, fluid=FluidRange(fraction, temperature))
        return lambda n, rng: variant.simulate(n, rng)

    def fixed(properties):
        return lambda n, rng: scene.simulate(n, rng, properties=properties)

    conditions = [
        Condition("η 1e-2–1e-1 Pa·s (the prior's middle decade)", "mid", decade(1e-2, 1e-1)),
        Condition(f"η {eta_lo:.2g}–1e-3 Pa·s (the prior's lowest decade; water's resonance in "
                  "the band)", "edge", decade(0, 1e-3)),
        Condition(f"η 1–{eta_hi:.2g} Pa·s (the prior's highest decade)", "edge",
                  decade(1.0, np.inf)),
        Condition("water at 60–95 °C (η 3–5e-4 Pa·s, below the prior)", "beyond",
                  fluid_range((0.0, 0.0), (60.0, 95.0))),
        Condition("glycerol at 0–10 °C (η 4–12 Pa·s, above the prior)", "beyond",
                  fluid_range((1.0, 1.0), (0.0, 10.0))),
        Condition(f"sphere in air (free tip, at resonance; η {AIR[0]:g} Pa·s)", "extreme",
                  fixed(AIR)),
        Condition(f"sphere held (clamped tip; η {CLAMPING_PASTE[0]:g} Pa·s)", "extreme",
                  fixed(CLAMPING_PASTE)),
    ]

    def onnx(model):
        return lambda rec: model.predict(rec["ze"], rec["t"])

    closed = ClassicalFluid(scene.excitation.omega, scene.sphere.radius)
    bayes = BayesFluid(scene, **BAYES_GRID)
    methods = [Method("closed form numpy (float64)", lambda rec: closed.predict(rec["ze"],
                                                                               rec["t"])),
               Method("closed form ONNX (float32)", onnx(classical)),
               Method("decoder ONNX", onnx(decoder)),
               Method("Bayes posterior mean", lambda rec: bayes.predict(rec["ze"], rec["t"]))]

    def error(rec: dict, pred: dict) -> float:
        return float(np.median(relative_errors(pred, rec["eta"], rec["rho"])["eta"]))

    def answer(rec: dict, pred: dict) -> str:
        rho = np.median(relative_errors(pred, rec["eta"], rec["rho"])["rho"])
        bad = int(np.sum(~(pred["eta"] > 0)))
        return (f"η median {np.median(pred['eta']):.3g} Pa·s (true {np.median(rec['eta']):.3g});"
                f" ρ error {100 * rho:.3g} %" + (f"; {bad} η ≤ 0" if bad else ""))

    peaks = _fluid_resonances(scene)
    notes = (f"Tip velocity per volt peaks at {peaks['air']:.1f} Hz with the sphere in air and "
             f"at {peaks['water']:.1f} Hz in water at 25 °C: the band "
             f"{scene.excitation.f_start_hz:g}–{scene.excitation.f_stop_hz:g} Hz holds the "
             "resonance, so the free tip and the lowest decade are the near-resonance rows.",)
    return Suite("fluid", "η median relative error", "%", 100.0, conditions, methods, error,
                 answer, (("closed form ONNX (float32)", "closed form numpy (float64)",
                           (("eta", 0.0), ("rho", 0.0))),), notes)


def _fluid_resonances(scene) -> dict[str, float]:
    """Hz where the tip velocity per volt ``|1/(t11 Zm + t12)|`` peaks with the sphere in air
    and in water at 25 °C, on a 0.1 Hz grid over half to twice the scene's band."""
    from wtml.physics import cascade, tip_mass
    from wtml.physics.fluids import water
    from wtml.physics.loads import stokes_sphere

    ex = scene.excitation
    f = np.arange(0.5 * ex.f_start_hz, 2 * ex.f_stop_hz, 0.1)
    w = 2 * np.pi * f
    t = cascade(scene.transducer.build().transduction_matrix(w), tip_mass(w, scene.sphere.mass))
    out = {}
    for name, (eta, rho) in (("air", AIR), ("water", water(25.0))):
        zm = stokes_sphere(eta, rho, scene.sphere.radius, w)
        out[name] = float(f[np.argmax(np.abs(1 / (t[:, 0, 0] * zm + t[:, 0, 1])))])
    return out


def radial(model_dir: Path, threads: int) -> Suite:
    """The radial task's suite (module docstring)."""
    from wtml.baselines.radial import InversionRadial, PolynomialRadial
    from wtml.scenes.radial import ContactSpec
    from wtml.signals import complex_noise

    decoder, classical = load_export(model_dir, threads=threads)
    scene = scene_from_dict(decoder.meta.scene)
    lo, hi = scene.contact.distance_um
    span = hi - lo
    k_lo, k_hi = scene.contact.stiffness

    def contacts(distance_um, stiffness):
        variant = dataclasses.replace(scene, contact=ContactSpec(distance_um=distance_um,
                                                                 stiffness=stiffness))
        return lambda n, rng: variant.simulate(n, rng)

    def untouched(n: int, rng: np.random.Generator) -> dict:
        free = np.broadcast_to(scene.free_ze(), (n, len(scene.excitation.omega)))
        return {"ze": complex_noise(free, scene.noise.ze_relative, rng),
                "ref": complex_noise(free, scene.noise.reference_relative, rng),
                "distance": np.full(n, np.nan), "stiffness": np.zeros(n)}

    trained_k = (k_lo, k_hi)
    conditions = [
        Condition(f"d {lo + MIDDLE[0] * span:g}–{lo + MIDDLE[1] * span:g} µm (the middle)",
                  "mid", contacts((lo + MIDDLE[0] * span, lo + MIDDLE[1] * span), trained_k)),
        Condition(f"d {lo:g}–{lo + EDGE * span:g} µm (the tip's end)", "edge",
                  contacts((lo, lo + EDGE * span), trained_k)),
        Condition(f"d {hi - EDGE * span:g}–{hi:g} µm (the far end)", "edge",
                  contacts((hi - EDGE * span, hi), trained_k)),
        Condition(f"d {hi + 50:g}–{hi + 200:g} µm (beyond the far end)", "beyond",
                  contacts((hi + 50, hi + 200), trained_k)),
        Condition(f"soft contacts, k 10–100 N/m (trained {k_lo:g}–{k_hi:g}; Ze's antiresonance "
                  "in the band)", "extreme", contacts((lo, hi), (10.0, 100.0))),
        Condition("rigid contacts, k 1e7–1e9 N/m (clamped there)", "extreme",
                  contacts((lo, hi), (1e7, 1e9))),
        Condition("no contact (free tip, at resonance)", "extreme", untouched),
    ]
    # the classical graph's polynomial, refitted in float64 by the export's recipe (20000
    # records of the scene's seed, wtml.exporters.matrix.export_matrix)
    train = scene.simulate(20000, np.random.default_rng([scene.seed, 10**6]))
    poly = PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"])
    inversion = InversionRadial(scene)

    def onnx(model):
        return lambda rec: model.predict(rec["ze"], rec["ref"])

    methods = [Method("decoder ONNX", onnx(decoder))]
    thesis = model_dir.parent / "radial_thesis"
    if thesis.is_dir():
        methods.append(Method("thesis 2-10-1 ONNX", onnx(load_export(thesis,
                                                                     threads=threads)[0])))
    methods += [Method("polynomial Im Ze/ref numpy (float64)",
                       lambda rec: poly.predict(rec["ze"], rec["ref"])),
                Method("polynomial Im Ze/ref ONNX (float32)", onnx(classical)),
                Method("physics inversion", lambda rec: inversion.predict(rec["ze"], rec["ref"]))]

    def error(rec: dict, pred: dict) -> float:
        err = pred["distance"] - rec["distance"]
        return float(np.sqrt(np.mean(err**2))) if np.all(np.isfinite(rec["distance"])) \
            else float("nan")

    def answer(rec: dict, pred: dict) -> str:
        d = 1e6 * pred["distance"]
        return f"d median {np.median(d):.4g} µm, range {np.min(d):.4g}–{np.max(d):.4g} µm"

    f = np.linspace(0.8, 1.6, 801) * scene.excitation.frequencies_hz[0]
    peaks = [f[np.argmax(np.abs(_ze_at(scene, f, distance)))] for distance in (None, hi)]
    band = scene.excitation.frequencies_hz
    notes = (f"The free whisker's Ze peaks (antiresonance) at {peaks[0]:.0f} Hz, inside the "
             f"band {min(band):g}–{max(band):g} Hz; a contact at {hi:g} µm of the reference "
             f"stiffness moves the peak to {peaks[1]:.0f} Hz, a soft one little.",)
    return Suite("radial", "RMSE of d", "µm", 1e6, conditions, methods, error, answer,
                 (("polynomial Im Ze/ref ONNX (float32)", "polynomial Im Ze/ref numpy (float64)",
                   (("distance", 1e-8 * span),)),), notes)


def _ze_at(scene, frequency_hz: np.ndarray, distance_um: float | None) -> np.ndarray:
    """Ze (Ω) of ``scene``'s device at ``frequency_hz``: the free whisker's (``distance_um``
    None), or with a contact that far from the tip at the reference stiffness."""
    beam, omega = scene.transducer(), 2 * np.pi * frequency_hz
    t = (beam.transduction_matrix(omega) if distance_um is None else
         beam.contact_transduction_matrix(omega, [beam.length - 1e-6 * distance_um],
                                          scene.reference_stiffness())[0])
    return t[:, 0, 1] / t[:, 1, 1]


def onset(model_dir: Path, threads: int) -> Suite:
    """The onset task's suite (module docstring)."""
    from wtml.bench.onset_transfer import location_scores
    from wtml.exporters.onset import record_inputs

    decoder, classical = load_export(model_dir, threads=threads)
    scene = scene_from_dict(decoder.meta.scene)
    g_lo, g_hi = scene.wall.gap_fraction
    span = g_hi - g_lo
    k_lo, k_hi = scene.wall.stiffness

    def walls(fraction, stiffness=None, free: float = 0.0):
        wall = dataclasses.replace(scene.wall, gap_fraction=fraction, free_fraction=free,
                                   stiffness=stiffness or scene.wall.stiffness)
        variant = dataclasses.replace(scene, wall=wall)
        return lambda n, rng: variant.simulate(n, rng)

    def frac(a: float, b: float) -> tuple[float, float]:
        return round(a, 4), round(b, 4)

    conditions = [
        Condition("g {:.2f}–{:.2f} of the whisk's amplitude (the middle)".format(
            *frac(g_lo + MIDDLE[0] * span, g_lo + MIDDLE[1] * span)), "mid",
            walls(frac(g_lo + MIDDLE[0] * span, g_lo + MIDDLE[1] * span))),
        Condition("g {:.2f}–{:.2f} (the near end)".format(*frac(g_lo, g_lo + EDGE * span)),
                  "edge", walls(frac(g_lo, g_lo + EDGE * span))),
        Condition("g {:.2f}–{:.2f} (the far end)".format(*frac(g_hi - EDGE * span, g_hi)),
                  "edge", walls(frac(g_hi - EDGE * span, g_hi))),
        Condition("g {:.2f}–{:.2f} (below the range)".format(
            *frac(g_lo - 0.1 * span, g_lo - 0.02 * span)), "beyond",
            walls(frac(g_lo - 0.1 * span, g_lo - 0.02 * span))),
        Condition("g {:.2f}–{:.2f} (beyond the range, near the reach)".format(
            *frac(g_hi + 0.02 * span, g_hi + 0.1 * span)), "beyond",
            walls(frac(g_hi + 0.02 * span, g_hi + 0.1 * span))),
        Condition(f"soft walls, k 1–2 N/m (trained {k_lo:g}–{k_hi:g})", "extreme",
                  walls(frac(g_lo, g_hi), (1.0, 2.0))),
        Condition("stiff walls, k 50–500 N/m (near clamping the tip)", "extreme",
                  walls(frac(g_lo, g_hi), (50.0, 500.0))),
        Condition("no wall (free whisking)", "extreme", walls(frac(g_lo, g_hi), free=1.0)),
    ]

    def graph(model):
        return lambda rec: model.run(*record_inputs(rec))

    methods = [Method("decoder ONNX", graph(decoder)),
               Method("thesis pipeline ONNX", graph(classical))]

    def error(rec: dict, pred: dict) -> float:
        if not np.any(np.isfinite(rec["gap"])):
            return float("nan")
        return location_scores(pred["gap"], rec["gap"])["rmse"]

    def answer(rec: dict, pred: dict) -> str:
        found = np.isfinite(pred["gap"])
        if not np.any(np.isfinite(rec["gap"])):
            return f"a wall reported in {int(found.sum())} of {len(found)} records"
        missed = int(np.sum(np.isfinite(rec["gap"]) & ~found))
        return f"{missed} of {len(found)} walls not located" if missed else ""

    def answered(rec: dict, pred: dict) -> float:
        return float(np.mean(np.isfinite(pred["gap"])))

    return Suite("onset", "location RMSE (located walls)", "µm", 1e6, conditions, methods,
                 error, answer, (), ("g as a fraction of the whisk's amplitude HUE(0)·V "
                                     f"({1e6 * scene.whisk_amplitude_m():.2f} µm).",),
                 answered)


def texture(model_dir: Path, threads: int) -> Suite:
    """The texture task's suite (module docstring)."""
    from wtml.runtime.texture import run_windows, windows

    decoder, classical = load_export(model_dir, threads=threads)
    scene = scene_from_dict(decoder.meta.scene)
    window = decoder.meta.n_samples
    # a condition narrows the whisking range, and with it the scene's own calibration_hz
    calibration_hz = np.array(decoder.meta.calibration_hz)
    d, c = scene.drive, scene.contact
    ranges = {"whisk_v": d.whisk_v, "whisk_hz": d.whisk_hz, "normal_force": c.normal_force}
    units = {"whisk_v": ("V", 1.0), "whisk_hz": ("Hz", 1.0), "normal_force": ("mN", 1e3)}

    def middle(name: str) -> tuple[float, float]:
        lo, hi = ranges[name]
        return lo + MIDDLE[0] * (hi - lo), lo + MIDDLE[1] * (hi - lo)

    def variant(**fixed) -> object:
        values = {name: fixed.get(name, middle(name)) for name in ranges}
        return dataclasses.replace(
            scene, drive=dataclasses.replace(d, whisk_v=values["whisk_v"],
                                             whisk_hz=values["whisk_hz"]),
            contact=dataclasses.replace(c, normal_force=values["normal_force"]))

    def make(s):  # every grade, each record its own specimen; T at the graph's frequencies
        return functools.partial(s.simulate_independent, calibration_hz=calibration_hz)

    def label(name: str, pair: tuple[float, float], where: str) -> str:
        unit, factor = units[name]
        return (f"{name.replace('_', ' ')} {factor * pair[0]:.4g}–{factor * pair[1]:.4g} "
                f"{unit} ({where})")

    conditions = [Condition("amplitude, frequency, normal force in the middle fifth", "mid",
                            make(variant()))]
    for name, (lo, hi) in ranges.items():
        for pair, where in (((lo, lo + EDGE * (hi - lo)), "low end"),
                            ((hi - EDGE * (hi - lo), hi), "high end")):
            conditions.append(Condition(label(name, pair, where), "edge",
                                        make(variant(**{name: pair}))))
    lo, hi = d.whisk_v
    for pair, where in (((lo - 0.4 * (hi - lo), lo - 0.15 * (hi - lo)), "below the range"),
                        ((hi + 0.15 * (hi - lo), hi + 0.4 * (hi - lo)), "above the range")):
        conditions.append(Condition(label("whisk_v", pair, where), "beyond",
                                    make(variant(whisk_v=pair))))

    def graph(model):
        def run(rec: dict) -> dict:
            cut, owner = windows(np.stack([rec["e"], rec["i"]]), window)
            out = run_windows(model, cut[0], cut[1], rec["t"][owner])
            return {**out, "grade": np.argmax(out["probabilities"], 1), "owner": owner}
        return run

    methods = [Method("decoder ONNX", graph(decoder)),
               Method("thesis cues ONNX", graph(classical))]

    def error(rec: dict, pred: dict) -> float:
        return float(np.mean(pred["grade"] != rec["grade"][pred["owner"]]))

    def answer(rec: dict, pred: dict) -> str:
        return f"{len(pred['grade'])} windows"

    return Suite("texture", "share of windows misclassified", "%", 100.0, conditions, methods,
                 error, answer, (), (f"Windows of {window} samples; the other two nuisances "
                                     "in the middle fifth of their ranges.",))


SUITES = {"fluid": fluid, "radial": radial, "onset": onset, "texture": texture}
"""Each task's suite builder: ``(export folder, threads) -> Suite``."""
