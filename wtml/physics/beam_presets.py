"""The thesis's transducers as beam models (physics.md §7), and how well they fit the thesis.

Each preset is a row of data below. What the thesis gives is used as given; what it does not
give is stated with its source or its assumption, and one free parameter per preset, the
bimorph's free length (the thesis gives the bimorph's length, not how much of it sits in the
clamp), is fitted to one thesis resonance within a plausible range (50–100 % of the bimorph).
Everything else the thesis reports is then a prediction, listed in :func:`fidelity_table`.

Assumptions (not in the thesis):
- layer stacks: macro PZT 0.2 / carbon fibre 0.15 / PZT 0.2 mm (§3.5, given); fluid
  PZT 0.2 / carbon fibre 0.2 / PZT 0.2 mm (total 0.6 mm given); micro two PZT layers of
  0.25 mm and no shim (total 0.5 mm given); series poling throughout;
- micro whisker 50×50 µm square steel (given), modelled as a square section;
- the macro epoxy block 3×2.1×0.5 mm (given) sits at the bimorph's free end;
- losses: structural loss factor 0.02 and tanδ 0.02 (soft-PZT class data sheets);
- tungsten E = 411 GPa, ρ = 19300 kg/m³; soda-lime glass 2500 kg/m³; polystyrene 1050 kg/m³
  (standard handbook values).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.optimize import least_squares

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

STEEL = (185e9, 7900.0)
CARBON_FIBRE = (20e9, 7600.0)  # Table 3.3 as restated in physics.md §7
EPOXY = (3.5e9, 1000.0)
TUNGSTEN = (411e9, 19300.0)
LOSS = 0.02
TAN_DELTA = 0.02

PRESETS: dict[str, dict] = {
    "macro": dict(bimorph=dict(length=46e-3, width=2.1e-3, t_piezo=0.2e-3, t_substrate=0.15e-3,
                               substrate=CARBON_FIBRE),
                  block=dict(length=3e-3, width=2.1e-3, thickness=0.5e-3, material=EPOXY),
                  whisker=dict(kind="round", length=61e-3, size=0.15e-3, material=STEEL),
                  clamp=dict(position=41e-3, mass=2.3338e-3),
                  fit=dict(parameters=("bimorph", "whisker"),
                           ranges=((23e-3, 46e-3), (50e-3, 61e-3)),
                           targets=(("bare", 53.5), ("clamp", 36.0)))),
    "micro": dict(bimorph=dict(length=32e-3, width=0.5e-3, t_piezo=0.25e-3, t_substrate=0.0,
                               substrate=(1.0, 1.0)),
                  whisker=dict(kind="square", length=5e-3, size=50e-6, material=STEEL),
                  fit=dict(parameters=("bimorph",), ranges=((16e-3, 32e-3),),
                           targets=(("bare", 400.0),))),
    "fluid": dict(bimorph=dict(length=46e-3, width=2.1e-3, t_piezo=0.2e-3, t_substrate=0.2e-3,
                               substrate=CARBON_FIBRE),
                  whisker=dict(kind="round", length=21e-3, size=0.3e-3, material=STEEL),
                  sphere=dict(radius=1.9e-3, density=2500.0),
                  fit=dict(parameters=("bimorph",), ranges=((23e-3, 46e-3),),
                           targets=(("sphere", 100.0),))),
    "micro-fluid": dict(bimorph=dict(length=32e-3, width=0.5e-3, t_piezo=0.25e-3,
                                     t_substrate=0.0, substrate=(1.0, 1.0)),
                        whisker=dict(kind="round", length=3.2e-3, size=50e-6, material=TUNGSTEN),
                        sphere=dict(radius=340e-6, density=1050.0),
                        fit=dict(parameters=("bimorph",), ranges=((16e-3, 32e-3),),
                                 targets=(("sphere", 400.0),))),
}
"""Preset data, SI units."""


def _whisker(spec: dict, loss: float) -> Segment:
    e, rho = spec["material"]
    if spec["kind"] == "round":
        return round_rod("whisker", spec["length"], spec["size"], e, rho, loss_factor=loss,
                         elements=8)
    return rectangular("whisker", spec["length"], spec["size"], spec["size"], e, rho,
                       loss_factor=loss, elements=8)


def sphere_mass(name: str) -> float:
    """Mass of the preset's tip sphere in kg (0 without one)."""
    s = PRESETS[name].get("sphere")
    return 0.0 if s is None else s["density"] * 4 / 3 * np.pi * s["radius"] ** 3


def build(name: str, fit_values: tuple[float, ...] | None = None, *, with_clamp: bool = True,
          factors: Mapping[str, float] | None = None) -> BeamTransducer:
    """The preset as a beam model; ``fit_values`` (m, the fitted lengths in the order of
    ``PRESETS[name]["fit"]["parameters"]``) default to the fitted ones. ``factors``: a
    device off the preset, each named parameter of :func:`device_parameters` times its
    factor (1 where not given; ``wtml.physics.spread`` draws them)."""
    if name not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {name!r}")
    p = PRESETS[name]
    unknown = sorted(set(factors or {}) - set(device_parameters(name)))
    if unknown:
        raise ValueError(f"factors: {unknown[0]!r} is not a parameter of preset {name!r}; "
                         f"allowed: {sorted(device_parameters(name))}")

    def f(key: str) -> float:
        return 1.0 if factors is None else float(factors.get(key, 1.0))

    values = dict(zip(p["fit"]["parameters"],
                      fitted_values(name) if fit_values is None else fit_values, strict=True))
    b = p["bimorph"]
    length = values.get("bimorph", b["length"]) * f("bimorph.length")
    loss = LOSS * f("loss_factor")
    piezo = PiezoMaterial(d31=PiezoMaterial.d31 * f("coupling"),
                          s11e=PiezoMaterial.s11e / f("bimorph.modulus"))
    substrate = (b["substrate"][0] * f("substrate.modulus"), b["substrate"][1])
    segs = [bimorph("bimorph", length, b["width"], b["t_piezo"] * f("bimorph.thickness"),
                    b["t_substrate"] * f("bimorph.thickness"), *substrate, piezo=piezo,
                    loss_factor=loss, elements=12)]
    if "block" in p:
        k = p["block"]
        segs.append(rectangular("block", k["length"] * f("block.length"), k["width"],
                                k["thickness"] * f("block.thickness"),
                                k["material"][0] * f("block.modulus"), k["material"][1],
                                loss_factor=loss, elements=2))
    w = p["whisker"] | ({"length": values["whisker"]} if "whisker" in values else {})
    segs.append(_whisker(w | {"length": w["length"] * f("whisker.length"),
                              "size": w["size"] * f("whisker.thickness"),
                              "material": (w["material"][0] * f("whisker.modulus"),
                                           w["material"][1])}, loss))
    masses = ()
    if with_clamp and "clamp" in p:
        # the thesis measures the clamp from the bimorph's fixed end, i.e. the holder
        offset = b["length"] - length
        masses = (PointMass(p["clamp"]["position"] - offset, p["clamp"]["mass"]),)
    return BeamTransducer(tuple(segs), masses, tan_delta=TAN_DELTA * f("tan_delta"))


def device_parameters(name: str) -> dict[str, str]:
    """The preset's parameters that a built device may differ in, each with its class (a
    field of ``wtml.physics.spread.DeviceSpread``): each segment's length and bending
    thickness (the bimorph's free length, and its layers together), each material's Young's
    modulus (the PZT's 1/s11E), the structural loss factor (all segments), tanδ and the piezo
    coupling (d31)."""
    p = PRESETS[name]
    segments = ["bimorph"] + ["block"] * ("block" in p) + ["whisker"]
    out = {f"{s}.{q}": cls for s in segments
           for q, cls in (("length", "length"), ("thickness", "thickness"),
                          ("modulus", "modulus"))}
    if p["bimorph"]["t_substrate"] > 0:
        out["substrate.modulus"] = "modulus"
    return out | {"loss_factor": "loss_factor", "tan_delta": "tan_delta",
                  "coupling": "coupling"}


def resonance(name: str, condition: str, fit_values: tuple[float, ...] | None = None) -> float:
    """First natural frequency in Hz: ``"bare"``, ``"clamp"`` (with the macro clamp) or
    ``"sphere"`` (with the tip sphere as a point mass)."""
    tr = build(name, fit_values, with_clamp=condition == "clamp")
    if condition == "sphere":
        tr = BeamTransducer(tr.segments, tr.masses + (PointMass(tr.length, sphere_mass(name)),),
                            tr.tan_delta)
    return float(tr.natural_frequencies(1)[0])


_FITTED: dict[str, tuple[float, ...]] = {}


def fitted_values(name: str) -> tuple[float, ...]:
    """The preset's fitted lengths (m): least squares of the relative misses of its target
    resonances, within the stated ranges."""
    if name not in _FITTED:
        fit = PRESETS[name]["fit"]
        lo, hi = np.array(fit["ranges"]).T

        def misses(x: np.ndarray) -> np.ndarray:
            return np.array([resonance(name, cond, tuple(x)) / hz - 1
                             for cond, hz in fit["targets"]])

        sol = least_squares(misses, (lo + hi) / 2, bounds=(lo, hi), x_scale=hi - lo,
                            xtol=1e-12, ftol=1e-12)
        _FITTED[name] = tuple(float(v) for v in sol.x)
    return _FITTED[name]


def _motional_peak(tr: BeamTransducer, sphere: float, f: np.ndarray, zm) -> float:
    omega = 2 * np.pi * f
    t = cascade(tr.transduction_matrix(omega), tip_mass(omega, sphere))
    motional = np.abs(1 / ze_from_zm(t, zm) - 1j * omega * tr.capacitance)
    return float(f[np.argmax(motional)])


def fidelity_table() -> list[dict]:
    """Computed against thesis numbers: one row per compared quantity."""
    labels = {"bare": "1st resonance", "clamp": "1st resonance with the clamp",
              "sphere": "1st resonance with the sphere"}
    rows = []
    for name, p in PRESETS.items():
        fit = p["fit"]
        for param, value, (lo, hi) in zip(fit["parameters"], fitted_values(name), fit["ranges"],
                                          strict=True):
            rows.append({"preset": name, "quantity": f"{param} free length (fitted)",
                         "computed": f"{1e3 * value:.2f} mm",
                         "thesis": f"not given; range allowed {1e3 * lo:.0f}–{1e3 * hi:.0f} mm"})
        for cond, hz in fit["targets"]:
            got = resonance(name, cond)
            rows.append({"preset": name, "quantity": f"{labels[cond]} (fit target)",
                         "computed": f"{got:.2f} Hz ({100 * (got / hz - 1):+.2f} %)",
                         "thesis": f"≈{hz:g} Hz"})
        tr = build(name)
        if name == "micro":
            rows.append({"preset": name, "quantity": "static tip displacement per volt",
                         "computed": f"{1e6 * tr.static_tip_displacement_per_volt():.3f} µm/V",
                         "thesis": "1.20 µm/V"})
        if name == "fluid":
            sphere = sphere_mass(name)
            with_sphere = BeamTransducer(tr.segments, (PointMass(tr.length, sphere),),
                                         tr.tan_delta)
            rows.append({"preset": name, "quantity": "2nd resonance with the sphere",
                         "computed": f"{with_sphere.natural_frequencies(2)[1]:.1f} Hz",
                         "thesis": "≈500 Hz"})
            f = np.linspace(85, 105, 4001)
            zm = stokes_sphere(*water(25.0), p["sphere"]["radius"], 2 * np.pi * f)
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


__all__ = ["PRESETS", "build", "device_parameters", "fidelity_table", "fitted_values",
           "format_fidelity", "resonance", "sphere_mass"]
