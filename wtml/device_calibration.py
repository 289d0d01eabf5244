"""``wtml calibrate``: a device's transduction matrix from its own measured loads (physics.md §4).

The walkthrough's least-squares calibration (:func:`wtml.physics.calibration.
calibrate_least_squares`) on a user's files: Ze measured under loads of known Zm at the
operating frequencies, the calibration loads fitting T(ω) and the validation loads (never seen
by the fit) measuring its error, as the thesis's Tables 4.3–4.4 do. The result is stored beside
the device file, ``<device>.calibration.npz`` (``frequency_hz``, ``t`` and the diagnostics: the
form ``wtml predict --calibration`` reads) and ``<device>.calibration.json`` (the summary), and
compared with the device model's own T. A measured HUE(0) (the tip's static displacement per
volt, m/V: what the onset scene and decoder need beside T at the probe) is stored with it when
given (``hue0``).

The loads file is a CSV with the columns ``frequency_hz, load, validation, zm_re, zm_im, ze_re,
ze_im``: one row per load and frequency, ``load`` a whole-number label, ``validation`` 1 for a
validation load and 0 for a calibration load, Zm in N·s/m and Ze in Ω. Every load is measured
on the same frequencies.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wtml.devices import device_hash, device_path, load_device
from wtml.files import FileError, read_npz, sha256
from wtml.physics.calibration import Calibration, calibrate_least_squares
from wtml.physics.measured import LoadSweep, Sweep, read_table
from wtml.physics.twoport import ze_from_zm
from wtml.schema import SceneError, SchemaError, bounded, build

COLUMNS = ("load", "validation", "zm_re", "zm_im", "ze_re", "ze_im")


CALIBRATION_MAX_BYTES = 64 * 1024**2
"""Bytes: the largest calibration file a scene reads."""


@dataclass(frozen=True)
class StoredCalibration:
    """A device's T as ``wtml calibrate`` stored it, carried by a scene (the fluid scene's
    ``transducer.calibration``, the onset and texture scenes' ``calibration``: what the
    classical path and the decoder believe, while the records come from the device's model).
    A scene file gives the path of the ``.npz``; the scene holds the values (so its hash covers
    them): ``frequency_hz`` (n,), T's real and imaginary parts flattened row by row,
    ``(n * 4,)`` each, and the measured HUE(0) in m/V where one was given."""

    source: str = ""
    frequency_hz: tuple[float, ...] = bounded(1e-3, 1e9, default=())
    t_re: tuple[float, ...] = bounded(-1e300, 1e300, default=())
    t_im: tuple[float, ...] = bounded(-1e300, 1e300, default=())
    hue0: float | None = bounded(1e-15, 1.0, default=None)

    def check(self, path: str) -> None:
        n = len(self.frequency_hz)
        if n < 1 or len(self.t_re) != 4 * n or len(self.t_im) != 4 * n:
            raise SchemaError(f"{path}: a calibration needs frequency_hz (n,) and T's 4 n "
                              f"parts, got {n} frequencies and {len(self.t_re)}, "
                              f"{len(self.t_im)} parts")
        if n > 1 and np.any(np.diff(self.frequency_hz) <= 0):
            raise SchemaError(f"{path}.frequency_hz: must be strictly increasing")

    @classmethod
    def resolve(cls, value: Any, path: str) -> StoredCalibration:
        """Read ``wtml calibrate``'s ``.npz`` at the path ``value``."""
        if not isinstance(value, str):
            raise SchemaError(f"{path}: must be the path of a `wtml calibrate` .npz, got "
                              f"{value!r:.80}")
        try:
            data = read_npz(value, what="calibration", max_bytes=CALIBRATION_MAX_BYTES,
                            keys=("frequency_hz", "t", "hue0"))
        except ValueError as err:
            raise SchemaError(f"{path}: {err}") from None
        f, t = data.get("frequency_hz"), data.get("t")
        if f is None or t is None or f.ndim != 1 or t.shape != (len(f), 2, 2) \
                or not np.all(np.isfinite(t)) or not np.all(np.isfinite(f)):
            raise SchemaError(f"{path}: {value}: a calibration needs finite frequency_hz (n,) "
                              "and t (n, 2, 2), as `wtml calibrate` writes it")
        t = np.asarray(t, complex).reshape(-1)
        hue0 = data.get("hue0")
        if hue0 is not None and (hue0.shape not in ((), (1,)) or not np.isfinite(hue0).all()):
            raise SchemaError(f"{path}: {value}: hue0 must be one finite number (m/V), got "
                              f"shape {hue0.shape}")
        return build(cls, {"source": f"{value} ({sha256(value)[:12]})",
                           "frequency_hz": [float(x) for x in f],
                           "t_re": [float(x) for x in t.real],
                           "t_im": [float(x) for x in t.imag],
                           "hue0": None if hue0 is None else float(hue0.reshape(-1)[0])},
                     path)

    def check_scene(self, pre: str, key: str, error_key: str, error: float, spread: bool,
                    frequency_hz: np.ndarray, hue0: bool = False) -> None:
        """What a scene on this calibration must hold (``pre``: the scene's key prefix,
        ``key``: the calibration's key, ``error_key``: the scene's calibration-error key): no
        calibration error of its own (the calibration's is the one the records carry), no
        spread (one device's calibration is not every record's), its grid ``frequency_hz``
        inside the calibrated band, and HUE(0) stored where the scene needs it (``hue0``).

        Raises:
            SceneError: one line naming the key and what is allowed.
        """
        if error != 0:
            raise SceneError(f"{pre}{error_key}: must be 0 with {key} (the calibration's own "
                             f"error is the one the records carry), got {error:g}")
        if spread:
            raise SceneError(f"{pre}spread: must be none with {key} (one device's calibration "
                             "is not every record's)")
        try:
            self.t_at(frequency_hz)
        except ValueError as err:
            raise SceneError(f"{pre}{key}: {err}") from None
        if hue0 and self.hue0 is None:
            raise SceneError(f"{pre}{key}: {self.source} holds no HUE(0), which this scene "
                             "needs beside T: calibrate with wtml calibrate --hue0 M_PER_V (the "
                             "tip's measured static displacement per volt)")

    def t_at(self, frequency_hz: np.ndarray) -> np.ndarray:
        """T at ``frequency_hz`` (within the calibrated band: linear in each element between
        calibrated frequencies), complex ``(len(frequency_hz), 2, 2)``.

        Raises:
            ValueError: a frequency outside the calibrated band.
        """
        f = np.asarray(self.frequency_hz)
        want = np.asarray(frequency_hz, float)
        if want.min() < f[0] * (1 - 1e-9) or want.max() > f[-1] * (1 + 1e-9):
            raise ValueError(f"the calibration covers {f[0]:g}-{f[-1]:g} Hz; the scene's grid "
                             f"{want.min():g}-{want.max():g} Hz lies outside it: calibrate "
                             "over the scene's band")
        t = (np.asarray(self.t_re) + 1j * np.asarray(self.t_im)).reshape(-1, 4)
        out = np.stack([np.interp(want, f, t[:, k].real) + 1j * np.interp(want, f, t[:, k].imag)
                        for k in range(4)], axis=-1)
        return out.reshape(-1, 2, 2)


def read_loads(path: str | Path) -> dict[str, np.ndarray]:
    """The loads file as arrays on its grid: ``frequency_hz`` (n_freq,), ``zm`` and ``ze``
    complex (n_loads, n_freq), ``validation`` bool (n_loads,), ``load`` labels (n_loads,).

    Raises:
        FileError: one line naming the file (and the line, column or load) and what is
            allowed.
    """
    _, v = read_table(path, "loads CSV", {"loads": COLUMNS},
                      "frequency_hz, " + ", ".join(COLUMNS), increasing=False)
    f, label, val = v[:, 0], v[:, 1], v[:, 2]
    if not np.all(label == np.round(label)) or not np.all(np.isin(val, (0, 1))):
        raise FileError(f"{path}: column 'load' must hold whole numbers and 'validation' 0 or 1")
    grid = np.unique(f)
    labels = np.unique(label)
    n_freq, n_loads = len(grid), len(labels)
    zm = np.full((n_loads, n_freq), np.nan, complex)
    ze = np.full((n_loads, n_freq), np.nan, complex)
    role = np.full(n_loads, -1.0)
    for row in v:
        i, j = np.searchsorted(labels, row[1]), np.searchsorted(grid, row[0])
        if not np.isnan(ze[i, j]):
            raise FileError(f"{path}: load {row[1]:g} is given twice at {row[0]:g} Hz")
        if role[i] not in (-1.0, row[2]):
            raise FileError(f"{path}: load {row[1]:g} is both a calibration and a validation "
                            "load; give each load one role")
        zm[i, j], ze[i, j], role[i] = row[3] + 1j * row[4], row[5] + 1j * row[6], row[2]
    missing = np.argwhere(np.isnan(ze))
    if len(missing):
        i, j = missing[0]
        raise FileError(f"{path}: load {labels[i]:g} has no row at {grid[j]:g} Hz: measure every "
                        f"load on the same frequencies ({n_freq} here)")
    if np.sum(role == 0) < 4:
        raise FileError(f"{path}: {int(np.sum(role == 0))} calibration loads (validation 0); "
                        "the least-squares calibration needs at least 4")
    return {"frequency_hz": grid, "zm": zm, "ze": ze, "validation": role == 1, "load": labels}


def load_sweeps(path: str | Path, *, sigma: float = 1e-3) -> tuple[LoadSweep, ...]:
    """Every load of a loads file as a tip-load sweep for ``wtml device fit`` (relative
    uncertainty ``sigma``), calibration and validation loads alike."""
    loads = read_loads(path)
    f, digest = loads["frequency_hz"], sha256(path)
    return tuple(LoadSweep(zm, Sweep(f, ze, sigma=sigma, source=str(path), sha256=digest),
                           label=f"{label:g}")
                 for label, zm, ze in zip(loads["load"], loads["zm"], loads["ze"], strict=True))


def calibrate(device_ref: str | Path, loads_path: str | Path, *,
              out: str | Path | None = None, max_condition: float = 1e4,
              hue0: float | None = None) -> tuple[Calibration, dict]:
    """Calibrate ``device_ref``'s T on ``loads_path`` (module docstring); store it beside the
    device file (or in folder ``out``), with the measured ``hue0`` (m/V) where given, and
    return it with its summary."""
    if hue0 is not None and not (np.isfinite(hue0) and 1e-15 <= hue0 <= 1.0):
        raise FileError(f"--hue0: must be in [1e-15, 1] m/V (the tip's static displacement "
                        f"per volt), got {hue0!r}")
    device = load_device(device_ref)
    loads = read_loads(loads_path)
    f, zm, ze, val = (loads[k] for k in ("frequency_hz", "zm", "ze", "validation"))
    omega = 2 * np.pi * f
    cal = calibrate_least_squares(zm[~val], ze[~val], omega, max_condition=max_condition)
    summary = {"device": {"name": device.name, "sha256": device_hash(device)},
               "loads": {"path": str(loads_path), "sha256": sha256(loads_path),
                         "calibration": int(np.sum(~val)), "validation": int(np.sum(val))},
               "frequency_hz": f.tolist(), "condition": cal.condition.tolist(),
               "residual": cal.residual.tolist()}
    if hue0 is not None:
        summary["hue0"] = float(hue0)
    if val.any():
        err = np.abs(cal.zm_from_ze(ze[val]) / zm[val] - 1)  # (n_val, n_freq)
        summary["validation_error"] = {"max": float(err.max()), "rms": float(
            np.sqrt(np.mean(err**2))), "per_frequency_max": err.max(axis=0).tolist()}
    model = _model_t(device, omega)
    if model is not None:
        # the model's T against the calibrated one, as the Ze each predicts for the loads
        summary["model_vs_calibrated_ze"] = float(np.max(np.abs(
            ze_from_zm(model, zm) / ze_from_zm(cal.t, zm) - 1)))
    folder = Path(out) if out is not None else device_path(device_ref).parent
    folder.mkdir(parents=True, exist_ok=True)
    npz, js = folder / f"{device.name}.calibration.npz", folder / f"{device.name}.calibration.json"
    extra = {} if hue0 is None else {"hue0": np.float64(hue0)}
    np.savez(npz, frequency_hz=f, t=cal.t, condition=cal.condition,
             residual=cal.residual,
             validation_error=np.asarray(summary.get("validation_error", {}).get(
                 "per_frequency_max", np.full(len(f), np.nan))), **extra)
    summary["files"] = [str(npz), str(js)]
    js.write_text(json.dumps(summary, indent=1) + "\n")
    return cal, summary


def _model_t(device, omega: np.ndarray) -> np.ndarray | None:
    """The device model's T at ``omega`` (tip sphere included), or None if it has none."""
    from wtml.physics import cascade, tip_mass

    if device.kind == "lumped":
        return device.transducer().transduction_matrix(omega)
    from wtml.physics.beam_presets import build

    t = build(device).transduction_matrix(omega)
    if device.sphere is not None:
        t = cascade(t, tip_mass(omega, device.sphere.mass))
    return t


def format_summary(summary: dict) -> str:
    """The calibration as text."""
    lines = [f"calibrated {summary['device']['name']} at "
             f"{len(summary['frequency_hz'])} frequencies on {summary['loads']['calibration']} "
             f"loads (condition number max {max(summary['condition']):.3g}, residual max "
             f"{max(summary['residual']):.2e})"]
    v = summary.get("validation_error")
    lines.append(f"validation on {summary['loads']['validation']} loads: Zm error max "
                 f"{100 * v['max']:.3g} %, rms {100 * v['rms']:.3g} %" if v else
                 "no validation loads: the calibration's error is not measured")
    if "model_vs_calibrated_ze" in summary:
        lines.append(f"the device model's T against the calibrated one: Ze of the loads "
                     f"differs by up to {100 * summary['model_vs_calibrated_ze']:.3g} %")
    if "hue0" in summary:
        lines.append(f"HUE(0) stored with it: {summary['hue0']:.4g} m/V")
    lines.append("written: " + ", ".join(summary["files"]))
    return "\n".join(lines)


__all__ = ["COLUMNS", "StoredCalibration", "calibrate", "format_summary", "load_sweeps",
           "read_loads"]
