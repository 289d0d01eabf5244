"""The thesis's transducers as beam models (physics.md §7), and how well they fit the thesis.

Each preset is a shipped device file (``configs/devices/<name>.yaml``, read by
:mod:`wtml.devices`); :func:`build` turns any beam device into its beam model. What the thesis
gives is used as given; what it does not give is stated with its source or its assumption, and
one free parameter per preset, the bimorph's free length (the thesis gives the bimorph's length,
not how much of it sits in the clamp), is fitted to one thesis resonance within a plausible
range (50–100 % of the bimorph); the files hold the fitted values and, as their provenance,
the ranges and targets (:func:`refit` does it again). Everything else the thesis reports is
then a prediction, listed in :func:`fidelity_table`.

Assumptions (not in the thesis):
- layer stacks: macro PZT 0.2 / carbon fibre 0.15 / PZT 0.2 mm (§3.5, given); fluid
  PZT 0.2 / carbon fibre 0.2 / PZT 0.2 mm (total 0.6 mm given); micro two PZT layers of
  0.25 mm and no shim (total 0.5 mm given); series poling throughout;
- micro whisker 50×50 µm square steel (given), modelled as a square section;
- the macro epoxy block 3×2.1×0.5 mm (given) sits at the bimorph's free end;
- losses: structural loss factor 0.02 and tanδ 0.02 (soft-PZT class data sheets);
- tungsten E = 411 GPa, ρ = 19300 kg/m³; soda-lime glass 2500 kg/m³; polystyrene 1050 kg/m³
  (standard handbook values);
- a round whisker's ``size`` is its radius (physics.md §7's r), a square one's its side.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping

import numpy as np
from scipy.optimize import least_squares

from wtml.devices import BeamDevice, Provenance, Whisker, load_device
from wtml.physics import cascade, tip_mass, ze_from_zm
from wtml.physics.beam import (
    BeamTransducer,
    PiezoMaterial,
    PointMass,
    Segment,
    bimorph,
    rectangular,
    round_rod,
)
from wtml.physics.fluids import water
from wtml.physics.loads import stokes_sphere

THESIS_DEVICES = ("macro", "micro", "fluid", "micro-fluid")
"""The thesis's transducers, shipped as device files (``configs/devices``), in the fidelity
table's order."""
PRESETS = THESIS_DEVICES
"""The names a scene's ``preset:`` (the key before ``device:``) accepts."""


WHISKER_ELEMENTS = 8
"""The whisker's finite elements unless a scene asks for more (:func:`whisker_mesh_error`):
the macro WT's modes below 5 kHz within 0.4 % of a mesh eight times as fine, the micro WT's
below 50 kHz within 0.01 %; the macro WT's modes 13-22 (9.6-29 kHz), which texture's grains
ring, are 1.5-12 % high at this count."""


def _whisker(w: Whisker, loss: float, elements: int) -> Segment:
    e, rho = w.material.modulus, w.material.density
    if w.section == "round":
        return round_rod("whisker", w.length, w.size, e, rho, loss_factor=loss,
                         elements=elements)
    return rectangular("whisker", w.length, w.size, w.size, e, rho, loss_factor=loss,
                       elements=elements)


def beam_device(device: BeamDevice | str) -> BeamDevice:
    """``device`` itself, or the shipped (or file) device it names; a lumped one is refused."""
    if isinstance(device, BeamDevice):
        return device
    got = load_device(device)
    if not isinstance(got, BeamDevice):
        raise ValueError(f"device {got.name!r} is a {got.kind} device; a beam one is needed")
    return got


def sphere_mass(device: BeamDevice | str) -> float:
    """Mass of the device's tip sphere in kg (0 without one)."""
    d = beam_device(device)
    return 0.0 if d.sphere is None else d.sphere.mass


def build(device: BeamDevice | str, fit_values: tuple[float, ...] | None = None, *,
          with_clamp: bool = True, factors: Mapping[str, float] | None = None,
          whisker_elements: int = WHISKER_ELEMENTS) -> BeamTransducer:
    """The device as a beam model (a :class:`~wtml.devices.BeamDevice`, or a shipped device's
    name or a device file's path). ``fit_values`` (m) replace the lengths its provenance
    fitted, in the order of ``provenance.free``. ``whisker_elements``: the whisker's finite
    elements (the bimorph has 12, a block 2). ``factors``: a device off this one, each named
    parameter of :func:`device_parameters` times its factor (1 where not given;
    ``wtml.physics.spread`` draws them, ``wtml.physics.identify`` fits them)."""
    d = beam_device(device)
    if fit_values is not None:
        d = d.with_lengths(dict(zip([f.name for f in d.provenance.free], fit_values,
                                    strict=True)))
    unknown = sorted(set(factors or {}) - set(fit_parameters(d)))
    if unknown:
        raise ValueError(f"factors: {unknown[0]!r} is not a parameter of device {d.name!r}; "
                         f"allowed: {sorted(fit_parameters(d))}")

    def f(key: str) -> float:
        return 1.0 if factors is None else float(factors.get(key, 1.0))

    b = d.bimorph
    length = b.free_length * f("bimorph.length")
    loss = d.losses.loss_factor * f("loss_factor")
    piezo = PiezoMaterial(d31=d.piezo.d31 * f("coupling"),
                          s11e=d.piezo.s11e / f("bimorph.modulus"), eps33s=d.piezo.eps33s,
                          density=d.piezo.density)
    segs = [bimorph("bimorph", length, b.width, b.t_piezo * f("bimorph.thickness"),
                    b.t_substrate * f("bimorph.thickness"),
                    b.substrate.modulus * f("substrate.modulus"), b.substrate.density,
                    piezo=piezo, loss_factor=loss, elements=12)]
    if d.block is not None:
        k = d.block
        segs.append(rectangular("block", k.length * f("block.length"), k.width,
                                k.thickness * f("block.thickness"),
                                k.material.modulus * f("block.modulus"), k.material.density,
                                loss_factor=loss, elements=2))
    w = d.whisker
    segs.append(_whisker(dataclasses.replace(
        w, length=w.length * f("whisker.length"), size=w.size * f("whisker.thickness"),
        material=dataclasses.replace(w.material,
                                     modulus=w.material.modulus * f("whisker.modulus"))),
        (d.losses.loss_factor if d.losses.whisker is None else d.losses.whisker)
        * f("loss_factor") * f("whisker.loss_factor"), whisker_elements))
    masses = ()
    if with_clamp and d.clamp is not None:
        # the thesis measures the clamp from the bimorph's fixed end, i.e. the holder
        offset = b.length - length
        masses = (PointMass(d.clamp.position - offset, d.clamp.mass),)
    return BeamTransducer(tuple(segs), masses, tan_delta=d.losses.tan_delta * f("tan_delta"))


@functools.lru_cache(maxsize=64)
def whisker_mesh_error(device: BeamDevice | str, top_hz: float, whisker_elements: int
                       ) -> float:
    """How far (relative) the device's natural frequencies below ``top_hz`` (Hz) move when
    its whisker's ``whisker_elements`` are doubled: the whisker's discretisation error over a
    band (the macro WT below 25.6 kHz: 0.12 at 8 elements, 6e-4 at 32). Kept per process
    (a frozen device, a float): every texture scene's load checks it, 35-50 ms each, and a
    generation worker loads the same scene for every shard."""
    coarse, fine = (build(device, whisker_elements=k) for k in (whisker_elements,
                                                                2 * whisker_elements))
    count = len(coarse.matrices()[2])  # every mode of the coarse mesh
    low, high = coarse.natural_frequencies(count), fine.natural_frequencies(count)
    kept = high < top_hz
    return float(np.max(np.abs(low[kept] / high[kept] - 1), initial=0.0))


def device_parameters(device: BeamDevice | str) -> dict[str, str]:
    """The device's parameters that a built device may differ in, each with its class (a
    field of ``wtml.physics.spread.DeviceSpread``): each segment's length and bending
    thickness (the bimorph's free length, and its layers together), each material's Young's
    modulus (the PZT's 1/s11E), the structural loss factor (all segments), tanδ and the piezo
    coupling (d31)."""
    d = beam_device(device)
    segments = ["bimorph"] + ["block"] * (d.block is not None) + ["whisker"]
    out = {f"{s}.{q}": cls for s in segments
           for q, cls in (("length", "length"), ("thickness", "thickness"),
                          ("modulus", "modulus"))}
    if d.bimorph.t_substrate > 0:
        out["substrate.modulus"] = "modulus"
    return out | {"loss_factor": "loss_factor", "tan_delta": "tan_delta",
                  "coupling": "coupling"}


def apply_factors(device: BeamDevice | str, factors: Mapping[str, float]) -> BeamDevice:
    """The device file of a device off ``device``: each named parameter of
    :func:`device_parameters` times its factor, written into the values, so that
    ``build(apply_factors(d, f))`` is ``build(d, factors=f)`` (what an identified device is
    saved as)."""
    d = beam_device(device)
    unknown = sorted(set(factors) - set(fit_parameters(d)))
    if unknown:
        raise ValueError(f"factors: {unknown[0]!r} is not a parameter of device {d.name!r}; "
                         f"allowed: {sorted(fit_parameters(d))}")

    def f(key: str) -> float:
        return float(factors.get(key, 1.0))

    whisker_loss = d.losses.whisker
    if whisker_loss is not None or "whisker.loss_factor" in factors:
        whisker_loss = ((d.losses.loss_factor if whisker_loss is None else whisker_loss)
                        * f("loss_factor") * f("whisker.loss_factor"))

    rep = dataclasses.replace
    b = d.bimorph
    bim = rep(b, free_length=b.free_length * f("bimorph.length"),
              t_piezo=b.t_piezo * f("bimorph.thickness"),
              t_substrate=b.t_substrate * f("bimorph.thickness"),
              substrate=rep(b.substrate, modulus=b.substrate.modulus * f("substrate.modulus")))
    if bim.free_length > bim.length:  # the free length is what the model sees
        bim = rep(bim, length=bim.free_length)
    w = d.whisker
    whisker = rep(w, length=w.length * f("whisker.length"), size=w.size * f("whisker.thickness"),
                  material=rep(w.material, modulus=w.material.modulus * f("whisker.modulus")))
    block = d.block
    if block is not None:
        block = rep(block, length=block.length * f("block.length"),
                    thickness=block.thickness * f("block.thickness"),
                    material=rep(block.material,
                                 modulus=block.material.modulus * f("block.modulus")))
    clamp = d.clamp
    if clamp is not None:  # measured from the bimorph's fixed end, which moved if it grew
        clamp = rep(clamp, position=clamp.position + (bim.length - b.length))
    return rep(d, bimorph=bim, whisker=whisker, block=block, clamp=clamp,
               piezo=rep(d.piezo, d31=d.piezo.d31 * f("coupling"),
                         s11e=d.piezo.s11e / f("bimorph.modulus")),
               losses=rep(d.losses, loss_factor=d.losses.loss_factor * f("loss_factor"),
                          tan_delta=d.losses.tan_delta * f("tan_delta"), whisker=whisker_loss),
               provenance=Provenance(source=f"{d.name} with factors "
                                            f"{ {k: round(v, 6) for k, v in factors.items()} }"))


def fit_parameters(device: BeamDevice | str) -> list[str]:
    """What :func:`build`'s factors may name: :func:`device_parameters` (the manufacturing
    spread's) and ``whisker.loss_factor``, the whisker's own loss, which identification may
    need and the spread does not draw."""
    return [*device_parameters(device), "whisker.loss_factor"]


def resonance(device: BeamDevice | str, condition: str,
              fit_values: tuple[float, ...] | None = None) -> float:
    """First natural frequency in Hz: ``"bare"``, ``"clamp"`` (with the clamp mass) or
    ``"sphere"`` (with the tip sphere as a point mass)."""
    tr = build(device, fit_values, with_clamp=condition == "clamp")
    if condition == "sphere":
        tr = BeamTransducer(tr.segments,
                            tr.masses + (PointMass(tr.length, sphere_mass(device)),),
                            tr.tan_delta)
    return float(tr.natural_frequencies(1)[0])


def refit(device: BeamDevice | str) -> tuple[float, ...]:
    """The lengths of the device's provenance fitted again (m, in the order of
    ``provenance.free``): least squares of the relative misses of its target resonances,
    within the stated ranges, from the middle of the ranges. For a shipped thesis device this
    is how its file's values were made (``tests/test_devices.py`` checks they agree)."""
    d = beam_device(device)
    free, targets = d.provenance.free, d.provenance.targets
    if not free or len(targets) < len(free):
        raise ValueError(f"device {d.name!r}: its provenance fits {len(free)} lengths to "
                         f"{len(targets)} resonances; nothing to refit")
    lo = np.array([f.low for f in free])
    hi = np.array([f.high for f in free])

    def misses(x: np.ndarray) -> np.ndarray:
        return np.array([resonance(d, t.condition, tuple(x)) / t.hz - 1 for t in targets])

    sol = least_squares(misses, (lo + hi) / 2, bounds=(lo, hi), x_scale=hi - lo,
                        xtol=1e-12, ftol=1e-12)
    return tuple(float(v) for v in sol.x)


def _motional_peak(tr: BeamTransducer, sphere: float, f: np.ndarray, zm) -> float:
    omega = 2 * np.pi * f
    t = cascade(tr.transduction_matrix(omega), tip_mass(omega, sphere))
    motional = np.abs(1 / ze_from_zm(t, zm) - 1j * omega * tr.capacitance)
    return float(f[np.argmax(motional)])


def fidelity_table() -> list[dict]:
    """Computed against thesis numbers: one row per compared quantity, for each of
    :data:`THESIS_DEVICES` (the fitted lengths refitted from each file's provenance)."""
    labels = {"bare": "1st resonance", "clamp": "1st resonance with the clamp",
              "sphere": "1st resonance with the sphere"}
    rows = []
    for name in THESIS_DEVICES:
        d = beam_device(name)
        for free, value in zip(d.provenance.free, refit(d), strict=True):
            rows.append({"preset": name,
                         "quantity": f"{free.name.split('.')[0]} free length (fitted)",
                         "computed": f"{1e3 * value:.2f} mm",
                         "thesis": f"not given; range allowed {1e3 * free.low:.0f}–"
                                   f"{1e3 * free.high:.0f} mm"})
        for t in d.provenance.targets:
            got = resonance(d, t.condition)
            rows.append({"preset": name, "quantity": f"{labels[t.condition]} (fit target)",
                         "computed": f"{got:.2f} Hz ({100 * (got / t.hz - 1):+.2f} %)",
                         "thesis": f"≈{t.hz:g} Hz"})
        tr = build(d)
        if name == "micro":
            rows.append({"preset": name, "quantity": "static tip displacement per volt",
                         "computed": f"{1e6 * tr.static_tip_displacement_per_volt():.3f} µm/V",
                         "thesis": "1.20 µm/V"})
        if name == "fluid":
            sphere = sphere_mass(d)
            with_sphere = BeamTransducer(tr.segments, (PointMass(tr.length, sphere),),
                                         tr.tan_delta)
            rows.append({"preset": name, "quantity": "2nd resonance with the sphere",
                         "computed": f"{with_sphere.natural_frequencies(2)[1]:.1f} Hz",
                         "thesis": "≈500 Hz"})
            f = np.linspace(85, 105, 4001)
            zm = stokes_sphere(*water(25.0), d.sphere.radius, 2 * np.pi * f)
            rows.append({"preset": name, "quantity": "resonance in water, 25 °C",
                         "computed": f"{_motional_peak(tr, sphere, f, zm):.2f} Hz",
                         "thesis": "≈96 Hz"})
    return rows


def format_fidelity(rows: list[dict]) -> str:
    """The fidelity table as markdown."""
    lines = ["| preset | quantity | computed | thesis |", "|---|---|---|---|"]
    lines += [f"| {r['preset']} | {r['quantity']} | {r['computed']} | {r['thesis']} |"
              for r in rows]
    return "\n".join(lines)


__all__ = ["PRESETS", "THESIS_DEVICES", "apply_factors", "beam_device", "build",
           "device_parameters", "fidelity_table", "fit_parameters", "format_fidelity", "refit",
           "resonance", "sphere_mass"]
