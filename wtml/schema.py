"""Schemas: frozen, validated dataclasses built from YAML or JSON, with errors that name the key
path.

Every structured file wtml reads (scene and training configs, dataset manifests, shard
sidecars, export manifests and metadata) is described by a dataclass here or beside its reader.
A field's allowed range lives in its metadata (:func:`bounded`, :func:`one_of`); :func:`build`
walks a mapping into nested dataclasses (and lists of them), refusing unknown keys, missing keys,
wrong types and out-of-range values with a :class:`SchemaError` such as
``excitation.n_freq: must be in [2, 4096], got 1``; a field made by :func:`overrides` reads
a mapping as changes to its own default. Readers prefix the file's path.
Imports numpy and pyyaml only: the device runtime uses it too.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml


class SchemaError(ValueError):
    """A file or mapping with an unknown key, a missing key, a wrong type or a value out of
    range (the message starts with the key path)."""


SceneError = SchemaError
"""The name scenes use for it."""


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


def overrides(factory: Any) -> Any:
    """A dataclass field whose default is ``factory()`` and whose mapping in a file changes only
    the keys it names (nested mappings alike), the rest staying the default's: a texture scene's
    ``acquisition: {effects: {hum: {enabled: true}}}`` keeps the texture acquisition's rate and
    full scales, where a plain field would take the class's own defaults for every key the
    mapping leaves out."""
    return dataclasses.field(default_factory=factory, metadata={"overrides": True})


def _over(default: Any, given: Any) -> Any:
    """``given`` laid over ``default`` key by key where both are mappings (a mapping of
    another ``kind``, a union's other member, replaces it whole); ``given`` otherwise."""
    if not (isinstance(default, Mapping) and isinstance(given, Mapping)) or (
            "kind" in given and given["kind"] != default.get("kind")):
        return given
    return {**default, **{k: _over(default[k], v) if k in default else v
                          for k, v in given.items()}}


def field_range(cls: Any, name: str) -> tuple[float, float]:
    """The ``(low, high)`` of dataclass ``cls``'s (or an instance's) :func:`bounded` field
    ``name``."""
    return next(f for f in dataclasses.fields(cls) if f.name == name).metadata["range"]


def one_of(*choices: str, default: Any = dataclasses.MISSING) -> Any:
    """A string field restricted to ``choices``."""
    return dataclasses.field(default=default, metadata={"choices": choices})


def mixture(path: str, weights: Any, family: tuple[str, ...]) -> np.ndarray:
    """The probabilities of a mixture ``{member: weight}`` over ``family``, in its order, shape
    ``(len(family),)``. A member not in the family, a weight that is not a number >= 0, or
    weights that are all 0 is a SchemaError naming ``path`` and the allowed members."""
    if not isinstance(weights, Mapping) or not weights:
        raise SchemaError(f"{path}: a mapping of members of {list(family)} to weights, "
                         f"got {weights!r}")
    for name, weight in weights.items():
        if name not in family:
            raise SchemaError(f"{path}: unknown law {name!r}; allowed laws: {list(family)}")
        if isinstance(weight, bool) or not isinstance(weight, int | float) or not (
                0 <= weight <= 1e300):  # finite, and an int that a float holds
            raise SchemaError(f"{path}.{name}: the weight must be a number in [0, 1e300], "
                              f"got {weight!r:.80}")
    p = np.array([float(weights.get(name, 0.0)) for name in family])
    if p.sum() <= 0:
        raise SchemaError(f"{path}: the weights must not all be 0 (laws: {list(family)})")
    return p / p.sum()


def _check_number(path: str, value: Any, low: float, high: float, kind: type) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SchemaError(f"{path}: must be a number in [{low:g}, {high:g}], got {value!r:.80}")
    if kind is int and isinstance(value, float) and not value.is_integer():  # inf, NaN too
        raise SchemaError(f"{path}: must be an integer in [{low:g}, {high:g}], got {value!r}")
    if not low <= value <= high:  # NaN fails too
        raise SchemaError(f"{path}: must be in [{low:g}, {high:g}], got {value!r:.80}")
    try:
        return kind(value)
    except OverflowError:  # an integer beyond a float's range
        raise SchemaError(f"{path}: must be in [{low:g}, {high:g}] and within a float's "
                          f"range, got {value!r:.80}") from None


def _convert(path: str, hint: Any, value: Any, meta: Mapping) -> Any:
    if dataclasses.is_dataclass(hint):
        resolve = getattr(hint, "resolve", None)  # a reference (a name, a path) to one
        if resolve is not None and not isinstance(value, Mapping):
            return resolve(value, path)
        return build(hint, value, path)
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None and len(args) < len(typing.get_args(hint)):
            return None
        if len(args) == 1:
            return _convert(path, args[0], value, meta)
        if all(dataclasses.is_dataclass(a) for a in args):  # a union of records: a "kind" picks
            kinds = {f.default: a for a in args for f in dataclasses.fields(a)
                     if f.name == "kind"}
            if isinstance(value, Mapping) and value.get("kind") in kinds:
                return build(kinds[value["kind"]], value, path)
            resolve = getattr(args[0], "resolve", None)
            if resolve is not None and not isinstance(value, Mapping):
                return resolve(value, path)
            raise SchemaError(f"{path}.kind: must be one of {sorted(kinds)}, got "
                              f"{value.get('kind') if isinstance(value, Mapping) else value!r:.80}")
        raise TypeError(f"{path}: unsupported field type {hint!r}")
    if origin is tuple and typing.get_args(hint)[-1] is Ellipsis:  # a list
        item = typing.get_args(hint)[0]
        if dataclasses.is_dataclass(item):  # a list of records
            if not isinstance(value, list | tuple):
                raise SchemaError(f"{path}: must be a list of mappings, got {value!r:.80}")
            return tuple(build(item, v, f"{path}[{k}]") for k, v in enumerate(value))
        if item is str:
            if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
                raise SchemaError(f"{path}: must be a list of strings, got {value!r:.80}")
            return tuple(value)
        low, high = meta.get("range", (-float("inf"), float("inf")))
        kind = int if item is int else float  # tuple[int, ...]: whole numbers (a shape)
        if not isinstance(value, list | tuple):
            what = "whole numbers" if kind is int else "numbers"
            raise SchemaError(f"{path}: must be a list of {what} in [{low:g}, {high:g}], "
                             f"got {value!r:.80}")
        return tuple(_check_number(f"{path}[{k}]", v, low, high, kind)
                     for k, v in enumerate(value))
    if origin is tuple:  # a (low, high) pair of floats
        low, high = meta.get("range", (-float("inf"), float("inf")))
        if not isinstance(value, list | tuple) or len(value) != 2:
            raise SchemaError(f"{path}: must be a [low, high] pair within [{low:g}, {high:g}], "
                             f"got {value!r}")
        pair = tuple(_check_number(f"{path}[{k}]", v, low, high, float)
                     for k, v in enumerate(value))
        if pair[0] > pair[1]:
            raise SchemaError(f"{path}: low {pair[0]:g} is above high {pair[1]:g}")
        return pair
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise SchemaError(f"{path}: must be a mapping, got {value!r}")
        return dict(value)
    if hint is str:
        choices = meta.get("choices")
        if not isinstance(value, str) or (choices and value not in choices):
            allowed = f"one of {list(choices)}" if choices else "a string"
            raise SchemaError(f"{path}: must be {allowed}, got {value!r:.80}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise SchemaError(f"{path}: must be true or false, got {value!r}")
        return value
    if hint in (int, float):
        low, high = meta.get("range", (-float("inf"), float("inf")))
        return _check_number(path, value, low, high, hint)
    raise TypeError(f"{path}: unsupported field type {hint!r}")


def build(cls: type, data: Any, path: str = "") -> Any:
    """Build dataclass ``cls`` from a mapping, validating every key (see module docstring)."""
    where = path or cls.__name__
    if not isinstance(data, Mapping):
        raise SchemaError(f"{where}: must be a mapping, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(map(str, set(data) - set(fields)))
    if unknown:
        raise SchemaError(f"{path + '.' if path else ''}{unknown[0]}: unknown key; "
                         f"allowed keys here: {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        key_path = f"{path}.{name}" if path else name
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SchemaError(f"{key_path}: missing")
            continue
        value = data[name]
        if f.metadata.get("overrides") and isinstance(value, Mapping):
            value = _over(to_dict(f.default_factory()), value)
        kwargs[name] = _convert(key_path, hints[name], value, f.metadata)
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if check is not None:
        check(path)
    return obj


def read_yaml(path: str | Path, *, what: str = "YAML file") -> Any:
    """The parsed contents of a YAML file, every failure one line naming the file: not a
    regular file or too large (:func:`wtml.files.regular_file`), not UTF-8 text, not YAML
    (with the line and column), nested too deeply.

    Raises:
        SchemaError: (a :class:`wtml.files.FileError` for the file itself) as above.
    """
    from wtml.files import JSON_MAX_BYTES, regular_file

    path = regular_file(path, what=what, max_bytes=JSON_MAX_BYTES)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as err:
        raise SchemaError(f"{path}: cannot read this {what} ({err.strerror})") from None
    except UnicodeDecodeError as err:
        raise SchemaError(f"{path}: not a text file (byte {err.start} is not UTF-8); a "
                          f"{what} is YAML text") from None
    try:
        return yaml_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise SchemaError(f"{path}: not valid YAML{at}: {problem}") from None
    except RecursionError:
        raise SchemaError(f"{path}: nested too deeply to be a {what}") from None


def load_yaml(cls: type, path: str | Path) -> Any:
    """Read a YAML file into dataclass ``cls``; errors name the file and the key path."""
    path = Path(path)
    data = read_yaml(path)
    try:
        return build(cls, data)
    except SchemaError as err:
        raise SchemaError(f"{path}: {err}") from None


def omitted_when_empty(**kwargs) -> Any:
    """A dataclass field (``dataclasses.field``'s arguments) that :func:`to_dict` leaves out
    while it is empty, so that adding it keeps the identity (:func:`config_hash`) of every
    config that does not use it."""
    return dataclasses.field(**kwargs, metadata={"omit_empty": True})


def to_dict(obj: Any) -> dict:
    """The plain mapping a config was built from (tuples as lists; a field made by
    :func:`omitted_when_empty` left out while empty)."""
    return json.loads(json.dumps(_plain(obj)))


def _plain(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not (f.metadata.get("omit_empty") and not getattr(obj, f.name))}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    return obj


def mapping_hash(mapping: Any) -> str:
    """sha256 of a plain mapping's canonical JSON (sorted keys, no spaces)."""
    blob = json.dumps(mapping, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()


def config_hash(obj: Any) -> str:
    """sha256 of the canonical JSON of a config: the identity of a scene."""
    return mapping_hash(to_dict(obj))
