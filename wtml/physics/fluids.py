"""Water and glycerol–water mixtures, 0–100 % glycerol by volume, 0–100 °C.

Viscosity after Cheng (2008), "Formula for the viscosity of a glycerol–water mixture",
Ind. Eng. Chem. Res. 47, 3285–3288 (T in °C, viscosities in mPa·s)::

    μw = 1.790 exp((-1230 - T) T / (36100 + 360 T))
    μg = 12100 exp((-1233 + T) T / (9900 + 70 T))
    a = 0.705 - 0.0017 T,   b = (4.9 + 0.036 T) a^2.5
    α = 1 - Cm + a b Cm (1 - Cm) / (a Cm + b (1 - Cm))
    μ = μw^α μg^(1 - α)

with Cm the glycerol mass fraction. Pure-component densities are Cheng's:
``ρg = 1277 - 0.654 T`` and ``ρw = 1000 (1 - |(T - 4)/622|^1.7)`` kg/m³; the mass fraction
follows from the volume fraction Cv of the unmixed components,
``Cm = ρg Cv / (ρg Cv + ρw (1 - Cv))``.

Density of the mixture: Volk & Kähler (2018), "Density model for aqueous glycerol solutions",
Exp. Fluids 59:75, which corrects ideal volume mixing for the contraction on mixing::

    ρ = κ (ρg Cv + ρw (1 - Cv)),   κ = 1 + A sin(Cv^1.31 π)^0.81,
    A = 1.78e-6 T² - 1.82e-4 T + 1.41e-2

It reproduces the thesis's Table 6.2 literature densities within 1.1 % (those carry three
significant digits). The thesis's Table 6.1 literature viscosities at 25 °C are reproduced
within 1 % (its 38 % and 67 % specimens are 3/8 and 2/3 by volume).
"""

from __future__ import annotations

import numpy as np

from wtml.physics.loads.sphere import fluid_from_zm
from wtml.physics.validation import check_range

__all__ = ["TABLES_6_1_6_2", "fluid_from_zm", "glycerol_density", "glycerol_viscosity",
           "glycerol_water", "water", "water_density", "water_viscosity"]

_T_RANGE = (0.0, 100.0)

TABLES_6_1_6_2 = {
    "cv": np.array([0.0, 0.25, 0.30, 3 / 8, 0.50, 0.60, 2 / 3, 0.75]),
    "eta": np.array([8.93e-4, 2.10e-3, 2.57e-3, 3.60e-3, 6.88e-3, 1.28e-2, 2.07e-2, 4.15e-2]),
    "rho": np.array([997.0, 1080.0, 1090.0, 1110.0, 1140.0, 1170.0, 1190.0, 1210.0]),
}
"""The thesis's "literature" columns at 25 °C: glycerol volume fraction (its 38 % and 67 %
specimens are 3/8 and 2/3), viscosity (Pa·s, Table 6.1) and density (kg/m³, Table 6.2)."""


def _temperature(temperature_c) -> np.ndarray:
    return check_range("temperature_c", temperature_c, *_T_RANGE, unit="°C")


def water_viscosity(temperature_c) -> np.ndarray:
    """Dynamic viscosity of water in Pa·s (Cheng 2008), for 0–100 °C."""
    t = _temperature(temperature_c)
    return 1e-3 * 1.790 * np.exp((-1230 - t) * t / (36100 + 360 * t))


def glycerol_viscosity(temperature_c) -> np.ndarray:
    """Dynamic viscosity of glycerol in Pa·s (Cheng 2008), for 0–100 °C."""
    t = _temperature(temperature_c)
    return 1e-3 * 12100 * np.exp((-1233 + t) * t / (9900 + 70 * t))


def water_density(temperature_c) -> np.ndarray:
    """Density of water in kg/m³ (Cheng 2008), for 0–100 °C."""
    t = _temperature(temperature_c)
    return 1000 * (1 - np.abs((t - 4) / 622) ** 1.7)


def glycerol_density(temperature_c) -> np.ndarray:
    """Density of glycerol in kg/m³ (Cheng 2008), for 0–100 °C."""
    t = _temperature(temperature_c)
    return 1277 - 0.654 * t


def water(temperature_c=25.0) -> tuple[np.ndarray, np.ndarray]:
    """``(eta, rho)`` of water in Pa·s and kg/m³."""
    return water_viscosity(temperature_c), water_density(temperature_c)


def glycerol_water(volume_fraction, temperature_c=25.0) -> tuple[np.ndarray, np.ndarray]:
    """Viscosity and density of a glycerol–water mixture.

    Args:
        volume_fraction: glycerol volume fraction Cv of the unmixed components, 0–1
            (0 is water, 1 is glycerol).
        temperature_c: temperature in °C, 0–100.

    Both broadcast together.

    Returns:
        ``(eta, rho)`` in Pa·s and kg/m³, the broadcast shape.
    """
    cv = check_range("volume_fraction", volume_fraction, 0.0, 1.0)
    t = _temperature(temperature_c)
    rho_g, rho_w = glycerol_density(t), water_density(t)
    cm = rho_g * cv / (rho_g * cv + rho_w * (1 - cv))
    a = 0.705 - 0.0017 * t
    b = (4.9 + 0.036 * t) * a**2.5
    alpha = 1 - cm + a * b * cm * (1 - cm) / (a * cm + b * (1 - cm))
    eta = water_viscosity(t) ** alpha * glycerol_viscosity(t) ** (1 - alpha)
    contraction = 1 + (1.78e-6 * t**2 - 1.82e-4 * t + 1.41e-2) * np.sin(cv**1.31 * np.pi) ** 0.81
    rho = contraction * (rho_g * cv + rho_w * (1 - cv))
    return eta, rho
