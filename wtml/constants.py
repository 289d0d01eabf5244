"""Physical constants and literal types shared across wtml (SI units throughout)."""

from typing import Literal

EPSILON_0 = 8.8541878128e-12
"""Vacuum permittivity, in F/m."""

SignRule = Literal["continuity", "re_t11_positive"]
"""How the overall sign of a calibrated T is fixed (see ``wtml.physics.calibration``)."""

CantileverModel = Literal["beam", "quasi_static"]
"""Point-impedance model of a calibration cantilever (see ``wtml.physics.loads.cantilever``)."""

BOLTZMANN = 1.380649e-23
"""Boltzmann's constant, in J/K."""
