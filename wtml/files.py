"""Opening any file wtml is given, before its contents are trusted.

Every reader of a dataset, an export or a recording goes through these: a regular file (not a
FIFO, a device or a folder) of bounded size; JSON that is strict (no ``NaN``, no duplicate
keys) and small; an ``.npz`` whose arrays are checked from their headers (names, dtypes,
shapes, total size) before any of them is read, loaded without pickle; a name that stays
inside its folder; a file's sha256. Each refusal is a :class:`FileError` whose message starts
with the file's path (and the key, where there is one) and says what is allowed.
And writing: a file replaced whole or not at all (:func:`atomic_write`), under a lock that
other processes wait on (:func:`locked`).
Imports numpy only: the device runtime uses it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import socket
import stat
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

MEMORY_CEILING = 2 * 1024**3
"""Bytes: the most that reading one input may cost (``wtml predict``'s stated ceiling); an
input that would need more is refused before the work, naming it."""
JSON_MAX_BYTES = 64 * 1024**2
"""Bytes: the largest manifest, sidecar or metadata file read."""
CSV_MAX_BYTES = 64 * 1024**2
"""Bytes: the largest CSV input (measurements, or an oscilloscope's recording; larger ones:
.npz, TDMS or WAV)."""


class FileError(ValueError):
    """A file that cannot be used: missing, not a regular file, too large, malformed, or
    holding a key of the wrong kind (the message names the file and the key)."""


def nbytes_text(n: float) -> str:
    """``1.5 GB``, ``12 MB``, ``3 kB`` (decimal units)."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def regular_file(path: str | Path, *, what: str = "file",
                 max_bytes: int = MEMORY_CEILING) -> Path:
    """``path`` if it is a regular file (symlinks followed) of at most ``max_bytes``.

    Raises:
        FileError: missing, a folder, a FIFO or device, or larger than ``max_bytes``.
    """
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FileError(f"{path}: no such {what}") from None
    except OSError as err:
        raise FileError(f"{path}: cannot open this {what} ({err.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise FileError(f"{path}: is a folder, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise FileError(f"{path}: not a regular file (a pipe, socket or device); a {what} "
                        "must be a plain file")
    if st.st_size > max_bytes:
        raise FileError(f"{path}: {nbytes_text(st.st_size)}, over the {nbytes_text(max_bytes)} "
                        f"a {what} may have")
    return path


def tmp_name(path: Path) -> Path:
    """Where ``path`` is written before its rename: ``.{name}.{host}.{pid}.tmp`` beside it (a
    process's own, so that two processes never share one and a dead one's can be told and
    removed; threads of one process must not write the same path at once)."""
    return path.with_name(f".{path.name}.{socket.gethostname()}.{os.getpid()}.tmp")


def tmp_writer(name: str) -> int | None:
    """The pid of the process writing ``name`` where it is a :func:`tmp_name` of this host;
    None for any other name."""
    match = re.match(rf"^\..+\.{re.escape(socket.gethostname())}\.(\d+)\.tmp$", name)
    return int(match[1]) if match else None


def atomic_write(path: str | Path, data: bytes | Callable[[BinaryIO], Any]) -> Path:
    """Write ``path`` whole or not at all: ``data`` (bytes, or a function that writes to the
    open binary file) into :func:`tmp_name`, flushed to disk, then renamed over ``path`` (a
    reader sees the old file or the new one, never a part). A write that fails removes its
    temporary file; one killed mid-way leaves it, for a dataset's ``clean_orphans`` to
    remove. Returns ``path``."""
    path = Path(path)
    tmp = tmp_name(path)
    try:
        with open(tmp, "wb") as fh:
            if isinstance(data, bytes):
                fh.write(data)
            else:
                data(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


@contextlib.contextmanager
def locked(path: str | Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the file ``path`` (made, with its folder, where missing)
    for the block: another process entering it on the same path waits until this one leaves
    (or dies: the lock goes with the open file). POSIX only, imported here: the device
    runtime never takes a lock."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def sha256(path: str | Path) -> str:
    """The hex sha256 of a file's bytes (read in 1 MiB blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        twice = next(k for k in keys if keys.count(k) > 1)
        raise ValueError(f"key {twice!r} appears twice")
    return dict(pairs)


def _infinity(name: str) -> float:
    if name == "NaN":
        raise ValueError("NaN is not a JSON number")
    return float(name)


def parse_json(text: str | bytes, where: str, *, infinity: bool = False) -> Any:
    """Strict JSON: ``NaN``, ``Infinity`` (unless ``infinity``: an unbounded range, as an
    export's metadata states one) and duplicate keys refused (:class:`FileError` naming
    ``where``)."""
    try:
        return json.loads(text, parse_constant=_infinity if infinity else _no_constant,
                          object_pairs_hook=_unique_keys)
    except RecursionError:
        raise FileError(f"{where}: nested too deeply to be a wtml file") from None
    except (ValueError, UnicodeDecodeError) as err:
        raise FileError(f"{where}: not valid JSON ({err})") from None


def read_json(path: str | Path, *, what: str = "JSON file",
              max_bytes: int = JSON_MAX_BYTES) -> Any:
    """The parsed contents of a small, regular, strict JSON file (:func:`parse_json`)."""
    path = regular_file(path, what=what, max_bytes=max_bytes)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise FileError(f"{path}: cannot read this {what} ({err.strerror})") from None
    return parse_json(data, str(path))


_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


def inside(folder: str | Path, name: Any, *, where: str) -> Path:
    """``folder / name`` for a plain file name (letters, digits, ``_ . -``; no separator, no
    ``..``, not absolute): what a manifest may name. ``where`` is the manifest and key."""
    if not isinstance(name, str) or not _NAME.match(name) or name in (".", ".."):
        raise FileError(f"{where}: must be a file name inside {folder} (letters, digits, "
                        f"'_', '.', '-'), got {name!r:.80}")
    return Path(folder) / name


def npz_headers(path: str | Path, *, max_bytes: int = MEMORY_CEILING,
                what: str = ".npz file") -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """The shape and dtype of every array in an ``.npz``, read from the archive's headers
    without loading any array.

    Raises:
        FileError: not a regular file, not a zip archive of ``.npy`` arrays, an array of
            Python objects, or arrays that together would take more than ``max_bytes``.
    """
    path = regular_file(path, what=what, max_bytes=max_bytes)
    out: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                name = info.filename.removesuffix(".npy")
                with archive.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                            else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read(fh, max_header_size=10000)
                if dtype.hasobject:
                    raise FileError(f"{path}: key '{name}' holds Python objects; wtml reads "
                                    "numeric arrays only (write it with numpy.savez from "
                                    "float or complex arrays)")
                total += int(np.prod(shape, dtype=float)) * dtype.itemsize
                out[name] = (tuple(shape), dtype)
    except FileError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, SyntaxError) as err:
        raise FileError(f"{path}: not a readable .npz of numeric arrays (empty, truncated or "
                        f"another kind of file: {type(err).__name__}); write it with "
                        "numpy.savez") from None
    if total > max_bytes:
        raise FileError(f"{path}: its arrays take {nbytes_text(total)}, over the "
                        f"{nbytes_text(max_bytes)} ceiling for a {what}")
    return out


def read_npz(path: str | Path, *, what: str = ".npz file", max_bytes: int = MEMORY_CEILING,
             keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` (only ``keys``, when given; those that exist), after
    :func:`npz_headers` has checked them; never unpickles."""
    heads = npz_headers(path, max_bytes=max_bytes, what=what)
    want = list(heads) if keys is None else [k for k in keys if k in heads]
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in want}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as err:
        raise FileError(f"{path}: not a readable .npz of numeric arrays (truncated or damaged: "
                        f"{type(err).__name__}); write it with numpy.savez") from None


def check_header(where: str, key: str, shape: tuple[int, ...], dtype: np.dtype, *,
                 real: bool = True, ndim: tuple[int, ...] | None = None) -> None:
    """The checks of :func:`check_array` that need no values (an array's shape and dtype, as
    :func:`npz_headers` gives them before loading): numbers only (no strings, no booleans),
    no imaginary part where the quantity is real, the allowed numbers of dimensions."""
    if dtype.kind not in "iufc":
        raise FileError(f"{where}: '{key}' must hold numbers, got dtype {dtype}")
    if real and dtype.kind == "c":
        raise FileError(f"{where}: '{key}' must be real (it is complex): give the measured "
                        "signal, not a phasor")
    if ndim is not None and len(shape) not in ndim:
        dims = " or ".join(str(n) for n in ndim)
        raise FileError(f"{where}: '{key}' must have {dims} dimension(s), got shape "
                        f"{tuple(shape)}")


def check_array(where: str, key: str, value: np.ndarray, *, real: bool = True,
                ndim: tuple[int, ...] | None = None, finite: bool = True) -> np.ndarray:
    """``value`` as a float (``real``) or complex array after checks that name ``where`` (the
    file) and ``key``: numbers only (no strings, no booleans), no imaginary part where the
    quantity is real, the allowed numbers of dimensions, finite."""
    a = np.asarray(value)
    check_header(where, key, a.shape, a.dtype, real=real, ndim=ndim)
    a = a.astype(float if real else complex, copy=False)
    if finite and a.size and not np.isfinite(a).all():
        first = np.unravel_index(np.flatnonzero(~np.isfinite(a))[0], a.shape)
        raise FileError(f"{where}: '{key}' is NaN or inf at index {tuple(map(int, first))}")
    return a


def scalar(where: str, key: str, value: np.ndarray, *, low: float, high: float) -> float:
    """A finite number in ``[low, high]`` stored as a 0-d or one-element array."""
    a = np.asarray(value)
    if a.dtype.kind not in "iuf" or a.size != 1:
        raise FileError(f"{where}: '{key}' must be one real number in [{low:g}, {high:g}], got "
                        f"dtype {a.dtype}, shape {a.shape}")
    x = float(a.reshape(()))
    if not low <= x <= high:
        raise FileError(f"{where}: '{key}' must be in [{low:g}, {high:g}], got {x:g}")
    return x


def within_ceiling(where: str, need: float, doing: str, *,
                   ceiling: int = MEMORY_CEILING) -> None:
    """Refuse work that would take more than ``ceiling`` bytes of memory, before doing it.

    Args:
        where: the input (a file, and the keys that make it large).
        need: the bytes the work would take (its arrays and their intermediate copies).
        doing: what the work is (``"resampling to 10 kHz"``).

    Raises:
        FileError: naming ``where``, the cost and the ceiling.
    """
    if need > ceiling:
        raise FileError(f"{where}: {doing} would take {nbytes_text(need)} of memory, over "
                        f"the {nbytes_text(ceiling)} ceiling of wtml predict; give fewer or "
                        "shorter records (or split the file)")
