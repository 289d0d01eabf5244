"""Datasets: sharded generation, the shard format and manifests, Dataset and DataModule."""

from wtml.data.shards import (
    DatasetError,
    Manifest,
    ShardEntry,
    checked_manifest,
    dataset_scene,
    generate,
    load_shards,
    read_manifest,
)

__all__ = ["DatasetError", "Manifest", "ShardEntry", "checked_manifest", "dataset_scene",
           "generate", "load_shards", "read_manifest"]
