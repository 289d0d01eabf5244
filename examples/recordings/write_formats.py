"""Write one record of a wtml ``rec.npz`` as instruments write it, to try ``wtml predict`` and
``wtml stream`` on those formats (README, "On a device"):

- ``rec.tdms``: LabVIEW TDMS as the thesis's NI PXI-4461 acquisition writes it: group ``WT``,
  channels ``drive voltage`` (V) and ``I-V converter`` (V: the current through a 100 kΩ
  transimpedance), ``wf_increment`` the sample period (read with
  ``configs/recordings/pxi4461.yaml``);
- ``rec.wav``: a sound card's two channels, 24-bit PCM at ±10 V full scale (e, then the I-V
  converter's volts);
- ``rec.csv``: an oscilloscope's export, ``time_s, e, i`` (V and A) at 7 significant digits;
- ``stream.f32``: interleaved little-endian float32 ``(e, i)`` pairs, what ``wtml stream``
  reads on its standard input;
- ``cal1.npz``: the record's own calibration, for these one-record files.

Usage: python examples/recordings/write_formats.py export/onset/rec.npz export/onset/cal.npz OUT
"""

from __future__ import annotations

import sys
import wave
from pathlib import Path

import numpy as np
from nptdms import ChannelObject, TdmsWriter

TRANSIMPEDANCE = 1e5
"""V per A of the I-V converter (the profile's i_scale is its inverse)."""
FULL_SCALE_V = 10.0
"""V at the sound card's full scale."""


def main(record: str, calibration: str, out: str) -> None:
    rec, cal = np.load(record), np.load(calibration)
    e, i = np.atleast_2d(rec["e"])[0], np.atleast_2d(rec["i"])[0]
    rate = float(rec["sample_rate_hz"])
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    volts = i * TRANSIMPEDANCE
    with TdmsWriter(out_dir / "rec.tdms") as w:
        w.write_segment([ChannelObject("WT", name, x, properties={"wf_increment": 1 / rate})
                         for name, x in (("drive voltage", e), ("I-V converter", volts))])
    counts = np.clip(np.round(np.stack([e, volts], -1) / FULL_SCALE_V * 2**23), -2**23,
                     2**23 - 1).astype("<i4")
    with wave.open(str(out_dir / "rec.wav"), "wb") as w:
        w.setnchannels(2), w.setsampwidth(3), w.setframerate(int(rate))
        w.writeframes(counts.view(np.uint8).reshape(-1, 4)[:, :3].tobytes())
    t = np.arange(len(e)) / rate
    np.savetxt(out_dir / "rec.csv", np.stack([t, e, i], -1), fmt="%.7g", delimiter=",",
               header="time_s,e,i", comments="")
    np.stack([e, i], -1).astype("<f4").tofile(out_dir / "stream.f32")
    t_cal, hue0 = cal["t"], np.atleast_1d(cal["hue0"])
    np.savez(out_dir / "cal1.npz", frequency_hz=cal["frequency_hz"],
             t=t_cal[0] if t_cal.ndim == 4 else t_cal, hue0=hue0[0])
    print(f"wrote rec.tdms, rec.wav, rec.csv, stream.f32 and cal1.npz to {out_dir}")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__.split("Usage: ")[1])
    main(*sys.argv[1:])
