"""``wtml bench runtime``: the device runtime as a device runs it.

Side by side in one run, on one onset record of the export's own scene:

- **cold start**: wall time and peak RSS of the whole ``wtml predict`` command (process start
  to exit), median over ``repeats``, in a lean runtime install (``pip install wtml``: numpy,
  onnxruntime, pyyaml; :func:`runtime_venv`), in the full install, and in the full install
  with the training stack imported first (``wtml.exporters.onset``: torch, lightning, numba,
  scipy, the scenes and decoders, what ``wtml predict`` imported before the runtime was split
  off);
- **per-record latency** of each graph on one record (median, after warm-up, one thread) and
  of the contact rule;
- **streaming**: ``stream.onnx`` through ``wtml stream``'s loop on one core (pinned): per-chunk
  latency (median and 99th percentile) and the real-time factor (work over signal time); and
  what streaming costs in accuracy: the contacts of the offline decoder (``wtml predict``) and
  of the stream (the same rule on the streaming graph's frames, whose detachment level is the
  one known so far) against the records' true ones (F1, median onset and detachment error);
- **installed size** of each install (the files of its distributions, pip and setuptools
  left out).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from wtml.bench.onset import event_metrics
from wtml.bench.timing import latency_p50
from wtml.exporters.onset import calibration_file
from wtml.runtime.contacts import Timing, contacts_from
from wtml.runtime.onset import read_onset_calibration, stream_record
from wtml.runtime.predict import InputError, load_export, task_of
from wtml.runtime.stream import run_stream
from wtml.scenes import scene_from_dict

RUNTIME_PACKAGES = ("numpy", "onnxruntime", "pyyaml")
"""What ``pip install wtml`` installs besides wtml (and their own dependencies)."""
TOOLS = {"pip", "setuptools", "wheel"}
"""Distributions a venv holds to install things, left out of an install's size."""
SOURCE = Path(__file__).resolve().parents[2]
"""This checkout (the folder with ``pyproject.toml``)."""


def runtime_venv(path: str | Path) -> Path:
    """A venv at ``path`` with ``pip install`` of this checkout and nothing else (the device
    runtime), its runtime packages pinned to the versions of this environment, so that both
    installs run the same numpy and onnxruntime; reused while it holds this checkout's code
    (the sources' hash and the pins in its marker). Built from a copy of the sources, so that
    no build folder in the checkout ships modules since deleted. Returns its python.

    Raises:
        RuntimeError: pip failed (with pip's last lines).
    """
    path = Path(path)
    python = path / "bin" / "python"
    marker = path / ".wtml-runtime"
    want = _pins() + f"wtml sources {_sources_hash()}\n"
    if marker.exists() and marker.read_text() == want:
        return python
    subprocess.run([sys.executable, "-m", "venv", "--clear", str(path)], check=True)
    pins = path / "constraints.txt"
    pins.write_text(_pins())
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "wtml"
        copy.mkdir()
        for name in ("pyproject.toml", "README.md"):
            shutil.copy(SOURCE / name, copy / name)
        shutil.copytree(SOURCE / "wtml", copy / "wtml",
                        ignore=shutil.ignore_patterns("__pycache__"))
        done = subprocess.run([str(python), "-m", "pip", "install", "-q",
                               "--disable-pip-version-check", "-c", str(pins), str(copy)],
                              capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"pip install of the runtime into {path} failed:\n"
                           + "\n".join((done.stdout + done.stderr).splitlines()[-8:]))
    marker.write_text(want)
    return python


def _pins() -> str:
    return "".join(f"{name}=={metadata.version(name)}\n" for name in RUNTIME_PACKAGES)


def _sources_hash() -> str:
    """sha256 over this checkout's ``pyproject.toml`` and ``wtml/**/*.py`` (names and bytes)."""
    digest = hashlib.sha256()
    for f in [SOURCE / "pyproject.toml", *sorted((SOURCE / "wtml").rglob("*.py"))]:
        digest.update(str(f.relative_to(SOURCE)).encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


LAUNCHER = """\
import os, subprocess, sys, tempfile, time
with tempfile.TemporaryFile() as log:
    start = time.perf_counter()
    proc = subprocess.Popen(sys.argv[1:], stdout=log, stderr=subprocess.STDOUT)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    log.seek(0)
    print(wall, usage.ru_maxrss / 1024, code)
    sys.stdout.flush()
    if code:
        sys.stdout.buffer.write(log.read()[-2000:])
"""
"""Runs a command and prints its wall seconds, peak RSS (MB) and exit code: a small process,
so that the command's peak is its own (a child forked from the bench itself would count the
bench's memory, resident before the exec, in its peak)."""


def cold_start(command: list[str], repeats: int) -> dict:
    """Median wall seconds and peak RSS (MB) of ``command`` run ``repeats`` times, each a
    fresh process started by :data:`LAUNCHER` (it must exit 0)."""
    walls, peaks = [], []
    for _ in range(repeats):
        done = subprocess.run([sys.executable, "-c", LAUNCHER, *command], capture_output=True)
        first, _, rest = done.stdout.partition(b"\n")
        wall, peak, code = first.split()
        if int(code):
            raise RuntimeError(f"{' '.join(command[:3])} ... exited {int(code)}:\n"
                               f"{rest.decode(errors='replace')}")
        walls.append(float(wall))
        peaks.append(float(peak))
    return {"wall_s": float(np.median(walls)), "peak_rss_mb": float(np.median(peaks)),
            "walls_s": walls}


def installed_mb(site_packages: Path) -> float:
    """MB of the files of every distribution in ``site_packages`` but :data:`TOOLS`."""
    total = 0
    for dist in metadata.distributions(path=[str(site_packages)]):
        if dist.metadata["Name"].lower() in TOOLS:
            continue
        for f in dist.files or ():
            where = Path(dist.locate_file(f))
            if where.is_file():
                total += where.stat().st_size
    return total / 1e6


def site_packages(python: Path) -> Path:
    """The site-packages folder of the venv whose interpreter is ``python``."""
    out = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                          "['purelib'])"], capture_output=True, text=True, check=True)
    return Path(out.stdout.strip())


class _Graph:
    """A loaded graph behind the ``predict`` interface :func:`latency_p50` times."""

    def __init__(self, model) -> None:
        self.model = model

    def predict(self, *inputs):
        return self.model.run(*inputs)


def _one_core():
    """Pin this process to one CPU (returns the previous set, to restore)."""
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(before)})
    return before


def run_runtime_bench(out: str | Path, *, model: str | Path = "export/onset", records: int = 64,
                      repeats: int = 5, venv: str | Path | None = None) -> str:
    """Measure the runtime (module docstring) on the onset export ``model``; write
    ``out/report.md`` and ``out/summary.json``; return the report. ``venv``: the runtime
    install's venv (made or reused by :func:`runtime_venv`; default ``out/runtime-venv``)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if task_of(model) != "onset":
        raise InputError(f"--model {model}: a {task_of(model)} export; the runtime bench runs "
                         "an onset export")
    decoder, classical, stream = load_export(model, stream=True, threads=1)
    meta = decoder.meta
    scene = scene_from_dict(dict(meta.scene))
    print(f"bench runtime: simulating {records} records of {model}'s scene", file=sys.stderr)
    rec = scene.simulate(records, np.random.default_rng([scene.seed, 24]))
    one = out / "record.npz"
    np.savez(one, e=rec["e"][0], i=rec["i"][0], sample_rate_hz=meta.sample_rate_hz)
    cal = calibration_file(out / "calibration.npz", scene,
                           {"t_probe": rec["t_probe"][:1], "hue0": rec["hue0"][:1]})
    cals = calibration_file(out / "calibrations.npz", scene, rec)  # every record's own
    args = ["predict", "--model", str(model), "--input", str(one), "--calibration", str(cal)]

    venv = Path(venv or out / "runtime-venv")
    print(f"bench runtime: the runtime install in {venv}", file=sys.stderr)
    lean = runtime_venv(venv)
    full = Path(sys.executable)
    before = ("import sys, wtml.exporters.onset; from wtml.cli import main; "
              "sys.exit(main(sys.argv[1:]))")
    print(f"bench runtime: {repeats} cold starts of each command", file=sys.stderr)
    starts = {
        "runtime install (pip install wtml)": cold_start([str(lean), "-m", "wtml.cli", *args],
                                                         repeats),
        "full install": cold_start([str(full), "-m", "wtml.cli", *args], repeats),
        "full install, training stack imported (as before)": cold_start(
            [str(full), "-c", before, *args], repeats),
    }
    sizes = {"runtime install (pip install wtml)": installed_mb(site_packages(lean)),
             "full install": installed_mb(site_packages(full))}

    inputs = (rec["e"][:1].astype(np.float32), rec["i"][:1].astype(np.float32),
              *read_onset_calibration(cal, float(decoder.frequency_hz[0]), 1))
    timing = Timing.of(meta)
    latency = {f"{m.name} (one record)": latency_p50(_Graph(m), inputs, 50)
               for m in (decoder, classical)}
    pred = decoder.run(*inputs)
    t0 = time.perf_counter()
    for _ in range(50):
        contacts_from(pred, timing)
    latency["contact rule (one record)"] = (time.perf_counter() - t0) / 50

    every = (rec["e"].astype(np.float32), rec["i"].astype(np.float32),
             *read_onset_calibration(cals, float(decoder.frequency_hz[0]), records))
    accuracy = {"offline decoder (wtml predict)": event_metrics(
                    rec, *contacts_from(decoder.run(*every), timing)),
                "stream (wtml stream)": event_metrics(
                    rec, *contacts_from(stream_record(stream, *every), Timing.of(stream.meta)))}

    pairs = np.stack([rec["e"], rec["i"]], -1).astype("<f4")  # (records, n, 2): one long stream
    restore = _one_core()
    try:
        summary = run_stream(model, io.BytesIO(pairs.tobytes()), cal, threads=1)
    finally:
        os.sched_setaffinity(0, restore)
    streaming = {"chunk_samples": stream.meta.chunk_samples,
                 "chunk_s": stream.meta.chunk_samples / meta.sample_rate_hz, **summary.stats()}
    result = {"model": str(model), "records": records, "repeats": repeats,
              "cold_start": starts, "installed_mb": sizes,
              "latency_s": latency, "streaming": streaming, "contacts": accuracy,
              "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}}
    (out / "summary.json").write_text(json.dumps(result, indent=1) + "\n")
    report = format_report(result)
    (out / "report.md").write_text(report + "\n")
    return report


def format_report(result: dict) -> str:
    """The runtime bench as markdown tables."""
    lines = [f"# wtml bench runtime: {result['model']}", "",
             f"Cold start of `wtml predict` on one onset record (whole command, median of "
             f"{result['repeats']}; {result['machine']['cpus']} CPUs):", "",
             "| install | wall s | peak RSS MB | installed MB |", "|---|---|---|---|"]
    for name, row in result["cold_start"].items():
        size = result["installed_mb"].get(name)
        lines.append(f"| {name} | {row['wall_s']:.3f} | {row['peak_rss_mb']:.0f} | "
                     f"{'' if size is None else f'{size:.0f}'} |")
    lines += ["", "Per record, one thread (median):", "", "| step | ms |", "|---|---|"]
    lines += [f"| {name} | {1e3 * s:.3f} |" for name, s in result["latency_s"].items()]
    s = result["streaming"]
    lines += ["", f"Streaming (`wtml stream`'s loop, one core): chunks of {s['chunk_samples']} "
              f"samples ({1e3 * s['chunk_s']:.2f} ms of signal), {s['chunks']} chunks "
              f"({s['signal_s']:.2f} s), {s['contacts']} contacts: per chunk median "
              f"{s['median_chunk_ms']:.3f} ms, 99th percentile {s['p99_chunk_ms']:.3f} ms; "
              f"real-time factor {s['real_time_factor']:.4f} (work / signal time).", "",
              f"Contacts on the {result['records']} records against their true ones:", "",
              "| path | F1 | median onset error ms | median detachment error ms |",
              "|---|---|---|---|"]
    lines += [f"| {name} | {m['f1']:.3f} | {m['onset_ms']:.2f} | {m['detach_ms']:.2f} |"
              for name, m in result["contacts"].items()]
    return "\n".join(lines)
