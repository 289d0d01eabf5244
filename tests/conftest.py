"""Shared fixtures: seeded generators, hypothesis profiles, and transducers of realistic size."""

import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from wtml.physics import LumpedTransducer

settings.register_profile("ci", max_examples=60, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=1000, deadline=None)
settings.load_profile("ci")


@pytest.fixture
def rng(request):
    """A generator seeded from the test's name: reproducible, different per test."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


MACRO = LumpedTransducer.from_resonance(c0=7.27e-9, phi=1e-5, m=2e-5, f0=36.0, q=30.0,
                                        tan_delta=0.02)
"""Macro-size bimorph: Ze ~ 1e5-1e6 Ω around 36 Hz."""

MICRO = LumpedTransducer.from_resonance(c0=5e-12, phi=2e-7, m=2e-8, f0=400.0, q=50.0,
                                        tan_delta=0.01)
"""Micro-size bimorph with a small electrode: Ze ~ 1e7-1e9 Ω over 20-800 Hz."""


@pytest.fixture(params=["macro", "micro"])
def transducer(request):
    return {"macro": MACRO, "micro": MICRO}[request.param]


def generate_and_train(tmp_path, scene_yaml: str, config_yaml: str, *extra: str):
    """Generate a shipped scene into ``tmp_path/data`` and train a shipped config on it from
    ``tmp_path`` (its runs/ land there); returns the scene."""
    import os
    from pathlib import Path

    from wtml.data import generate
    from wtml.scenes import load_scene
    from wtml.training import cli_main

    root = Path(__file__).resolve().parents[1]
    scene = load_scene(root / scene_yaml)
    generate(scene, tmp_path / "data", progress=False)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        cli_main(["fit", "--config", str(root / config_yaml),
                  "--data.init_args.data_dir", str(tmp_path / "data"), *extra])
    finally:
        os.chdir(cwd)
    return scene
