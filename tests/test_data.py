"""Sharded generation: determinism, atomic resumable shards, checksums, manifests."""

import json

import numpy as np
import pytest

from wtml.data import DatasetError, generate, load_shards, read_manifest
from wtml.data.datamodule import ShardDataModule, split_shards
from wtml.data.shards import shard_sizes
from wtml.scenes import FluidScene
from wtml.schema import build

SCENE = build(FluidScene, {"samples": 400, "shards": 4})


def test_bit_for_bit_and_independent_of_order(tmp_path):
    a = generate(SCENE, tmp_path / "a", progress=False)
    for k in (3, 1, 0, 2):  # shards one by one, out of order, as parallel jobs would
        generate(SCENE, tmp_path / "b", shard=k, progress=False)
    b = generate(SCENE, tmp_path / "b", progress=False)
    assert [s["sha256"] for s in a["shards"]] == [s["sha256"] for s in b["shards"]]
    assert a["complete"] and a["samples"] == 400 and a["n_shards"] == 4
    assert a["scene"]["samples"] == 400 and a["package_version"]


def test_resume_regenerates_only_missing_and_damaged(tmp_path, capsys):
    out = tmp_path / "ds"
    generate(SCENE, out, progress=False)
    (out / "shard-00002.npz").unlink()
    raw = bytearray((out / "shard-00001.npz").read_bytes())
    raw[200] ^= 0xFF
    (out / "shard-00001.npz").write_bytes(bytes(raw))
    with pytest.raises(DatasetError, match=r"shard-00001.npz: missing or its sha256"):
        load_shards(out)
    before = (out / "shard-00000.npz").stat().st_mtime_ns
    generate(SCENE, out, progress=True)
    assert "2 made" in capsys.readouterr().err
    assert (out / "shard-00000.npz").stat().st_mtime_ns == before
    assert load_shards(out)["eta"].shape == (400,)


def test_partial_dataset_is_refused_until_complete(tmp_path):
    out = tmp_path / "ds"
    generate(SCENE, out, shard=0, progress=False)
    with pytest.raises(DatasetError, match=r"incomplete \(1 of 4 shards\)"):
        read_manifest(out)


def test_another_scene_is_refused(tmp_path):
    out = tmp_path / "ds"
    generate(SCENE, out, progress=False)
    other = build(FluidScene, {"samples": 400, "shards": 4, "seed": 1})
    with pytest.raises(DatasetError, match="another scene"):
        generate(other, out, progress=False)
    with pytest.raises(DatasetError, match=r"shard must be in \[0, 3\]"):
        generate(SCENE, out, shard=4, progress=False)


def test_shards_hold_plain_arrays(tmp_path):
    generate(SCENE, tmp_path, progress=False)
    with np.load(tmp_path / "shard-00000.npz", allow_pickle=False) as data:
        assert data["ze"].dtype == np.complex128 and data["ze"].shape == (100, 31)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert [s["count"] for s in manifest["shards"]] == [100] * 4
    assert shard_sizes(10, 3) == [4, 3, 3]


def test_split_by_shard_and_datamodule(tmp_path):
    assert split_shards(8, 1, 1) == {"train": list(range(6)), "val": [6], "test": [7]}
    with pytest.raises(DatasetError, match="cannot give"):
        split_shards(2, 1, 1)
    generate(SCENE, tmp_path, progress=False)
    dm = ShardDataModule(str(tmp_path), batch_size=32)
    ze_re, ze_im, t_re, t_im, y = dm.train_tensors()
    assert ze_re.shape == (200, 31) and y.shape == (200, 2) and t_im.shape == (200, 31, 4)
    np.testing.assert_allclose(10 ** y[:, 0].double().numpy(),
                               load_shards(tmp_path, [0, 1])["eta"], rtol=1e-6)
    assert len(dm.test_dataloader().dataset) == 100


def test_loaders_give_the_batches_of_a_per_sample_loader(tmp_path):
    """Batches indexed whole are the batches a collating DataLoader gives in the epoch's
    permutation (drawn from ``epoch_seed``), the short last one included; an epoch's order
    depends on the run's seed and the epoch only, never on the global random state (what makes
    a resumed run exact), and the epochs differ."""
    import torch
    from torch.utils.data import DataLoader

    from wtml.data.datamodule import epoch_seed

    generate(SCENE, tmp_path, progress=False)
    dm = ShardDataModule(str(tmp_path), batch_size=48)
    for make, reference, shuffle in ((dm.train_dataloader, "train", True),
                                     (dm.test_dataloader, "test", False)):
        torch.manual_seed(7)
        ours = list(make())
        torch.manual_seed(8)  # another global state: the order must not follow it
        assert all(torch.equal(x, y) for a, b in zip(ours, make(), strict=True)
                   for x, y in zip(a, b, strict=True))
        batch = 48 if shuffle else dm.eval_batch
        data = dm._dataset(reference)
        gen = torch.Generator().manual_seed(epoch_seed(0))  # the first epoch's permutation
        order = torch.randperm(len(data), generator=gen).tolist() if shuffle else None
        theirs = list(DataLoader(data, batch_size=batch, sampler=order))
        assert len(ours) == len(theirs) == -(-len(dm._dataset(reference)) // batch)
        for a, b in zip(ours, theirs, strict=True):
            assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert epoch_seed(0) != epoch_seed(1)


def test_mapped_inputs_are_the_map_of_each_batch(tmp_path):
    """After ``map_inputs`` the loaders hand ``(fn(*inputs), targets)``: under the same seed,
    the batches of the unmapped loader with ``fn`` applied to each, bit for bit (the fluid
    net's feature layer, computed once per sample instead of in every step)."""
    import torch

    from wtml.decoders.layers import SignedLogZm

    generate(SCENE, tmp_path, progress=False)
    dm = ShardDataModule(str(tmp_path), batch_size=48)
    fn = SignedLogZm(0.01 * SCENE.reference_zm(), SCENE.excitation.n_freq)
    torch.manual_seed(3)
    raw = list(dm.train_dataloader())
    dm.map_inputs(fn)
    assert dm.train_tensors()[0].shape == (200, 2 * 31 + SignedLogZm.N_DEVICE)
    torch.manual_seed(3)
    mapped = list(dm.train_dataloader())
    assert len(mapped) == len(raw) == 5
    for (x, y), (*inputs, y_raw) in zip(mapped, raw, strict=True):
        assert torch.equal(y, y_raw) and torch.equal(x, fn(*inputs))
