"""The contact-onset scene: horizontal location of a wall by the whisking tip (thesis §5.2).

The micro WT whisks at 1 Hz (9.5 V) with a 420 Hz probe (20 mV) on top, two whisk cycles; a
wall stands at g from the tip's rest position along the whisking direction, somewhere across
the reachable range. The transducer is the modal model of the preset
(``wtml.physics.modal``), the wall a unilateral spring-damper, stepped exactly at the sampling
rate, or a contact law of the family drawn per record (``wall.law``,
``wtml.physics.contact``), stepped implicitly. Both channels go through a 24-bit ADC with noise
(e in V; i through an I-V converter, so its full scale is in A), and what a real acquisition
adds (``acquisition.effects``, :mod:`wtml.signals.acquisition`: the converter's noise, the ADC
floor, mains hum, the drive DAC's amplitude error per record and the coupling's temperature
drift, which multiplies the calibration error's factor in ``coupling``). The dielectric loss
current is ``ω Cp tanδ E`` at each of the drive's two tones (:meth:`OnsetScene.drive_tones`).

The drive is ``e = -AL cos(ωL t) + AH sin(ωH t)``: the whisk starts at its far end, so every
contact lies inside the record. A lead-in of ``lead_s`` before t = 0, the drive raised from 0
by a raised-cosine ramp, lets the probe's resonance (ring time ~40 ms) settle from rest; it is
simulated and not recorded. Each record's device differs from the calibrated one by its piezo
coupling, a factor ``1 + N(0, calibration_error)``: HUE(0) and T at 420 Hz are off by about
that much, and no method sees it (the classical path and the decoders use the calibrated model).

The device (issue 21 §1): with a ``device:`` block (:class:`wtml.physics.spread.DeviceSpread`,
relative half-widths of uniform tolerance bands around the preset; all zero by default) each
record's transducer is drawn from the preset's manufacturing spread: ``spread.devices`` built
devices per call of :meth:`OnsetScene.simulate`, the records assigned to them at random, each
device's modal model ``ModalTransducer.from_beam(build(preset, factors=...), n_modes)``. Every
record carries what its user measures on their own device when it is calibrated (physics.md
§4): ``t_probe``, the device's T at the probe frequency (complex ``(n, 2, 2)``), and ``hue0``,
its HUE(0) (m/V). The calibration error above (the coupling factor) stays unknown on top of it.
With no spread the records are those of the preset alone, draw for draw (nothing more is drawn
from the generator), and ``t_probe``, ``hue0`` the preset's.

Labels: ``gap`` g (m; NaN in a record without a wall), and every contact's ``onset`` and
``detachment`` (s; NaN-padded to ``max_contacts``). A contact is a stretch of touching; touches
on successive probe peaks (gaps shorter than ``merge_periods`` probe periods) are one contact.
Stored: ``e`` and ``i`` float32 ``(n, n_samples)``: 2 × 4 bytes × 53760 samples = 430 kB per
record at the defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

import wtml.signals.acquisition as acq  # as a module: it imports wtml.schema
from wtml.device_calibration import StoredCalibration
from wtml.devices import BeamDevice, shipped
from wtml.interface import OutputRange
from wtml.physics.beam import BeamTransducer
from wtml.physics.beam_presets import build
from wtml.physics.contact import (
    HUNT_CROSSLEY,
    LAWS,
    LINEAR,
    MOUNT_HERTZ,
    POWER,
    SLIP_SPEED,
    ContactWall,
)
from wtml.physics.modal import ModalTransducer, Wall
from wtml.physics.spread import DeviceSpread, draw_factors
from wtml.runtime.contacts import intervals
from wtml.schema import SceneError, bounded, mixture, one_of
from wtml.signals.excitation import lead_in
from wtml.signals.noise import quantize

BYTES_PER_SAMPLE = 64
"""Bytes of working memory per sample of a record while a shard is simulated (the float64
current, voltage and velocity, the float32 records, the decimation's copies), times the
oversampling: what a shard's size is checked against before any work."""


def check_shard_memory(pre: str, samples: int, shards: int, n_samples: int,
                       oversample: int = 1) -> None:
    """Refuse a scene whose shards would take more than :data:`wtml.files.MEMORY_CEILING` to
    simulate (``pre``: the key path's prefix), naming ``samples`` and the shards it needs."""
    from wtml.files import MEMORY_CEILING, nbytes_text

    per_record = n_samples * BYTES_PER_SAMPLE * oversample
    per_shard = -(-samples // shards)
    if per_record > MEMORY_CEILING:
        raise SceneError(f"{pre}drive: a record of {n_samples} samples would take about "
                         f"{nbytes_text(per_record)} to simulate, over the "
                         f"{nbytes_text(MEMORY_CEILING)} ceiling; shorten the record")
    if per_shard * per_record > MEMORY_CEILING:
        fits = MEMORY_CEILING // per_record
        raise SceneError(f"{pre}shards: {per_shard} records of {n_samples} samples per shard "
                         f"would take about {nbytes_text(per_shard * per_record)} to simulate, "
                         f"over the {nbytes_text(MEMORY_CEILING)} ceiling; use at least "
                         f"{-(-samples // fits)} shards for {samples} samples")

@dataclass(frozen=True)
class OnsetDrive:
    """Whisking and probe tones (V, Hz) and how many whisk cycles a record holds."""

    whisk_hz: float = bounded(0.01, 100.0, default=1.0)
    whisk_v: float = bounded(0.0, 1e3, default=9.5)
    probe_hz: float = bounded(1.0, 1e5, default=420.0)
    probe_v: float = bounded(0.0, 10.0, default=0.02)
    cycles: float = bounded(0.5, 100.0, default=2.0)
    lead_s: float = bounded(0.0, 10.0, default=0.25)


@dataclass(frozen=True)
class Acquisition:
    """Sampling rate (Hz; also the simulation step), ADC bits, full scales of the voltage (V)
    and current (A) channels, white noise on each (V rms, A rms), and what a real acquisition
    adds (``effects``: :class:`wtml.signals.acquisition.AcquisitionEffects`, all off unless
    the scene's YAML switches them on)."""

    sample_rate_hz: float = bounded(1e3, 1e7, default=26880.0)
    adc_bits: int = bounded(8, 32, default=24)
    e_full_scale_v: float = bounded(1e-3, 1e4, default=10.0)
    i_full_scale_a: float = bounded(1e-12, 1.0, default=1e-6)
    e_noise_v: float = bounded(0.0, 1.0, default=1e-6)
    i_noise_a: float = bounded(0.0, 1e-3, default=1e-12)
    effects: acq.AcquisitionEffects = field(default_factory=lambda: acq.AcquisitionEffects())

    def record(self, e, i, capacitance: float, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
        """The two channels as recorded, float32 ``(n, n_samples)``: ``e`` (V, broadcast to
        ``i``'s shape) and ``i`` (A, ``(n, n_samples)``) with the white noise, the effects'
        noise (the transducer's capacitance ``capacitance``, F) and the ADC's quantisation."""
        fx, shape = self.effects, np.shape(i)
        e_noise = self.e_noise_v * rng.standard_normal(shape)
        i_noise = self.i_noise_a * rng.standard_normal(shape)
        e_noise += fx.voltage_noise(shape, self.sample_rate_hz, self.e_full_scale_v, rng)
        i_noise += fx.current_noise(shape, self.sample_rate_hz, capacitance,
                                    self.i_full_scale_a, rng)
        e_noise += e  # the recorded signal, in the noise's array (records of a few 100 MB)
        e_rec = quantize(e_noise, self.adc_bits, self.e_full_scale_v).astype(np.float32)
        del e_noise
        i_noise += i
        return e_rec, quantize(i_noise, self.adc_bits, self.i_full_scale_a).astype(np.float32)


@dataclass(frozen=True)
class WallSpec:
    """Where the wall stands, as a fraction of the tip's whisking amplitude HUE(0)·whisk_v
    (uniform), and its contact stiffness (N/m, log-uniform) and damping (N·s/m, uniform):
    nuisance around the thesis's |Zm| ≈ 2e-3 N·s/m at 420 Hz (k_c ≈ 5 N/m).
    ``free_fraction`` of the records have no wall (free whisking).

    The contact law (:mod:`wtml.physics.contact`, physics.md §12) is drawn per record from the
    mixture ``law`` (weights, normalised, over :data:`~wtml.physics.contact.LAWS`; default
    the linear wall alone). ``stiffness`` is every law's tangent k_ref at the reference
    penetration ``delta_ref`` (m, uniform; default 0.5–2 µm, the penetrations the whisk reaches
    at k ≈ 5 N/m across the gap range); ``power_n`` the power law's and Hunt–Crossley's
    exponent (uniform, 1 to Hertz's 1.5); ``alpha`` Hunt–Crossley's damping (s/m, uniform,
    0.1–1); ``mount_fraction`` the share k_ref/k_m of the mount in the mount+Hertz law's
    compliance at δ_ref (uniform, 0.5–0.9: the mount dominates, as §12 argues). ``damping``
    is the linear law's; the others have their own (Hunt–Crossley) or none.

    ``friction``: the range of μ (uniform) of a Coulomb friction as the tip's surface slides
    along the wall (:mod:`wtml.physics.contact`: through the tip's slope, at half the
    whisker's thickness from its axis), regularised over ``slip_speed`` (m/s); default
    ``(0, 0)``: none, nothing drawn, the records those of a scene without the option. With
    friction every law, the linear one included, is stepped implicitly."""

    gap_fraction: tuple[float, float] = bounded(-0.5, 1.5, default=(0.1, 0.9))
    stiffness: tuple[float, float] = bounded(1e-3, 1e6, default=(3.0, 8.0))
    damping: tuple[float, float] = bounded(0.0, 1.0, default=(5e-5, 3e-4))
    free_fraction: float = bounded(0.0, 1.0, default=0.0)
    law: dict[str, float] = field(default_factory=lambda: {"linear": 1.0})
    delta_ref: tuple[float, float] = bounded(1e-9, 1e-4, default=(0.5e-6, 2e-6))
    power_n: tuple[float, float] = bounded(1.0, 1.5, default=(1.0, 1.5))
    alpha: tuple[float, float] = bounded(0.0, 100.0, default=(0.1, 1.0))
    mount_fraction: tuple[float, float] = bounded(0.01, 0.99, default=(0.5, 0.9))
    friction: tuple[float, float] = bounded(0.0, 2.0, default=(0.0, 0.0))
    slip_speed: float = bounded(1e-12, 1.0, default=SLIP_SPEED)

    def mixture(self, path: str = "wall") -> np.ndarray:
        """Each law's probability, in the order of :data:`~wtml.physics.contact.LAWS`
        (SceneError naming ``path.law`` and the allowed laws where it is not a mixture of
        them)."""
        return mixture(f"{path}.law", self.law, LAWS)

    def check(self, path: str) -> None:
        self.mixture(path)
        lo, hi = self.friction
        if lo > hi:
            raise SceneError(f"{path}.friction: low {lo:g} above high {hi:g}")


def onset_calibration(arrays: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Each onset record's calibration as the decoder's graph takes it
    (``wtml.decoders.onset.CALIBRATION``): ``t_re, t_im`` ``(n, 4)`` (its device's T at the
    probe, flattened t11, t12, t21, t22) and ``hue0`` ``(n,)`` m/V, from a dataset's (or
    :meth:`OnsetScene.simulate`'s) ``t_probe`` ``(n, 2, 2)`` and ``hue0`` ``(n,)``."""
    t = np.asarray(arrays["t_probe"]).reshape(-1, 4)
    return t.real, t.imag, np.asarray(arrays["hue0"], float)


@dataclass(frozen=True)
class OnsetScene:
    """A contact-onset scene (``configs/scenes/onset.yaml``)."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("gap", "sigma")
    """What an onset decoder returns per record, each ``(batch,)``: the wall's location g and
    the decoder's own std of it; the contact intervals come beside them."""
    UNITS: ClassVar[dict[str, str]] = {"gap": "m", "sigma": "m"}
    INPUT_KEYS: ClassVar[tuple[str, ...]] = ("e", "i", "t_probe", "t_probe", "hue0")
    """The array each of :meth:`decoder_inputs` comes from."""

    name: str = "onset"
    task: str = one_of("onset", default="onset")
    seed: int = bounded(0, 2**32 - 1, default=0)
    samples: int = bounded(1, 10**7, default=480)
    shards: int = bounded(1, 10**5, default=6)
    device: BeamDevice = field(default_factory=shipped("micro"))
    n_modes: int = bounded(1, 40, default=3)
    drive: OnsetDrive = field(default_factory=OnsetDrive)
    acquisition: Acquisition = field(default_factory=Acquisition)
    wall: WallSpec = field(default_factory=WallSpec)
    calibration_error: float = bounded(0.0, 0.2, default=0.01)
    max_contacts: int = bounded(1, 1000, default=8)
    merge_periods: float = bounded(0.0, 100.0, default=2.0)
    spread: DeviceSpread = field(default_factory=DeviceSpread)
    calibration: StoredCalibration | None = None
    """The device's own calibration (``wtml calibrate --hue0``'s ``.npz``, over the probe
    frequency): the T at the probe and the HUE(0) every record carries, instead of the model's
    with ``calibration_error``; the records still come from the device's model."""

    @staticmethod
    def decoder_inputs(arrays: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """What the decoder takes, from a dataset's (or :meth:`simulate`'s) arrays: ``e``
        (V), ``i`` (A), each ``(n, n_samples)``, then each record's calibration
        (:func:`onset_calibration`)."""
        return arrays["e"], arrays["i"], *onset_calibration(arrays)

    @staticmethod
    def targets(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """The training targets, ``(n, 2 + 2 max_contacts)``: ``gap`` (m), the contacts'
        ``onset`` then ``detachment`` times (s; NaN-padded, and ``gap`` NaN without a wall)
        and ``coupling``."""
        return np.concatenate([arrays["gap"][:, None], arrays["onset"], arrays["detachment"],
                               arrays["coupling"][:, None]], 1)

    @staticmethod
    def target_keys(n_targets: int) -> tuple[str, ...]:
        """The array each of the ``n_targets`` columns of :meth:`targets` comes from."""
        c = (n_targets - 2) // 2
        return ("gap", *["onset"] * c, *["detachment"] * c, "coupling")

    def check(self, path: str) -> None:
        pre = path + "." if path else ""
        if self.calibration is not None:
            self.calibration.check_scene(pre, "calibration", "calibration_error",
                                         self.calibration_error, not self.spread.none,
                                         np.array([self.drive.probe_hz]), hue0=True)
        self.spread.check_device(pre, self.device)
        if self.shards > self.samples:
            raise SceneError(f"{pre}shards: {self.shards} shards for {self.samples} samples; "
                             "must be <= samples")
        check_shard_memory(pre, self.samples, self.shards, self.n_samples)
        nyquist = self.acquisition.sample_rate_hz / 2
        if self.drive.probe_hz >= nyquist / 4:
            raise SceneError(f"{pre}drive.probe_hz: {self.drive.probe_hz:g} Hz must stay below "
                             f"a quarter of Nyquist ({nyquist / 4:g} Hz) for exact stepping")
        lo, hi = self.wall.gap_fraction
        if lo > hi:
            raise SceneError(f"{pre}wall.gap_fraction: low {lo:g} above high {hi:g}")

    # --- the model -------------------------------------------------------------------------
    def transducer(self, factors: dict[str, float] | None = None) -> ModalTransducer:
        """The calibrated modal model of the preset, or of a device off it (``factors``: each
        named parameter's actual / nominal, ``wtml.physics.spread.draw_factors``)."""
        return ModalTransducer.from_beam(self.beam(factors), self.n_modes)

    def beam(self, factors: dict[str, float] | None = None) -> BeamTransducer:
        """The device's finite-element beam (with ``factors`` a device off it), that
        :meth:`transducer` reduces to its modes."""
        return build(self.device, factors=factors)

    def modal_band_hz(self) -> tuple[float, float]:
        """The band (Hz) that ``n_modes: auto`` holds the modal model to
        (:mod:`wtml.scenes.modes`): the whisk's tone up to 10 % above the probe's, where the
        decoders read Zm (the probe band of the thesis's pipeline, ±10 %)."""
        return self.drive.whisk_hz, 1.1 * self.drive.probe_hz

    def calibrated(self, model: ModalTransducer) -> tuple[np.ndarray, float]:
        """What a user measures on the device ``model`` when calibrating it: its T at the
        probe frequency (complex ``(2, 2)``) and HUE(0) (m/V); with the scene's
        ``calibration``, the stored ones."""
        if self.calibration is not None:
            return (self.calibration.t_at(np.array([self.drive.probe_hz]))[0],
                    float(self.calibration.hue0))
        wh = 2 * np.pi * self.drive.probe_hz
        return (model.transduction_matrix(np.array([wh]))[0],
                model.static_tip_displacement_per_volt())

    def device_models(self, n: int, rng: np.random.Generator,
                      widths: dict[str, float] | None = None
                      ) -> tuple[list[ModalTransducer], np.ndarray]:
        """The devices of ``n`` records and which one each record's is, ``(n,)`` int: the
        preset alone without a spread (nothing drawn from ``rng``), else
        ``spread.devices`` devices drawn from the spread (``widths``: each named parameter's
        half-width instead of the device block's, e.g. ``DeviceSpread.only``, and then no
        posterior), the records
        assigned at random; only the devices some record uses are built."""
        posterior = self.spread.posterior if widths is None else 0.0
        widths = self.spread.widths(self.device) if widths is None else widths
        if not any(widths.values()) and not posterior:
            return [self.transducer()], np.zeros(n, int)
        count = self.spread.devices
        factors = draw_factors(self.device, widths, count, rng, posterior)
        which = rng.integers(0, count, n)
        used, which = np.unique(which, return_inverse=True)
        return [self.transducer({p: float(v[d]) for p, v in factors.items()})
                for d in used], which

    @property
    def n_samples(self) -> int:
        """Samples per record."""
        return int(round(self.drive.cycles / self.drive.whisk_hz
                         * self.acquisition.sample_rate_hz))

    def times(self) -> np.ndarray:
        """Sample instants, s, shape ``(n_samples,)``."""
        return np.arange(self.n_samples) / self.acquisition.sample_rate_hz

    def drive_tones(self, lead: bool = False) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The drive's two tones, whisk then probe: each ``(ω rad/s, E V, dE/dt V/s)`` at the
        samples, ``(n_samples,)`` (with ``lead``: the lead-in's samples first, ramped)."""
        d, rate = self.drive, self.acquisition.sample_rate_hz
        n_lead = int(round(d.lead_s * rate)) if lead else 0
        t = np.arange(-n_lead, self.n_samples) / rate
        wl, wh = 2 * np.pi * d.whisk_hz, 2 * np.pi * d.probe_hz
        tones = [(wl, -d.whisk_v * np.cos(wl * t), d.whisk_v * wl * np.sin(wl * t)),
                 (wh, d.probe_v * np.sin(wh * t), d.probe_v * wh * np.cos(wh * t))]
        if n_lead:
            tones = [(w, *lead_in(t, e, de, d.lead_s)) for w, e, de in tones]
        return tones

    def drive_voltage(self, lead: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """E (V) and dE/dt (V/s) at the samples, each ``(n_samples,)`` (with ``lead``: the
        lead-in's samples first): the sum of :meth:`drive_tones`."""
        (_, el, del_), (_, eh, deh) = self.drive_tones(lead)
        return el + eh, del_ + deh

    def whisk_amplitude_m(self) -> float:
        """The tip's whisking amplitude HUE(0)·whisk_v of the calibrated model, m."""
        return self.transducer().static_tip_displacement_per_volt() * self.drive.whisk_v

    def gap_range_m(self) -> tuple[float, float]:
        lo, hi = self.wall.gap_fraction
        amp = self.whisk_amplitude_m()
        return lo * amp, hi * amp

    def output_ranges(self) -> dict[str, OutputRange]:
        """g over the scene's range, 2 % of its span beyond still in domain; physically
        anywhere the tip can reach (± twice the whisking amplitude); NaN ("no wall": free
        whisking) is a legitimate answer."""
        lo, hi = self.gap_range_m()
        amp = self.whisk_amplitude_m()
        return {"gap": OutputRange(lo, hi, (-2 * amp, 2 * amp), margin=0.02, absent_ok=True)}

    def contact_offset_m(self) -> float:
        """The contact point's distance from the whisker's axis, m: half its thickness (the
        preset's whisker size: a square's side, a rod's diameter), the lever of the wall's
        friction on the tip's slope."""
        return self.device.whisker.size / 2

    def reference_stiffness(self) -> float:
        """Geometric mean of the contact-stiffness range, N/m (the classical threshold's)."""
        return float(np.sqrt(np.prod(self.wall.stiffness)))

    # --- generation --------------------------------------------------------------------------
    def contacts(self, touching: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Onset and detachment times (s) of each record's contacts from the per-sample
        touching state ``(n, n_samples)``; touches closer than ``merge_periods`` probe
        periods are one contact. Each ``(n, max_contacts)``, NaN-padded."""
        return intervals(touching, self.acquisition.sample_rate_hz,
                         self.merge_periods / self.drive.probe_hz, self.max_contacts)

    def simulate(self, n: int, rng: np.random.Generator, *, batch: int = 64, gaps=None,
                 widths: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """``n`` records: ``e`` (V) and ``i`` (A) float32 ``(n, n_samples)``; each record's
        device's calibration ``t_probe`` (complex ``(n, 2, 2)``) and ``hue0`` (m/V, ``(n,)``)
        (module docstring; ``widths`` as :meth:`device_models`); labels ``gap``
        (m, NaN without a wall), ``onset``, ``detachment`` (s, ``(n, max_contacts)``);
        nuisance ``stiffness`` (every law's k_ref), ``damping``, ``coupling`` and the contact
        law: ``law`` (its code in :data:`~wtml.physics.contact.LAWS`), ``law_n`` (1 for the
        linear law), ``law_alpha`` (0 but for Hunt–Crossley), ``law_delta_ref`` (m, NaN for the
        linear law) and ``law_mount_fraction`` (1 but for mount+Hertz). ``gaps`` (m,
        ``(n,)``) fixes the walls instead of drawing them (NaN: no wall)."""
        w, a = self.wall, self.acquisition
        lo, hi = self.gap_range_m()
        gap = rng.uniform(lo, hi, n)
        gap[rng.random(n) < w.free_fraction] = np.nan
        if gaps is not None:
            gap = np.broadcast_to(np.asarray(gaps, dtype=float), (n,)).copy()
        k = np.exp(rng.uniform(*np.log(w.stiffness), n))
        c = rng.uniform(*w.damping, n)
        scale = 1 + self.calibration_error * rng.standard_normal(n)
        scale = scale * a.effects.coupling_scale(n, rng)  # temperature drift
        dac = a.effects.drive_scale(n, rng)  # the drive DAC's amplitude error
        tones = self.drive_tones(lead=True)
        law = self.draw_laws(n, rng)
        mu = np.zeros(n)
        if w.friction[1] > 0:  # drawn only where on: without it the records are unchanged
            mu = rng.uniform(*w.friction, n)
            law["law_mu"] = mu
        e, de = self.drive_voltage(lead=True)
        n_lead = len(e) - self.n_samples
        # the object moving with the floor against the transducer's base: the wall's gap
        # follows it, and every law is then stepped implicitly (the switched wall's g is fixed)
        base = a.effects.base_motion(n, len(e), a.sample_rate_hz, rng)
        moving = a.effects.base.enabled
        models, which = self.device_models(n, rng, widths)
        cal = [self.calibrated(m) for m in models]
        draw = {"law": law, "k": k, "c": c, "base": base, "dac": dac, "scale": scale, "mu": mu}
        cur = np.empty((n, self.n_samples), np.float32)
        touching = np.empty((n, self.n_samples), bool)
        for start in range(0, n, batch):
            sl = slice(start, min(n, start + batch))
            # no wall: one far beyond the reach (never touched: exactly the free answer)
            g = np.where(np.isnan(gap[sl]), 1.0, gap[sl])
            # today's exact switched wall (bool: ``~moving`` of a Python bool is an int); with
            # friction a sliding tip is stepped implicitly
            linear = (law["law"][sl] == LINEAR) & (not moving) & (mu[sl] == 0)
            for d, model in enumerate(models):
                mine = which[sl] == d
                for part, is_linear in ((linear & mine, True), (~linear & mine, False)):
                    if part.any():
                        rows = np.arange(sl.start, sl.stop)[part]
                        cur[rows], touching[rows] = self._step(
                            model, rows, g[part], is_linear, draw, (e, de, tones), n_lead)
        # the converter's e_n through Cp: the devices' mean Cp (they differ by ~1 %)
        cp = float(np.mean([m.capacitance for m in models]))
        e_rec, i_rec = a.record(dac[:, None] * e[None, n_lead:], cur, cp, rng)
        onset, detach = self.contacts(touching)
        t_probe = np.array([t for t, _ in cal])[which]
        hue0 = np.array([h for _, h in cal])[which]
        return {"e": e_rec, "i": i_rec, "t_probe": t_probe, "hue0": hue0, "gap": gap,
                "onset": onset, "detachment": detach, "stiffness": k, "damping": c,
                "coupling": scale, **law}

    def _step(self, model: ModalTransducer, rows: np.ndarray, g: np.ndarray, linear: bool,
              draw: dict, drive: tuple, n_lead: int) -> tuple[np.ndarray, np.ndarray]:
        """Step the records ``rows`` (all of one device ``model``; walls at ``g`` m, all on the
        linear switched wall or all on a :class:`ContactWall`) from rest under ``drive``
        (``(E, dE/dt, tones)`` with the lead-in); ``draw`` holds every record's nuisance. Returns
        their current (A) and touching state after the lead-in, each ``(len(rows), n_samples)``."""
        a, law, k, c = self.acquisition, draw["law"], draw["k"], draw["c"]
        e, de, tones = drive
        if linear:
            wall = Wall(g, k[rows], c[rows])
        else:
            mount = law["law_mount_fraction"][rows]
            at = g[:, None] + draw["base"][rows] if a.effects.base.enabled else g
            wall = ContactWall(at, law["law"][rows], k[rows],
                               np.nan_to_num(law["law_delta_ref"][rows], nan=1e-6),
                               law["law_n"][rows], law["law_alpha"][rows], k[rows] / mount,
                               c[rows], friction=draw["mu"][rows],
                               slip_speed=self.wall.slip_speed, offset=self.contact_offset_m())
        amp = draw["dac"][rows, None] if a.effects.dac.enabled else np.ones((1, 1))
        out = model.simulate(amp * e, 1 / a.sample_rate_hz, wall, drive_rate=amp * de,
                             coupling_scale=draw["scale"][rows], record=("i",),
                             dtype=np.float64, tones=[(w, amp * x) for w, x, _ in tones])
        return out["i"][:, n_lead:], out["contact"][:, n_lead:]

    def draw_laws(self, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Each record's contact law from the mixture ``wall.law`` and its parameters
        (labels as :meth:`simulate` names them). A mixture of the linear law alone draws
        nothing, so its records are those of a scene without the option."""
        w = self.wall
        weights = w.mixture()
        law = np.full(n, LINEAR, np.int8)
        n_exp, alpha = np.ones(n), np.zeros(n)
        delta_ref, mount = np.full(n, np.nan), np.ones(n)
        if weights[LINEAR] < 1:
            law = rng.choice(len(LAWS), n, p=weights).astype(np.int8)
            smooth = law != LINEAR
            delta_ref[smooth] = rng.uniform(*w.delta_ref, n)[smooth]
            power = (law == POWER) | (law == HUNT_CROSSLEY)
            n_exp[power] = rng.uniform(*w.power_n, n)[power]
            alpha[law == HUNT_CROSSLEY] = rng.uniform(*w.alpha, n)[law == HUNT_CROSSLEY]
            mount[law == MOUNT_HERTZ] = rng.uniform(*w.mount_fraction, n)[law == MOUNT_HERTZ]
        return {"law": law, "law_n": n_exp, "law_alpha": alpha, "law_delta_ref": delta_ref,
                "law_mount_fraction": mount}
