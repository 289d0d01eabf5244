"""``wtml evaluate``: a checkpoint's accuracy on the test shard of its dataset, beside the
task's classical path: fluid by viscosity decade (decoder and the thesis's closed form),
radial by range of d (decoder and the polynomial in Im Ze, with the Cramér–Rao bound)."""

from __future__ import annotations

from pathlib import Path

from wtml.data import dataset_scene, load_shards, read_manifest
from wtml.data.datamodule import split_shards
from wtml.decoders.checkpoint import CheckpointError, checkpoint_task


def evaluate(checkpoint: str | Path, data_dir: str | Path) -> str:
    """The evaluation report (markdown) of ``checkpoint`` on the test shard of ``data_dir``.

    Raises:
        CheckpointError: a bad checkpoint, or one of another task than the dataset's.
        DatasetError: a missing or damaged dataset.
    """
    manifest = read_manifest(data_dir)
    scene = dataset_scene(data_dir)
    task = checkpoint_task(checkpoint)
    if task != scene.task:
        raise CheckpointError(f"{checkpoint}: a checkpoint of the {task!r} task, but "
                              f"{data_dir} is a {scene.task!r} dataset")
    split = split_shards(manifest["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    where = f"the test shard {split['test']} of {data_dir}"
    if task == "fluid":
        from wtml.baselines import ClassicalFluid
        from wtml.bench.accuracy import by_decade, format_decades, relative_errors
        from wtml.decoders.fluid import TorchFluid, load_fluid_net

        net, _ = load_fluid_net(str(checkpoint))
        parts = []
        for p in (TorchFluid(net), ClassicalFluid(scene.excitation.omega,
                                                  scene.sphere.radius)):
            err = relative_errors(p.predict(test["ze"], test["t"]), test["eta"], test["rho"])
            parts.append(format_decades(f"{p.name} on {where}", by_decade(err, test["eta"])))
        return "\n\n".join(parts)
    from wtml.baselines.radial import PolynomialRadial
    from wtml.bench.bounds import radial_crlb
    from wtml.bench.radial import format_ranges, range_rows
    from wtml.decoders.radial import TorchRadial, load_radial_net

    net, _ = load_radial_net(str(checkpoint))
    train = load_shards(data_dir, split["train"])
    d, crlb = test["distance"], radial_crlb(scene, test["distance"], test["stiffness"])
    results = []
    for p in (TorchRadial(net),
              PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"])):
        err = p.predict(test["ze"], test["ref"])["distance"] - d
        results.append({"name": p.name, "rows": range_rows(err, d, crlb)})
    return f"RMSE (µm) by range of d and RMSE / CRLB, on {where}\n\n" + format_ranges(results)
