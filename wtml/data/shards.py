"""Deterministic, sharded, resumable dataset generation and checked loading.

Layout of a dataset folder::

    scene.json              the folder's identity: the scene hash and shard count (written
                            first, exclusively: a folder holds one scene's shards)
    manifest.json           scene, seed, package version, counts, every shard's entry
    shard-00000.npz         arrays of one shard (numpy .npz, no pickle)
    shard-00000.json        that shard's entry (written after the shard): index, file, count,
                            sha256, scene hash, and every array's name, dtype and trailing shape

Shard ``k`` is generated from ``numpy.random.default_rng([scene.seed, k])``, so any shard can be
made by any process, in any order, bit for bit. Files are written to a temporary name and
renamed, so a kill leaves either a complete shard or none. Re-running skips shards whose
checksum matches their sidecar and regenerates the rest; the manifest is rebuilt from the
sidecars at the end of every run (after parallel ``--shard K`` jobs, one run without
``--shard`` completes and verifies it).

Every file is checked before it is trusted (:class:`Manifest`, :class:`ShardEntry`,
:class:`Identity`; :mod:`wtml.files`): the manifest against its schema and its scene's hash,
each shard as a regular file of bounded size whose arrays (from the zip headers, before loading)
are those the manifest lists, then its sha256, then its values: finite, but for the labels that
are NaN by design (:data:`NAN_BY_DESIGN`). Every refusal is a :class:`DatasetError` naming the
file and the key.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from wtml import __version__
from wtml.devices import DeviceIdentity, identity
from wtml.files import (
    MEMORY_CEILING,
    FileError,
    atomic_write,
    inside,
    nbytes_text,
    npz_headers,
    read_json,
    read_npz,
    sha256,
    tmp_name,
    tmp_writer,
)
from wtml.scenes import FluidScene, config_hash, device_of, scene_from_dict, to_dict
from wtml.schema import SchemaError, bounded, build, mapping_hash, one_of

FORMAT = "wtml.dataset/3"
"""The manifest's format. Older ones are refused (:data:`OLD_FORMATS`): generate such a
dataset again."""
OLD_FORMATS = {"wtml.dataset/1": "its shards list no arrays and no scene",
               "wtml.dataset/2": "its scene names a preset, not a device file"}
"""Formats an older wtml wrote, and why they are refused."""
IDENTITY = "scene.json"
IDENTITY_FORMAT = "wtml.dataset-scene/1"
MAX_SHARDS = 10**5
"""Shards per dataset at most (the scenes' bound; ``shard-{k:05d}`` names)."""
MAX_SAMPLES = 10**8
"""Samples per dataset at most (the scenes' largest bound)."""
SHARD_MAX_BYTES = MEMORY_CEILING
"""Bytes: the largest shard file, and the most its arrays may take once loaded."""
DTYPES = ("|b1", "|i1", "|u1", "<i2", "<u2", "<i4", "<u4", "<i8", "<u8", "<f2", "<f4", "<f8",
          "<c8", "<c16")
"""The dtypes a shard's arrays may have (``numpy.dtype.str``): numbers, never objects."""

TASK_ARRAYS: dict[str, dict[str, tuple[str, tuple[int | str, ...]]]] = {
    "fluid": {"ze": ("c", ("F",)), "t": ("c", ("F", 2, 2)), "eta": ("f", ()), "rho": ("f", ())},
    "radial": {"ze": ("c", ("F",)), "ref": ("c", ("F",)), "distance": ("f", ())},
    "onset": {"e": ("f", ("N",)), "i": ("f", ("N",)), "t_probe": ("c", (2, 2)),
              "hue0": ("f", ()), "gap": ("f", ()), "onset": ("f", ("C",)),
              "detachment": ("f", ("C",)), "coupling": ("f", ())},
    "texture": {"e": ("f", ("N",)), "i": ("f", ("N",)), "t": ("c", ("K", 2, 2)),
                "grade": ("i", ()), "grain_m": ("f", ())},
}
"""The arrays each task's decoders and benches read from every shard: numpy dtype kind
(``f`` real, ``c`` complex, ``i`` integer) and shape after the record axis, where a letter is a
length the scene sets (the same in every key that names it: ``F`` frequencies, ``N`` samples
of a record, ``C`` contacts, ``K`` calibration frequencies). Other arrays (nuisance drawn) may
be there too."""

NAN_BY_DESIGN: dict[str, tuple[str, ...]] = {
    "onset": ("gap", "onset", "detachment", "law_delta_ref"),
}
"""The arrays that may hold NaN by design (never ±inf): onset's ``gap`` (no wall),
``onset`` and ``detachment`` (NaN-padded to ``max_contacts``; a contact still on at the end has
no detachment) and ``law_delta_ref`` (the linear law has none). Every other array of every task
(fluid, radial and texture: all of them) must be finite."""


class DatasetError(ValueError):
    """A dataset folder that is missing, damaged or made from another scene."""


# --- schemas -------------------------------------------------------------------------------
_HEX64 = re.compile(r"^[0-9a-f]{64}$")
_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")


def _pre(path: str) -> str:
    return f"{path}." if path else ""


def _hex64(path: str, value: str) -> None:
    if not _HEX64.match(value):
        raise SchemaError(f"{path}: must be 64 lowercase hex digits (a sha256), "
                          f"got {value!r:.80}")


def shard_name(k: int) -> str:
    """Shard ``k``'s file name in its dataset folder."""
    return f"shard-{k:05d}.npz"


def shard_size(samples: int, n_shards: int, k: int) -> int:
    """Samples in shard ``k`` (:func:`shard_sizes` without the list)."""
    base, extra = divmod(samples, n_shards)
    return base + (k < extra)


def shard_sizes(samples: int, shards: int) -> list[int]:
    """Samples per shard: as equal as possible, the first ones one larger."""
    return [shard_size(samples, shards, k) for k in range(shards)]


@dataclasses.dataclass(frozen=True)
class ArraySpec:
    """One array of a shard: ``name``, ``dtype`` (``numpy.dtype.str``) and ``shape`` after
    the record axis (the leading length is the shard's ``count``)."""

    name: str
    dtype: str = one_of(*DTYPES)
    shape: tuple[int, ...] = bounded(0, 2**31)

    def check(self, path: str) -> None:
        if not _KEY.match(self.name):
            raise SchemaError(f"{_pre(path)}name: must be an array name (letters, digits, '_'), "
                              f"got {self.name!r:.80}")
        if len(self.shape) > 8:
            raise SchemaError(f"{_pre(path)}shape: at most 8 dimensions, got {len(self.shape)}")


@dataclasses.dataclass(frozen=True)
class ShardEntry:
    """A shard's sidecar, and its entry in the manifest."""

    index: int = bounded(0, MAX_SHARDS - 1)
    file: str
    count: int = bounded(1, MAX_SAMPLES)
    sha256: str
    scene_hash: str
    arrays: tuple[ArraySpec, ...]

    def check(self, path: str) -> None:
        p = _pre(path)
        if self.file != shard_name(self.index):
            raise SchemaError(f"{p}file: must be {shard_name(self.index)!r}, shard "
                              f"{self.index}'s name in the dataset folder (a name, never a "
                              f"path), got {self.file!r:.80}")
        _hex64(f"{p}sha256", self.sha256)
        _hex64(f"{p}scene_hash", self.scene_hash)
        if not self.arrays:
            raise SchemaError(f"{p}arrays: must list the shard's arrays, got none")
        names = [a.name for a in self.arrays]
        if len(set(names)) != len(names):
            twice = next(n for n in names if names.count(n) > 1)
            raise SchemaError(f"{p}arrays: {twice!r} is listed twice")

    def row_bytes(self) -> int:
        """Bytes of one record over all the arrays."""
        return sum(int(np.prod(a.shape, dtype=float)) * np.dtype(a.dtype).itemsize
                   for a in self.arrays)


@dataclasses.dataclass(frozen=True)
class Manifest:
    """``manifest.json``: the scene (rebuilt and hashed on read), the shard count, and every
    shard's entry (indices ``0 .. n_shards - 1`` once each when ``complete``)."""

    format: str = one_of(FORMAT)
    scene: dict
    scene_hash: str
    device: DeviceIdentity
    seed: int = bounded(0, 2**32 - 1)
    package_version: str
    n_shards: int = bounded(1, MAX_SHARDS)
    samples: int = bounded(1, MAX_SAMPLES)
    complete: bool
    shards: tuple[ShardEntry, ...]

    def check(self, path: str) -> None:
        p = _pre(path)
        _hex64(f"{p}scene_hash", self.scene_hash)
        if self.n_shards > self.samples:
            raise SchemaError(f"{p}n_shards: must be in [1, {self.samples}] (the samples), "
                              f"got {self.n_shards}")
        if len(self.shards) > self.n_shards:
            raise SchemaError(f"{p}shards: {len(self.shards)} entries for {self.n_shards} "
                              "shards")
        first: dict[int, int] = {}
        for pos, e in enumerate(self.shards):
            at = f"{p}shards[{pos}]"
            if e.index >= self.n_shards:
                raise SchemaError(f"{at}.index: must be in [0, {self.n_shards - 1}], "
                                  f"got {e.index}")
            if e.index in first:
                raise SchemaError(f"{at}.index: shard {e.index} is listed twice (also "
                                  f"shards[{first[e.index]}]); each shard once")
            first[e.index] = pos
            want = shard_size(self.samples, self.n_shards, e.index)
            if e.count != want:
                raise SchemaError(f"{at}.count: shard {e.index} of {self.samples} samples in "
                                  f"{self.n_shards} shards holds {want}, got {e.count}")
            if e.scene_hash != self.scene_hash:
                raise SchemaError(f"{at}.scene_hash: {e.scene_hash[:12]}… is not the "
                                  f"manifest's scene {self.scene_hash[:12]}…: a shard of "
                                  "another scene")
            if e.arrays != self.shards[0].arrays:
                raise SchemaError(f"{at}.arrays: differ from shards[0].arrays (every shard "
                                  "holds the same arrays)")
        if self.complete != (len(self.shards) == self.n_shards):
            raise SchemaError(f"{p}complete: {str(self.complete).lower()}, but "
                              f"{len(self.shards)} of {self.n_shards} shards are listed")


@dataclasses.dataclass(frozen=True)
class Identity:
    """``scene.json``: the scene a dataset folder belongs to, and its shard count."""

    format: str = one_of(IDENTITY_FORMAT)
    task: str
    scene_hash: str
    n_shards: int = bounded(1, MAX_SHARDS)

    def check(self, path: str) -> None:
        _hex64(f"{_pre(path)}scene_hash", self.scene_hash)


def check_task_arrays(task: str, arrays: tuple[ArraySpec, ...], where: str) -> None:
    """Refuse a dataset of ``task`` whose shards lack an array its decoders read, or hold it
    with another kind or shape (:data:`TASK_ARRAYS`); ``where`` is the file and key."""
    have = {a.name: a for a in arrays}
    sizes: dict[str, tuple[str, int]] = {}
    for name, (kind, shape) in TASK_ARRAYS[task].items():
        spec = "(n" + "".join(f", {d}" for d in shape) + ")"
        kinds = {"f": "real float", "c": "complex", "i": "integer"}[kind]
        need = f"a {task} dataset's '{name}' is {kinds}, shape {spec}"
        if name not in have:
            raise DatasetError(f"{where}: no '{name}' array; {need}")
        a = have[name]
        if np.dtype(a.dtype).kind != kind or len(a.shape) != len(shape):
            raise DatasetError(f"{where}: '{name}' is {a.dtype}, shape (n"
                               + "".join(f", {d}" for d in a.shape) + f"); {need}")
        for d, n in zip(shape, a.shape, strict=True):
            if isinstance(d, int) and n != d:
                raise DatasetError(f"{where}: '{name}' has shape (n"
                                   + "".join(f", {x}" for x in a.shape) + f"); {need}")
            if isinstance(d, str):
                if n < 1:
                    raise DatasetError(f"{where}: '{name}' has {d} = 0; {need}, {d} >= 1")
                if d in sizes and sizes[d][1] != n:
                    raise DatasetError(f"{where}: '{name}' has {d} = {n} but '{sizes[d][0]}' "
                                       f"has {d} = {sizes[d][1]}; {need}")
                sizes[d] = (name, n)


# --- reading -------------------------------------------------------------------------------
def _read_schema(path: Path, cls: type, what: str) -> Any:
    """A small JSON file of schema ``cls``; every refusal a DatasetError naming the file."""
    try:
        return build(cls, read_json(path, what=what, max_bytes=64 * 1024**2))
    except FileError as err:
        raise DatasetError(str(err)) from None
    except SchemaError as err:
        raise DatasetError(f"{path}: {err}") from None


def checked_manifest(folder: str | Path, *, complete: bool = True) -> tuple[Manifest, Any]:
    """The manifest of dataset folder ``folder`` and its scene, every key checked: the schema
    (:class:`Manifest`), the scene rebuilt from it and hashed, the arrays its task needs
    (:func:`check_task_arrays`), ``scene.json`` agreeing, complete (unless ``complete`` is
    false).

    Raises:
        DatasetError: one line naming ``manifest.json`` (or ``scene.json``) and the key.
    """
    folder = Path(folder)
    path = folder / "manifest.json"
    if not folder.is_dir():
        raise DatasetError(f"{folder}: no dataset there (not a folder); make it with `wtml "
                           f"generate --config configs/scenes/<task>.yaml --out {folder}`")
    if not os.path.lexists(path):
        raise DatasetError(f"{folder}: no dataset there (no manifest.json); make it with "
                           f"`wtml generate --config configs/scenes/<task>.yaml --out {folder}`")
    try:
        data = read_json(path, what="dataset manifest")
    except FileError as err:
        raise DatasetError(f"{err}; run the same wtml generate again after deleting it "
                           "(complete shards are kept)") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: must be a JSON object (a dataset manifest), got "
                           f"{type(data).__name__}")
    fmt = data.get("format")
    if fmt in OLD_FORMATS:
        raise DatasetError(f"{path}: format: {fmt!r}, generated by an older wtml "
                           f"({OLD_FORMATS[fmt]}); generate it again into a new folder")
    try:
        m = build(Manifest, data)
        scene = scene_from_dict(m.scene, "scene")
    except SchemaError as err:
        raise DatasetError(f"{path}: {err}") from None
    actual = config_hash(scene)
    if actual != m.scene_hash:
        if mapping_hash(m.scene) == m.scene_hash:  # as written, by a wtml with fewer keys
            raise DatasetError(f"{path}: scene: written by an older wtml (its scene lacks "
                               "keys this version's scenes hold, so the dataset's identity "
                               "has changed); generate it again into a new folder")
        raise DatasetError(f"{path}: scene_hash: {m.scene_hash[:12]}… is not the hash of its "
                           f"scene ({actual[:12]}…): the manifest was edited")
    device = identity(device_of(scene))
    if to_dict(m.device) != device:
        raise DatasetError(f"{path}: device: {m.device.name} {m.device.sha256[:12]}… is not "
                           f"its scene's ({device['name']} {device['sha256'][:12]}…): the "
                           "manifest was edited")
    for key, value in (("seed", scene.seed), ("samples", scene.samples)):
        if getattr(m, key) != value:
            raise DatasetError(f"{path}: {key}: {getattr(m, key)}, but scene.{key} is {value}")
    if m.shards:
        check_task_arrays(scene.task, m.shards[0].arrays, f"{path}: shards[0].arrays")
    if complete and not m.complete:
        raise DatasetError(f"{folder}: incomplete ({len(m.shards)} of {m.n_shards} shards); "
                           "run wtml generate again to finish")
    ident = folder / IDENTITY
    if not os.path.lexists(ident):
        raise DatasetError(f"{folder}: no {IDENTITY} (the folder's scene): generated by an "
                           "older wtml, or the file was removed; generate it again into a new "
                           "folder")
    who = _read_schema(ident, Identity, "dataset identity")
    if (who.scene_hash, who.n_shards) != (m.scene_hash, m.n_shards):
        raise DatasetError(f"{path}: scene {m.scene_hash[:12]}… in {m.n_shards} shards, but the "
                           f"folder's {IDENTITY} says {who.scene_hash[:12]}… in {who.n_shards}: "
                           "the files of two datasets are mixed; generate it again into a new "
                           "folder")
    return m, scene


def read_manifest(path: str | Path) -> dict:
    """The manifest of a complete dataset folder as a mapping, every key checked
    (:class:`Manifest`, the scene rebuilt and hashed, ``scene.json`` agreeing)."""
    return to_dict(checked_manifest(path)[0])


def dataset_scene(path: str | Path) -> FluidScene:
    """The scene a dataset was generated from."""
    return checked_manifest(path)[1]


def _fmt_shape(shape: tuple[int, ...]) -> str:
    return "(" + ", ".join(map(str, shape)) + ("," if len(shape) == 1 else "") + ")"


def check_shard_file(npz: Path, entry: ShardEntry) -> None:
    """Refuse shard file ``npz`` unless it is a regular file of bounded size whose arrays (read
    from the zip headers, nothing loaded) are those ``entry`` lists: the same names, dtypes
    and trailing shapes, ``entry.count`` records each."""
    try:
        heads = npz_headers(npz, max_bytes=SHARD_MAX_BYTES, what="dataset shard")
    except FileError as err:
        raise DatasetError(f"{err}; run wtml generate again to regenerate it") from None
    for a in entry.arrays:
        if a.name not in heads:
            raise DatasetError(f"{npz}: key '{a.name}' is missing (the manifest lists it); "
                               "run wtml generate again to regenerate the shard")
        shape, dtype = heads[a.name]
        want = (entry.count, *a.shape)
        if dtype.str != a.dtype or shape != want:
            raise DatasetError(f"{npz}: key '{a.name}' is {dtype.str} {_fmt_shape(shape)}; the "
                               f"manifest says {a.dtype} {_fmt_shape(want)}; run wtml generate "
                               "again to regenerate the shard")
    extra = sorted(set(heads) - {a.name for a in entry.arrays})
    if extra:
        raise DatasetError(f"{npz}: key '{extra[0]}' is not in the manifest's list of this "
                           "shard's arrays; run wtml generate again to regenerate the shard")


def check_finite(where: str | Path, arrays: dict[str, np.ndarray], task: str) -> None:
    """Refuse a NaN or inf in any array, but NaN in those :data:`NAN_BY_DESIGN` (never inf):
    a :class:`DatasetError` naming ``where`` (the shard), the key and the row."""
    nan_ok = NAN_BY_DESIGN.get(task, ())
    for key, a in arrays.items():
        if a.dtype.kind not in "fc" or not a.size:
            continue
        bad = np.isinf(a) if key in nan_ok else ~np.isfinite(a)
        if bad.any():
            flat = int(np.flatnonzero(bad.reshape(len(a), -1).any(1))[0])
            what = "inf" if key in nan_ok else "NaN or inf"
            allowed = (" (it may be NaN by design, never infinite)" if key in nan_ok else "")
            raise DatasetError(f"{where}: '{key}' is {what} in row {flat}{allowed}; a dataset "
                               "must hold finite numbers: generate it again")


IMPEDANCES = ("ze", "ref")
"""The arrays that hold a transducer's electrical impedance (Ω), never 0: the bimorph is a
capacitor in every load."""


def check_values(where: str | Path, arrays: dict[str, np.ndarray], scene) -> None:
    """Refuse what the scene cannot have made, named with the key and the row: an impedance
    (:data:`IMPEDANCES`) of 0, or a label outside the range the scene draws it from
    (``scene.output_ranges()``'s trained range, to 1e-9 of its span; NaN where
    :func:`check_finite` allowed it)."""
    for key in IMPEDANCES:
        if key in arrays and not np.all(arrays[key] != 0):
            row = int(np.flatnonzero((arrays[key] == 0).reshape(len(arrays[key]), -1).any(1))[0])
            raise DatasetError(f"{where}: '{key}' is 0 Ω in row {row}; an electrical impedance "
                               "is never 0: generate the dataset again")
    for key, r in scene.output_ranges().items():
        if key not in arrays:
            continue
        a, slack = arrays[key], 1e-9 * max(abs(r.high - r.low), abs(r.high))
        bad = (a < r.low - slack) | (a > r.high + slack)
        if bad.any():
            row = int(np.flatnonzero(bad.reshape(len(a), -1).any(1))[0])
            raise DatasetError(f"{where}: '{key}' is {a.reshape(len(a), -1)[row, 0]:.6g} in row "
                               f"{row}, outside the scene's [{r.low:.6g}, {r.high:.6g}]; a "
                               "dataset holds what its scene makes: generate it again")


def load_shards(path: str | Path, indices: list[int] | None = None) -> dict[str, np.ndarray]:
    """Concatenated arrays of the given shards (all by default), every shard checked before
    use: a regular file of bounded size, its arrays those of the manifest (from the zip
    headers), its sha256, then its values (:func:`check_finite`, :func:`check_values`).

    Raises:
        DatasetError: naming the shard file (and the key and row) that fails a check.
    """
    path = Path(path)
    m, scene = checked_manifest(path)
    where = path / "manifest.json"
    pos = {e.index: p for p, e in enumerate(m.shards)}
    if indices is None:
        indices = list(range(m.n_shards))
    indices = list(indices)
    for k in indices:
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k not in pos:
            raise DatasetError(f"{path}: shard {k!r} is not in the manifest "
                               f"(shards 0 to {m.n_shards - 1})")
    if not indices:
        raise DatasetError(f"{path}: no shards asked for; a split holds at least one")
    entries = [m.shards[pos[k]] for k in indices]
    total = sum(e.count for e in entries)
    need = total * entries[0].row_bytes()
    ceiling = _memory_bytes()
    if need > ceiling:
        raise DatasetError(f"{path}: shards {indices[0]}..{indices[-1]} take "
                           f"{nbytes_text(need)} loaded, over the {nbytes_text(ceiling)} this "
                           "machine has; load fewer shards")
    out = {a.name: np.empty((total, *a.shape), np.dtype(a.dtype)) for a in entries[0].arrays}
    row = 0
    for k, e in zip(indices, entries, strict=True):
        npz = inside(path, e.file, where=f"{where}: shards[{pos[k]}].file")
        check_shard_file(npz, e)
        try:
            if sha256(npz) != e.sha256:
                raise DatasetError(f"{npz}: missing or its sha256 does not match the manifest; "
                                   "run wtml generate again to regenerate it")
            data = read_npz(npz, what="dataset shard", max_bytes=SHARD_MAX_BYTES)
        except FileError as err:
            raise DatasetError(str(err)) from None
        except OSError as err:
            raise DatasetError(f"{npz}: cannot read this shard ({err.strerror})") from None
        check_finite(npz, data, scene.task)
        check_values(npz, data, scene)
        for key, a in data.items():
            out[key][row:row + e.count] = a
        row += e.count
    return out


def _memory_bytes() -> int:
    """This machine's physical memory in bytes (16 GiB where it cannot be read)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 16 * 1024**3


# --- writing -------------------------------------------------------------------------------
def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def clean_orphans(out: Path) -> list[Path]:
    """Remove the temporary files that a killed writer left in ``out`` (``kill -9`` during a
    shard write): those of this host whose process is gone. Files of a live writer (a
    parallel ``--shard`` job) and of other hosts sharing the folder are left alone.
    Returns the removed paths."""
    removed = []
    for tmp in out.iterdir():
        pid = tmp_writer(tmp.name)
        if pid is not None and not _pid_alive(pid):
            tmp.unlink(missing_ok=True)
            removed.append(tmp)
    return removed


def _shard_path(out: Path, k: int) -> Path:
    return out / shard_name(k)


def _identity(scene: FluidScene, n_shards: int) -> dict:
    return {"format": IDENTITY_FORMAT, "task": scene.task, "scene_hash": config_hash(scene),
            "n_shards": n_shards}


def _leftovers(out: Path) -> list[str]:
    """Finished dataset files in ``out`` (shards, sidecars, a manifest): a writer's temporary
    files are left to :func:`clean_orphans` (a live one's exist only after its claim)."""
    pattern = re.compile(r"^(shard-\d+\.(npz|json)|manifest\.json)$")
    return sorted(p.name for p in out.iterdir() if pattern.match(p.name))


def _foreign(out: Path, who: Identity, scene: FluidScene, n_shards: int) -> str | None:
    """Why a folder of identity ``who`` cannot take ``scene`` in ``n_shards`` (None: it can)."""
    ours = config_hash(scene)
    if who.scene_hash != ours:
        return (f"{out}: holds shards of another scene, {who.scene_hash[:12]}… ({who.task}, "
                f"{who.n_shards} shards; this one is {ours[:12]}…); choose another --out")
    if who.n_shards != n_shards:
        return (f"{out}: holds this scene in {who.n_shards} shards, not {n_shards}; give "
                f"--shards {who.n_shards} or choose another --out")
    return None


def _read_identity(path: Path) -> Identity:
    """``scene.json``, waiting briefly for a writer that is creating it (the O_EXCL
    fallback writes it after creating it)."""
    for attempt in range(20):
        try:
            return _read_schema(path, Identity, "dataset identity")
        except DatasetError:
            if attempt == 19 or time.time() - path.stat().st_mtime > 5:
                raise
            time.sleep(0.05)
    raise AssertionError("unreachable")


def claim(out: Path, scene: FluidScene, n_shards: int) -> None:
    """Make ``out`` the folder of ``scene`` in ``n_shards`` shards, or check that it is.

    The first writer creates ``scene.json`` exclusively (a hard link of a finished temporary
    file: it appears whole or not at all) before any shard; every writer reads it. So two
    writers of one scene share a folder (parallel ``--shard`` jobs) and a writer of another
    scene is refused, whoever comes first.

    Raises:
        DatasetError: ``out`` belongs to another scene or shard count, or holds dataset files
            without ``scene.json`` (an older wtml's, or a folder copied together).
    """
    ident = out / IDENTITY
    while True:
        if os.path.lexists(ident):
            why = _foreign(out, _read_identity(ident), scene, n_shards)
            if why:
                raise DatasetError(why)
            return
        left = _leftovers(out)
        if left and os.path.lexists(ident):
            continue  # a writer claimed it meanwhile, then began: check what it claimed
        if left:
            raise DatasetError(f"{out}: holds dataset files of an unknown scene ({left[0]}, "
                               f"{len(left)} in all; no {IDENTITY}: an older wtml's or copied "
                               "in); choose another --out")
        blob = json.dumps(_identity(scene, n_shards), indent=1).encode()
        tmp = tmp_name(ident)
        tmp.write_bytes(blob)
        try:
            os.link(tmp, ident)
        except FileExistsError:
            continue  # another writer was first: check what it claimed
        except OSError:  # no hard links here: create it exclusively, then write it
            try:
                fd = os.open(ident, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                continue
            with os.fdopen(fd, "wb") as fh:
                fh.write(blob)
        finally:
            tmp.unlink(missing_ok=True)
        return


def _read_sidecar(side: Path) -> ShardEntry | None:
    """A shard's sidecar (None if missing or unreadable: the shard is made again)."""
    try:
        return _read_schema(side, ShardEntry, "shard sidecar")
    except DatasetError:
        return None


def _shard_ok(out: Path, k: int, scene_hash: str, count: int) -> bool:
    npz, side = _shard_path(out, k), _shard_path(out, k).with_suffix(".json")
    entry = _read_sidecar(side)
    if entry is None:
        return False
    if entry.scene_hash != scene_hash:
        raise DatasetError(f"{side}: a shard of another scene ({entry.scene_hash[:12]}…) in the "
                           f"folder of scene {scene_hash[:12]}…; choose another --out")
    if entry.index != k or entry.count != count:
        return False
    try:
        check_shard_file(npz, entry)
    except DatasetError:
        return False
    return sha256(npz) == entry.sha256


def array_specs(arrays: dict[str, np.ndarray], count: int, where: str) -> list[dict]:
    """The ``arrays`` entry of a sidecar: each array's name, dtype and trailing shape."""
    specs = []
    for name, a in arrays.items():
        if a.dtype.str not in DTYPES or len(a) != count or not _KEY.match(name):
            raise DatasetError(f"{where}: '{name}' is {a.dtype.str} {_fmt_shape(a.shape)}; a "
                               f"shard holds numeric arrays of {count} records")
        specs.append({"name": name, "dtype": a.dtype.str, "shape": list(a.shape[1:])})
    return specs


def _write_shard(scene: FluidScene, out: Path, k: int, count: int) -> None:
    npz = _shard_path(out, k)
    for path in (npz, npz.with_suffix(".json")):
        if path.is_dir() and not path.is_symlink():
            raise DatasetError(f"{path}: is a folder, where shard {k}'s file goes; remove it")
    arrays = scene.simulate(count, np.random.default_rng([scene.seed, k]))
    specs = array_specs(arrays, count, f"scene {scene.task}, shard {k}")
    check_finite(f"{npz} (as simulated)", arrays, scene.task)
    atomic_write(npz, lambda fh: np.savez(fh, **arrays))
    side = {"index": k, "file": npz.name, "count": count, "sha256": sha256(npz),
            "scene_hash": config_hash(scene), "arrays": specs}
    atomic_write(npz.with_suffix(".json"), lambda fh: fh.write(json.dumps(side).encode()))


def _write_manifest(scene: FluidScene, out: Path, n_shards: int) -> dict:
    h = config_hash(scene)
    shards = []
    for k in range(n_shards):
        entry = _read_sidecar(_shard_path(out, k).with_suffix(".json"))
        if (entry is not None and entry.scene_hash == h and entry.index == k
                and entry.count == shard_size(scene.samples, n_shards, k)):
            shards.append(to_dict(entry))
    manifest = {"format": FORMAT, "scene": to_dict(scene), "scene_hash": h,
                "device": identity(device_of(scene)), "seed": scene.seed,
                "package_version": __version__, "n_shards": n_shards,
                "samples": scene.samples, "complete": len(shards) == n_shards,
                "shards": shards}
    build(Manifest, manifest)  # what is written is what a reader accepts
    atomic_write(out / "manifest.json",
                 lambda fh: fh.write(json.dumps(manifest, indent=1).encode()))
    return manifest


def _check_old_manifest(out: Path, scene: FluidScene, n_shards: int) -> None:
    """Refuse a folder whose manifest is unreadable, an older wtml's, or another scene's."""
    old = out / "manifest.json"
    if not os.path.lexists(old):
        return
    try:
        prev = read_json(old, what="dataset manifest")
        if not isinstance(prev, dict):
            raise FileError(f"{old}: not a JSON object")
    except FileError as err:
        raise DatasetError(
            f"{old}: corrupt ({err}); delete it and run the same wtml generate again: "
            "complete shards are kept (each has its own checksum file) and the manifest "
            "is rebuilt") from None
    if prev.get("format") != FORMAT:
        raise DatasetError(f"{out}: holds a dataset of an older wtml (format "
                           f"{str(prev.get('format'))!r:.40}); choose another --out")
    theirs = prev.get("scene_hash")
    if theirs != config_hash(scene) or prev.get("n_shards") != n_shards:
        raise DatasetError(f"{out}: holds shards of another scene or shard count, "
                           f"{str(theirs)[:12]}… ({str(prev.get('n_shards'))[:12]} shards; this "
                           f"one is {config_hash(scene)[:12]}…, {n_shards}); choose another "
                           "--out")


def generate(scene: FluidScene, out: str | Path, *, shards: int | None = None,
             shard: int | None = None, progress: bool = True) -> dict:
    """Generate (or complete) a dataset; returns the manifest.

    Args:
        scene: the scene.
        out: dataset folder (created).
        shards: number of shards (default ``scene.shards``).
        shard: make only this shard index (for parallel jobs).
        progress: print a progress bar to stderr.

    Raises:
        DatasetError: ``out`` holds a dataset of another scene or shard count (see
            :func:`claim`), or a bad ``shards`` or ``shard``.
    """
    out = Path(out)
    n_shards = scene.shards if shards is None else shards
    top = min(scene.samples, MAX_SHARDS)
    if isinstance(n_shards, bool) or not isinstance(n_shards, int) or not 1 <= n_shards <= top:
        raise DatasetError(f"--shards: must be a whole number in [1, {top}] (at most the "
                           f"sample count, {scene.samples}, and {MAX_SHARDS}), got {n_shards!r}")
    if shard is not None and (isinstance(shard, bool) or not isinstance(shard, int)
                              or not 0 <= shard < n_shards):
        raise DatasetError(f"--shard: shard must be in [0, {n_shards - 1}], got {shard!r}")
    if out.exists() and not out.is_dir():
        raise DatasetError(f"--out {out}: is a file; give a folder for the dataset "
                           "(e.g. datasets/<task>)")
    out.mkdir(parents=True, exist_ok=True)
    removed = clean_orphans(out)
    if removed and progress:
        print(f"{out}: removed {len(removed)} unfinished file(s) of an interrupted run",
              file=sys.stderr)
    claim(out, scene, n_shards)
    _check_old_manifest(out, scene, n_shards)
    h = config_hash(scene)
    todo = [shard] if shard is not None else range(n_shards)
    bar = tqdm(todo, desc=f"generate {out.name}", unit="shard", disable=not progress,
               file=sys.stderr, dynamic_ncols=True,
               mininterval=0.1 if sys.stderr.isatty() else 10.0)  # a log: few updates
    made = 0
    for done, k in enumerate(bar, start=1):
        size = shard_size(scene.samples, n_shards, k)
        if not _shard_ok(out, k, h, size):
            _write_shard(scene, out, k, size)
            made += 1
        bar.set_postfix_str(f"{made} made, {done - made} kept", refresh=False)
    return _write_manifest(scene, out, n_shards)
