"""The shipped example's "measurements": simulated Ze of a hidden device near start.yaml.

The hidden device is start.yaml with the factors in TRUTH, and a whisker lossier than its
bimorph (a loss model the fit does not have). Written: the free-tip sweep as CSV and Touchstone
.s1p, and Ze with a rigid pin at 1, 2 and 3 mm from the tip, each with 1e-4 relative noise (what
`wtml device fit` reads); and, for `wtml predict` on the radial decoder trained on the fitted
device, ``contacts.npz`` (Ze at radial.yaml's tones with a 1e4 N/m contact at the distances
in ``distance_m``, 2e-5 noise) and ``reference.npz`` (the free whisker's Ze there, 2e-6); for
`wtml calibrate`, ``loads.csv``: Ze at those tones under tip loads of known Zm (springs and a
damper around the tip's own impedance, 1e-4 noise), six to calibrate and two to validate.

    python examples/own_device/make_measurements.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wtml.physics.beam_presets import build
from wtml.physics.identify import contact_ze, free_ze, with_segment_losses
from wtml.physics.measured import write_csv, write_s1p
from wtml.signals.noise import complex_noise

HERE = Path(__file__).resolve().parent
TRUTH = {"bimorph.length": 1.06, "coupling": 0.93, "loss_factor": 1.2, "tan_delta": 0.85,
         "whisker.length": 1.03, "whisker.modulus": 0.95}
"""The hidden device: factors of start.yaml's values."""
WHISKER_LOSS = 0.035
"""The hidden whisker's own loss factor (its bimorph's: 0.02 x 1.2 = 0.024)."""
NOISE = 1e-4
PINS_MM = (1.0, 2.0, 3.0)
TONES_HZ = np.array([360.0, 320.0, 340.0, 380.0, 400.0])
"""radial.yaml's tones."""
CONTACTS_MM = np.arange(0.2, 3.2, 0.2)
LOADS = ((0.0, 0.0, 0), (0.1, -90.0, 0), (0.3, -80.0, 0), (1.0, -90.0, 0), (3.0, -60.0, 0),
         (10.0, -90.0, 0), (0.5, -85.0, 1), (2.0, -70.0, 1))
"""Tip loads: (|Zm| over the tip's scale, phase in degrees, validation 0/1)."""


def truth():
    """The hidden device's beam model."""
    return with_segment_losses(build(HERE / "start.yaml", factors=TRUTH),
                               {"whisker": WHISKER_LOSS})


def main() -> None:
    rng = np.random.default_rng(2026)
    tr = truth()
    f = np.geomspace(250.0, 3500.0, 300)
    ze = complex_noise(free_ze(tr, 2 * np.pi * f), NOISE, rng)
    write_csv(HERE / "free.csv", f, ze, form="ma")
    write_s1p(HERE / "free.s1p", f, ze)
    fp = np.geomspace(250.0, 3500.0, 150)
    for mm in PINS_MM:
        zp = complex_noise(contact_ze(tr, 2 * np.pi * fp, mm * 1e-3), NOISE, rng)
        write_csv(HERE / f"pin_{mm:g}mm.csv", fp, zp)
    omega = 2 * np.pi * TONES_HZ
    ze = np.stack([contact_ze(tr, omega, mm * 1e-3, 1e4) for mm in CONTACTS_MM])
    np.savez(HERE / "contacts.npz", frequency_hz=TONES_HZ, ze=complex_noise(ze, 2e-5, rng),
             distance_m=CONTACTS_MM * 1e-3)
    np.savez(HERE / "reference.npz", frequency_hz=TONES_HZ,
             ze=complex_noise(free_ze(tr, omega), 2e-6, rng))
    t = tr.transduction_matrix(omega)
    scale = np.abs(t[:, 1, 1] / t[:, 1, 0])  # N s/m: where a tip load starts to show in Ze
    lines = ["frequency_hz,load,validation,zm_re,zm_im,ze_re,ze_im"]
    for load, (size, phase, validation) in enumerate(LOADS):
        zm = size * scale * np.exp(1j * np.deg2rad(phase))
        ze = complex_noise((t[:, 0, 0] * zm + t[:, 0, 1]) / (t[:, 1, 0] * zm + t[:, 1, 1]),
                           NOISE, rng)
        lines += [f"{float(f)!r},{load},{validation},{float(z.real)!r},{float(z.imag)!r},"
                  f"{float(e.real)!r},{float(e.imag)!r}"
                  for f, z, e in zip(TONES_HZ, zm, ze, strict=True)]
    (HERE / "loads.csv").write_text("\n".join(lines) + "\n")
    print(f"wrote {HERE}/free.csv, free.s1p, pin_*mm.csv, contacts.npz, reference.npz, "
          "loads.csv")


if __name__ == "__main__":
    main()
