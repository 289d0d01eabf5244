"""Physics core: pure numpy functions and small dataclasses, complex128, SI units.

Imports nothing from torch. See ``shared/physics.md`` for the equations and conventions.
"""

from wtml.physics.calibration import (
    Calibration,
    CalibrationError,
    calibrate_free_clamped,
    calibrate_least_squares,
    calibrate_open_short,
)
from wtml.physics.lumped import LumpedTransducer
from wtml.physics.structure import Structure
from wtml.physics.twoport import (
    cascade,
    det_error,
    displacement_per_charge,
    displacement_per_voltage,
    drive_velocity,
    drive_voltage,
    efficiency,
    electrical_from_mechanical,
    electrical_power,
    force_per_charge,
    force_per_voltage,
    mechanical_from_electrical,
    mechanical_power,
    tip_mass,
    ym_from_ze,
    ze_from_zm,
    zm_from_ze,
)

__all__ = [
    "Calibration",
    "CalibrationError",
    "LumpedTransducer",
    "Structure",
    "calibrate_free_clamped",
    "calibrate_least_squares",
    "calibrate_open_short",
    "cascade",
    "det_error",
    "displacement_per_charge",
    "displacement_per_voltage",
    "drive_velocity",
    "drive_voltage",
    "efficiency",
    "electrical_from_mechanical",
    "electrical_power",
    "force_per_charge",
    "force_per_voltage",
    "mechanical_from_electrical",
    "mechanical_power",
    "tip_mass",
    "ym_from_ze",
    "ze_from_zm",
    "zm_from_ze",
]
