"""``wtml evaluate``: a checkpoint's accuracy on the test shard of its dataset, beside the
task's classical path, in the report its task declares (``wtml.tasks``' ``evaluate`` part):
fluid by viscosity decade (decoder and the thesis's closed form,
:func:`wtml.bench.fluid.evaluate_checkpoint`), radial by range of d (decoder and the
polynomial in Im Ze, with the Cramér–Rao bound, :func:`wtml.bench.radial.evaluate_checkpoint`).
"""

from __future__ import annotations

from pathlib import Path

from wtml.data import dataset_scene, load_shards, read_manifest
from wtml.data.datamodule import split_shards
from wtml.decoders.checkpoint import CheckpointError, checkpoint_task
from wtml.tasks import TASKS


def evaluate(checkpoint: str | Path, data_dir: str | Path) -> str:
    """The evaluation report (markdown) of ``checkpoint`` on the test shard of ``data_dir``.

    Raises:
        CheckpointError: a bad checkpoint, one of another task than the dataset's, or of a
            task without an evaluation report (its bench has the numbers).
        DatasetError: a missing or damaged dataset.
    """
    manifest = read_manifest(data_dir)
    scene = dataset_scene(data_dir)
    task = checkpoint_task(checkpoint)
    if task != scene.task:
        raise CheckpointError(f"{checkpoint}: a checkpoint of the {task!r} task, but "
                              f"{data_dir} is a {scene.task!r} dataset")
    if not TASKS[task].evaluate:
        raise CheckpointError(f"{checkpoint}: `wtml evaluate` has no report for the {task!r} "
                              f"task; `wtml bench {task}` measures it")
    split = split_shards(manifest["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    where = f"the test shard {split['test']} of {data_dir}"
    return TASKS[task].load("evaluate")(checkpoint, data_dir, scene, split, test, where)
