"""The fuzz harness: every file kind wtml reads, mutated, fed to the command that reads it.

The property (issue 22): a command ends in exit 0 with a right or flagged answer, or exit 2
with one line on stderr naming the file (and the key); never a traceback, never a usage dump,
never more than ``wtml.files.MEMORY_CEILING`` (tracemalloc's peak), never a hang (a time
limit per input). Each input runs in a forked child (tests/fuzz/runner.py).

``test_fuzz[kind]`` draws a few cases per kind (derandomized: the same cases every run, so
the counts are reproducible); ``test_fuzz_thorough[kind]`` (``-m slow``) draws many more and
the slow commands (training, resuming, exporting). ``test_corpus[case]`` replays each failure
the harness has found (tests/fuzz_corpus/<kind>/<case>.json). The counts per kind print at
the end of the session (``pytest tests/test_fuzz.py``; ``python -m tests.fuzz.report``).
``FUZZ_SAVE_CORPUS=1`` writes each new failure (a new signature) into the corpus.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tests.fuzz import bases as base_files
from tests.fuzz import cases
from tests.fuzz.stats import record

CORPUS = Path(__file__).parent / "fuzz_corpus"
EXAMPLES = {"scene": 8, "config": 3, "manifest": 10, "sidecar": 5, "shard": 8,
            "checkpoint": 8, "export": 10, "input": 8, "calibration": 5, "reference": 5,
            "record": 5}
"""Cases per kind in the quick run (fluid and radial; the onset and texture files, which
need their own small flows, ~1 min each, in the slow run)."""
THOROUGH = int(os.environ.get("FUZZ_EXAMPLES", "150"))
"""Cases per kind in the slow run (``FUZZ_EXAMPLES`` changes it)."""
LIGHT = ("fluid", "radial")
"""Tasks whose bases are shared session fixtures (cheap); onset and texture cost ~1 min each."""


@pytest.fixture(scope="module")
def light(flow, radial_flow, tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz_bases")
    b = cases.Bases({"fluid": base_files.fluid(flow, root / "fluid"),
                     "radial": base_files.radial(radial_flow, root / "radial")})
    for task in b.tasks:
        cases.baseline(b, task, "predict", tmp_path_factory.mktemp(f"baseline_{task}"))
    return b


@pytest.fixture(scope="module")
def heavy(light, tmp_path_factory):
    """The light bases and the onset and texture ones (a flow each: ~1 min)."""
    root = tmp_path_factory.mktemp("fuzz_heavy")
    b = cases.Bases({**light.tasks, "onset": base_files.onset(root / "onset"),
                     "texture": base_files.texture(root / "texture")}, dict(light.baselines))
    for task in ("onset", "texture"):
        cases.baseline(b, task, "predict", tmp_path_factory.mktemp(f"baseline_{task}"))
    return b


def _save(kind: str, case: dict, result, signature: str) -> None:
    name = f"{case['task']}-{case['command']}-{result.outcome}-" \
           f"{hashlib.sha1(signature.encode()).hexdigest()[:8]}"
    path = CORPUS / kind / f"{name}.json"
    if path.exists():
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    found = {"outcome": result.outcome, "signature": signature,
             "said": (result.error or result.stderr).strip()[-400:]}
    path.write_text(json.dumps({**case, "owner": cases.OWNERS[kind], "found_on_main": found},
                               indent=1) + "\n")


def fuzz(bases: cases.Bases, kind: str, n: int, slow: bool, tmp_path_factory) -> None:
    if n == 0:
        return
    broken: dict[str, tuple[dict, str]] = {}
    tasks = [t for t in cases.PLAN[kind] if t in bases.tasks]
    assert tasks, kind

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              phases=[Phase.generate], suppress_health_check=list(HealthCheck))
    @given(st.data())
    def one(data):
        case = cases.draw_case(data, bases, kind, slow)
        tmp = tmp_path_factory.mktemp(f"fuzz_{kind}")
        result = cases.replay(bases, case, tmp, limit_s=cases.time_limit(case["command"]))
        record(kind, case, result)
        if result.outcome not in ("ok", "flagged", "clear"):
            sig = cases.signature(case, result)
            broken.setdefault(sig, (case, result.summary()))
            if os.environ.get("FUZZ_SAVE_CORPUS"):
                _save(kind, case, result, sig)

    one()
    assert not broken, f"{len(broken)} kinds of failure:\n" + "\n".join(
        f"{json.dumps(c)}\n    -> {s[:700]}" for c, s in broken.values())


@pytest.mark.parametrize("kind", cases.KINDS)
def test_fuzz(kind, light, tmp_path_factory):
    """A few derandomized cases of ``kind`` on fluid and radial (the quick run)."""
    fuzz(light, kind, EXAMPLES[kind], False, tmp_path_factory)


@pytest.mark.slow
@pytest.mark.parametrize("kind", cases.KINDS)
def test_fuzz_thorough(kind, heavy, tmp_path_factory):
    """Many cases of ``kind`` on all four tasks, training, resuming and exporting included."""
    fuzz(heavy, kind, THOROUGH, True, tmp_path_factory)


def _corpus() -> list:
    return [pytest.param(p, id=f"{p.parent.name}/{p.stem}")
            for p in sorted(CORPUS.glob("*/*.json"))]


@pytest.mark.parametrize("path", _corpus())
def test_corpus(path, request, tmp_path):
    """Each failure the harness has found, replayed: it must now satisfy the property."""
    case = json.loads(path.read_text())
    named = json.dumps(case["mutation"])  # another task's file: swap, foreign, $base
    heavy = case["task"] not in LIGHT or any(t in named for t in ("onset", "texture"))
    bases = request.getfixturevalue("heavy" if heavy else "light")
    result = cases.replay(bases, case, tmp_path, limit_s=cases.time_limit(case["command"]))
    record("corpus", {**case, "file": f"{path.parent.name}/{path.stem}"}, result)
    assert result.outcome in ("ok", "flagged", "clear"), result.summary()
