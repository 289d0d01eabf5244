"""Mechanical loads at the whisker tip; each has ``impedance(omega) -> Zm`` in N·s/m."""

from wtml.physics.loads.base import Load
from wtml.physics.loads.cantilever import CantileverPoint
from wtml.physics.loads.mass_spring_damper import MassSpringDamper
from wtml.physics.loads.sphere import SphereInFluid, fluid_from_zm, stokes_sphere
from wtml.physics.loads.whisker_contact import WhiskerContact

__all__ = [
    "CantileverPoint",
    "Load",
    "MassSpringDamper",
    "SphereInFluid",
    "WhiskerContact",
    "fluid_from_zm",
    "stokes_sphere",
]
