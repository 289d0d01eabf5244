"""``wtml device fit``: a device file fitted to a user's measurements (physics.md §13).

The starting device file says which parameters are free (its ``identify.free`` block, factors of
its values with their ranges; ``--free`` on the command line overrides it); the measurements are
files (:func:`wtml.physics.measured.load_measurements`). The fit is
:func:`wtml.physics.identify.fit_device`; its result is written as a new device file (the
factors folded into the values, :func:`wtml.physics.beam_presets.apply_factors`, with the fit as
its provenance), a JSON report, and a Bode plot.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import yaml

from wtml.devices import (
    BeamDevice,
    Identify,
    Posterior,
    Provenance,
    Sphere,
    device_hash,
    load_device,
)
from wtml.physics.beam_presets import apply_factors, beam_device, build, fit_parameters
from wtml.physics.identify import DeviceFit, fit_device, format_resonance_table, nominal_values
from wtml.physics.measured import Measurements
from wtml.schema import SchemaError, to_dict


def free_factors(device: BeamDevice, overrides: list[str] | None = None
                 ) -> dict[str, tuple[float, float]]:
    """``{parameter: (low, high)}``: the device file's ``identify.free``, or ``overrides``
    (``NAME=LOW:HIGH`` each) where given. Unknown names and bad ranges are one line naming
    them and the allowed names."""
    allowed = sorted(fit_parameters(device)) + (["tip_mass"] if device.sphere else [])
    if overrides:
        free = {}
        for text in overrides:
            name, _, rng = text.partition("=")
            low, _, high = rng.partition(":")
            try:
                free[name] = (float(low), float(high))
            except ValueError:
                raise ValueError(f"--free {text!r}: write NAME=LOW:HIGH (factors), e.g. "
                                 "bimorph.length=0.9:1.1") from None
        where = "--free"
    else:
        free = {f.parameter: (f.low, f.high) for f in device.identify.free}
        where = f"{device.name}: identify.free"
    if not free:
        raise ValueError(f"{device.name}: nothing to fit: give the device file an identify.free "
                         "block or --free NAME=LOW:HIGH (factors of the file's values); "
                         f"parameters: {allowed}")
    for name, (low, high) in free.items():
        if name not in allowed:
            raise ValueError(f"{where}: {name!r} is not a parameter of device {device.name!r}; "
                             f"allowed: {allowed}")
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low < 1 < high):
            raise ValueError(f"{where}: {name}: the range must be 0 < low < 1 < high (factors "
                             f"of the file's value), got [{low:g}, {high:g}]")
    return free


def fit(device_ref: str | Path, measurements: Measurements, *,
        free: list[str] | None = None) -> tuple[BeamDevice, DeviceFit]:
    """The starting device and its fit to ``measurements`` (see the module docstring)."""
    device = beam_device(load_device(device_ref))
    ranges = free_factors(device, free)
    tip = device.sphere.mass if device.sphere is not None else 0.0
    result = fit_device(lambda f: build(device, factors=f), ranges, measurements,
                        tip_mass=tip, nominal=nominal_values(device))
    return device, result


def fitted_device(device: BeamDevice, result: DeviceFit, name: str) -> BeamDevice:
    """The fitted device file: the factors folded into the values, the tip mass into the
    sphere's density, the fit as its provenance."""
    factors = {k: v for k, v in result.factors.items() if k != "tip_mass"}
    out = apply_factors(device, factors)
    if "tip_mass" in result.factors and device.sphere is not None:
        out = dataclasses.replace(out, sphere=Sphere(
            device.sphere.radius, device.sphere.density * result.factors["tip_mass"]))
    parts = ", ".join(f"{k} x{result.factors[k]:.6g} ± {result.standard_errors[k]:.2g}"
                      for k in result.free)
    files = ", ".join(f"{f['role']} {Path(f['path']).name} ({f['sha256'][:12]})"
                      for f in result.measurements.files())
    source = (f"wtml device fit of {device.name} ({device_hash(device)[:12]}) to "
              f"{files or 'measurements'}: {parts}; reduced chi2 {result.reduced_chi2:.3g}")
    return dataclasses.replace(out, name=name, provenance=Provenance(
        source=source, posterior=posterior(result)), identify=Identify())


def posterior(result: DeviceFit) -> Posterior:
    """The fit's Gaussian posterior about the fitted values (the device file's
    ``provenance.posterior``, what a scene's ``spread.posterior`` draws from): each free
    parameter's standard error relative to its fitted factor and their correlations. The
    tip mass, which the sphere's density holds and no spread draws, is held at its fit: the
    others' covariance is the one conditional on it. A parameter the fit could not determine
    (a non-finite standard error, which ``wtml device fit`` refuses) is left out."""
    names = list(result.free)
    f = np.array([result.factors[k] for k in names])
    cov = np.asarray(result.covariance, float) / np.outer(f, f)
    finite = np.isfinite(np.diag(cov)) & np.all(np.isfinite(cov), axis=1)
    keep = [i for i, k in enumerate(names) if k != "tip_mass" and finite[i]]
    held = [i for i, k in enumerate(names) if k == "tip_mass" and finite[i]]
    c = cov[np.ix_(keep, keep)]
    if held:
        cab = cov[np.ix_(keep, held)]
        c = c - cab @ np.linalg.solve(cov[np.ix_(held, held)], cab.T)
    sd = np.sqrt(np.clip(np.diag(c), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.clip(c / np.outer(sd, sd), -1.0, 1.0)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    return Posterior(parameters=tuple(names[i] for i in keep),
                     standard_errors=tuple(float(x) for x in sd),
                     correlation=tuple(float(x) for x in corr.ravel()))


def write_device(device: BeamDevice, path: str | Path) -> Path:
    """A device file (YAML, SI units) that :func:`wtml.devices.load_device` reads back to the
    same device."""
    path = Path(path)
    text = ("# A device file written by wtml device fit (SI units: m, kg, Pa, F/m).\n"
            + yaml.safe_dump(to_dict(device), sort_keys=False, width=100, allow_unicode=True))
    path.write_text(text)
    if load_device(path) != device:  # what is written is what is read
        raise SchemaError(f"{path}: the written device does not read back the same")
    return path


def on_bound(result: DeviceFit) -> list[str]:
    """The free parameters whose fit sits on a bound of its range (within 1e-6 of its width):
    the answer there is the range's, not the data's."""
    return [name for name, (lo, hi) in result.free.items()
            if min(result.factors[name] - lo, hi - result.factors[name]) <= 1e-6 * (hi - lo)]


def format_report(device: BeamDevice, result: DeviceFit) -> str:
    """The fit as text: every free parameter (start, fit, standard error, SI value), the
    reduced χ², the residuals, the resonance table and the notes."""
    lines = [f"device fit of {device.name}: {len(result.free)} free parameters, reduced chi2 "
             f"{result.reduced_chi2:.3g}",
             "| parameter | range | factor | standard error | SI value |",
             "|---|---|---|---|---|"]
    nominal = result.nominal
    for name, (lo, hi) in result.free.items():
        f, se = result.factors[name], result.standard_errors[name]
        si = ""
        if name in nominal:
            value, unit = nominal[name]
            si = f"{value * f:.6g} ± {abs(value) * se:.2g} {unit}"
        lines.append(f"| {name} | {lo:g}–{hi:g} | {f:.6f} | {se:.2g} | {si} |")
    lines += [f"warning: {name} = {result.factors[name]:g} sits on its bound: the truth may "
              "lie outside the range, or the measurements do not pin it (widen the range, or "
              "measure what shows it)" for name in on_bound(result)]
    rms = ", ".join(f"{k} {v:.2e}" for k, v in result.residual_rms().items())
    lines += [f"residual rms (relative): {rms}", "", format_resonance_table(result.table)]
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def write_outputs(device: BeamDevice, result: DeviceFit, out: Path, *, name: str | None = None,
                  plot: Path | None = None, report: Path | None = None) -> BeamDevice:
    """The fitted device file at ``out`` and, where asked, the Bode plot and the JSON report."""
    fitted = fitted_device(device, result, name or f"{device.name}-fitted")
    for path in (out, plot, report):
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_device(fitted, out)
    if plot is not None:
        result.plot(plot)
    if report is not None:
        Path(report).write_text(json.dumps(result.report() | {
            "device": {"start": device.name, "fitted": fitted.name,
                       "sha256": device_hash(fitted)}}, indent=1) + "\n")
    return fitted


__all__ = ["fit", "fitted_device", "format_report", "free_factors", "on_bound", "posterior",
           "write_device", "write_outputs"]
