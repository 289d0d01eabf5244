"""Deterministic, sharded, resumable dataset generation and checked loading.

Layout of a dataset folder::

    manifest.json           scene, seed, package version, counts, sha256 per shard
    shard-00000.npz         arrays of one shard (numpy .npz, no pickle)
    shard-00000.json        that shard's count and sha256 (written after the shard)

Shard ``k`` is generated from ``numpy.random.default_rng([scene.seed, k])``, so any shard can be
made by any process, in any order, bit for bit. Files are written to a temporary name and
renamed, so a kill leaves either a complete shard or none. Re-running skips shards whose
checksum matches their sidecar and regenerates the rest; the manifest is rebuilt from the
sidecars at the end of every run (after parallel ``--shard K`` jobs, one run without
``--shard`` completes and verifies it). Loading verifies every checksum.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import socket
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from wtml import __version__
from wtml.scenes import FluidScene, config_hash, scene_from_dict, to_dict

FORMAT = "wtml.dataset/1"


class DatasetError(ValueError):
    """A dataset folder that is missing, damaged or made from another scene."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _tmp_name(path: Path) -> Path:
    """Where ``path`` is written before its rename: ``.{name}.{host}.{pid}.tmp``."""
    return path.with_name(f".{path.name}.{socket.gethostname()}.{os.getpid()}.tmp")


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
    mine = re.compile(rf"^\..+\.{re.escape(socket.gethostname())}\.(\d+)\.tmp$")
    removed = []
    for tmp in out.iterdir():
        match = mine.match(tmp.name)
        if match and not _pid_alive(int(match[1])):
            tmp.unlink(missing_ok=True)
            removed.append(tmp)
    return removed


def _atomic_write(path: Path, write) -> None:
    tmp = _tmp_name(path)
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def shard_sizes(samples: int, shards: int) -> list[int]:
    """Samples per shard: as equal as possible, the first ones one larger."""
    base, extra = divmod(samples, shards)
    return [base + (k < extra) for k in range(shards)]


def _shard_path(out: Path, k: int) -> Path:
    return out / f"shard-{k:05d}.npz"


def _shard_ok(out: Path, k: int) -> bool:
    npz, side = _shard_path(out, k), _shard_path(out, k).with_suffix(".json")
    if not (npz.exists() and side.exists()):
        return False
    try:
        return json.loads(side.read_text())["sha256"] == _sha256(npz)
    except (json.JSONDecodeError, KeyError):
        return False


def _write_shard(scene: FluidScene, out: Path, k: int, count: int) -> None:
    arrays = scene.simulate(count, np.random.default_rng([scene.seed, k]))
    npz = _shard_path(out, k)
    _atomic_write(npz, lambda fh: np.savez(fh, **arrays))
    side = {"index": k, "file": npz.name, "count": count, "sha256": _sha256(npz)}
    _atomic_write(npz.with_suffix(".json"), lambda fh: fh.write(json.dumps(side).encode()))


def _write_manifest(scene: FluidScene, out: Path, sizes: list[int]) -> dict:
    shards = []
    for k in range(len(sizes)):
        side = _shard_path(out, k).with_suffix(".json")
        if side.exists():
            shards.append(json.loads(side.read_text()))
    manifest = {"format": FORMAT, "scene": to_dict(scene), "scene_hash": config_hash(scene),
                "seed": scene.seed, "package_version": __version__, "n_shards": len(sizes),
                "samples": scene.samples, "complete": len(shards) == len(sizes),
                "shards": shards}
    _atomic_write(out / "manifest.json",
                  lambda fh: fh.write(json.dumps(manifest, indent=1).encode()))
    return manifest


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
        DatasetError: ``out`` holds a dataset of another scene or shard count.
    """
    out = Path(out)
    n_shards = scene.shards if shards is None else shards
    if not 1 <= n_shards <= scene.samples:
        raise DatasetError(f"shards must be in [1, {scene.samples}] (the sample count), "
                           f"got {n_shards}")
    if shard is not None and not 0 <= shard < n_shards:
        raise DatasetError(f"shard must be in [0, {n_shards - 1}], got {shard}")
    if out.exists() and not out.is_dir():
        raise DatasetError(f"--out {out}: is a file; give a folder for the dataset "
                           "(e.g. datasets/<task>)")
    out.mkdir(parents=True, exist_ok=True)
    removed = clean_orphans(out)
    if removed and progress:
        print(f"{out}: removed {len(removed)} unfinished file(s) of an interrupted run",
              file=sys.stderr)
    old = out / "manifest.json"
    if old.exists():
        try:
            prev = json.loads(old.read_text())
            if not isinstance(prev, dict):
                raise ValueError("not a JSON object")
        except (ValueError, UnicodeDecodeError) as err:
            raise DatasetError(
                f"{old}: corrupt ({err}); delete it and run the same wtml generate again: "
                "complete shards are kept (each has its own checksum file) and the manifest "
                "is rebuilt") from None
        if prev.get("scene_hash") != config_hash(scene) or prev.get("n_shards") != n_shards:
            raise DatasetError(f"{out} holds a dataset of another scene or shard count "
                               f"(scene {prev.get('scene_hash', '?')[:12]}, "
                               f"{prev.get('n_shards')} shards); choose a new --out")
    sizes = shard_sizes(scene.samples, n_shards)
    todo = [shard] if shard is not None else range(n_shards)
    bar = tqdm(todo, desc=f"generate {out.name}", unit="shard", disable=not progress,
               file=sys.stderr, dynamic_ncols=True,
               mininterval=0.1 if sys.stderr.isatty() else 10.0)  # a log: few updates
    made = 0
    for done, k in enumerate(bar, start=1):
        if not _shard_ok(out, k):
            _write_shard(scene, out, k, sizes[k])
            made += 1
        bar.set_postfix_str(f"{made} made, {done - made} kept", refresh=False)
    return _write_manifest(scene, out, sizes)


def read_manifest(path: str | Path) -> dict:
    """The manifest of a dataset folder, checked for format and completeness."""
    path = Path(path)
    try:
        manifest = json.loads((path / "manifest.json").read_text())
    except FileNotFoundError:
        raise DatasetError(f"{path}: no dataset there (no manifest.json); make it with "
                           f"`wtml generate --config configs/scenes/<task>.yaml --out {path}`"
                           ) from None
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path / 'manifest.json'}: corrupt ({err}); run the same wtml "
                           "generate again after deleting it (complete shards are kept)") from None
    if manifest.get("format") != FORMAT:
        raise DatasetError(f"{path}: format {manifest.get('format')!r}, expected {FORMAT!r}")
    if not manifest.get("complete"):
        raise DatasetError(f"{path}: incomplete ({len(manifest['shards'])} of "
                           f"{manifest['n_shards']} shards); run wtml generate again to finish")
    return manifest


def load_shards(path: str | Path, indices: list[int] | None = None) -> dict[str, np.ndarray]:
    """Concatenated arrays of the given shards (all by default), each checksum verified.

    Raises:
        DatasetError: naming the shard whose file is missing or does not match its sha256.
    """
    path = Path(path)
    manifest = read_manifest(path)
    entries = {e["index"]: e for e in manifest["shards"]}
    parts: dict[str, list[np.ndarray]] = {}
    for k in range(manifest["n_shards"]) if indices is None else indices:
        if k not in entries:
            raise DatasetError(f"{path}: shard {k} is not in the manifest")
        npz = path / entries[k]["file"]
        if not npz.exists() or _sha256(npz) != entries[k]["sha256"]:
            raise DatasetError(f"{npz}: missing or its sha256 does not match the manifest; "
                               "run wtml generate again to regenerate it")
        with np.load(npz, allow_pickle=False) as data:
            for key in data.files:
                parts.setdefault(key, []).append(data[key])
    return {key: np.concatenate(v) for key, v in parts.items()}


def dataset_scene(path: str | Path) -> FluidScene:
    """The scene a dataset was generated from."""
    return scene_from_dict(read_manifest(path)["scene"])
