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


def test_a_v1_mount_named_by_its_own_controllers_and_lines_that_are_not_groups(tmp_path):
    proc, fs = tmp_path / "cgroup", tmp_path / "fs"
    _write(proc, "garbage\n\n7:cpu,cpuacct,cpuset:/job\n")  # no v2 line: "garbage" is none
    _write(fs / "cpu.max", "100000 100000\n")  # read only for a "0::" line
    _write(fs / "cpu,cpuacct,cpuset" / "job" / "cpu.cfs_quota_us", "300000\n")
    _write(fs / "cpu,cpuacct,cpuset" / "job" / "cpu.cfs_period_us", "100000\n")
    assert cgroup_cores(fs, proc) == pytest.approx(3.0)


@pytest.mark.parametrize("text", ["inf 100000", "1e400 100000", "nan 100000", "-5 100000"])
def test_a_quota_that_is_no_number_of_cores_is_none(tmp_path, text):
    proc = tmp_path / "cgroup"
    _write(proc, "0::/\n")
    _write(tmp_path / "fs" / "cpu.max", text)
    assert cgroup_cores(tmp_path / "fs", proc) is None


def test_files_that_cannot_be_read_or_decoded_are_no_quota(tmp_path, monkeypatch):
    proc = tmp_path / "cgroup"
    proc.write_bytes(b"0::/\xff\xfe\n")  # not UTF-8
    _write(tmp_path / "fs" / "cpu.max", "100000 100000\n")
    assert cgroup_cores(tmp_path / "fs", proc) is None
    _write(proc, "3:cpu:/\n")

    def refused(self):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(type(tmp_path), "is_dir", refused)  # a cgroup root we may not list
    assert cgroup_cores(tmp_path / "fs", proc) is None
