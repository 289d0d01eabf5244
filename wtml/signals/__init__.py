"""Signal processing: excitations, phasors, analytic signals, bands, bridge, noise."""

from wtml.signals.analytic import analytic_fft, analytic_fir, hilbert_fir
from wtml.signals.bands import split_bands
from wtml.signals.bridge import bridge_channels, impedance_from_bridge
from wtml.signals.excitation import multitone, sample_times, sweep, tone
from wtml.signals.noise import complex_noise, drift_ramp, gain_phase_drift, quantize, white_noise
from wtml.signals.phasor import phasor_fft, phasor_lsq

__all__ = [
    "analytic_fft",
    "analytic_fir",
    "bridge_channels",
    "complex_noise",
    "drift_ramp",
    "gain_phase_drift",
    "hilbert_fir",
    "impedance_from_bridge",
    "multitone",
    "phasor_fft",
    "phasor_lsq",
    "quantize",
    "sample_times",
    "split_bands",
    "sweep",
    "tone",
    "white_noise",
]
