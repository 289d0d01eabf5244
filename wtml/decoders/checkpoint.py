"""Reading wtml checkpoints safely: tensors and plain types only, never code.

Every checkpoint that wtml opens goes through :func:`read_checkpoint`, which loads with
``torch.load(..., weights_only=True)``: a file that holds anything but tensors, numbers,
strings, lists and dicts (a crafted pickle that would run code on loading, say) is refused
before any of it is built. What wtml itself puts in a checkpoint is plain: the scene as a
mapping, the net's shapes, the run length (``DecoderModule.on_save_checkpoint``).
"""

from __future__ import annotations

import dataclasses
import io
import pickle
import re
from pathlib import Path

import torch

from wtml.files import MEMORY_CEILING, regular_file
from wtml.schema import SchemaError, bounded, build
from wtml.tasks import TASKS, UNNAMED

RESUME_KEYS = ("epoch", "global_step", "state_dict", "loops", "optimizer_states",
               "lr_schedulers")
"""What a checkpoint needs besides the ``wtml`` block for ``--ckpt_path`` to resume it."""


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, unsafe, or not what the caller needs."""


@dataclasses.dataclass(frozen=True)
class CheckpointInfo:
    """The ``wtml`` block of a checkpoint (``DecoderModule.on_save_checkpoint``).

    Attributes:
        scene: the scene the decoder was trained for, as a mapping (rebuilt and checked by
            :func:`read_checkpoint`).
        shape: what the task's ``build_from_checkpoint`` needs to rebuild the net's shapes.
        max_epochs: the run's length (its learning-rate schedules are laid out over it).
        seed: the run's seed (``seed_everything``), from which each epoch's data order and
            random state are drawn; -1 in checkpoints written before it was kept.
        world_size: the processes the run trained on (DDP; its steps per epoch, hence its
            schedules, depend on it); 1 in checkpoints written before it was kept.
    """

    scene: dict
    shape: dict
    max_epochs: int = bounded(1, 10**6)
    seed: int = bounded(-1, 2**32 - 1, default=-1)
    world_size: int = bounded(1, 2**20, default=1)


def _load_bytes(data: bytes, path: Path) -> dict:
    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"GLOBAL (\S+)", str(err))
        reason = f"it would call {found[1]}" if found else "objects that are not plain data"
        raise CheckpointError(
            f"{path}: refused: it holds objects other than tensors and plain types, which "
            f"could run code when loaded ({reason}); wtml loads checkpoints with "
            "weights_only=True only. Use a checkpoint written by `python train.py fit`") from None
    except Exception as err:  # a damaged archive fails in many ways (zip, storage, unpickler)
        raise CheckpointError(f"{path}: not a readable checkpoint (truncated or another kind "
                              f"of file: {str(err).splitlines()[0][:120]}); train again or use "
                              "another last.ckpt") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not a checkpoint (holds a {type(state).__name__})")
    return state


def read_checkpoint(path: str | Path, task: str | None = None) -> dict:
    """The checkpoint's contents, loaded with ``weights_only=True`` and checked.

    Args:
        path: a ``.ckpt`` file written by ``python train.py fit``.
        task: if given, the task the checkpoint must be for (``"fluid"``, ``"radial"``,
            ``"onset"``).

    Raises:
        CheckpointError: one line naming the file and what to do: missing, truncated or
            not a checkpoint, refused as unsafe, not made by wtml, or of another task.
    """
    return _checked(Path(path), task)[0]


def _checked(path: Path, task: str | None) -> tuple[dict, bytes]:
    from wtml.scenes import SCENES, scene_from_dict

    if not path.exists():
        raise CheckpointError(f"{path}: no such checkpoint file; train one with "
                              "`python train.py fit --config configs/<task>.yaml`")
    try:
        regular_file(path, what="checkpoint", max_bytes=MEMORY_CEILING)
    except ValueError as err:
        raise CheckpointError(str(err)) from None
    data = path.read_bytes()
    if not data:
        raise CheckpointError(f"{path}: empty file; train again or use another last.ckpt")
    state = _load_bytes(data, path)
    info = state.get("wtml")
    if not isinstance(info, dict) or not isinstance(info.get("scene"), dict):
        raise CheckpointError(f"{path}: not a wtml checkpoint (no scene inside); use one "
                              "written by `python train.py fit`")
    found = info["scene"].get("task", UNNAMED)
    if found not in SCENES:
        raise CheckpointError(f"{path}: wtml.scene.task: a checkpoint of the {found!r:.40} "
                              f"task, which this version of wtml does not know (tasks: "
                              f"{sorted(SCENES)})")
    if task is not None and found != task:
        raise CheckpointError(f"{path}: a checkpoint of the {found!r} task, not {task!r}")
    try:
        build(CheckpointInfo, info, "wtml")
        scene_from_dict(info["scene"])
    except SchemaError as err:
        where = "" if str(err).startswith("wtml") else "wtml.scene."
        raise CheckpointError(f"{path}: {where}{err}") from None
    weights = state.get("state_dict")
    if not isinstance(weights, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in weights.items()):
        raise CheckpointError(f"{path}: state_dict: must map parameter names to tensors")
    for name, value in weights.items():
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise CheckpointError(f"{path}: state_dict.{name}: holds NaN or infinite "
                                  "values; a diverged run's weights are not used")
    return state, data


def resume_checkpoint(path: str | Path, task: str) -> dict:
    """A checkpoint that ``python train.py fit --ckpt_path`` can resume: as
    :func:`read_checkpoint` for ``task``, with the trainer's state (``RESUME_KEYS``) too.

    Raises:
        CheckpointError: one line naming the file and what is wrong.
    """
    state = read_checkpoint(path, task)
    missing = [k for k in RESUME_KEYS if k not in state]
    if missing:
        raise CheckpointError(f"{path}: {missing[0]}: missing; this checkpoint holds weights "
                              "only, without the trainer's state a run resumes from")
    for key, kind in (("loops", dict), ("optimizer_states", list), ("lr_schedulers", list)):
        if not isinstance(state[key], kind) or (kind is list and not all(
                isinstance(item, dict) for item in state[key])):
            raise CheckpointError(f"{path}: {key}: must be a "
                                  f"{'mapping' if kind is dict else 'list of mappings'}, "
                                  f"got {type(state[key]).__name__}")
    step = state["global_step"]
    if isinstance(step, bool) or not isinstance(step, int) or not 0 <= step < 2**62:
        raise CheckpointError(f"{path}: global_step: must be a whole number >= 0, "
                              f"got {step!r:.40}")
    epoch = state["epoch"]
    if isinstance(epoch, bool) or not isinstance(epoch, int) or not 0 <= epoch < 10**6:
        raise CheckpointError(f"{path}: epoch: must be a whole number in [0, 1000000), "
                              f"got {epoch!r:.40}")
    return state


def checkpoint_task(path: str | Path) -> str:
    """The task a checkpoint was trained for (``scene.task``)."""
    return read_checkpoint(path)["wtml"]["scene"].get("task", UNNAMED)


def load_module(cls, path: str | Path, task: str):
    """A LightningModule of class ``cls`` from a checked checkpoint of ``task`` (CPU, eval),
    loaded with ``weights_only=True``."""
    return _module(cls, _checked(Path(path), task)[1], path)


def _module(cls, data: bytes, path: str | Path):
    """``cls`` loaded from checked checkpoint bytes (``weights_only=True``), CPU, eval."""
    try:
        module = cls.load_from_checkpoint(io.BytesIO(data), weights_only=True,
                                          map_location="cpu")
    except (KeyError, TypeError, RuntimeError) as err:  # shapes or weights that do not fit
        first = str(err).splitlines()[0][:160] if str(err) else type(err).__name__
        raise CheckpointError(f"{path}: a checkpoint whose weights do not fit its own "
                              f"{cls.__name__} ({first})") from None
    return module.eval()


def load_decoder(path: str | Path):
    """The trained LightningModule of any task's checkpoint (its ``net``, ``gate`` and
    ``scene``), CPU, eval mode."""
    state, data = _checked(Path(path), None)
    task = state["wtml"]["scene"].get("task", UNNAMED)
    if task not in TASKS:
        raise CheckpointError(f"{path}: a checkpoint of the {task!r} task, which this version "
                              f"of wtml cannot load (tasks: {sorted(TASKS)})")
    return _module(TASKS[task].load("decoder"), data, path)
