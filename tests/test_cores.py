"""How many cores wtml computes on: the affinity, a container's CPU quota, ``$WTML_THREADS``."""

from __future__ import annotations

import os

import pytest

from wtml import cores
from wtml.cores import THREADS_ENV, available_cores, cgroup_cores


def _write(path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_a_v2_quota_is_read_from_the_process_group_and_the_least_above_it_wins(tmp_path):
    proc = tmp_path / "cgroup"
    _write(proc, "0::/outer/inner\n")
    _write(tmp_path / "fs" / "cpu.max", "max 100000\n")  # the root: no quota
    _write(tmp_path / "fs" / "outer" / "cpu.max", "150000 100000\n")
    _write(tmp_path / "fs" / "outer" / "inner" / "cpu.max", "400000 100000\n")
    assert cgroup_cores(tmp_path / "fs", proc) == pytest.approx(1.5)
    _write(tmp_path / "fs" / "outer" / "cpu.max", "max 100000\n")
    assert cgroup_cores(tmp_path / "fs", proc) == pytest.approx(4.0)


def test_a_v1_quota_is_read_from_the_cpu_controller_and_a_container_root(tmp_path):
    proc = tmp_path / "cgroup"
    # a container: its path names the host's group, its own group is mounted at the root
    _write(proc, "4:memory:/docker/abc\n3:cpu,cpuacct:/docker/abc\n1:name=systemd:/\n")
    fs = tmp_path / "fs"
    _write(fs / "cpu,cpuacct" / "cpu.cfs_quota_us", "200000\n")
    _write(fs / "cpu,cpuacct" / "cpu.cfs_period_us", "100000\n")
    _write(fs / "memory" / "cpu.cfs_quota_us", "50000\n")  # not the cpu controller's
    _write(fs / "memory" / "cpu.cfs_period_us", "100000\n")
    assert cgroup_cores(fs, proc) == pytest.approx(2.0)
    _write(fs / "cpu,cpuacct" / "cpu.cfs_quota_us", "-1\n")  # v1's "no quota"
    assert cgroup_cores(fs, proc) is None


@pytest.mark.parametrize("text", ["", "max", "garbage 100000", "0 100000", "100000 0"])
def test_no_quota_or_an_unreadable_one_is_none(tmp_path, text):
    proc = tmp_path / "cgroup"
    _write(proc, "0::/\n")
    _write(tmp_path / "fs" / "cpu.max", text)
    assert cgroup_cores(tmp_path / "fs", proc) is None
    assert cgroup_cores(tmp_path / "fs", tmp_path / "missing") is None  # not Linux


def test_available_cores_is_the_least_of_affinity_quota_and_the_cap(monkeypatch):
    mine = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    monkeypatch.delenv(THREADS_ENV, raising=False)
    monkeypatch.setattr(cores, "cgroup_cores", lambda: None)
    assert available_cores() == mine
    monkeypatch.setattr(cores, "cgroup_cores", lambda: 0.5)  # half a core: still one thread
    assert available_cores() == 1
    monkeypatch.setattr(cores, "cgroup_cores", lambda: mine + 0.5)  # above the affinity
    assert available_cores() == mine
    monkeypatch.setattr(cores, "cgroup_cores", lambda: 1.0)
    assert available_cores() == 1  # a whole quota is not rounded up past itself
    monkeypatch.setattr(cores, "cgroup_cores", lambda: 1.2)
    assert available_cores() == min(2, mine)
    monkeypatch.setattr(cores, "cgroup_cores", lambda: 100.0)
    monkeypatch.setenv(THREADS_ENV, "1")
    assert available_cores() == 1
