"""The radial scene: a contact on the shaft of the micro whisker (thesis §5.3).

The contact is on the shaft, not at the tip, so the scene needs the beam model
(``wtml.physics.beam``): the preset's dynamic stiffness is inverted once per frequency and every
contact (position, stiffness) is a rank-one update of it. The tip is free, so the measured
quantity is the free-tip Ze of the contacted structure. Tip-load scenes keep the 2×2 path.

Nuisance: the contact stiffness, log-uniform over a stated range (default 1e3–1e5 N/m, the
Hertzian stiffness of a steel pin on the 50 µm whisker; the whisker's own stiffness at the
contact ranges from ~2e-3 N/m at the tip to ~50 N/m 3.2 mm from it, so the contact is stiff
but not rigid, and its stiffness shifts Ze by more than the noise), and complex Gaussian noise
on Ze. The invalid-contact variant
(§5.5.4: a protrusion touching the shaft while the tip is free) is the same physics at the
thesis's three distances: ``contact.distances_um: [500, 1500, 2500]``.

The device (issue 21): with a ``device:`` block (``wtml.physics.spread.DeviceSpread``, relative
half-widths of uniform tolerance bands; all zero by default, the preset itself) each record's
transducer is drawn from the preset's manufacturing spread (``spread.devices`` devices per
simulated batch, records assigned at random), and each record also carries ``ref``: the free
(untouched) whisker's Ze of its device at the same tones, the reference a user measures when
the device is set up, with its own measurement noise (``noise.reference_relative``). With no
spread the records' ``ze``, ``distance`` and ``stiffness`` are those of the preset alone, draw
for draw.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from wtml.devices import BeamDevice, shipped
from wtml.interface import OutputRange
from wtml.physics.beam_presets import build
from wtml.physics.spread import DeviceSpread, device_ze, devices, draw_factors
from wtml.schema import SceneError, bounded, one_of
from wtml.signals import complex_noise


@dataclass(frozen=True)
class ToneSpec:
    """Excitation frequencies in Hz and amplitude in V. The first frequency is the one the
    thesis's decoder and the polynomials use (420 Hz in the thesis); the others form a band
    around it for decoders that use more."""

    frequencies_hz: tuple[float, ...] = bounded(1.0, 1e5, default=(420.0,))
    amplitude_v: float = bounded(1e-6, 1e3, default=0.02)

    def check(self, path: str) -> None:
        if not self.frequencies_hz:
            raise SceneError(f"{path}.frequencies_hz: needs at least one frequency")

    @property
    def frequency_hz(self) -> np.ndarray:
        """The tones, ``(n_freq,)`` Hz."""
        return np.asarray(self.frequencies_hz)

    @property
    def omega(self) -> np.ndarray:
        return 2 * np.pi * np.asarray(self.frequencies_hz)


@dataclass(frozen=True)
class ContactSpec:
    """Where and how stiffly the shaft is touched: distance from the tip in µm, uniform over
    ``distance_um`` (or drawn from ``distances_um`` when given); stiffness in N/m,
    log-uniform over ``stiffness``."""

    distance_um: tuple[float, float] = bounded(0.0, 1e5, default=(0.0, 3200.0))
    distances_um: tuple[float, ...] = bounded(0.0, 1e5, default=())
    stiffness: tuple[float, float] = bounded(1e-3, 1e9, default=(1e3, 1e5))


@dataclass(frozen=True)
class RadialNoise:
    """Relative std of the complex Gaussian noise on each Ze (``ze_relative``) and on each
    free-whisker reference (``reference_relative``: the same lock-in at set-up, averaged 100×
    as long as a contact's measurement since it is taken once, hence 10× less noise; the
    ratio of the two then carries 1.005× the contact's noise, so the Cramér–Rao bound of a
    known device still holds)."""

    ze_relative: float = bounded(0.0, 0.1, default=2e-5)
    reference_relative: float = bounded(0.0, 0.1, default=2e-6)


@dataclass(frozen=True)
class RadialScene:
    """A radial-location scene (``configs/scenes/radial.yaml``)."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("distance", "sigma")
    """What a radial decoder returns, each ``(batch,)``: the contact's distance from the tip
    and the decoder's own std of it (0 where it has none)."""
    UNITS: ClassVar[dict[str, str]] = {"distance": "m", "sigma": "m"}
    INPUT_KEYS: ClassVar[tuple[str, ...]] = ("ze", "ze", "ref", "ref")
    """The array each of :meth:`decoder_inputs` comes from."""

    name: str = "radial"
    task: str = one_of("radial", default="radial")
    seed: int = bounded(0, 2**32 - 1, default=0)
    samples: int = bounded(1, 10**8, default=240000)
    shards: int = bounded(1, 10**5, default=8)
    device: BeamDevice = field(default_factory=shipped("micro"))
    excitation: ToneSpec = field(default_factory=ToneSpec)
    contact: ContactSpec = field(default_factory=ContactSpec)
    noise: RadialNoise = field(default_factory=RadialNoise)
    spread: DeviceSpread = field(default_factory=DeviceSpread)

    @staticmethod
    def decoder_inputs(arrays: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """What the decoder and the exported graphs take, from a dataset's (or
        :meth:`simulate`'s) arrays: ``ze_re, ze_im`` and ``ref_re, ref_im`` (the free
        whisker's Ze of the record's device, the user's reference), each ``(n, n_freq)`` Ω."""
        return arrays["ze"].real, arrays["ze"].imag, arrays["ref"].real, arrays["ref"].imag

    @staticmethod
    def targets(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """The training targets, ``(n, 1)``: the contact's distance from the tip, m."""
        return arrays["distance"][:, None]

    @staticmethod
    def target_keys(n_targets: int) -> tuple[str, ...]:
        """The array each of the ``n_targets`` columns of :meth:`targets` comes from."""
        return ("distance",)

    def check(self, path: str) -> None:
        pre = path + "." if path else ""
        if self.shards > self.samples:
            raise SceneError(f"{pre}shards: {self.shards} shards for {self.samples} samples; "
                             "must be <= samples")
        self.spread.check_device(pre, self.device)
        whisker = 1e6 * self.whisker_length_m() * (1 - self.spread.whisker_margin(self.device))
        for key, values in (("distance_um", self.contact.distance_um),
                            ("distances_um", self.contact.distances_um)):
            if values and max(values) >= whisker:
                raise SceneError(f"{pre}contact.{key}: must stay below the whisker length "
                                 f"{whisker:g} µm (its shortest in the spread), got "
                                 f"{max(values):g}")

    def whisker_length_m(self) -> float:
        """Length of the preset's whisker (its last beam segment), m."""
        return build(self.device).segments[-1].length

    def reference_stiffness(self) -> float:
        """The contact stiffness at the middle of its log-uniform range (geometric mean), N/m."""
        return float(np.sqrt(np.prod(self.contact.stiffness)))

    def distance_range_m(self) -> tuple[float, float]:
        """The span of d (m from the tip) that decoders and inversions search: the scene's
        range, or 0 to 1.2× the largest of its discrete distances (at most to the middle of
        the rest of the whisker)."""
        c = self.contact
        if c.distances_um:
            top = 1e-6 * max(c.distances_um)
            return 0.0, min(1.2 * top, (top + self.whisker_length_m()) / 2)
        return 1e-6 * c.distance_um[0], 1e-6 * c.distance_um[1]

    def output_ranges(self) -> dict[str, OutputRange]:
        """The distance over :meth:`distance_range_m`, 2 % of its span beyond it still in
        domain; physically, a contact lies on the whisker, 0 to its length from the tip."""
        lo, hi = self.distance_range_m()
        return {"distance": OutputRange(lo, hi, (0.0, self.whisker_length_m()), margin=0.02)}

    def transducer(self):
        """The preset's beam model (built once per call)."""
        return build(self.device)

    def ze_of(self, distance: np.ndarray, stiffness: np.ndarray, transducer=None) -> np.ndarray:
        """Noise-free free-tip Ze (Ω) for contacts at ``distance`` (m from the tip) with
        ``stiffness`` (N/m), shape ``(n, n_freq)``."""
        tr = transducer or self.transducer()
        t = tr.contact_transduction_matrix(self.excitation.omega, tr.length - distance,
                                           stiffness)
        return t[..., 0, 1] / t[..., 1, 1]

    def free_ze(self, transducer=None) -> np.ndarray:
        """Noise-free Ze (Ω) of the preset with its tip free, ``(n_freq,)``."""
        t = (transducer or self.transducer()).transduction_matrix(self.excitation.omega)
        return t[:, 0, 1] / t[:, 1, 1]

    def simulate(self, n: int, rng: np.random.Generator, *,
                 widths: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """``n`` samples: ``ze`` (n, n_freq) complex Ω, the reference ``ref`` (n, n_freq)
        complex Ω (the free whisker's Ze of the record's device), target ``distance`` (n,)
        in m, nuisance ``stiffness`` (n,) in N/m (module docstring). ``widths``: the spread's
        half-width per named parameter instead of the device block's (e.g. one parameter
        alone: ``DeviceSpread.only``; then no posterior)."""
        c = self.contact
        if c.distances_um:
            d = 1e-6 * rng.choice(np.asarray(c.distances_um), n)
        else:
            d = 1e-6 * rng.uniform(*c.distance_um, n)
        k = np.exp(rng.uniform(*np.log(c.stiffness), n))
        posterior = self.spread.posterior if widths is None else 0.0
        widths = self.spread.widths(self.device) if widths is None else widths
        if not any(widths.values()) and not posterior:
            tr = self.transducer()
            ze = self.ze_of(d, k, tr)
            ref = np.broadcast_to(self.free_ze(tr), ze.shape)
        else:
            count = self.spread.devices
            factors = draw_factors(self.device, widths, count, rng, posterior)
            which = rng.integers(0, count, n)
            free, ze = device_ze(devices(self.device, factors), self.excitation.omega, which, d,
                                 k)
            ref = free[which]
        ze = complex_noise(ze, self.noise.ze_relative, rng)
        ref = complex_noise(ref, self.noise.reference_relative, rng)
        return {"ze": ze, "ref": ref, "distance": d, "stiffness": k}
