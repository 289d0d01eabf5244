"""What a real acquisition adds to a time-domain scene's records (physics.md §12).

Each effect has a physical parameter, not a bare noise level, and is switched by its ``enabled``:

- the current channel's I–V converter (:class:`IVConverter`): the feedback resistor's Johnson
  current noise ``4kT/R_f``, the op-amp's input current noise with a 1/f corner, and its input
  voltage noise e_n across the transducer's capacitance: ``e_n² (1/R_f² + (ω Cp)²)``, a current
  noise that grows with f (one-sided densities, A²/Hz);
- the ADC's noise floor at its dynamic range below a full-scale sine (:class:`ADCNoise`), on
  both channels (its quantisation is :func:`wtml.signals.noise.quantize`, as before);
- mains hum at 50 or 60 Hz and its harmonics (:class:`MainsHum`), on both channels, as a
  fraction of each channel's full scale, with a random phase per record and harmonic;
- the drive DAC's amplitude error (:class:`DACError`), a factor on the drive per record;
- the piezo coupling drifting with temperature (:class:`CouplingDrift`): d31's temperature
  coefficient times a per-record temperature offset from calibration, a factor on the coupling;
- the object vibrating against the transducer's base (:class:`BaseMotion`): a band-limited
  displacement x_b(t), drawn by :func:`base_motion` (a scene applies it to what it moves).

Noise of a stated density is drawn by shaping white noise's spectrum
(:func:`coloured_noise`). Everything draws from the ``numpy.random.Generator`` it is given,
and only for the effects that are on, so records are reproducible from (scene, seed).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from wtml.constants import BOLTZMANN
from wtml.physics.validation import check_range
from wtml.schema import SceneError, bounded


@dataclass(frozen=True)
class IVConverter:
    """The current channel's transimpedance amplifier: feedback resistor R_f (Ω) at
    ``temperature_k`` (K), the op-amp's input current noise density i_n (A/√Hz, white above
    ``corner_hz``, ``i_n² (1 + f_c/f)`` below) and input voltage noise density e_n (V/√Hz)."""

    enabled: bool = False
    feedback_ohm: float = bounded(1e2, 1e12, default=1e7)
    temperature_k: float = bounded(1.0, 500.0, default=296.0)
    current_noise: float = bounded(0.0, 1e-9, default=0.8e-15)
    corner_hz: float = bounded(0.0, 1e4, default=30.0)
    voltage_noise: float = bounded(0.0, 1e-5, default=5.1e-9)

    def densities(self, f, capacitance: float) -> dict[str, np.ndarray]:
        """Each part's one-sided current noise density at the input, A²/Hz, at ``f`` (Hz,
        > 0): ``johnson`` 4kT/R_f, ``current`` i_n² (1 + f_c/f), ``voltage``
        e_n² (1/R_f² + (2πf Cp)²) with Cp (F) the transducer's capacitance."""
        f = check_range("f", f, 0.0, np.inf, unit="Hz", low_open=True, high_open=True)
        check_range("capacitance", capacitance, 0.0, 1.0, unit="F")
        return {
            "johnson": np.full(f.shape, 4 * BOLTZMANN * self.temperature_k / self.feedback_ohm),
            "current": self.current_noise**2 * (1 + self.corner_hz / f),
            "voltage": self.voltage_noise**2 * (
                1 / self.feedback_ohm**2 + (2 * np.pi * f * capacitance) ** 2)}

    def density(self, f, capacitance: float) -> np.ndarray:
        """The converter's total current noise density at ``f`` (Hz), A²/Hz."""
        return sum(self.densities(f, capacitance).values())


@dataclass(frozen=True)
class ADCNoise:
    """The ADC's noise floor: ``dynamic_range_db`` below a full-scale sine (rms)."""

    enabled: bool = False
    dynamic_range_db: float = bounded(40.0, 200.0, default=118.0)

    def rms(self, full_scale: float) -> float:
        """The floor's rms in the channel's unit for a full scale (peak) ``full_scale``."""
        return full_scale / np.sqrt(2) * 10 ** (-self.dynamic_range_db / 20)


@dataclass(frozen=True)
class MainsHum:
    """Mains hum: the fundamental at ``mains_hz`` (50 or 60) with amplitude ``level`` × the
    channel's full scale, and ``harmonics``: the 2nd, 3rd, ... harmonics' amplitudes relative
    to the fundamental."""

    enabled: bool = False
    mains_hz: float = bounded(50.0, 60.0, default=50.0)
    level: float = bounded(0.0, 0.1, default=3e-4)
    harmonics: tuple[float, ...] = bounded(0.0, 10.0, default=(0.04, 0.15, 0.04, 0.3))

    def check(self, path: str) -> None:
        if self.mains_hz not in (50.0, 60.0):
            raise SceneError(f"{path + '.' if path else ''}mains_hz: must be 50 or 60, "
                             f"got {self.mains_hz!r}")

    def amplitudes(self) -> np.ndarray:
        """Each harmonic's amplitude relative to full scale, fundamental first."""
        return self.level * np.concatenate([[1.0], self.harmonics])


@dataclass(frozen=True)
class DACError:
    """The drive DAC's amplitude error: a factor ``1 + N(0, amplitude_error)`` per record."""

    enabled: bool = False
    amplitude_error: float = bounded(0.0, 0.1, default=1e-3)


@dataclass(frozen=True)
class CouplingDrift:
    """The piezo coupling's temperature coefficient (relative change of d31 per K) and the
    std of each record's temperature offset from the calibration's (K): a factor
    ``1 + per_kelvin · N(0, temperature_k)`` on the coupling per record."""

    enabled: bool = False
    per_kelvin: float = bounded(0.0, 0.05, default=2e-3)
    temperature_k: float = bounded(0.0, 50.0, default=1.0)


@dataclass(frozen=True)
class BaseMotion:
    """The object vibrating against the transducer's base: rms displacement (m) within the
    band ``band_hz`` (flat displacement density there, none outside)."""

    enabled: bool = False
    rms_m: float = bounded(0.0, 1e-2, default=0.8e-6)
    band_hz: tuple[float, float] = bounded(0.01, 1e5, default=(5.0, 20.0))


@dataclass(frozen=True)
class AcquisitionEffects:
    """What a real acquisition adds (see the module docstring); each effect switched by its
    ``enabled`` (all off by default: the ideal acquisition)."""

    iv: IVConverter = field(default_factory=IVConverter)
    adc: ADCNoise = field(default_factory=ADCNoise)
    hum: MainsHum = field(default_factory=MainsHum)
    dac: DACError = field(default_factory=DACError)
    drift: CouplingDrift = field(default_factory=CouplingDrift)
    base: BaseMotion = field(default_factory=BaseMotion)

    NAMES: ClassVar[tuple[str, ...]] = ("iv", "adc", "hum", "dac", "drift", "base")

    def only(self, *names: str) -> AcquisitionEffects:
        """A copy with only the effects ``names`` on, at their levels here (none: all off)."""
        unknown = set(names) - set(self.NAMES)
        if unknown:
            raise ValueError(f"effects: unknown {sorted(unknown)}; choose from {self.NAMES}")
        return dataclasses.replace(self, **{n: dataclasses.replace(getattr(self, n),
                                                                   enabled=n in names)
                                            for n in self.NAMES})

    def drive_scale(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Each record's drive amplitude over the commanded one (the DAC's error), ``(n,)``."""
        if not self.dac.enabled:
            return np.ones(n)
        return 1 + self.dac.amplitude_error * rng.standard_normal(n)

    def coupling_scale(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Each record's piezo coupling over the calibrated one from temperature drift,
        ``(n,)``."""
        if not self.drift.enabled:
            return np.ones(n)
        d = self.drift
        return 1 + d.per_kelvin * d.temperature_k * rng.standard_normal(n)

    def current_noise(self, shape: tuple[int, int], rate: float, capacitance: float,
                      full_scale: float, rng: np.random.Generator) -> np.ndarray:
        """The current channel's added noise, A, ``shape = (n, n_samples)`` at ``rate`` (Hz):
        the I–V converter's (transducer capacitance ``capacitance``, F), the ADC floor and
        hum for a full scale ``full_scale`` (A)."""
        out = np.zeros(shape)
        if self.iv.enabled:
            out += coloured_noise(lambda f: self.iv.density(f, capacitance), shape, rate, rng)
        return self._add_channel(out, rate, full_scale, rng)

    def voltage_noise(self, shape: tuple[int, int], rate: float, full_scale: float,
                      rng: np.random.Generator) -> np.ndarray:
        """The voltage channel's added noise, V: the ADC floor and hum for a full scale
        ``full_scale`` (V), ``shape = (n, n_samples)`` at ``rate`` (Hz)."""
        return self._add_channel(np.zeros(shape), rate, full_scale, rng)

    def _add_channel(self, out: np.ndarray, rate, full_scale, rng) -> np.ndarray:
        """``out`` (float64 ``(n, n_samples)``) with the ADC floor and hum added in place
        (records of a few hundred MB: no temporary beyond one of ``out``'s size)."""
        if self.adc.enabled:
            floor = rng.standard_normal(out.shape)
            floor *= self.adc.rms(full_scale)
            out += floor
            del floor
        if self.hum.enabled:
            out += mains_hum(self.hum.mains_hz, full_scale * self.hum.amplitudes(), out.shape,
                             rate, rng)
        return out

    def base_motion(self, n: int, n_samples: int, rate: float, rng: np.random.Generator
                    ) -> np.ndarray:
        """x_b(t) of each record, m, ``(n, n_samples)`` (zeros when off)."""
        if not self.base.enabled:
            return np.zeros((n, n_samples))
        return base_motion(self.base.rms_m, self.base.band_hz, (n, n_samples), rate, rng)


def coloured_noise(density: Callable[[np.ndarray], np.ndarray], shape: tuple[int, ...],
                   rate: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise of one-sided density ``density(f)`` (unit²/Hz, f in Hz > 0) sampled at
    ``rate`` (Hz), ``shape = (..., n_samples)``: white noise's spectrum shaped over the
    record's frequencies (``numpy.fft.rfftfreq``), nothing at f = 0; its variance is the
    density's sum over those frequencies times their spacing ``rate/n_samples`` (the Nyquist
    frequency's counted half)."""
    check_range("rate", rate, 0.0, np.inf, unit="Hz", low_open=True, high_open=True)
    n = shape[-1]
    f = np.fft.rfftfreq(n, 1 / rate)
    gain = np.zeros(len(f))
    gain[1:] = np.sqrt(np.asarray(density(f[1:]), dtype=float) * rate / 2)
    if not np.all(np.isfinite(gain)):
        raise ValueError("density: must be finite and >= 0 at every f > 0")
    spectrum = np.fft.rfft(rng.standard_normal(shape), axis=-1)
    spectrum *= gain
    return np.fft.irfft(spectrum, n, axis=-1)


def mains_hum(mains_hz: float, amplitudes, shape: tuple[int, int], rate: float,
              rng: np.random.Generator) -> np.ndarray:
    """Hum ``Σ_h a_h sin(2π h f_m t + φ_h)``, ``shape = (n, n_samples)`` at ``rate`` (Hz), t from
    0: ``amplitudes`` a_h (the channel's unit) of the harmonics h = 1, 2, ... of ``mains_hz``,
    each with a uniform random phase per record. Harmonics must lie below Nyquist.

    Summed as ``a_h cos φ_h sin(ω_h t) + a_h sin φ_h cos(ω_h t)``: one matrix product of the
    records' ``(n, 2H)`` weights with the ``(2H, n_samples)`` waves, the sines taken once for
    all records (a sine per sample, harmonic and record took 0.4 s a channel on 120 texture
    records); equal to the plain sum to rounding."""
    a = check_range("amplitudes", amplitudes, 0.0, np.inf, high_open=True)
    check_range("mains_hz", mains_hz, 0.0, rate / (2 * len(a)), unit="Hz", low_open=True,
                high_open=True)
    phase = rng.uniform(0, 2 * np.pi, (shape[0], len(a)))
    angle = 2 * np.pi * mains_hz * np.arange(1, len(a) + 1)[:, None] * (np.arange(shape[1])
                                                                         / rate)
    weights = np.concatenate([a * np.cos(phase), a * np.sin(phase)], axis=1)
    return weights @ np.concatenate([np.sin(angle), np.cos(angle)])


def base_motion(rms_m: float, band_hz: tuple[float, float], shape: tuple[int, int],
                rate: float, rng: np.random.Generator) -> np.ndarray:
    """The object's displacement against the transducer's base, x_b(t) in m,
    ``shape = (n, n_samples)`` at ``rate`` (Hz): Gaussian, flat density within ``band_hz``
    (Hz, below Nyquist, at least one of the record's frequencies inside) and none outside,
    ``rms_m`` rms in expectation (e.g. a floor at 50 µm/s rms near 10 Hz: 0.8 µm; an
    isolated optical table: ~10 nm)."""
    check_range("rms_m", rms_m, 0.0, 1.0, unit="m")
    lo, hi = band_hz
    check_range("band_hz", band_hz, 0.0, rate / 2, unit="Hz", low_open=True)
    if lo >= hi:
        raise ValueError(f"band_hz: low {lo:g} Hz must be below high {hi:g} Hz")
    f = np.fft.rfftfreq(shape[-1], 1 / rate)
    inside = (f >= lo) & (f <= hi)
    if not np.any(inside):
        raise ValueError(f"band_hz: [{lo:g}, {hi:g}] Hz holds none of the record's "
                         f"frequencies (spacing {rate / shape[-1]:g} Hz)")
    level = rms_m**2 / (np.sum(inside) * rate / shape[-1])  # m²/Hz, flat in the band
    return coloured_noise(lambda x: np.where((x >= lo) & (x <= hi), level, 0.0), shape,
                          rate, rng)
