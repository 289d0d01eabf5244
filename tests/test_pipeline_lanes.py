"""The main job's lanes (``wtml pipeline --lanes``): slices side by side in processes of their
own, one thread each, their logs kept and printed whole, a failure reported with its log.

The slices here are stand-ins registered as tasks (:class:`StandIn`, which the lanes'
processes get whole): each proves it ran beside the other by waiting for the other's file,
which one lane alone would never write in time.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import pytest

from wtml import pipeline
from wtml.cores import available_cores
from wtml.tasks import Task


def _stand_in(name: str, other: str, folder: str, fail: bool, wait_s: float, stages, *,
              max_epochs=None) -> dict:
    import torch

    from wtml.cores import available_cores

    stages.begin(name, "work", f"stand-in {name}")
    print(f"{name} says hello")
    (Path(folder) / name).write_text(str(os.getpid()))
    start = time.perf_counter()
    while not (Path(folder) / other).exists():
        if time.perf_counter() - start > wait_s:
            raise RuntimeError(f"{name}: {other} never ran beside it")
        time.sleep(0.05)
    if fail:
        raise RuntimeError(f"{name} failed on purpose")
    return {"pid": os.getpid(), "cores": available_cores(),
            "torch_threads": torch.get_num_threads(), "max_epochs": max_epochs}


def _warm_stand_in(name: str, folder: str) -> None:
    (Path(folder) / f"warm-{name}").write_text(str(os.getpid()))


@dataclass(frozen=True)
class StandIn(Task):
    """A task whose slice is :func:`_stand_in`, waiting for ``other``'s file in ``folder``;
    its warm part (where it declares one) writes ``warm-<name>`` there."""

    other: str = ""
    folder: str = ""
    fail: bool = False
    wait_s: float = 60.0

    def load(self, part: str):
        if part == "warm":
            return partial(_warm_stand_in, self.name, self.folder)
        assert part == "pipeline"
        return partial(_stand_in, self.name, self.other, self.folder, self.fail, self.wait_s)


@pytest.fixture
def lanes(tmp_path, monkeypatch):
    """``(register, folder, seen)``: ``register(**kw)`` makes the stand-ins the registry,
    ``seen["results"]`` the results the summary was given."""
    if available_cores() < 2:
        pytest.skip("the lanes need two cores (run_all runs one lane per core it may use)")
    monkeypatch.setattr(pipeline, "LOGS", tmp_path / "logs")
    seen: dict = {}
    monkeypatch.setattr(pipeline, "summary", lambda results, stages: seen.update(
        results=results, times=stages.times) or "summary")

    def register(fail: str = "", wait_s: float = 60.0, warm: bool = False) -> None:
        monkeypatch.setattr(pipeline, "TASKS", {
            name: StandIn(name, "a stand-in", "measurements", "", "", "", "", "", "",
                          pipeline_s=cost, warm="stand-in warm" if warm and cost > 1 else "",
                          warm_s=1.0, other=other, folder=str(tmp_path),
                          fail=name == fail, wait_s=wait_s)
            for name, other, cost in (("first", "second", 2.0), ("second", "first", 1.0))})
    return register, tmp_path, seen


def test_two_lanes_run_two_slices_side_by_side_on_one_thread_each(lanes, capfd):
    register, folder, seen = lanes
    register()
    pipeline.run_all(max_epochs=3, lanes=2)
    out = capfd.readouterr().out
    results = seen["results"]
    assert list(results) == ["first", "second"]  # the registry's order
    assert results["first"]["pid"] != results["second"]["pid"] != os.getpid()
    for r in results.values():
        assert (r["cores"], r["torch_threads"], r["max_epochs"]) == (1, 1, 3)
    for name in ("first", "second"):
        log = (folder / "logs" / f"{name}.log").read_text()
        assert f"{name} says hello" in log and log in out  # kept, and printed whole
    assert "2 slices in 2 lanes of 1 thread(s), in the order that ends first (first, second)" in out
    assert os.environ.get("WTML_THREADS") is None  # this process's threads untouched


def test_the_warm_up_holds_a_lane_of_its_own_before_the_slices_it_serves(lanes, capfd):
    """The warm job is submitted first: one lane runs it while the first slice of the order
    starts in the other; the second slice takes the warm job's lane once it frees (the
    stand-ins wait for each other, so neither could end before both had started)."""
    register, folder, seen = lanes
    register(warm=True)
    pipeline.run_all(lanes=2)
    out = capfd.readouterr().out
    warm_pid = int((folder / "warm-first").read_text())
    assert warm_pid not in {r["pid"] for r in seen["results"].values()} | {os.getpid()}
    assert (folder / "warm-first").stat().st_mtime <= (folder / "second").stat().st_mtime
    assert not (folder / "warm-second").exists()  # only a task with a warm part is warmed
    assert "warm-up (first) first, in the order that ends first" in out
    log = (folder / "logs" / "warm-up.log").read_text()
    assert "warm-up: first's done in" in log and log in out
    assert set(seen["times"]["warm-up"]) == {"first"}


def test_one_lane_compiles_in_the_slices_themselves(lanes, capfd):
    """One lane has no lane to spare: no warm job (each slice compiles on first use)."""
    register, folder, seen = lanes
    register(warm=True, wait_s=0.0)
    with pytest.raises(RuntimeError, match="never ran beside it"):
        pipeline.run_all(lanes=1)
    assert not (folder / "warm-first").exists()


def test_a_failing_slice_stops_the_job_with_its_log_printed(lanes, capfd):
    register, _, _ = lanes
    register(fail="second")
    with pytest.raises(RuntimeError, match="second failed on purpose"):
        pipeline.run_all(lanes=2)
    assert "second says hello" in capfd.readouterr().out


def test_one_lane_cannot_run_slices_that_need_each_other(lanes):
    """The stand-ins' proof has teeth: in one lane the first waits in vain."""
    register, _, _ = lanes
    register(wait_s=1.0)
    with pytest.raises(RuntimeError, match="first: second never ran beside it"):
        pipeline.run_all(lanes=1)


def test_lanes_must_be_positive():
    with pytest.raises(ValueError, match="--lanes: must be at least 1, got 0"):
        pipeline.run_all(lanes=0)


def test_a_dataset_generated_ahead_is_waited_for_then_kept(tmp_path, monkeypatch):
    """``generate_locked`` holds the dataset's lock: a second generation of it (the slice's
    own, while the warm-up still generates) waits, then finds every shard complete."""
    import fcntl
    import threading

    monkeypatch.setattr(pipeline, "LOGS", tmp_path / "logs")
    scene = str(Path(__file__).resolve().parents[1] / "configs/scenes/fluid.yaml")
    out = tmp_path / "fluid"
    (tmp_path / "logs").mkdir()
    with open(tmp_path / "logs" / "fluid.generate.lock", "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # another process generating it
        second = threading.Thread(target=pipeline.generate_locked, args=(scene, out))
        second.start()
        second.join(1.0)
        assert second.is_alive() and not (out / "manifest.json").exists()  # waiting
        fcntl.flock(held, fcntl.LOCK_UN)
    second.join(60)
    first = (out / "manifest.json").read_bytes()
    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}
    assert stamps and pipeline.generate_locked(scene, out)["n_shards"] == len(stamps)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == stamps  # kept
    assert (out / "manifest.json").read_bytes() == first
