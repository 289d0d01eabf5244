"""Mutations as data: each is a JSON-ready mapping (what the corpus stores) that
:func:`apply` turns into a tampered copy of a file, and hypothesis strategies that draw them.

Values that JSON cannot hold are encoded: ``{"$float": "nan"}`` (also ``"inf"``,
``"-inf"``), ``{"$complex": [re, im]}``; ``"$base:TASK/NAME"`` is the path of a base file
(another task's dataset, say), resolved when the case is replayed. Operations:

- structured (YAML, JSON, a checkpoint's ``wtml`` block, ONNX metadata): ``set`` (``path``,
  ``value``), ``delete`` (``path``), ``root`` (the whole document becomes ``value``);
- arrays (``.npz``): ``npz_transform`` (``key``, ``transform``: see :data:`TRANSFORMS`),
  ``npz_set`` (``key``, ``value``: a scalar or a list), ``npz_delete`` (``key``),
  ``npz_lie`` (``key``, ``shape``: a header that claims this shape over a tiny body),
  ``npz_many`` (``ops``: several of these in a row);
- whole files: ``truncate`` (``keep``: fraction of the bytes), ``empty``, ``bytes``
  (``hex``), ``fifo``, ``devzero`` (a symlink to /dev/zero), ``folder``, ``missing``,
  ``foreign`` (``with``: another base file's name, copied over it), ``symlink_escape``
  (a symlink to a file outside the folder);
- text (``.csv``): ``csv_cell`` (``row``, ``column``, ``text``), ``csv_drop_column``.

A mutation may carry ``resign: true``: the sha256 that a manifest or sidecar holds for the
file is updated after the tampering (a faulty writer, not a transfer error).
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

# ---------------------------------------------------------------- values


def decode(v: Any) -> Any:
    if isinstance(v, dict):
        if set(v) == {"$float"}:
            return float(v["$float"])
        if set(v) == {"$complex"}:
            return complex(*v["$complex"])
        return {k: decode(x) for k, x in v.items()}
    if isinstance(v, list):
        return [decode(x) for x in v]
    return v


def encode(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return {"$float": str(v)}
    if isinstance(v, complex):
        return {"$complex": [v.real, v.imag]}
    if isinstance(v, dict):
        return {k: encode(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [encode(x) for x in v]
    return v


NAN, INF = {"$float": "nan"}, {"$float": "inf"}
ESCAPES = ["../../x.npz", "/etc/passwd", "/dev/zero", "..", "shard-00000.npz/../../x",
           "a/b.npz", ""]
VALUES = st.sampled_from([
    None, True, False, 0, -1, 1, 2, 7, 10**9, -10**9, 10**18, 1e308, -1e308, 1e-300, 0.5,
    NAN, INF, {"$float": "-inf"}, "x", "1e3", "12", "nan", "", [], [1, 2], [None], {},
    {"a": 1}, [[1, 2], [3, 4]], "ﬁ\u0000", *ESCAPES])


def _same_kind(old: Any) -> st.SearchStrategy:
    """Values near the old one: numbers scaled, negated, zeroed; strings altered."""
    if isinstance(old, bool):
        return st.just(not old)
    if isinstance(old, int | float):
        return st.sampled_from([0, -old, old * 1000, old / 1000, old + 1, -1e-9, 1e12,
                                NAN, INF, str(old), [old]]).map(encode)
    if isinstance(old, str):
        return st.sampled_from([old + "x", old.upper(), "", old * 50, *ESCAPES])
    if isinstance(old, list):
        return st.sampled_from([[], old[:1], old * 3, list(reversed(old)), [old],
                                encode([float("nan")] * len(old))])
    return VALUES


# ---------------------------------------------------------------- structured documents


def paths(doc: Any, prefix: tuple = (), depth: int = 0) -> list[tuple]:
    """Every node's path (mapping keys, list indices: the first, the second and the last)."""
    out = [prefix] if prefix else []
    if depth > 8:
        return out
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths(v, (*prefix, k), depth + 1)
    elif isinstance(doc, list):
        for k in sorted({0, 1, len(doc) - 1} & set(range(len(doc)))):
            out += paths(doc[k], (*prefix, k), depth + 1)
    return out


def _get(doc: Any, path: list) -> Any:
    for k in path:
        doc = doc[k]
    return doc


def apply_structured(doc: Any, m: dict) -> Any:
    """A mutated deep copy of ``doc`` (``set``, ``delete``, ``root``)."""
    if m["op"] == "root":
        return decode(m["value"])
    doc = copy.deepcopy(doc)
    path = list(m["path"])
    parent = _get(doc, path[:-1])
    key = path[-1]
    if isinstance(parent, list):
        key = int(key)
    if m["op"] == "set":
        if isinstance(parent, list) and key >= len(parent):
            parent.append(decode(m["value"]))
        else:
            parent[key] = decode(m["value"])
    elif m["op"] == "delete":
        del parent[key]
    else:
        raise ValueError(m["op"])
    return doc


@st.composite
def structured(draw, doc: Any, *, focus: tuple[str, ...] = (),
               special: dict[str, list] | None = None) -> dict:
    """A ``set``, ``delete``, extra key or ``root`` mutation of ``doc``; ``focus``: key names
    drawn more often (those the reader indexes); ``special``: key name -> values worth trying
    there (another task's dataset for ``data_dir``, ``gpu`` for ``accelerator``)."""
    every = paths(doc)
    choice = draw(st.sampled_from(["set", "set", "set", "delete", "extra", "root"]))
    if choice == "root":
        return {"op": "root", "value": draw(st.sampled_from(
            [None, [], {}, "x", 3, [encode(doc)] if _jsonable(doc) else [1]]))}
    hot = [p for p in every if p and p[-1] in focus]
    path = draw(st.sampled_from(hot)) if hot and draw(st.booleans()) else draw(
        st.sampled_from(every))
    if choice == "delete":
        return {"op": "delete", "path": list(path)}
    if choice == "extra":
        parents = [p for p in [(), *every] if isinstance(_get(doc, list(p)), dict)]
        parent = draw(st.sampled_from(parents))
        return {"op": "set", "path": [*parent, draw(st.sampled_from(["extra", "x", "__class__",
                                                                        "format2"]))],
                "value": draw(VALUES)}
    old = _get(doc, list(path))
    pool = [VALUES, _same_kind(old)]
    if special and path and path[-1] in special:
        pool.append(st.sampled_from(special[path[-1]]))
    value = draw(st.one_of(*pool))
    return {"op": "set", "path": list(path), "value": value}


def _jsonable(doc: Any) -> bool:
    try:
        json.dumps(doc)
        return True
    except (TypeError, ValueError):
        return False


# ---------------------------------------------------------------- arrays

TRANSFORMS = ("nan", "inf", "complex", "empty", "scalar", "flatten", "extra_axis", "int",
              "bool", "string", "huge", "negate", "zero", "half", "transpose", "float16",
              "one_row")


def transform(a: np.ndarray, how: str) -> np.ndarray:
    """``a`` altered: its type, shape or values (:data:`TRANSFORMS`)."""
    a = np.array(a)
    if how in ("nan", "inf"):
        b = a.astype(np.result_type(a.dtype, np.float64))
        if b.size:
            b.reshape(-1)[0] = np.nan if how == "nan" else np.inf
        return b
    if how == "complex":
        return a + 1j
    if how == "empty":
        return a[:0] if a.ndim else np.zeros(0)
    if how == "scalar":
        return a.reshape(-1)[0] if a.size else np.float64(1.0)
    if how == "flatten":
        return a.reshape(-1)
    if how == "extra_axis":
        return a[None, None]
    if how == "int":
        return np.real(a).astype(np.int64)
    if how == "bool":
        return a.astype(bool)
    if how == "string":
        return np.array(["x"] * max(a.size, 1))
    if how == "huge":
        return a * 1e300 if a.dtype.kind in "fc" else np.full(a.shape, 2**62)
    if how == "negate":
        return -a if a.dtype.kind != "b" else ~a
    if how == "zero":
        return np.zeros_like(a)
    if how == "half":
        return a[: max(len(a) // 2, 1)] if a.ndim else a
    if how == "transpose":
        return a.T.copy()
    if how == "float16":
        return a.astype(np.float16) if a.dtype.kind != "c" else a.astype(np.complex64)
    if how == "one_row":
        return a[:1] if a.ndim else a
    raise ValueError(how)


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asanyarray(a), allow_pickle=False)
    return buf.getvalue()


def _lying_npy(shape: list[int], dtype: str) -> bytes:
    """An .npy whose header claims ``shape`` over 16 bytes of data."""
    buf = io.BytesIO()
    header = {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": tuple(shape)}
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + b"\0" * 16


def apply_npz(path: Path, m: dict) -> None:
    """Rewrite the ``.npz`` at ``path`` with one array changed, removed, added or lying."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    raw: dict[str, bytes] = {}
    key = m.get("key", "")
    if m["op"] == "npz_transform":
        arrays[key] = transform(arrays.get(key, np.ones(3)), m["transform"])
    elif m["op"] == "npz_set":
        value = decode(m["value"])
        arrays[key] = np.array(value)
    elif m["op"] == "npz_delete":
        arrays.pop(key, None)
    elif m["op"] == "npz_many":  # several changes at once (every key emptied, say)
        path_ops = m["ops"]
        for sub in path_ops:
            apply_npz(path, sub)
        return
    elif m["op"] == "npz_lie":
        arrays.pop(key, None)
        raw[key] = _lying_npy(m["shape"], m.get("dtype", "<f8"))
    else:
        raise ValueError(m["op"])
    with zipfile.ZipFile(path, "w") as z:
        for k, a in arrays.items():
            z.writestr(f"{k}.npy", _npy_bytes(a))
        for k, b in raw.items():
            z.writestr(f"{k}.npy", b)


@st.composite
def npz_mutation(draw, keys: list[str], *, extra: dict[str, list] | None = None) -> dict:
    """A mutation of an ``.npz`` holding ``keys``; ``extra``: key -> values to try there
    (e.g. sample rates)."""
    choice = draw(st.sampled_from(["transform", "transform", "transform", "set", "delete",
                                   "add", "lie"]))
    key = draw(st.sampled_from(keys))
    if choice == "transform":
        return {"op": "npz_transform", "key": key, "transform": draw(st.sampled_from(TRANSFORMS))}
    if choice == "set":
        pool = [0, -1, 1, 1e308, NAN, INF, [], [1.0, 2.0], [[1.0]], {"$complex": [1, 1]}]
        pool += (extra or {}).get(key, [])
        return {"op": "npz_set", "key": key, "value": draw(st.sampled_from(pool))}
    if choice == "delete":
        return {"op": "npz_delete", "key": key}
    if choice == "add":
        return {"op": "npz_set", "key": draw(st.sampled_from(["extra", "ze", "t", "e"])),
                "value": draw(st.sampled_from([1.0, [1.0, 2.0], "x"]))}
    shape = draw(st.sampled_from([[10**9], [10**5, 10**5], [2**40], [3, 10**10], [0]]))
    return {"op": "npz_lie", "key": key, "shape": shape,
            "dtype": draw(st.sampled_from(["<f8", "<c16", "<f4"]))}


# ---------------------------------------------------------------- whole files

FILE_OPS = ("truncate", "truncate", "empty", "bytes", "fifo", "devzero", "folder", "missing",
            "foreign", "symlink_escape")


@st.composite
def file_mutation(draw, foreign: list[str]) -> dict:
    op = draw(st.sampled_from(FILE_OPS))
    if op == "truncate":
        return {"op": op, "keep": draw(st.sampled_from([0.0, 0.01, 0.1, 0.5, 0.9, 0.999]))}
    if op == "bytes":
        return {"op": op, "hex": draw(st.sampled_from(
            [b"PK\x03\x04".hex(), b"\x00\xff\xfe".hex(), b"{}".hex(), b"[1, 2]".hex(),
             b"NaN".hex(), b"a: [".hex(), "é".encode("latin-1").hex()]))}
    if op == "foreign":
        return {"op": op, "with": draw(st.sampled_from(foreign))}
    return {"op": op}


def apply_file(path: Path, m: dict, pool: dict[str, Path]) -> None:
    """Replace the file at ``path`` as ``m`` says (``pool``: base files by name, for
    ``foreign``)."""
    op = m["op"]
    if op == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * m["keep"])])
        return
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    if op == "empty":
        path.write_bytes(b"")
    elif op == "bytes":
        path.write_bytes(bytes.fromhex(m["hex"]))
    elif op == "fifo":
        os.mkfifo(path)
    elif op == "devzero":
        path.symlink_to("/dev/zero")
    elif op == "folder":
        path.mkdir()
    elif op == "missing":
        pass
    elif op == "foreign":
        shutil.copy(pool[m["with"]], path)
    elif op == "symlink_escape":
        outside = path.parent.parent / "outside.bin"
        outside.write_bytes(b"\0" * 64)
        path.symlink_to(os.path.relpath(outside, path.parent))
    else:
        raise ValueError(op)


# ---------------------------------------------------------------- csv


def apply_csv(path: Path, m: dict) -> None:
    lines = path.read_text().splitlines()
    rows = [line.split(",") for line in lines]
    if m["op"] == "csv_cell":
        r = min(m["row"], len(rows) - 1)
        c = min(m["column"], len(rows[r]) - 1)
        rows[r][c] = m["text"]
    elif m["op"] == "csv_drop_column":
        c = m["column"]
        rows = [row[:c] + row[c + 1:] for row in rows]
    path.write_text("\n".join(",".join(row) for row in rows) + "\n")


@st.composite
def csv_mutation(draw, n_rows: int, n_cols: int) -> dict:
    if draw(st.integers(0, 4)) == 0:
        return {"op": "csv_drop_column", "column": draw(st.integers(0, n_cols - 1))}
    return {"op": "csv_cell", "row": draw(st.sampled_from([0, 1, n_rows - 1])),
            "column": draw(st.integers(0, n_cols - 1)),
            "text": draw(st.sampled_from(["", "x", "nan", "inf", "1e999", "-1", "1+2j",
                                          "0x10", "1,2", '"', "9" * 400, "sample"]))}


STRUCTURED_OPS = ("set", "delete", "root")
NPZ_OPS = ("npz_transform", "npz_set", "npz_delete", "npz_lie", "npz_many")
CSV_OPS = ("csv_cell", "csv_drop_column")
