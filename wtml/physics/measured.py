"""What a user measures on their transducer (physics.md §13), and reading it from files.

A :class:`Sweep` is an electrical impedance Ze(f) over a frequency grid, with the relative
uncertainty the user states for it (``sigma``: the relative standard deviation of circular
complex noise, as :func:`wtml.signals.noise.complex_noise` draws it; an impedance analyser's
basic accuracy is ~1e-3). :class:`Measurements` gathers what identification uses: the free-tip
sweep (required), optionally a clamped-tip sweep, HUE(0) (static tip displacement per volt), the
tip velocity per volt at some frequencies, and sweeps with a contact (a pin, rigid or of a
stated stiffness) at a known distance from the tip.

Files:
- CSV: a header with ``frequency_hz`` and either ``re_ohm, im_ohm`` or ``magnitude_ohm,
  phase_deg``; lines starting with ``#`` are comments; frequencies positive, finite and
  strictly increasing. A bad cell is refused with one line naming the file, the line and the
  column (:class:`wtml.files.FileError`).
- Touchstone ``.s1p`` (any parameter, format and reference impedance that scikit-rf reads;
  ``Network.z`` gives Ze).
"""

from __future__ import annotations

import csv
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wtml.files import FileError, regular_file, sha256

MEASUREMENT_MAX_BYTES = 16 * 1024**2
"""Bytes: the largest sweep file read (an analyser's sweep is kilobytes)."""

MAX_POINTS = 100_000
"""Frequencies in one sweep at most (an impedance analyser's sweep has up to ~10 000)."""

_FORMS = {"ri": ("re_ohm", "im_ohm"), "ma": ("magnitude_ohm", "phase_deg")}


@dataclass(frozen=True, eq=False)
class Sweep:
    """Ze(f) of the transducer under one condition.

    Attributes:
        frequency_hz: shape ``(n,)``, positive, strictly increasing.
        ze: complex Ω, shape ``(n,)``.
        sigma: stated relative uncertainty of each point (circular complex, ``E|n|² = σ²``).
        source: the file it was read from ("" when made in memory).
        sha256: the file's sha256 ("" when made in memory).
    """

    frequency_hz: np.ndarray
    ze: np.ndarray
    sigma: float = 1e-3
    source: str = ""
    sha256: str = ""

    def __post_init__(self) -> None:
        where = self.source or "sweep"
        f = np.asarray(self.frequency_hz, dtype=float)
        ze = np.asarray(self.ze, dtype=complex)
        if f.size > MAX_POINTS:
            raise FileError(f"{where}: {f.size} frequencies; a sweep has at most {MAX_POINTS}")
        if f.ndim != 1 or ze.shape != f.shape or f.size < 2:
            raise FileError(f"{where}: frequency_hz and ze must be 1-D of one length ≥ 2, got "
                            f"{f.shape} and {ze.shape}")
        if not (np.isfinite(f).all() and (f > 0).all() and (np.diff(f) > 0).all()):
            raise FileError(f"{where}: frequency_hz must be finite, > 0 and strictly increasing")
        if not (np.isfinite(ze).all() and (ze != 0).all()):
            raise FileError(f"{where}: Ze must be finite and nonzero at every frequency")
        if not (0 < self.sigma < 1):
            raise FileError(f"{where}: sigma must be in (0, 1) (relative), got {self.sigma}")
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "ze", ze)

    @property
    def omega(self) -> np.ndarray:
        """rad/s."""
        return 2 * np.pi * self.frequency_hz


@dataclass(frozen=True, eq=False)
class ContactSweep:
    """A free-tip sweep with the whisker touched by a pin at a known place.

    Attributes:
        distance: m from the whisker's tip (as the radial scenes measure it).
        sweep: Ze(f) with the pin there.
        stiffness: N/m of the pin (``inf``: rigid).
    """

    distance: float
    sweep: Sweep
    stiffness: float = math.inf

    def __post_init__(self) -> None:
        if not (math.isfinite(self.distance) and self.distance >= 0):
            raise ValueError(f"contact.distance: must be ≥ 0 m and finite, got {self.distance}")
        if not self.stiffness > 0:
            raise ValueError(f"contact.stiffness: must be > 0 N/m (inf rigid), got "
                             f"{self.stiffness}")


@dataclass(frozen=True, eq=False)
class LoadSweep:
    """Ze with a tip load of known impedance (a calibration load of physics.md §4).

    Attributes:
        zm: the load's Zm at the sweep's frequencies, N·s/m, complex ``(n,)``.
        sweep: Ze(f) with the load on the tip.
        label: the load's label in its file.
    """

    zm: np.ndarray
    sweep: Sweep
    label: str = ""

    def __post_init__(self) -> None:
        zm = np.atleast_1d(np.asarray(self.zm, dtype=complex))
        if zm.shape != self.sweep.frequency_hz.shape or not np.isfinite(zm).all():
            raise ValueError(f"load {self.label}: zm must be finite, one per frequency of its "
                             "sweep")
        object.__setattr__(self, "zm", zm)


@dataclass(frozen=True, eq=False)
class TipVelocity:
    """|tip velocity / drive voltage| at some frequencies (a vibrometer), free tip.

    Attributes:
        frequency_hz: shape ``(n,)``; velocity_per_volt: m/s/V, shape ``(n,)`` (its magnitude
        is fitted: a vibrometer's phase reference is seldom the drive's); sigma: relative;
        source, sha256: the file it came from, if any.
    """

    frequency_hz: np.ndarray
    velocity_per_volt: np.ndarray
    sigma: float = 0.01
    source: str = ""
    sha256: str = ""

    def __post_init__(self) -> None:
        f = np.atleast_1d(np.asarray(self.frequency_hz, dtype=float))
        v = np.atleast_1d(np.asarray(self.velocity_per_volt, dtype=complex))
        if f.shape != v.shape or not (np.isfinite(f).all() and (f > 0).all()):
            raise ValueError("tip_velocity: frequency_hz must be finite and > 0, one per value")
        if not (np.isfinite(v).all() and (v != 0).all()):
            raise ValueError("tip_velocity: velocity_per_volt must be finite and nonzero")
        if not (0 < self.sigma < 1):
            raise ValueError(f"tip_velocity.sigma: must be in (0, 1), got {self.sigma}")
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "velocity_per_volt", v)


@dataclass(frozen=True, eq=False)
class Measurements:
    """Everything identification may use (module docstring).

    Attributes:
        free: the free-tip sweep (required).
        clamped: a clamped-tip sweep, or None.
        hue0: |static tip displacement per volt|, m/V, or None; ``hue0_sigma`` relative.
        tip_velocity: tip velocity per volt, or None.
        contacts: sweeps with a pin at a known distance from the tip.
        loads: sweeps with a known load on the tip (``wtml calibrate``'s loads file).
    """

    free: Sweep
    clamped: Sweep | None = None
    hue0: float | None = None
    hue0_sigma: float = 0.01
    tip_velocity: TipVelocity | None = None
    contacts: tuple[ContactSweep, ...] = field(default_factory=tuple)
    loads: tuple[LoadSweep, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.hue0 is not None and not (math.isfinite(self.hue0) and self.hue0 != 0):
            raise ValueError(f"hue0: must be a finite nonzero m/V, got {self.hue0}")
        if not (0 < self.hue0_sigma < 1):
            raise ValueError(f"hue0_sigma: must be in (0, 1), got {self.hue0_sigma}")
        object.__setattr__(self, "contacts", tuple(self.contacts))
        object.__setattr__(self, "loads", tuple(self.loads))

    def files(self) -> list[dict]:
        """The files behind these measurements: role, path and sha256."""
        roles = [("free", self.free), ("clamped", self.clamped)]
        roles += [(f"contact at {1e3 * c.distance:g} mm", c.sweep) for c in self.contacts]
        roles += [("tip loads", self.loads[0].sweep)] if self.loads else []  # one file
        roles.append(("tip velocity", self.tip_velocity))
        return [{"role": role, "path": s.source, "sha256": s.sha256}
                for role, s in roles if s is not None and s.source]


def _number(path: Path, line: int, column: str, cell: str | None) -> float:
    if cell is None or cell.strip() == "":
        raise FileError(f"{path}: line {line}: no value in column '{column}'")
    try:
        value = float(cell)
    except ValueError:
        raise FileError(f"{path}: line {line}: column '{column}' = {cell.strip()[:40]!r} is "
                        "not a number") from None
    if not math.isfinite(value):
        raise FileError(f"{path}: line {line}: column '{column}' = {cell.strip()[:40]!r} "
                        "must be finite")
    return value


def read_table(path: str | Path, what: str, forms: dict[str, tuple[str, ...]],
               allowed: str, positive: tuple[str, ...] = (), increasing: bool = True
               ) -> tuple[str, np.ndarray]:
    """The header's form (a key of ``forms``: the columns besides ``frequency_hz``) and the
    values ``(n_rows, 1 + n_columns)`` of a small CSV, every cell checked (module
    docstring); ``positive``: columns that must be > 0; ``increasing``: frequencies strictly
    increasing down the rows (a sweep; a table of several loads repeats them)."""
    path = regular_file(path, what=what, max_bytes=MEASUREMENT_MAX_BYTES)
    rows: list[tuple[int, list[str]]] = []
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            lines = ((n, text) for n, text in enumerate(fh, start=1)
                     if text.strip() and not text.lstrip().startswith("#"))
            for n, text in lines:
                rows.append((n, next(csv.reader([text]))))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise FileError(f"{path}: not a readable CSV ({err})") from None
    if not rows:
        raise FileError(f"{path}: empty; a {what} needs a header ({allowed}) and rows")
    header_line, header = rows[0]
    names = [h.strip() for h in header]
    found = [k for k, cols in forms.items() if set(cols) <= set(names)]
    if "frequency_hz" not in names or not found:
        raise FileError(f"{path}: line {header_line}: the header must name {allowed}; got "
                        f"{names[:6]}")
    if len(found) > 1:
        raise FileError(f"{path}: line {header_line}: give one of {allowed}, not both")
    form = found[0]
    cols = ("frequency_hz", *forms[form])
    index = {c: names.index(c) for c in cols}
    values = np.empty((len(rows) - 1, len(cols)))
    for r, (n, row) in enumerate(rows[1:]):
        for j, c in enumerate(cols):
            k = index[c]
            values[r, j] = _number(path, n, c, row[k] if k < len(row) else None)
            if (c == "frequency_hz" or c in positive) and values[r, j] <= 0:
                raise FileError(f"{path}: line {n}: column '{c}' = {values[r, j]:g} must be "
                                "> 0")
        if increasing and r and values[r, 0] <= values[r - 1, 0]:
            raise FileError(f"{path}: line {n}: column 'frequency_hz' = {values[r, 0]:g} must "
                            f"be above the line before ({values[r - 1, 0]:g}): frequencies "
                            "strictly increasing")
    return form, values


def read_csv(path: str | Path, *, sigma: float = 1e-3) -> Sweep:
    """A sweep from CSV (module docstring for the columns).

    Raises:
        FileError: one line naming the file, and the line and column where there is one.
    """
    form, values = read_table(
        path, "sweep CSV", _FORMS,
        "frequency_hz with re_ohm, im_ohm or with magnitude_ohm, phase_deg",
        positive=("magnitude_ohm",))
    if form == "ri":
        zero = np.flatnonzero((values[:, 1] == 0) & (values[:, 2] == 0))
        if zero.size:
            raise FileError(f"{path}: data line {zero[0] + 1}: Ze = 0 Ω (re_ohm and im_ohm "
                            "both 0)")
    if len(values) < 2:
        raise FileError(f"{path}: {len(values)} data line(s); a sweep needs at least 2")
    if form == "ri":
        ze = values[:, 1] + 1j * values[:, 2]
    else:
        ze = values[:, 1] * np.exp(1j * np.deg2rad(values[:, 2]))
    return Sweep(values[:, 0], ze, sigma, str(path), sha256(path))


def read_tip_velocity(path: str | Path, *, sigma: float = 0.01) -> TipVelocity:
    """Tip velocity per volt from CSV: ``frequency_hz, velocity_m_s_per_v`` (its magnitude,
    m/s/V, > 0), refused like :func:`read_csv`."""
    _, values = read_table(path, "tip velocity CSV", {"v": ("velocity_m_s_per_v",)},
                            "frequency_hz, velocity_m_s_per_v",
                            positive=("velocity_m_s_per_v",))
    if len(values) < 1:
        raise FileError(f"{path}: no data line; give at least one frequency")
    return TipVelocity(values[:, 0], values[:, 1], sigma, str(path), sha256(path))


def write_csv(path: str | Path, sweep_or_f, ze=None, *, form: str = "ri") -> Path:
    """Write a sweep as CSV (``form`` ``"ri"`` or ``"ma"``), 17 significant digits."""
    if form not in _FORMS:
        raise ValueError(f"form must be one of {sorted(_FORMS)}, got {form!r}")
    f, z = ((sweep_or_f.frequency_hz, sweep_or_f.ze) if ze is None
            else (np.asarray(sweep_or_f, float), np.asarray(ze, complex)))
    a, b = (z.real, z.imag) if form == "ri" else (np.abs(z), np.rad2deg(np.angle(z)))
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(("frequency_hz", *_FORMS[form]))
        w.writerows((repr(float(x)), repr(float(y)), repr(float(v)))
                    for x, y, v in zip(f, a, b, strict=True))
    return path


def read_s1p(path: str | Path, *, sigma: float = 1e-3) -> Sweep:
    """A sweep from a Touchstone one-port file through scikit-rf (``Network.z``).

    Raises:
        FileError: not a file scikit-rf reads, not one port, or a frequency or Ze it cannot
            use (one line naming the file).
    """
    path = regular_file(path, what="Touchstone file", max_bytes=MEASUREMENT_MAX_BYTES)
    if path.suffix.lower() != ".s1p":
        raise FileError(f"{path}: a Touchstone sweep must be a one-port .s1p file")
    import skrf

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            net = skrf.Network(str(path))
            z = net.z
    except Exception as err:  # scikit-rf raises many kinds on a malformed file
        text = " ".join(str(err).split())[:120] or type(err).__name__
        raise FileError(f"{path}: not a Touchstone file scikit-rf can read ({text})") from None
    if net.nports != 1:
        raise FileError(f"{path}: {net.nports} ports; a sweep is one port (.s1p)")
    f = np.asarray(net.f, dtype=float)
    ze = np.asarray(z[:, 0, 0], dtype=complex)
    if f.size < 2:
        raise FileError(f"{path}: {f.size} frequency point(s); a sweep needs at least 2")
    bad = np.flatnonzero(~np.isfinite(ze) | (ze == 0))
    if bad.size:
        raise FileError(f"{path}: frequency point {bad[0] + 1} ({f[bad[0]]:g} Hz): Ze is "
                        f"{ze[bad[0]]} (an open or short at the reference plane?); must be "
                        "finite and nonzero")
    if not (np.isfinite(f).all() and (f > 0).all() and (np.diff(f) > 0).all()):
        raise FileError(f"{path}: frequencies must be finite, > 0 and strictly increasing")
    return Sweep(f, ze, sigma, str(path), sha256(path))


def write_s1p(path: str | Path, sweep_or_f, ze=None, *, reference_ohm: float | None = None
              ) -> Path:
    """Write a sweep as a Touchstone ``.s1p`` of Z-parameters (scikit-rf), normalised to
    ``reference_ohm`` (default: the geometric mean of |Ze|, so no digits are lost)."""
    import skrf

    f, z = ((sweep_or_f.frequency_hz, sweep_or_f.ze) if ze is None
            else (np.asarray(sweep_or_f, float), np.asarray(ze, complex)))
    ref = float(np.exp(np.mean(np.log(np.abs(z))))) if reference_ohm is None else reference_ohm
    path = Path(path)
    net = skrf.Network.from_z(z[:, None, None], frequency=skrf.Frequency.from_f(f, unit="Hz"),
                              z0=ref)
    out = path.with_suffix(".s1p")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        written = net.write_touchstone(str(out.with_suffix("")), parameter="Z", r_ref=ref,
                                       format_spec_A="{:.17g}", format_spec_B="{:.17g}",
                                       format_spec_freq="{:.17g}", return_string=True)
    out.write_text(written, encoding="utf-8")  # scikit-rf names a Z file .z1p; keep .s1p
    return out


def read_sweep(path: str | Path, *, sigma: float = 1e-3) -> Sweep:
    """A sweep from ``.csv`` or ``.s1p`` by its suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return read_csv(path, sigma=sigma)
    if suffix == ".s1p":
        return read_s1p(path, sigma=sigma)
    raise FileError(f"{path}: a sweep must be .csv (frequency_hz, re_ohm, im_ohm or "
                    "magnitude_ohm, phase_deg) or a Touchstone .s1p")


def load_measurements(free: str | Path, *, sigma: float = 1e-3, clamped: str | Path | None = None,
                      contacts: tuple = (), hue0: float | None = None, hue0_sigma: float = 0.01,
                      tip_velocity: str | Path | None = None, tip_sigma: float = 0.01
                      ) -> Measurements:
    """:class:`Measurements` from files: ``free`` and ``clamped`` sweeps (.csv or .s1p, each
    with the stated relative uncertainty ``sigma``), ``contacts`` as ``(distance_m, path)`` or
    ``(distance_m, path, stiffness_n_per_m)`` (rigid when not given), ``hue0`` in m/V and a
    tip velocity CSV (:func:`read_tip_velocity`)."""
    pins = []
    for i, c in enumerate(contacts):
        if len(c) not in (2, 3):
            raise ValueError(f"contacts[{i}]: give (distance_m, path) or (distance_m, path, "
                             f"stiffness_n_per_m), got {c!r}")
        stiff = float(c[2]) if len(c) == 3 else math.inf
        pins.append(ContactSweep(float(c[0]), read_sweep(c[1], sigma=sigma), stiff))
    return Measurements(
        read_sweep(free, sigma=sigma),
        clamped=None if clamped is None else read_sweep(clamped, sigma=sigma),
        hue0=hue0, hue0_sigma=hue0_sigma,
        tip_velocity=None if tip_velocity is None else read_tip_velocity(tip_velocity,
                                                                          sigma=tip_sigma),
        contacts=tuple(pins))


__all__ = ["MAX_POINTS", "MEASUREMENT_MAX_BYTES", "ContactSweep", "Measurements", "Sweep",
           "TipVelocity", "load_measurements", "read_csv", "read_s1p", "read_sweep", "read_table",
           "read_tip_velocity", "write_csv", "write_s1p"]
