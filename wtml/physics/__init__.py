"""Physics core: pure numpy functions and small dataclasses, complex128, SI units.

Imports nothing from torch. See ``shared/physics.md`` for the equations and conventions.
"""

from wtml.lazy import lazy_exports

_WHERE = {
    "Calibration": "wtml.physics.calibration",
    "CalibrationError": "wtml.physics.calibration",
    "LumpedTransducer": "wtml.physics.lumped",
    "Structure": "wtml.physics.structure",
    "calibrate_free_clamped": "wtml.physics.calibration",
    "calibrate_least_squares": "wtml.physics.calibration",
    "calibrate_open_short": "wtml.physics.calibration",
    "cascade": "wtml.physics.twoport",
    "det_error": "wtml.physics.twoport",
    "displacement_per_charge": "wtml.physics.twoport",
    "displacement_per_voltage": "wtml.physics.twoport",
    "drive_velocity": "wtml.physics.twoport",
    "drive_voltage": "wtml.physics.twoport",
    "efficiency": "wtml.physics.twoport",
    "electrical_from_mechanical": "wtml.physics.twoport",
    "electrical_power": "wtml.physics.twoport",
    "force_per_charge": "wtml.physics.twoport",
    "force_per_voltage": "wtml.physics.twoport",
    "mechanical_from_electrical": "wtml.physics.twoport",
    "mechanical_power": "wtml.physics.twoport",
    "tip_mass": "wtml.physics.twoport",
    "ym_from_ze": "wtml.physics.twoport",
    "ze_from_zm": "wtml.physics.twoport",
    "zm_from_ze": "wtml.physics.twoport",
}
"""Each name this package exports and the module that holds it, imported on first use
(:mod:`wtml.lazy`)."""

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
