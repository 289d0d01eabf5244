"""Lumped single-mode stand-ins for the thesis's transducers (physics.md §7).

Each is a lumped model (:class:`~wtml.physics.lumped.LumpedTransducer`), shipped as a device
file (``configs/devices/macro-lumped.yaml``, ``fluid-lumped.yaml``), whose parameters are
chosen, not fitted, as follows.

macro (§3.5, §4.1): bimorph 46×2.1 mm, two PZT layers of 0.2 mm, operated at 36 Hz, the
first resonance with the 2.3338 g clamp.

- ``c0 = ε33S A / (2 t) = 3400 ε0 · 46 mm · 2.1 mm / 0.4 mm = 7.27 nF``: the two PZT layers
  in series (Table 3.2's clamped permittivity; series poling assumed, the thesis does not say).
- ``tan_delta = 0.02``: a typical soft-PZT (PZT-5A class) loss tangent at low field from
  manufacturers' data sheets; the thesis gives none.
- ``f0 = 36 Hz`` (§3.5), ``q = 30`` (assumed; a lightly damped bimorph in air).
- ``m = 2e-5 kg`` modal mass referred to the whisker tip and ``phi = 1e-5 N/V``: chosen so that
  the tip moves ≈0.7 m/s (≈3 mm) at 10 V on resonance, and so that the thesis's calibration
  loads (|Zm| ≈ 7e-4–1e-3 N·s/m at 36 Hz) shift Ze by a few per cent, as in its Fig. 4.10.

fluid (§6.5): bimorph 46×2.1×0.6 mm, steel whisker 21 mm, glass sphere R = 1.9 mm carried at
the tip (as ``cascade(T_w, tip_mass(ω, ms))``, not part of this model). Two thesis numbers fix
the mechanics: the free resonance ≈100 Hz (with the sphere) and ≈96 Hz in water at 25 °C.
Water adds the sphere's fluid mass ``mf(96 Hz) = (2/3)πR³ρ + 3πR² sqrt(2ηρ/ω) = 1.62e-5 kg``,
so ``(m + ms)((100/96)² - 1) = mf`` gives ``m + ms = 1.90e-4 kg``; with the glass sphere
``ms = 2500 · (4/3)πR³ = 7.18e-5 kg`` (soda-lime glass, 2500 kg/m³, standard tables)
``m = 1.18e-4 kg``, and ``k = (m + ms)(2π·100 Hz)² = 75.0 N/m``. The rest is chosen:
``c0`` as the macro bimorph (same footprint and PZT), ``phi = 1.5e-4 N/V`` (coupling
``φ²/(k C0) ≈ 0.04``, typical of a bimorph), ``q = 50`` in air, ``tan_delta = 0.02``.
"""

from __future__ import annotations

import numpy as np

from wtml.constants import EPSILON_0
from wtml.devices import load_device
from wtml.physics.lumped import LumpedTransducer

MACRO_C0 = 3400 * EPSILON_0 * 46e-3 * 2.1e-3 / (2 * 0.2e-3)
"""Clamped capacitance of the macro bimorph, two 0.2 mm PZT layers in series, in F."""


def macro_lumped() -> LumpedTransducer:
    """The macro transducer with its clamp, as one mode at 36 Hz (see the module docstring):
    the shipped device ``macro-lumped``."""
    return load_device("macro-lumped").transducer()


FLUID_SPHERE_RADIUS = 1.9e-3
"""Glass sphere of the fluid sensor, radius in m."""
FLUID_SPHERE_MASS = 2500.0 * 4 / 3 * np.pi * FLUID_SPHERE_RADIUS**3
"""Its mass in kg (soda-lime glass, 2500 kg/m³)."""


def fluid_lumped() -> LumpedTransducer:
    """The fluid sensor's bimorph and whisker as one mode, sphere excluded (module docstring):
    with the sphere it resonates at 100 Hz free and ≈96 Hz in water: the shipped device
    ``fluid-lumped`` (``tests/test_devices.py`` derives its numbers again from the docstring's)."""
    return load_device("fluid-lumped").transducer()


FLUID_TOTAL_MASS = 1.9006e-4
"""kg: the fluid transducer's modal mass with the sphere, from the 100 Hz / 96 Hz pair."""


PRESETS = {"macro": macro_lumped, "fluid": fluid_lumped}
"""Lumped presets by name."""
