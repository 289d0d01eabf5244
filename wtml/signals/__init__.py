"""Signal processing: excitations, phasors, analytic signals, bands, bridge, noise."""

from wtml.lazy import lazy_exports

_WHERE = {
    "analytic_fft": "wtml.signals.analytic",
    "analytic_fir": "wtml.signals.analytic",
    "bridge_channels": "wtml.signals.bridge",
    "complex_noise": "wtml.signals.noise",
    "drift_ramp": "wtml.signals.noise",
    "gain_phase_drift": "wtml.signals.noise",
    "hilbert_fir": "wtml.signals.analytic",
    "impedance_from_bridge": "wtml.signals.bridge",
    "multitone": "wtml.signals.excitation",
    "phasor_fft": "wtml.signals.phasor",
    "phasor_lsq": "wtml.signals.phasor",
    "quantize": "wtml.signals.noise",
    "sample_times": "wtml.signals.excitation",
    "split_bands": "wtml.signals.bands",
    "sweep": "wtml.signals.excitation",
    "tone": "wtml.signals.excitation",
    "white_noise": "wtml.signals.noise",
}
"""Each name this package exports and the module that holds it, imported on first use
(:mod:`wtml.lazy`)."""

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
