"""A preset's manufacturing spread: built devices drawn around its nominal values (physics.md §12).

A built transducer differs from its drawing. :class:`DeviceSpread` states by how much, per
class of parameter, as the relative half-width of a uniform tolerance band (a part within
±w of its nominal value, every value in the band equally likely: std ``w/√3``). The named
parameters of each preset and their classes are ``beam_presets.device_parameters``: each
segment's length (the bimorph's free length, the block's, the whisker's) and bending
thickness (the bimorph's layers together, the whisker's side or radius), each material's
Young's modulus (the PZT's 1/s11E, the substrate's, the whisker's), the structural loss factor
(one for all segments), tanδ, and the piezo coupling (d31). Each parameter is drawn
independently within its band; a fitted device's parameters can instead (or also) be drawn
from the fit's Gaussian posterior, correlated (``DeviceSpread.posterior``). Densities, widths
and the clamp are kept nominal.

Assembling a beam model takes ~1 ms, so a scene draws a finite set of devices per call
(:attr:`DeviceSpread.devices`, a few hundred) and assigns its records to them at random;
:func:`device_ze` then evaluates every device's free Ze and every record's contact with one
batched inverse per device (``wtml.physics.beam.device_forms``), a few devices at a time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wtml.devices import BeamDevice
from wtml.physics.beam import BeamTransducer, contact_transduction_matrices, device_forms
from wtml.physics.beam_presets import beam_device, build, device_parameters, fit_parameters
from wtml.schema import SceneError, field_range, omitted_when_empty

DEVICE_CHUNK = 64
"""Devices whose beam inverses :func:`device_ze` holds at once."""


def _width(high: float, default=0.0):
    """A field in [0, high], validated by ``wtml.schema.build`` like one made by its
    ``bounded`` (which this module cannot import: ``wtml.scenes`` imports it)."""
    return field(default=default, metadata={"range": (0.0, high)})


CLASSES = ("length", "thickness", "modulus", "loss_factor", "tan_delta", "coupling")
"""The spread's classes of parameter (the fields of :class:`DeviceSpread` that are widths)."""
POSTERIOR_MAX = 0.2
"""The widest relative standard deviation (posterior × standard error) a posterior spread
draws Gaussian factors with: at 0.2, a factor at or below 0 is 5 standard deviations away."""


@dataclass(frozen=True)
class DeviceSpread:
    """Relative half-widths of uniform tolerance bands around a preset (module docstring).
    All zero (the default): every device is the preset itself.

    Attributes:
        length: each segment's length (bimorph free length, block, whisker); issue 21:
            0.005–0.01.
        thickness: each segment's bending thickness (the bimorph's layers, the whisker's
            side or radius); 0.005–0.01.
        modulus: each material's Young's modulus (PZT 1/s11E, substrate, block, whisker);
            ~0.03.
        loss_factor: the structural loss factor η of every segment; ~0.25.
        tan_delta: the dielectric loss tangent; ~0.25.
        coupling: the piezo coupling d31; ~0.03.
        posterior: for a fitted device (``wtml device fit``'s file, whose provenance holds
            the fit's :class:`~wtml.devices.Posterior`): each device's fitted parameters also
            drawn from the fit's Gaussian posterior, its standard errors times this (1: the
            posterior itself, what the measurements leave unknown), correlated as the fit
            found them. 0 (default): not drawn.
        devices: distinct devices drawn per simulated batch (records are assigned to them
            uniformly at random).
        parameters: half-widths of named parameters (of ``beam_presets.device_parameters``)
            that replace their class's, each within its class's range: texture's
            ``whisker.modulus: 0.1`` moves the macro WT's modes above the first by 1-4.6 %
            (36 Hz by 0.25 %), a stand-in for what no model knows of a real whisker's upper
            modes (its class's 0.03 moves them by about a third of that).
    """

    length: float = _width(0.1)
    thickness: float = _width(0.1)
    modulus: float = _width(0.3)
    loss_factor: float = _width(0.9)
    tan_delta: float = _width(0.9)
    coupling: float = _width(0.3)
    posterior: float = _width(10.0)
    devices: int = field(default=256, metadata={"range": (1, 100_000)})
    parameters: dict[str, float] = omitted_when_empty(default_factory=dict, hash=False)

    @property
    def none(self) -> bool:
        """Whether every width and the posterior are zero (every device is the preset)."""
        return self.posterior == 0 and not self.tolerances

    @property
    def tolerances(self) -> bool:
        """Whether any class or named parameter has a tolerance band (devices that differ by
        more than a fit's posterior)."""
        return (any(getattr(self, c) != 0 for c in CLASSES)
                or any(w != 0 for w in self.parameters.values()))

    def check_device(self, pre: str, device: BeamDevice) -> None:
        """Named widths (:attr:`parameters`) must name the device's parameters, each within
        its class's range; a posterior spread needs a device with a fit's posterior of
        parameters it can build (``pre``: the scene's key prefix).

        Raises:
            SceneError: one line naming ``spread.parameters.<name>`` or ``spread.posterior``
                and what is needed.
        """
        named = device_parameters(device)
        for name, width in self.parameters.items():
            if name not in named:
                raise SceneError(f"{pre}spread.parameters.{name}: not a parameter of device "
                                 f"{device.name!r}; allowed: {sorted(named)}")
            high = field_range(DeviceSpread, named[name])[1]
            if isinstance(width, bool) or not isinstance(width, int | float) or not (
                    0 <= width <= high):
                raise SceneError(f"{pre}spread.parameters.{name}: must be a number in [0, "
                                 f"{high:g}] (its class {named[name]}'s range), got "
                                 f"{width!r:.80}")
        if self.posterior == 0:
            return
        post = device.provenance.posterior
        if post is None or not post.parameters:
            raise SceneError(f"{pre}spread.posterior: device {device.name!r} holds no fit "
                             "posterior (provenance.posterior): fit it with wtml device fit, "
                             "or give the spread as widths")
        unknown = sorted(set(post.parameters) - set(fit_parameters(device)))
        if unknown:
            raise SceneError(f"{pre}spread.posterior: device {device.name!r}'s posterior "
                             f"names {unknown[0]!r}, not one of its parameters "
                             f"{sorted(fit_parameters(device))}")
        widest = self.posterior * max(post.standard_errors)
        if widest > POSTERIOR_MAX:
            name = post.parameters[int(np.argmax(post.standard_errors))]
            raise SceneError(f"{pre}spread.posterior: {self.posterior:g} times {name}'s "
                             f"relative standard error is {widest:.3g}; a Gaussian draw of "
                             f"factors holds up to {POSTERIOR_MAX:g} (beyond, factors near 0 "
                             "or below): measure more, or give that class as a tolerance "
                             "width")

    def whisker_margin(self, device: BeamDevice) -> float:
        """How much shorter than nominal (relative) a drawn whisker may be: the length
        band, plus 5 posterior standard deviations of ``whisker.length``."""
        post = device.provenance.posterior
        se = 0.0
        if self.posterior and post is not None and "whisker.length" in post.parameters:
            se = post.standard_errors[post.parameters.index("whisker.length")]
        return self.parameters.get("whisker.length", self.length) + 5 * self.posterior * se

    def only(self, parameter: str, preset: BeamDevice | str) -> dict[str, float]:
        """Half-width of each of ``preset``'s parameters with all but ``parameter`` at zero
        (for a one-parameter-at-a-time study)."""
        widths = self.widths(preset)
        if parameter not in widths:
            raise ValueError(f"parameter must be one of {sorted(widths)}, got {parameter!r}")
        return {p: w if p == parameter else 0.0 for p, w in widths.items()}

    def widths(self, preset: BeamDevice | str) -> dict[str, float]:
        """Half-width of each of ``preset``'s named parameters (a device, or its name)."""
        return {p: float(self.parameters.get(p, getattr(self, cls)))
                for p, cls in device_parameters(preset).items()}


def draw_factors(preset: BeamDevice | str, widths: dict[str, float], n: int,
                 rng: np.random.Generator, posterior: float = 0.0) -> dict[str, np.ndarray]:
    """``n`` devices' factors (actual / nominal), each parameter ``(n,)`` uniform on
    ``1 ± width``; exactly 1 where the width is 0. Draws in the preset's parameter order;
    then, with ``posterior`` > 0, each fitted parameter times a draw from the device's fit
    posterior (:class:`DeviceSpread`)."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    factors = {p: 1.0 + widths.get(p, 0.0) * rng.uniform(-1.0, 1.0, n)
               for p in device_parameters(preset)}
    if posterior > 0:
        device = beam_device(preset)
        post = device.provenance.posterior
        if post is None:
            raise ValueError(f"posterior: device {device.name!r} holds no fit posterior")
        for p, x in post.draw(posterior, n, rng).items():
            factors[p] = factors.get(p, 1.0) * x
    return factors


def devices(preset: BeamDevice | str, factors: dict[str, np.ndarray]) -> list[BeamTransducer]:
    """The beam model of each drawn device (``factors`` from :func:`draw_factors`)."""
    n = len(next(iter(factors.values())))
    return [build(preset, factors={p: float(v[i]) for p, v in factors.items()})
            for i in range(n)]


def device_ze(transducers: list[BeamTransducer], omega: np.ndarray, which: np.ndarray,
              distance: np.ndarray, stiffness: np.ndarray, chunk: int = DEVICE_CHUNK
              ) -> tuple[np.ndarray, np.ndarray]:
    """Ze (Ω) of each device with its tip free, ``(n_devices, n_freq)``, and of record c with
    a contact ``distance[c]`` m from the tip of device ``which[c]`` of stiffness
    ``stiffness[c]`` N/m (free tip), ``(n, n_freq)``: one batched inverse per device for both,
    ``chunk`` devices at a time (their inverses ``G``, 128 kB per device and frequency on the
    micro preset's mesh, are the memory: a whole shard's 2048 devices at 5 frequencies held
    0.26 GB, and ~0.45 GB at its peak)."""
    omega = np.atleast_1d(omega)
    which = np.asarray(which, dtype=int)
    distance = np.asarray(distance, dtype=float)
    stiffness = np.broadcast_to(np.asarray(stiffness, dtype=float), distance.shape)
    if which.size and (which.min() < 0 or which.max() >= len(transducers)):
        raise ValueError(f"which: device indices must be in [0, {len(transducers) - 1}], got "
                         f"{which.min()}..{which.max()}")
    length = np.array([tr.length for tr in transducers])
    free_ze = np.empty((len(transducers), len(omega)), dtype=complex)
    ze = np.empty((len(which), len(omega)), dtype=complex)
    for start in range(0, len(transducers), chunk):
        group = transducers[start:start + chunk]
        forms = device_forms(group, omega)
        free = BeamTransducer._t_from_forms(omega, *forms[-1])
        free_ze[start:start + len(group)] = free[..., 0, 1] / free[..., 1, 1]
        rows = np.flatnonzero((which >= start) & (which < start + len(group)))
        if len(rows):
            t = contact_transduction_matrices(
                group, which[rows] - start, omega, length[which[rows]] - distance[rows],
                stiffness[rows], forms=forms)
            ze[rows] = t[..., 0, 1] / t[..., 1, 1]
    return free_ze, ze


__all__ = ["CLASSES", "DeviceSpread", "device_ze", "devices", "draw_factors"]
