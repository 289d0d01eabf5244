"""Device files: a transducer described in YAML, validated, named and hashed (physics.md §7, §13).

A device is what a sensor builder has on the bench: a beam transducer (:class:`BeamDevice`: the
bimorph's layers, an optional epoxy block, the whisker, an optional clamp mass and tip sphere,
the piezo constants and the losses) or a one-mode lumped stand-in (:class:`LumpedDevice`).
Shipped devices live in ``configs/devices/<name>.yaml`` (the thesis's transducers, with their
fitted free lengths); a scene's ``device:`` names one of them or gives the path of a user's
file. Every value is SI (units in the shipped files' comments) and checked like a scene's: one
line naming the key path and the allowed range.

A device's identity is its name and :func:`device_hash`, the sha256 of its validated physical
contents (comments, key order, number spelling, provenance and fit settings do not count):
dataset manifests and exports carry both, and ``wtml predict --device`` compares them.

Imports numpy and pyyaml only (through :mod:`wtml.schema`): the device runtime uses it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wtml.schema import SchemaError, bounded, build, mapping_hash, one_of, read_yaml, to_dict

DEVICES_DIR = Path(__file__).resolve().parent.parent / "configs" / "devices"
"""Where the shipped device files are (``configs/devices`` of the repository)."""
DEVICE_MAX_BYTES = 256 * 1024
"""Bytes: the largest device file read."""

FITTABLE_LENGTHS = ("bimorph.free_length", "whisker.length")
"""The lengths a preset's provenance may have fitted to the thesis's resonances."""


@dataclass(frozen=True)
class Material:
    """An isotropic passive material: Young's modulus in Pa, density in kg/m³."""

    modulus: float = bounded(1.0, 1e13)
    density: float = bounded(1.0, 1e5)


@dataclass(frozen=True)
class Piezo:
    """The PZT's constants (physics.md §7, Table 3.2): d31 in m/V, s11E in m²/N, ε33S in F/m,
    density in kg/m³."""

    d31: float = bounded(-1e-8, 1e-8, default=-2.74e-10)
    s11e: float = bounded(1e-13, 1e-9, default=1.65e-11)
    eps33s: float = bounded(1e-12, 1e-6, default=3400 * 8.8541878128e-12)
    density: float = bounded(100.0, 1e5, default=7500.0)

    def check(self, path: str) -> None:
        if self.d31 == 0:
            raise SchemaError(f"{path}.d31: must not be 0 (a piezo without coupling)")


@dataclass(frozen=True)
class Bimorph:
    """The PZT / substrate / PZT bimorph, series poled: ``length`` as bought and
    ``free_length`` outside the holder (m; the clamp mass's position is measured from the
    bimorph's fixed end, ``length - free_length`` inside the holder); ``width``, each PZT
    layer's ``t_piezo`` and the middle layer's ``t_substrate`` (0: none) in m."""

    length: float = bounded(1e-5, 1.0)
    free_length: float = bounded(1e-5, 1.0)
    width: float = bounded(1e-6, 0.1)
    t_piezo: float = bounded(1e-7, 0.01)
    t_substrate: float = bounded(0.0, 0.01)
    substrate: Material = field(default_factory=lambda: Material(1.0, 1.0))

    def check(self, path: str) -> None:
        if self.free_length > self.length:
            raise SchemaError(f"{path}.free_length: {self.free_length:g} m is longer than the "
                              f"bimorph, length {self.length:g} m")


@dataclass(frozen=True)
class Block:
    """A passive block (the macro transducer's epoxy) at the bimorph's free end, bending
    across ``thickness``; lengths in m."""

    length: float = bounded(1e-6, 0.1)
    width: float = bounded(1e-6, 0.1)
    thickness: float = bounded(1e-7, 0.1)
    material: Material = field(default_factory=lambda: Material(3.5e9, 1000.0))


@dataclass(frozen=True)
class Whisker:
    """The whisker: ``section`` round (``size`` is its radius, m) or square (``size`` is its
    side, m), ``length`` in m from the bimorph's (or block's) end to the tip."""

    section: str = one_of("round", "square")
    length: float = bounded(1e-5, 1.0)
    size: float = bounded(1e-7, 0.01)
    material: Material = field(default_factory=lambda: Material(185e9, 7900.0))


@dataclass(frozen=True)
class Clamp:
    """A point mass clamped on the bimorph (the macro transducer's 2.3338 g clamp):
    ``position`` in m from the bimorph's fixed end, ``mass`` in kg."""

    position: float = bounded(0.0, 1.0)
    mass: float = bounded(0.0, 1.0)


@dataclass(frozen=True)
class Sphere:
    """A sphere carried on the tip: ``radius`` in m, ``density`` in kg/m³."""

    radius: float = bounded(1e-6, 0.05)
    density: float = bounded(1.0, 1e5)

    @property
    def mass(self) -> float:
        """kg."""
        return self.density * 4 / 3 * math.pi * self.radius**3


@dataclass(frozen=True)
class Losses:
    """The structural loss factor of every segment (a complex modulus ``E(1 + i η)``), the
    whisker's where it differs, and the PZT's dielectric loss tangent tanδ, dimensionless."""

    loss_factor: float = bounded(0.0, 1.0, default=0.02)
    tan_delta: float = bounded(0.0, 1.0, default=0.02)
    whisker: float | None = bounded(0.0, 1.0, default=None)
    """The whisker's own loss factor where it differs from the rest (a glued steel wire is
    not the PZT); ``null``: ``loss_factor``."""


@dataclass(frozen=True)
class FreeLength:
    """One length a preset's provenance fitted, within ``[low, high]`` m."""

    name: str = one_of(*FITTABLE_LENGTHS)
    low: float = bounded(0.0, 1.0)
    high: float = bounded(0.0, 1.0)

    def check(self, path: str) -> None:
        if self.low > self.high:
            raise SchemaError(f"{path}.low: {self.low:g} is above high {self.high:g}")


@dataclass(frozen=True)
class Target:
    """A resonance a fit matched: ``condition`` bare, clamp (with the clamp mass) or sphere
    (with the tip sphere), at ``hz``."""

    condition: str = one_of("bare", "clamp", "sphere")
    hz: float = bounded(1e-3, 1e7)


@dataclass(frozen=True)
class Posterior:
    """What a fit (``wtml device fit``) left unknown: the Gaussian posterior of its free
    parameters about the file's values, as each one's relative standard error (its factor's
    standard error over the fitted factor) and their correlations (``n × n``, row by row). A
    scene's ``spread.posterior`` draws devices from it: correlated, so the devices differ by
    what the measurements could not tell apart, not by a box of independent tolerances."""

    parameters: tuple[str, ...] = ()
    standard_errors: tuple[float, ...] = bounded(0.0, 10.0, default=())
    correlation: tuple[float, ...] = bounded(-1.0, 1.0, default=())

    def check(self, path: str) -> None:
        n = len(self.parameters)
        if len(set(self.parameters)) != n:
            raise SchemaError(f"{path}.parameters: each parameter once, got "
                              f"{list(self.parameters)}")
        if len(self.standard_errors) != n or len(self.correlation) != n * n:
            raise SchemaError(f"{path}: {n} parameters need {n} standard_errors and {n * n} "
                              f"correlations (row by row), got {len(self.standard_errors)} "
                              f"and {len(self.correlation)}")
        corr = self.correlation_matrix()
        if n and (not np.allclose(corr, corr.T, atol=1e-9)
                  or not np.allclose(np.diag(corr), 1.0, atol=1e-9)
                  or np.linalg.eigvalsh(corr).min() < -1e-9):
            raise SchemaError(f"{path}.correlation: must be a correlation matrix (symmetric, "
                              "ones on the diagonal, positive semidefinite)")

    def correlation_matrix(self) -> np.ndarray:
        """The correlations, ``(n, n)``."""
        n = len(self.parameters)
        return np.asarray(self.correlation, float).reshape(n, n)

    def draw(self, scale: float, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``n`` devices' factors of the file's values, each parameter ``(n,)``: Gaussian
        about 1 with the posterior's covariance times ``scale²``."""
        sd = np.asarray(self.standard_errors, float)
        try:  # the Cholesky factor: the same draws on every machine
            root = np.linalg.cholesky(self.correlation_matrix()) * sd[:, None] * scale
        except np.linalg.LinAlgError:  # correlations singular to rounding
            vals, vecs = np.linalg.eigh(self.correlation_matrix())
            root = vecs * np.sqrt(np.clip(vals, 0.0, None)) * sd[:, None] * scale
        x = root @ rng.standard_normal((len(sd), n))
        return {p: 1.0 + x[i] for i, p in enumerate(self.parameters)}


@dataclass(frozen=True)
class Provenance:
    """Where the values come from: ``source`` in words and, for a fitted device, the lengths
    that were free and the resonances they were fitted to (a thesis preset's), or the fit's
    posterior (``wtml device fit``'s)."""

    source: str = ""
    free: tuple[FreeLength, ...] = ()
    targets: tuple[Target, ...] = ()
    posterior: Posterior | None = None


@dataclass(frozen=True)
class FreeFactor:
    """A parameter ``wtml device fit`` may adjust: a factor of the device's value within
    ``[low, high]`` (``parameter``: one of ``wtml.physics.beam_presets.device_parameters``, or
    ``tip_mass``, the sphere's mass)."""

    parameter: str
    low: float = bounded(1e-3, 1e3)
    high: float = bounded(1e-3, 1e3)

    def check(self, path: str) -> None:
        if not self.low < 1.0 < self.high:
            raise SchemaError(f"{path}: the range must hold factor 1 (the file's value) "
                              f"inside: low < 1 < high, got [{self.low:g}, {self.high:g}]")


@dataclass(frozen=True)
class Identify:
    """What ``wtml device fit`` adjusts when this file is its starting point."""

    free: tuple[FreeFactor, ...] = ()


@dataclass(frozen=True)
class BeamDevice:
    """A beam transducer (physics.md §3, §7): segments bimorph [, block], whisker, with an
    optional clamp mass and tip sphere."""

    name: str
    bimorph: Bimorph
    whisker: Whisker
    kind: str = one_of("beam", default="beam")
    block: Block | None = None
    clamp: Clamp | None = None
    sphere: Sphere | None = None
    piezo: Piezo = field(default_factory=Piezo)
    losses: Losses = field(default_factory=Losses)
    provenance: Provenance = field(default_factory=Provenance)
    identify: Identify = field(default_factory=Identify)

    def check(self, path: str) -> None:
        _check_name(self.name, path)
        for i, free in enumerate(self.provenance.free):
            value = self.length_of(free.name)
            if not free.low <= value <= free.high:
                raise SchemaError(f"{path + '.' if path else ''}provenance.free[{i}]: "
                                  f"{free.name} = {value:g} m is outside its fitted range "
                                  f"[{free.low:g}, {free.high:g}]")
        if any(t.condition == "clamp" for t in self.provenance.targets) and self.clamp is None:
            raise SchemaError(f"{path + '.' if path else ''}provenance.targets: a clamp "
                              "target needs a clamp")
        if any(t.condition == "sphere" for t in self.provenance.targets) and self.sphere is None:
            raise SchemaError(f"{path + '.' if path else ''}provenance.targets: a sphere "
                              "target needs a sphere")

    @classmethod
    def resolve(cls, value: Any, path: str) -> BeamDevice:
        """A scene's ``device:`` given as a name or a path: it must hold a beam device."""
        return _of_kind(cls, value, path)

    def length_of(self, name: str) -> float:
        """The value of a fittable length (:data:`FITTABLE_LENGTHS`), m."""
        return {"bimorph.free_length": self.bimorph.free_length,
                "whisker.length": self.whisker.length}[name]

    def with_lengths(self, values: dict[str, float]) -> BeamDevice:
        """This device with fittable lengths replaced (``{name: m}``)."""
        bim, wh = self.bimorph, self.whisker
        if "bimorph.free_length" in values:
            bim = dataclasses.replace(bim, free_length=float(values["bimorph.free_length"]))
        if "whisker.length" in values:
            wh = dataclasses.replace(wh, length=float(values["whisker.length"]))
        return dataclasses.replace(self, bimorph=bim, whisker=wh)


@dataclass(frozen=True)
class LumpedDevice:
    """A one-mode lumped transducer (physics.md §3; ``wtml.physics.lumped``), referred to the
    whisker tip: clamped capacitance ``c0`` in F, coupling ``phi`` in N/V, modal mass ``m`` in
    kg, resonance ``f0`` in Hz (short-circuited, without a sphere), quality factor ``q``,
    dielectric loss tangent ``tan_delta``."""

    name: str
    c0: float = bounded(1e-15, 1e-3)
    phi: float = bounded(1e-12, 1e3)
    m: float = bounded(1e-12, 1e3)
    f0: float = bounded(1e-3, 1e7)
    q: float = bounded(0.1, 1e7)
    kind: str = one_of("lumped", default="lumped")
    tan_delta: float = bounded(0.0, 1.0, default=0.02)
    provenance: Provenance = field(default_factory=Provenance)

    def check(self, path: str) -> None:
        _check_name(self.name, path)
        if self.provenance.posterior is not None:
            raise SchemaError(f"{path + '.' if path else ''}provenance.posterior: a lumped "
                              "device has no fit posterior (wtml device fit fits beams)")

    @classmethod
    def resolve(cls, value: Any, path: str) -> LumpedDevice:
        """A scene's ``device:`` given as a name or a path: it must hold a lumped device."""
        return _of_kind(cls, value, path)

    def transducer(self):
        """The :class:`~wtml.physics.lumped.LumpedTransducer`."""
        from wtml.physics.lumped import LumpedTransducer

        return LumpedTransducer.from_resonance(c0=self.c0, phi=self.phi, m=self.m, f0=self.f0,
                                               q=self.q, tan_delta=self.tan_delta)


@dataclass(frozen=True)
class DeviceIdentity:
    """What a dataset manifest, a checkpoint and an export carry of their device: its name and
    :func:`device_hash`."""

    name: str
    sha256: str

    def check(self, path: str) -> None:
        _check_name(self.name, path)
        if not re.fullmatch(r"[0-9a-f]{64}", self.sha256):
            raise SchemaError(f"{path + '.' if path else ''}sha256: must be 64 hex digits, got "
                              f"{self.sha256!r:.80}")


Device = BeamDevice | LumpedDevice
KINDS = {"beam": BeamDevice, "lumped": LumpedDevice}


def _check_name(name: str, path: str) -> None:
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        raise SchemaError(f"{path + '.' if path else ''}name: must be 1-64 letters, digits, "
                          f"'.', '-' or '_', got {name!r:.80}")


def device_from_dict(data: Any, path: str = "device") -> Device:
    """A device from a mapping (a device file's, or the one stored in a scene); its ``kind``
    picks the class. Errors are :class:`SchemaError` starting with ``path``."""
    if not isinstance(data, dict):
        raise SchemaError(f"{path}: must be a device's name, a device file's path or a mapping "
                          f"of a device's keys, got {type(data).__name__}")
    kind = data.get("kind")
    if kind not in KINDS:
        raise SchemaError(f"{path}.kind: must be one of {sorted(KINDS)}, got {kind!r:.80}")
    return build(KINDS[kind], data, path)


def shipped_devices() -> list[str]:
    """Names of the shipped device files, sorted."""
    return sorted(p.stem for p in DEVICES_DIR.glob("*.yaml"))


def device_path(ref: str | Path) -> Path:
    """The file a device reference names: a shipped name (``micro``) or a path to a ``.yaml``
    file. A reference that is neither is a :class:`SchemaError` listing the shipped names."""
    text = str(ref)
    if "/" not in text and not text.endswith((".yaml", ".yml")):
        path = DEVICES_DIR / f"{text}.yaml"
        if not path.is_file():
            raise SchemaError(f"unknown device {text!r:.80}: not a shipped device "
                              f"({', '.join(shipped_devices())}) nor a path to a .yaml file")
        return path
    return Path(text)


def load_device(ref: str | Path) -> Device:
    """Read a device: a shipped name or a path. Errors name the file and the key path."""
    path = device_path(ref)
    data = read_yaml(path, what="device file")
    try:
        device = device_from_dict(data, "")
    except SchemaError as err:
        raise SchemaError(f"{path}: {str(err).lstrip('.')}") from None
    return device


def resolve(value: Any, path: str) -> Device:
    """A scene's ``device:`` value as a device: a name or path (read from its file), or the
    mapping of one (as a manifest stores it). Errors start with ``path``."""
    if isinstance(value, str):
        try:
            return load_device(value)
        except ValueError as err:  # SchemaError, or wtml.files.FileError for the file itself
            raise SchemaError(f"{path}: {err}") from None
    return device_from_dict(value, path)


def _of_kind(cls: type, value: Any, path: str) -> Any:
    device = resolve(value, path)
    if not isinstance(device, cls):
        want = next(k for k, c in KINDS.items() if c is cls)
        raise SchemaError(f"{path}: this scene needs a {want} device; {device.name!r} is a "
                          f"{device.kind} one (shipped: {', '.join(shipped_devices())})")
    return device


def shipped(name: str) -> Any:
    """A default factory: the shipped device ``name`` (read when a scene is built)."""
    return lambda: load_device(name)


NOT_PHYSICS = ("provenance", "identify")
"""A device's keys that say where it comes from or how to fit it, not what it is: outside its
hash."""


def physical_hash(device: dict) -> str:
    """sha256 of the canonical JSON of a device's mapping (as a scene or manifest stores it),
    :data:`NOT_PHYSICS` left out."""
    return mapping_hash({k: v for k, v in device.items() if k not in NOT_PHYSICS})


def device_hash(device: Device) -> str:
    """sha256 of the device's validated physical contents (not its provenance or fit
    settings): its identity beside its name."""
    return physical_hash(to_dict(device))


def identity(device: Device) -> dict[str, str]:
    """``{"name": ..., "sha256": ...}``: what datasets and exports carry."""
    return {"name": device.name, "sha256": device_hash(device)}


__all__ = ["DEVICES_DIR", "BeamDevice", "Block", "Bimorph", "Clamp", "Device", "DeviceIdentity",
           "LumpedDevice", "Losses", "Material", "Piezo", "Posterior", "Provenance", "Sphere",
           "Whisker", "device_from_dict", "device_hash", "device_path", "identity", "load_device",
           "resolve", "shipped_devices"]
