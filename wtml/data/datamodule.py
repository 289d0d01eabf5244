"""Tensors for training: shards split by index into train, validation and test."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Sampler, TensorDataset

from wtml.data.shards import DatasetError, checked_manifest, load_shards, shard_name
from wtml.scenes import to_dict


def split_shards(n_shards: int, val_shards: int, test_shards: int) -> dict[str, list[int]]:
    """Fixed split by shard index: test = the last ``test_shards``, val = the ones before."""
    if n_shards < val_shards + test_shards + 1:
        raise DatasetError(f"{n_shards} shards cannot give {val_shards} validation and "
                           f"{test_shards} test shards and still train")
    train_end = n_shards - val_shards - test_shards
    return {"train": list(range(train_end)),
            "val": list(range(train_end, train_end + val_shards)),
            "test": list(range(train_end + val_shards, n_shards))}


TARGETS = {
    "fluid": lambda a: np.stack([np.log10(a["eta"]), a["rho"]], -1),  # log10 Pa·s, kg/m³
    "radial": lambda a: a["distance"][:, None],  # m from the tip
    "onset": lambda a: np.concatenate([a["gap"][:, None], a["onset"], a["detachment"],
                                       a["coupling"][:, None]], 1),
    "texture": lambda a: np.stack([a["grade"], a["grain_m"]], -1),  # class index, m
}
"""The training targets of each task, shape ``(n, n_targets)``."""

INPUT_KEYS = {"fluid": ("ze", "ze", "t", "t"), "radial": ("ze", "ze", "ref", "ref"),
              "onset": ("e", "i", "t_probe", "t_probe", "hue0"), "texture": ("e", "i", "t", "t")}
"""The shard array each input tensor of :func:`task_tensors` comes from."""


def target_keys(task: str, n_targets: int) -> tuple[str, ...]:
    """The shard array each column of ``TARGETS[task]`` comes from."""
    if task == "onset":
        c = (n_targets - 2) // 2
        return ("gap", *["onset"] * c, *["detachment"] * c, "coupling")
    return {"fluid": ("eta", "rho"), "radial": ("distance",),
            "texture": ("grade", "grain_m")}[task]


def check_tensors(tensors: tuple[torch.Tensor, ...], task: str, where: list[tuple[str, int]]
                  ) -> None:
    """Refuse a non-finite training value before the first step: a NaN or inf in an input,
    or in a target but for the NaN that onset's are padded with (``gap``, ``onset``,
    ``detachment``: NaN by design, never inf). ``where`` is each shard's file and record count
    in the order the rows come; the :class:`DatasetError` names the shard, the key and the row
    there. The shards' own values were checked on load: this finds what the float32 tensors
    add (a number beyond float32's range, the log of an ``eta`` <= 0)."""
    *inputs, targets = tensors
    keys = [*INPUT_KEYS[task]]
    columns = target_keys(task, targets.shape[1])
    for key, x in zip(keys, inputs, strict=True):
        bad = ~torch.isfinite(x.reshape(len(x), -1)).all(1)
        _refuse_rows(bad, key, where)
    for col, key in enumerate(columns):
        y = targets[:, col]
        nan_ok = task == "onset" and key != "coupling"
        _refuse_rows(torch.isinf(y) if nan_ok else ~torch.isfinite(y), key, where)


def _refuse_rows(bad: torch.Tensor, key: str, where: list[tuple[str, int]]) -> None:
    if not bool(bad.any()):
        return
    row = int(torch.nonzero(bad)[0, 0])
    starts = np.cumsum([0] + [count for _, count in where])
    shard = int(np.searchsorted(starts, row, side="right")) - 1  # the shard the row is in
    file, row = where[shard][0], row - int(starts[shard])
    raise DatasetError(f"{file}: '{key}' gives a NaN or inf training value in row {row} "
                       "(beyond float32's range, or the log of a value <= 0); a dataset must "
                       "hold finite numbers: generate it again")


def onset_calibration(arrays: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Each onset record's calibration as the decoder's graph takes it
    (``wtml.decoders.onset.CALIBRATION``): ``t_re, t_im`` ``(n, 4)`` (its device's T at the
    probe, flattened t11, t12, t21, t22) and ``hue0`` ``(n,)`` m/V."""
    if "t_probe" not in arrays or "hue0" not in arrays:
        raise DatasetError("an onset dataset without each record's calibration ('t_probe', "
                           "'hue0'): made by an older wtml; generate it again")
    t = np.asarray(arrays["t_probe"]).reshape(-1, 4)
    return t.real, t.imag, np.asarray(arrays["hue0"], float)


def task_tensors(arrays: dict[str, np.ndarray], task: str) -> tuple[torch.Tensor, ...]:
    """The input tensors and the targets, float32: ``(ze_re, ze_im, ref_re, ref_im,
    targets)`` for radial (``ref``: the free whisker's Ze of the record's device, the user's
    reference), ``(ze_re, ze_im, t_re, t_im, targets)`` for fluid (each record's calibrated T,
    ``(n, n_freq, 4)`` flattened as t11, t12, t21, t22), ``(e, i, t_re, t_im, targets)`` (V, A;
    NaN-padded targets: gap m, onsets s, detachments s) for texture (T at the scene's
    ``calibration_hz``), and for onset ``e, i`` then each record's calibration
    (:func:`onset_calibration`); targets as in ``TARGETS``. The arrays each task needs are
    checked when the manifest is read (``wtml.data.shards.TASK_ARRAYS``)."""
    if task == "onset":
        inputs = (arrays["e"], arrays["i"], *onset_calibration(arrays))
    elif task in ("fluid", "texture"):
        if "t" not in arrays:
            raise DatasetError(f"a {task} dataset without each record's calibrated T ('t'): "
                               "made by an older wtml; generate it again")
        t = arrays["t"].reshape(*arrays["t"].shape[:-2], 4)
        signals = ((arrays["ze"].real, arrays["ze"].imag) if task == "fluid"
                   else (arrays["e"], arrays["i"]))
        inputs = (*signals, t.real, t.imag)
    elif task == "radial":
        if "ref" not in arrays:
            raise DatasetError("a radial dataset without each record's free reference ('ref'): "
                               "made by an older wtml; generate it again")
        inputs = (arrays["ze"].real, arrays["ze"].imag, arrays["ref"].real, arrays["ref"].imag)
    else:
        inputs = (arrays["ze"].real, arrays["ze"].imag)
    with np.errstate(all="ignore"):  # a log10 of eta <= 0: refused by check_tensors
        targets = TARGETS[task](arrays)
        return tuple(torch.tensor(a, dtype=torch.float32) for a in (*inputs, targets))


def epoch_seed(epoch: int) -> int:
    """The seed of a training epoch, from the run's seed (``seed_everything``'s, which
    Lightning keeps in ``PL_GLOBAL_SEED``; 0 when the run set none) and the epoch alone: a
    resumed run draws each epoch's data order and random state as the run never
    interrupted drew them, whatever came before."""
    base = int(os.environ.get("PL_GLOBAL_SEED", 0))
    return int(np.random.SeedSequence([base, epoch]).generate_state(1)[0])


class EpochBatches(Sampler):
    """Batches of the indices ``0 .. n-1``, whole tensors of indices: in order, or in a
    permutation drawn for each epoch from :func:`epoch_seed` (like ``DistributedSampler``
    with ``set_epoch``, but the epoch read when the batches are drawn, from ``epoch()``).

    Args:
        n: samples.
        batch_size: samples per batch (the last one may be short).
        shuffle: a new order each epoch.
        epoch: the training epoch now (0-based), asked when an epoch's batches are drawn.
    """

    def __init__(self, n: int, batch_size: int, shuffle: bool,
                 epoch: Callable[[], int] = lambda: 0) -> None:
        self.n, self.batch_size, self.shuffle, self.epoch = n, batch_size, shuffle, epoch

    def __len__(self) -> int:
        return -(-self.n // self.batch_size)

    def __iter__(self) -> Iterator[torch.Tensor]:
        if self.shuffle:
            gen = torch.Generator().manual_seed(epoch_seed(self.epoch()))
            order = torch.randperm(self.n, generator=gen)
        else:
            order = torch.arange(self.n)
        yield from order.split(self.batch_size)


class ShardDataModule(L.LightningDataModule):
    """Any task's shards, for its LightningModule (``wtml.decoders``).

    Args:
        data_dir: a dataset folder made by ``wtml generate``.
        batch_size: samples per batch.
        val_shards, test_shards: how many of the last shards to hold out.
    """

    def __init__(self, data_dir: str, batch_size: int = 256, val_shards: int = 1,
                 test_shards: int = 1) -> None:
        super().__init__()
        for name, value, low in (("batch_size", batch_size, 1), ("val_shards", val_shards, 1),
                                 ("test_shards", test_shards, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= 10**7:
                raise DatasetError(f"data.{name} must be a whole number in [{low}, 10000000], "
                                   f"got {value!r}")
        if not isinstance(data_dir, str | Path) or not Path(data_dir).is_dir():
            raise DatasetError(f"data.data_dir: {data_dir} does not exist; make the dataset with "
                               "`wtml generate --config configs/scenes/<task>.yaml --out "
                               f"{data_dir}`")
        self.data_dir = data_dir
        self.batch_size = batch_size
        try:
            manifest, self.scene = checked_manifest(data_dir)
        except DatasetError as err:
            raise DatasetError(f"data.data_dir: {err}") from None
        self.counts = {e.index: e.count for e in manifest.shards}
        self.split = split_shards(manifest.n_shards, val_shards, test_shards)
        self.scene_dict = to_dict(self.scene)
        self._data: dict[str, TensorDataset] = {}
        self._input_map = None
        records = self.scene.task in ("onset", "texture")
        self.eval_batch = 64 if records else 4096  # records vs phasors

    def _dataset(self, split: str) -> TensorDataset:
        if split not in self._data:
            shards = self.split[split]
            tensors = task_tensors(load_shards(self.data_dir, shards), self.scene.task)
            if not len(tensors[-1]):
                raise DatasetError(f"{self.data_dir}: the {split} split (shards {shards}) holds "
                                   "no records")
            check_tensors(tensors, self.scene.task,
                          [(str(Path(self.data_dir) / shard_name(k)), self.counts[k])
                           for k in shards])
            *inputs, targets = tensors
            if self._input_map is not None:
                with torch.no_grad():
                    inputs = [torch.cat([self._input_map(*(x[s:s + 65536] for x in inputs))
                                         for s in range(0, len(targets), 65536)])]
            self._data[split] = TensorDataset(*inputs, targets)
        return self._data[split]

    def map_inputs(self, fn) -> None:
        """Hand every split's batches as ``(fn(*inputs), targets)`` from now on, ``fn`` computed
        once per sample (in chunks, without gradients): for a net whose first layer is fixed
        (the fluid net's Zm through each record's T), which then costs nothing per step.
        Splits already loaded are mapped again from their shards."""
        if fn is not self._input_map:
            self._input_map = fn
            self._data.clear()

    def train_tensors(self) -> tuple[torch.Tensor, ...]:
        """The whole training split, for normalisation statistics (the inputs as the batches
        hold them: see :meth:`map_inputs`)."""
        return self._dataset("train").tensors

    def _loader(self, split: str, batch_size: int, shuffle: bool) -> DataLoader:
        """Whole batches indexed at once from the in-memory tensors (:class:`EpochBatches`),
        without collating one sample at a time (that took 2 s of every radial epoch);
        shuffled, each epoch's order is drawn from the run's seed and the epoch alone."""
        data = self._dataset(split)
        # its own generator: a DataLoader otherwise draws a seed from the global torch RNG
        # whenever it starts an epoch, which a resumed run's first epoch does at another time
        return DataLoader(data, sampler=EpochBatches(len(data), batch_size, shuffle,
                                                     self._epoch), batch_size=None,
                          generator=torch.Generator())

    def _epoch(self) -> int:
        """The trainer's epoch now (0 without a trainer)."""
        trainer = self.trainer
        return 0 if trainer is None else int(trainer.fit_loop.epoch_progress.current.processed)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", self.batch_size, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", self.eval_batch, shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", self.eval_batch, shuffle=False)
