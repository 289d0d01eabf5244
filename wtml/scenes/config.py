"""Frozen, validated config dataclasses loaded from YAML, with errors that name the key path.

A field's allowed range lives in its metadata (:func:`bounded`); :func:`build` walks a mapping
into nested dataclasses, refusing unknown keys, missing keys and out-of-range values with a
:class:`SceneError` such as ``excitation.n_freq: must be in [2, 4096], got 1``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml


class SceneError(ValueError):
    """A scene file with an unknown key, a missing key or a value out of range."""


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``2.4e4`` and ``1e-3`` as numbers: YAML 1.1 wants a dot
    and a signed exponent (``2.4e+4``) and would return the string ``"2.4e4"``."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def yaml_load(text: str) -> Any:
    """Parse YAML safely (no Python objects), numbers in scientific notation included."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader: plain types only


def bounded(low: float, high: float, *, default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field whose value (or each element of a pair) must lie in [low, high]."""
    return dataclasses.field(default=default, metadata={"range": (low, high)})


def one_of(*choices: str, default: Any = dataclasses.MISSING) -> Any:
    """A string field restricted to ``choices``."""
    return dataclasses.field(default=default, metadata={"choices": choices})


def mixture(path: str, weights: Any, family: tuple[str, ...]) -> np.ndarray:
    """The probabilities of a mixture ``{member: weight}`` over ``family``, in its order, shape
    ``(len(family),)``. A member not in the family, a weight that is not a number >= 0, or
    weights that are all 0 is a SceneError naming ``path`` and the allowed members."""
    if not isinstance(weights, Mapping) or not weights:
        raise SceneError(f"{path}: a mapping of members of {list(family)} to weights, "
                         f"got {weights!r}")
    for name, weight in weights.items():
        if name not in family:
            raise SceneError(f"{path}: unknown law {name!r}; allowed laws: {list(family)}")
        if isinstance(weight, bool) or not isinstance(weight, int | float) or not (
                0 <= weight < float("inf")):
            raise SceneError(f"{path}.{name}: the weight must be a number >= 0, got {weight!r}")
    p = np.array([float(weights.get(name, 0.0)) for name in family])
    if p.sum() <= 0:
        raise SceneError(f"{path}: the weights must not all be 0 (laws: {list(family)})")
    return p / p.sum()


def _check_number(path: str, value: Any, low: float, high: float, kind: type) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SceneError(f"{path}: must be a number in [{low:g}, {high:g}], got {value!r}")
    if kind is int and float(value) != int(value):
        raise SceneError(f"{path}: must be an integer in [{low:g}, {high:g}], got {value!r}")
    if not low <= value <= high:  # NaN fails too
        raise SceneError(f"{path}: must be in [{low:g}, {high:g}], got {value!r}")
    return kind(value)


def _convert(path: str, hint: Any, value: Any, meta: Mapping) -> Any:
    if dataclasses.is_dataclass(hint):
        return build(hint, value, path)
    origin = typing.get_origin(hint)
    if origin is tuple and typing.get_args(hint)[-1] is Ellipsis:  # a list of floats
        low, high = meta.get("range", (-float("inf"), float("inf")))
        if not isinstance(value, list | tuple):
            raise SceneError(f"{path}: must be a list of numbers in [{low:g}, {high:g}], "
                             f"got {value!r}")
        return tuple(_check_number(f"{path}[{k}]", v, low, high, float)
                     for k, v in enumerate(value))
    if origin is tuple:  # a (low, high) pair of floats
        low, high = meta.get("range", (-float("inf"), float("inf")))
        if not isinstance(value, list | tuple) or len(value) != 2:
            raise SceneError(f"{path}: must be a [low, high] pair within [{low:g}, {high:g}], "
                             f"got {value!r}")
        pair = tuple(_check_number(f"{path}[{k}]", v, low, high, float)
                     for k, v in enumerate(value))
        if pair[0] > pair[1]:
            raise SceneError(f"{path}: low {pair[0]:g} is above high {pair[1]:g}")
        return pair
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise SceneError(f"{path}: must be a mapping, got {value!r}")
        return dict(value)
    if hint is str:
        choices = meta.get("choices")
        if not isinstance(value, str) or (choices and value not in choices):
            allowed = f"one of {list(choices)}" if choices else "a string"
            raise SceneError(f"{path}: must be {allowed}, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise SceneError(f"{path}: must be true or false, got {value!r}")
        return value
    if hint in (int, float):
        low, high = meta.get("range", (-float("inf"), float("inf")))
        return _check_number(path, value, low, high, hint)
    raise TypeError(f"{path}: unsupported field type {hint!r}")


def build(cls: type, data: Any, path: str = "") -> Any:
    """Build dataclass ``cls`` from a mapping, validating every key (see module docstring)."""
    where = path or cls.__name__
    if not isinstance(data, Mapping):
        raise SceneError(f"{where}: must be a mapping, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise SceneError(f"{path + '.' if path else ''}{unknown[0]}: unknown key; "
                         f"allowed keys here: {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        key_path = f"{path}.{name}" if path else name
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SceneError(f"{key_path}: missing")
            continue
        kwargs[name] = _convert(key_path, hints[name], data[name], f.metadata)
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if check is not None:
        check(path)
    return obj


def load_yaml(cls: type, path: str | Path) -> Any:
    """Read a YAML file into dataclass ``cls``; errors name the file and the key path."""
    path = Path(path)
    try:
        data = yaml_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise SceneError(f"{path}: cannot read: {err}") from err
    try:
        return build(cls, data)
    except SceneError as err:
        raise SceneError(f"{path}: {err}") from None


def to_dict(obj: Any) -> dict:
    """The plain mapping a config was built from (tuples as lists)."""
    return json.loads(json.dumps(dataclasses.asdict(obj)))


def config_hash(obj: Any) -> str:
    """sha256 of the canonical JSON of a config: the identity of a scene."""
    blob = json.dumps(to_dict(obj), sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()
