"""Scenes: typed, validated descriptions of one experiment, and their generators."""

from pathlib import Path

from wtml.scenes.fluid import FluidScene
from wtml.scenes.onset import OnsetScene
from wtml.scenes.radial import RadialScene
from wtml.scenes.texture import TextureScene
from wtml.schema import SceneError, config_hash, load_yaml, to_dict, yaml_load

SCENES = {"fluid": FluidScene, "radial": RadialScene, "onset": OnsetScene,
          "texture": TextureScene}
"""Scene classes by task name."""


def load_scene(path: str | Path) -> FluidScene | RadialScene | OnsetScene | TextureScene:
    """Load a scene YAML; its ``task`` key picks the scene class (default ``fluid``)."""
    import yaml

    try:
        task = (yaml_load(Path(path).read_text()) or {}).get("task", "fluid")
    except (OSError, yaml.YAMLError, AttributeError) as err:
        raise SceneError(f"{path}: cannot read a scene: {err}") from err
    if task not in SCENES:
        raise SceneError(f"{path}: task: must be one of {sorted(SCENES)}, got {task!r}")
    return load_yaml(SCENES[task], path)


def scene_from_dict(data: dict) -> FluidScene | RadialScene | OnsetScene | TextureScene:
    """Rebuild a scene from the mapping stored in a manifest."""
    from wtml.schema import build

    return build(SCENES[data.get("task", "fluid")], data)


__all__ = ["SCENES", "FluidScene", "OnsetScene", "RadialScene", "SceneError", "TextureScene",
           "config_hash",
           "load_scene", "scene_from_dict", "to_dict"]
