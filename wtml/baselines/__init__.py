"""Baselines: the classical matrix paths and fits, with the decoders' predict interface."""

from wtml.baselines.fluid_classical import ClassicalFluid, band_design, band_pseudo_inverse

__all__ = ["ClassicalFluid", "band_design", "band_pseudo_inverse"]
