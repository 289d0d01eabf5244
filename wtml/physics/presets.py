"""Lumped single-mode stand-ins for the thesis's transducers (physics.md §7).

The beam model of the structure is a later piece of work; until then each preset here is a
lumped model (:class:`~wtml.physics.lumped.LumpedTransducer`) whose parameters are chosen,
not fitted, as follows.

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
"""

from __future__ import annotations

from wtml.constants import EPSILON_0
from wtml.physics.lumped import LumpedTransducer

MACRO_C0 = 3400 * EPSILON_0 * 46e-3 * 2.1e-3 / (2 * 0.2e-3)
"""Clamped capacitance of the macro bimorph, two 0.2 mm PZT layers in series, in F."""


def macro_lumped() -> LumpedTransducer:
    """The macro transducer with its clamp, as one mode at 36 Hz (see the module docstring)."""
    return LumpedTransducer.from_resonance(c0=MACRO_C0, phi=1e-5, m=2e-5, f0=36.0, q=30.0,
                                           tan_delta=0.02)
