"""Scenes: typed, validated descriptions of one experiment, and their generators."""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from wtml.scenes.fluid import FluidScene
from wtml.scenes.modes import auto_request, with_auto_modes
from wtml.scenes.onset import OnsetScene
from wtml.scenes.radial import RadialScene
from wtml.scenes.texture import TextureScene
from wtml.schema import SceneError, build, config_hash, to_dict, yaml_load
from wtml.tasks import UNNAMED

SCENES = {"fluid": FluidScene, "radial": RadialScene, "onset": OnsetScene,
          "texture": TextureScene}
"""Scene classes by task name."""

SCENE_MAX_BYTES = 1024**2
"""Bytes: the largest scene YAML read."""


def load_scene(path: str | Path) -> FluidScene | RadialScene | OnsetScene | TextureScene:
    """Load a scene YAML; its ``task`` key picks the scene class (default ``fluid``).

    Raises:
        SceneError: one line naming the file and the key: not a regular file (a FIFO, a
            device, a folder) of at most :data:`SCENE_MAX_BYTES`, not YAML, not a mapping,
            or a key the scene refuses.
    """
    import yaml

    from wtml.files import FileError, regular_file

    try:
        text = regular_file(path, what="scene file", max_bytes=SCENE_MAX_BYTES).read_text()
        data = yaml_load(text)
    except FileError as err:
        raise SceneError(str(err)) from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError, ValueError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise SceneError(f"{path}: cannot read a scene: {first}") from None
    try:
        return scene_from_dict(beside(Path(path).parent, {} if data is None else data))
    except SceneError as err:
        raise SceneError(f"{path}: {err}") from None


def beside(folder: Path, data: Any) -> Any:
    """A scene file's mapping with a relative device file path (``device: my.yaml``, the fluid
    scene's ``transducer.device`` and ``transducer.calibration``, the onset and texture scenes'
    ``calibration``) made relative to the scene
    file's ``folder``, where the file is there; shipped names and everything else unchanged."""
    from wtml.devices import DEVICES_DIR

    def near(value: Any, suffixes: tuple[str, ...] = (".yaml", ".yml")) -> Any:
        if (isinstance(value, str) and value.endswith(suffixes)
                and not Path(value).is_absolute() and (folder / value).is_file()
                and not (DEVICES_DIR / value).is_file()):
            return str(folder / value)
        return value

    if not isinstance(data, Mapping):
        return data
    out = dict(data)
    for key in ("device", "preset"):
        if key in out:
            out[key] = near(out[key])
    if "calibration" in out:  # the onset and texture scenes'
        out["calibration"] = near(out["calibration"], (".npz",))
    spec = out.get("transducer")
    if isinstance(spec, Mapping):
        out["transducer"] = dict(spec) | {k: near(spec[k], (".yaml", ".yml", ".npz"))
                                          for k in ("device", "calibration") if k in spec}
    return out


def scene_from_dict(data: Any, path: str = ""
                    ) -> FluidScene | RadialScene | OnsetScene | TextureScene:
    """Rebuild a scene from a mapping (a scene YAML's, or the one stored in a manifest); its
    ``task`` key picks the class (default ``fluid``); ``n_modes: auto`` is resolved to a count
    here (:mod:`wtml.scenes.modes`). Errors are :class:`SceneError` starting with the key path
    under ``path`` (``scene.samples: ...``), whatever ``data`` is."""
    if not isinstance(data, Mapping):
        raise SceneError(f"{path or 'scene'}: must be a mapping of a scene's keys, got "
                         f"{type(data).__name__}")
    task = data.get("task", UNNAMED)
    if not isinstance(task, str) or task not in SCENES:
        raise SceneError(f"{path + '.' if path else ''}task: must be one of {sorted(SCENES)}, "
                         f"got {task!r:.80}")
    data, auto = auto_request(SCENES[task], legacy_keys(data), path)  # n_modes: auto
    scene = build(SCENES[task], data, path)
    return scene if auto is None else with_auto_modes(scene, auto, path)


def device_of(scene: Any) -> Any:
    """The device a scene simulates: ``scene.device`` (radial, onset, texture) or
    ``scene.transducer.device`` (fluid)."""
    return scene.transducer.device if isinstance(scene, FluidScene) else scene.device


LUMPED_PRESETS = {"fluid": "fluid-lumped", "macro": "macro-lumped"}
"""The fluid scene's ``transducer.preset`` names and the device files that hold them."""


LEGACY_WHISKER_ELEMENTS = 8
"""The whisker's elements of every texture scene stored before ``whisker_elements`` (30 Nov)."""


def legacy_keys(data: Mapping) -> dict:
    """A scene written before device files, in today's keys: ``preset: micro`` is
    ``device: micro``; a ``device:`` mapping without a ``kind`` (the manufacturing spread's
    half-widths) is ``spread:``; the fluid scene's ``transducer.preset: fluid`` is
    ``transducer.device: fluid-lumped``; a texture scene stored whole (a manifest's or an
    export's: with ``calibration`` and ``oversample``) without ``whisker_elements`` was made
    on the 8-element whisker of before 30 Nov, and says so (its check refuses it: its modes
    were not converged). Anything else is left to the schema to judge."""
    out = dict(data)
    if (out.get("task") == "texture" and "whisker_elements" not in out
            and {"calibration", "oversample"} <= set(out)):
        out["whisker_elements"] = LEGACY_WHISKER_ELEMENTS
    old = out.get("device")
    if isinstance(old, Mapping) and "kind" not in old and "spread" not in out:
        out["spread"] = out.pop("device")
    if "preset" in out and "device" not in out:
        out["device"] = out.pop("preset")
    spec = out.get("transducer")
    if isinstance(spec, Mapping) and "preset" in spec and "device" not in spec:
        spec = dict(spec)
        name = spec.pop("preset")
        spec["device"] = LUMPED_PRESETS.get(name, name) if isinstance(name, str) else name
        out["transducer"] = spec
    return out


__all__ = ["SCENES", "FluidScene", "OnsetScene", "RadialScene", "SceneError", "TextureScene",
           "config_hash", "device_of", "legacy_keys",
           "load_scene", "scene_from_dict", "to_dict"]
