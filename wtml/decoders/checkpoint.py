"""Reading wtml checkpoints safely: tensors and plain types only, never code.

Every checkpoint that wtml opens goes through :func:`read_checkpoint`, which loads with
``torch.load(..., weights_only=True)``: a file that holds anything but tensors, numbers,
strings, lists and dicts (a crafted pickle that would run code on loading, say) is refused
before any of it is built. What wtml itself puts in a checkpoint is plain: the scene as a
mapping, the net's shapes, the run length (``DecoderModule.on_save_checkpoint``).
"""

from __future__ import annotations

import io
import pickle
import re
from pathlib import Path

import torch


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, unsafe, or not what the caller needs."""


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
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file; train one with "
                              "`python train.py fit --config configs/<task>.yaml`")
    data = path.read_bytes()
    if not data:
        raise CheckpointError(f"{path}: empty file; train again or use another last.ckpt")
    state = _load_bytes(data, path)
    info = state.get("wtml")
    if not isinstance(info, dict) or not isinstance(info.get("scene"), dict):
        raise CheckpointError(f"{path}: not a wtml checkpoint (no scene inside); use one "
                              "written by `python train.py fit`")
    found = info["scene"].get("task", "fluid")
    if task is not None and found != task:
        raise CheckpointError(f"{path}: a checkpoint of the {found!r} task, not {task!r}")
    return state, data


def checkpoint_task(path: str | Path) -> str:
    """The task a checkpoint was trained for (``scene.task``)."""
    return read_checkpoint(path)["wtml"]["scene"].get("task", "fluid")


def load_module(cls, path: str | Path, task: str):
    """A LightningModule of class ``cls`` from a checked checkpoint of ``task`` (CPU, eval),
    loaded with ``weights_only=True``."""
    return _module(cls, _checked(Path(path), task)[1])


def _module(cls, data: bytes):
    """``cls`` loaded from checked checkpoint bytes (``weights_only=True``), CPU, eval."""
    module = cls.load_from_checkpoint(io.BytesIO(data), map_location="cpu", weights_only=True)
    return module.eval()


def load_decoder(path: str | Path):
    """The trained LightningModule of any task's checkpoint (its ``net``, ``gate`` and
    ``scene``), CPU, eval mode."""
    from wtml.decoders.fluid import FluidDecoder
    from wtml.decoders.onset import OnsetDecoder
    from wtml.decoders.radial import RadialDecoder
    from wtml.decoders.texture import TextureDecoder

    classes = {"fluid": FluidDecoder, "radial": RadialDecoder, "onset": OnsetDecoder,
               "texture": TextureDecoder}
    state, data = _checked(Path(path), None)
    task = state["wtml"]["scene"].get("task", "fluid")
    if task not in classes:
        raise CheckpointError(f"{path}: a checkpoint of the {task!r} task, which this version "
                              f"of wtml cannot load (tasks: {sorted(classes)})")
    return _module(classes[task], data)
