"""Tensors for training: shards split by index into train, validation and test."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Sampler, TensorDataset

from wtml.data.shards import (
    NAN_BY_DESIGN,
    DatasetError,
    checked_manifest,
    load_shards,
    shard_name,
)
from wtml.scenes import to_dict
from wtml.scenes.onset import onset_calibration as onset_calibration  # its old home
from wtml.tasks import TASKS


def split_shards(n_shards: int, val_shards: int, test_shards: int) -> dict[str, list[int]]:
    """Fixed split by shard index: test = the last ``test_shards``, val = the ones before."""
    if n_shards < val_shards + test_shards + 1:
        raise DatasetError(f"{n_shards} shards cannot give {val_shards} validation and "
                           f"{test_shards} test shards and still train")
    train_end = n_shards - val_shards - test_shards
    return {"train": list(range(train_end)),
            "val": list(range(train_end, train_end + val_shards)),
            "test": list(range(train_end + val_shards, n_shards))}


def check_tensors(tensors: tuple[torch.Tensor, ...], task: str, where: list[tuple[str, int]]
                  ) -> None:
    """Refuse a non-finite training value before the first step: a NaN or inf in an input,
    or in a target but for the NaN its task's arrays hold by design (never inf;
    ``wtml.data.shards.NAN_BY_DESIGN``: onset's ``gap``, ``onset``, ``detachment``), each
    named by its scene's ``INPUT_KEYS`` and ``target_keys``. ``where`` is each shard's file
    and record count in the order the rows come; the :class:`DatasetError` names the shard,
    the key and the row there. The shards' own values were checked on load: this finds what
    the float32 tensors add (a number beyond float32's range, the log of an ``eta`` <= 0)."""
    *inputs, targets = tensors
    scene = TASKS[task].load("scene")
    for key, x in zip(scene.INPUT_KEYS, inputs, strict=True):
        bad = ~torch.isfinite(x.reshape(len(x), -1)).all(1)
        _refuse_rows(bad, key, where)
    for col, key in enumerate(scene.target_keys(targets.shape[1])):
        y = targets[:, col]
        nan_ok = key in NAN_BY_DESIGN.get(task, ())
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


def task_tensors(arrays: dict[str, np.ndarray], task: str) -> tuple[torch.Tensor, ...]:
    """The decoder's input tensors, then its training targets, float32: the task's scene's
    ``decoder_inputs(arrays)`` (its ``INPUT_KEYS`` name the array of each) and
    ``targets(arrays)``, ``(n, n_targets)`` (``wtml.scenes``). The arrays each task needs are
    checked when the manifest is read (``wtml.data.shards.TASK_ARRAYS``); ``arrays`` without
    one of the inputs' (an older wtml's) is refused here.

    Raises:
        DatasetError: an input's array is missing.
    """
    scene = TASKS[task].load("scene")
    missing = [key for key in dict.fromkeys(scene.INPUT_KEYS) if key not in arrays]
    if missing:
        raise DatasetError(f"no {', '.join(map(repr, missing))} in this {task} dataset (its "
                           "decoder reads it): made by an older wtml; generate it again")
    with np.errstate(all="ignore"):  # a log10 of eta <= 0: refused by check_tensors
        return tuple(torch.tensor(a, dtype=torch.float32)
                     for a in (*scene.decoder_inputs(arrays), scene.targets(arrays)))


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
    Under DDP, Lightning wraps it: each process takes every ``world_size``-th batch.

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
        records = TASKS[self.scene.task].reads == "recordings"
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
