"""The main job, end to end on small defaults, for the fluid, radial, onset and texture slices:
generate -> train -> export -> predict -> bench, then one summary of every slice.

Each stage prints the command that does it alone. Work already done is kept: complete shards
are skipped, and training resumes from ``last.ckpt`` when it belongs to the same dataset,
model config and run length (otherwise the run is replaced, and the pipeline says so).
"""

from __future__ import annotations

import csv
import fcntl
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

import numpy as np

from wtml.bench.timing import BUSY_SHARE, duration
from wtml.cores import available_cores, capped
from wtml.files import locked
from wtml.lanes import lane_order
from wtml.memory import release_memory
from wtml.runtime.predict import domain_warning, format_predictions, predict_file
from wtml.schema import read_yaml
from wtml.tasks import TASKS, Task
from wtml.workers import watch_parent

TRANSFER_RECORDS = 4
"""Fresh records per row of the time-domain benches' transfer tables in the main job (a small
version: their benches' defaults are the full tables)."""
INDEPENDENT_RECORDS = 4
"""Records of the independent simulator in the main job's onset transfer table."""
ONSET_SCENE, FEPA_SCENE = "configs/scenes/onset.yaml", "configs/scenes/texture_fepa.yaml"
ONSET_DATA, FEPA_DATA = Path("datasets/onset"), Path("datasets/texture_fepa")
"""Scenes and folders of the datasets the warm-up generates ahead (:func:`warm_onset`,
:func:`warm_texture`) as well as their slices."""
TEXTURE_SCENE = "configs/scenes/texture.yaml"
"""The texture slice's scene: its dataset's, and the one whose oracles the warm-up computes."""
DEVICE_RECORDS = {"onset": 8, "texture": 16}
"""Fresh records per row of the main job's device-spread tables (texture's rows are paired:
the same specimens and nuisance on every device)."""


class Stages:
    """Wall-clock time of each stage of each slice, for the closing summary.

    Args:
        echo: where a one-line note of each stage also goes as it begins (a slice in a lane
            of its own prints its log to a file: this is the terminal), or None.
        bench_lock: a file that each ``bench`` stage holds locked while it runs (slices side by
            side: their benches, each slice's largest memory and its timings, take turns;
            the wait counts in the stage's time), or None.
    """

    def __init__(self, echo: TextIO | None = None, bench_lock: Path | None = None) -> None:
        self.start = time.perf_counter()
        self.times: dict[str, dict[str, float]] = {}
        self._slice, self._stage, self._t0 = "", "", 0.0
        self.echo = echo
        self.bench_lock = bench_lock
        self._held: TextIO | None = None

    def begin(self, slice_: str, stage: str, command: str) -> None:
        """Close the running stage, hand the memory it freed back to the system
        (:func:`wtml.memory.release_memory`), open this one and print its stand-alone
        command."""
        self.end()
        release_memory()
        self._slice, self._stage, self._t0 = slice_, stage, time.perf_counter()
        print(f"\n== {slice_} {stage}: {command}", flush=True)
        self._note(f"{slice_}: {stage}")
        if stage == "bench" and self.bench_lock is not None:
            self._held = open(self.bench_lock, "a")  # noqa: SIM115 (closed in end())
            try:
                fcntl.flock(self._held, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                self._note(f"{slice_}: bench waits for the other lane's bench")
                fcntl.flock(self._held, fcntl.LOCK_EX)

    def _note(self, text: str) -> None:
        if self.echo is not None:
            print(f"{time.strftime('%H:%M:%S')} {text}", file=self.echo, flush=True)

    def end(self) -> None:
        if self._stage:
            spent = time.perf_counter() - self._t0
            times = self.times.setdefault(self._slice, {})
            times[self._stage] = times.get(self._stage, 0.0) + spent  # generate: two datasets
            self._stage = ""
        if self._held is not None:
            fcntl.flock(self._held, fcntl.LOCK_UN)
            self._held.close()
            self._held = None

    def line(self, slice_: str) -> str:
        return ", ".join(f"{k} {duration(v)}" for k, v in self.times.get(slice_, {}).items())


def checkpoint_matches(ckpt: Path, scene_hash: str, config: str,
                       max_epochs: int | None = None) -> bool:
    """Whether ``ckpt`` can resume ``config`` on the dataset of ``scene_hash``: same scene,
    the model arguments of the config are those the checkpoint was made with (an edited
    config starts afresh rather than failing on the old weights' shapes), and so is the run
    length (``max_epochs``, else the config's): the learning-rate schedules are laid out over
    it. A checkpoint that cannot be read safely never matches."""
    from wtml.decoders.checkpoint import CheckpointError, read_checkpoint
    from wtml.scenes import config_hash, scene_from_dict

    if not ckpt.exists():
        return False
    try:
        state = read_checkpoint(ckpt)
    except CheckpointError as err:
        print(f"{err}: not resumed")
        return False
    info, hparams = state["wtml"], state.get("hyper_parameters", {})
    if config_hash(scene_from_dict(info["scene"])) != scene_hash:
        return False
    cfg = read_yaml(config)
    epochs = max_epochs if max_epochs is not None else cfg.get("trainer", {}).get("max_epochs")
    if info.get("max_epochs") != epochs:
        return False
    wanted = cfg["model"].get("init_args", {})
    return all(hparams.get(key) == value for key, value in wanted.items())


def write_sample_csv(data_dir: Path, path: Path, n: int = 3) -> dict[str, Path]:
    """A few test-shard measurements of a measurement task's dataset as a CSV that ``wtml
    predict`` reads (``sample``, ``frequency_hz`` Hz, ``ze_real``, ``ze_imag`` Ω, then the
    truth columns the task declares), and the reference their export needs beside it, as its
    ``MatrixTask`` (``wtml.tasks``' ``measurement`` part) names it: fluid their devices'
    calibrated T, ``calibration.npz`` (``--calibration``); radial their devices' free
    references, ``sample_input_reference.npz`` (``--reference``; not the export's own
    ``sample_reference.npz``, which its manifest lists with its hash). Returns ``{keyword:
    path}`` of that reference, ``predict_file``'s keyword argument.

    Raises:
        ValueError: a dataset of a task that reads recordings.
    """
    from wtml.data import dataset_scene, load_shards, read_manifest
    from wtml.data.datamodule import split_shards

    manifest = read_manifest(data_dir)
    data = load_shards(data_dir, split_shards(manifest["n_shards"], 1, 1)["test"])
    scene = dataset_scene(data_dir)
    spec = TASKS[scene.task].load("measurement")
    freq = scene.excitation.frequency_hz
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["sample", "frequency_hz", "ze_real", "ze_imag", *spec.truth.values()])
        for s in range(n):
            for f, z in zip(freq, data["ze"][s], strict=True):
                w.writerow([s, repr(float(f)), repr(float(z.real)), repr(float(z.imag))]
                           + [repr(float(data[k][s])) for k in spec.truth])
    reference = path.with_name(spec.reference_file)
    np.savez(reference, frequency_hz=freq,
             **{spec.reference_key: data[spec.reference_array][:n]})
    return {spec.reference: reference}


def _generate(stages: Stages, slice_: str, scene_path: str, out: Path) -> dict:
    stages.begin(slice_, "generate", f"wtml generate --config {scene_path} --out {out}")
    manifest = generate_locked(scene_path, out)
    print(f"{manifest['samples']} samples in {manifest['n_shards']} shards")
    return manifest


def generate_locked(scene_path: str, out: Path) -> dict:
    """``wtml generate`` of the scene ``scene_path`` into ``out`` (its manifest), holding the
    dataset's lock file in :data:`LOGS` (``<name>.generate.lock``): a dataset the warm-up
    generates ahead (:func:`warm_onset`, :func:`warm_texture`) is waited for, then found
    complete, by its slice's own ``generate`` whatever the lanes' timing."""
    from wtml.data import generate
    from wtml.scenes import load_scene

    with locked(LOGS / f"{out.name}.generate.lock"):
        return generate(load_scene(scene_path), out)


def train_config(config: str, data: Path, *, max_epochs: int | None = None,
                 begin: Callable[[str], None] = print) -> Path:
    """Train ``config`` on the dataset ``data``, resuming its ``last.ckpt`` where that
    matches (:func:`checkpoint_matches`; a finished run is kept as it is) and starting afresh
    where it does not; ``begin`` is given the stand-alone command first. Returns the
    checkpoint."""
    from wtml.data import read_manifest
    from wtml.decoders.checkpoint import read_checkpoint
    from wtml.training import cli_main

    root = Path(read_yaml(config)["trainer"]["default_root_dir"])
    ckpt = root / "checkpoints" / "last.ckpt"
    args = ["fit", "--config", config, "--data.init_args.data_dir", str(data)]
    if max_epochs is not None:
        args += ["--trainer.max_epochs", str(max_epochs)]
    finished = False
    if checkpoint_matches(ckpt, read_manifest(data)["scene_hash"], config, max_epochs):
        state = read_checkpoint(ckpt)
        finished = state["epoch"] + 1 >= state["wtml"]["max_epochs"]  # nothing to resume
        args += ["--ckpt_path", str(ckpt)]
    elif ckpt.exists():
        print(f"{ckpt} is for another scene, model config or run length: training afresh")
        args += ["--overwrite", "true"]
    begin("python train.py " + " ".join(args))
    if finished:
        print(f"{ckpt}: trained already ({state['wtml']['max_epochs']} epochs)")
    else:
        cli_main(args)
    return ckpt


def _train(stages: Stages, slice_: str, config: str, data: Path,
           max_epochs: int | None) -> Path:
    name = Path(read_yaml(config)["trainer"]["default_root_dir"]).name
    return train_config(config, data, max_epochs=max_epochs,
                        begin=lambda command: stages.begin(slice_, f"train {name}", command))


def _export_and_predict(stages: Stages, slice_: str, ckpt: Path, model: Path,
                        data: Path) -> None:
    from wtml.exporters.common import export_model

    stages.begin(slice_, f"export {model.name}",
                 f"wtml export --checkpoint {ckpt} --out {model}")
    for kind, path in export_model(ckpt, model).items():
        print(f"{kind}: {path}")
    sample = model / "sample_input.csv"
    references = write_sample_csv(data, sample)
    flag = "".join(f" --{key} {path}" for key, path in references.items())
    stages.begin(slice_, "predict", f"wtml predict --model {model} --input {sample}{flag}")
    rows = predict_file(model, sample, **references)
    print(format_predictions(rows))
    warning = domain_warning(rows)
    if warning:
        print(warning)


def run_fluid(stages: Stages, *, max_epochs: int | None = None) -> dict:
    """The fluid slice end to end; returns its bench summary."""
    from wtml.bench.fluid import run_bench

    data, model, bench = Path("datasets/fluid"), Path("export/fluid"), Path("runs/fluid/bench")
    _generate(stages, "fluid", "configs/scenes/fluid.yaml", data)
    ckpt = _train(stages, "fluid", "configs/fluid.yaml", data, max_epochs)
    _export_and_predict(stages, "fluid", ckpt, model, data)
    stages.begin("fluid", "bench", f"wtml bench fluid --out {bench} --device-records 300 "
                                   f"--threads {available_cores()}")
    report = run_bench(data, ckpt, model, bench, device_records=300, threads=available_cores())
    print(report.split("\n## By viscosity decade")[0])
    stages.end()
    return json.loads((bench / "summary.json").read_text())


def run_radial(stages: Stages, *, max_epochs: int | None = None) -> dict:
    """The radial slice end to end (the shipped decoder on the preset's device, and the
    variant trained over the device spread); returns its bench summary."""
    from wtml.bench.radial import run_bench
    from wtml.exporters.common import export_model

    data, invalid = Path("datasets/radial"), Path("datasets/radial_invalid")
    spread = Path("datasets/radial_spread")
    _generate(stages, "radial", "configs/scenes/radial.yaml", data)
    _generate(stages, "radial", "configs/scenes/radial_invalid.yaml", invalid)
    _generate(stages, "radial", "configs/scenes/radial_spread.yaml", spread)
    ckpts = {}
    for name in ("radial", "radial_thesis", "radial_spread"):
        on = spread if name == "radial_spread" else data
        ckpts[name] = _train(stages, "radial", f"configs/{name}.yaml", on, max_epochs)
        if name == "radial_thesis":
            stages.begin("radial", "export radial_thesis",
                         f"wtml export --checkpoint {ckpts[name]} --out export/{name}")
            export_model(ckpts[name], Path("export") / name)
        else:
            _export_and_predict(stages, "radial", ckpts[name], Path("export") / name, on)
    bench = Path("runs/radial/bench")
    stages.begin("radial", "bench", f"wtml bench radial --out {bench} "
                                    f"--threads {available_cores()}")
    print(run_bench(data, ckpts["radial"], ckpts["radial_thesis"], "export/radial",
                    "export/radial_thesis", bench, invalid_dir=invalid, spread_dir=spread,
                    spread_model_dir="export/radial_spread", threads=available_cores()))
    stages.end()
    return json.loads((bench / "summary.json").read_text())


def _spread_lines(radial: dict) -> list[str]:
    """The radial summary's device-spread lines (none for a summary without them)."""
    if "nominal_spread" not in radial:
        return []

    def row(r: dict) -> str:
        cover = "" if r["cover"] != r["cover"] else f", {100 * r['cover']:.0f} % within 2σ"
        return f"{1e6 * r['rmse']:.1f} µm{cover}, {100 * r['flagged']:.1f} % flagged"

    lines = ["  over the device spread: ours (the preset's device) "
             + row(radial["nominal_spread"])]
    s = radial.get("ours_spread")
    if s:
        lines.append(
            f"  ours spread-trained (configs/radial_spread.yaml): RMSE {1e6 * s['rmse']:.1f} µm "
            f"(target ≤ 5 µm: {_met(s['rmse'] <= 5e-6)}), {100 * s['cover']:.0f} % of in-domain "
            f"answers within 2σ (target ≥ 90 %: {_met(s['cover'] >= 0.9)}), "
            f"{100 * s['flagged']:.1f} % flagged; on the nominal device "
            f"{row(radial['ours_spread_nominal'])}")
        if "ours_spread_whisker" in radial:
            lines.append("  the same over the spread with the whisker measured (its length, "
                         "thickness and modulus nominal): "
                         + row(radial["ours_spread_whisker"]))
    if radial.get("spread_limit"):
        lines.append(f"  limited by {radial['spread_limit']} alone")
    return lines


def _met(ok: bool) -> str:
    return "met" if ok else "MISSED"


def _timed(timing: dict) -> tuple[str, str]:
    """How a bench's times were taken, for a summary line: ``", on N threads"`` (empty where
    unsaid) and, where other processes kept more than
    :data:`~wtml.bench.timing.BUSY_SHARE` of the cores busy (the other lane's stages), a
    clause saying so for the line's parenthesis (else empty)."""
    threads, share, cores = (timing.get(k) for k in ("threads", "busy_elsewhere", "cores"))
    where = f", on {threads} thread{'s' if threads != 1 else ''}" if threads else ""
    busy = ""
    if share is not None and share > BUSY_SHARE:
        busy = (f"; timed while other work kept {100 * share:.0f} % of the "
                f"{f'{cores} ' if cores else ''}cores busy: `wtml bench fluid` alone times it "
                "on a quiet machine")
    return where, busy


def _device_lines(fluid: dict) -> list[str]:
    """The device-spread table in two lines: the decoder over the whole spread against the
    targets, and the parameter that limits it."""
    rows = {r["device"]: {m["name"]: m for m in r["methods"]} for r in fluid["device_spread"]}
    dec = rows["trained spread"]["decoder ONNX"]
    alone = {k: v["decoder ONNX"] for k, v in rows.items() if k.endswith("only")}
    # the parameter whose spread alone costs most against the targets (η 3 %, ρ 0.6 %)
    worst = max(alone, key=lambda k: max(alone[k]["eta_median"] / 0.03,
                                         alone[k]["rho_median"] / 0.006))
    return [
        f"  devices of the trained spread ({fluid['device_records']} records): η median "
        f"{100 * dec['eta_median']:.2f} % (target ≤ 3 %: {_met(dec['eta_median'] <= 0.03)}), "
        f"ρ {100 * dec['rho_median']:.3f} % (target ≤ 0.6 %: "
        f"{_met(dec['rho_median'] <= 0.006)}), flagged {100 * dec['flagged']:.1f} %",
        f"  limited by {worst.removesuffix(' only')}: η {100 * alone[worst]['eta_median']:.2f} %, "
        f"ρ {100 * alone[worst]['rho_median']:.3f} % alone"]


def summary(results: dict[str, dict], stages: Stages) -> str:
    """The closing summary: each slice's key numbers against its targets, where the reports
    and plots are, the stage timings and the total time."""
    lines = ["", "== summary"]
    fluid = results.get("fluid")
    if fluid:
        dec, bayes, closed = fluid["decoder_onnx"], fluid["bayes"], fluid["closed_form"]
        gain = {k: closed[f"{k}_median"] / dec[f"{k}_median"] for k in ("eta", "rho")}
        fast = fluid["decoder_onnx_latency_s"], fluid["decoder_onnx_throughput"]
        where, busy = _timed(fluid.get("timing", {}))
        lines += [
            "fluid (test shard, decoder ONNX):",
            f"  η median {100 * dec['eta_median']:.2f} % "
            f"({dec['eta_median'] / bayes['eta_median']:.2f}× the Bayes posterior mean's "
            f"{100 * bayes['eta_median']:.2f} %; target ≤ 1 %: "
            f"{_met(dec['eta_median'] <= 0.01)}, the Bayes estimate itself is above it)",
            f"  ρ median {100 * dec['rho_median']:.3f} % "
            f"({dec['rho_median'] / bayes['rho_median']:.2f}× Bayes; target ≤ 0.5 %: "
            f"{_met(dec['rho_median'] <= 0.005)})",
            f"  against the thesis's closed form: {gain['eta']:.1f}× in η, {gain['rho']:.1f}× "
            f"in ρ (target ≥ 2×: {_met(min(gain.values()) >= 2)})",
            f"  {1e6 * fast[0]:.0f} µs at batch 1, {fast[1]:.3g}/s at batch 4096{where} "
            f"(targets ≤ 50 µs, ≥ 1e6/s: {_met(fast[0] <= 50e-6)}, {_met(fast[1] >= 1e6)}"
            f"{busy}); in-domain test rows flagged: {100 * fluid['false_alarm']:.2f} %",
            *_device_lines(fluid),
            "  report runs/fluid/bench/report.md, plot runs/fluid/bench/error_vs_latency.png",
            f"  time: {stages.line('fluid')}"]
    radial = results.get("radial")
    if radial:
        ours, inv = radial["ours_onnx"], radial["inversion"]
        lines += [
            "radial (ours ONNX; nominal device):",
            f"  RMSE {1e6 * ours['rmse']:.2f} µm = {ours['ratio']:.2f}× the CRLB, worst 800 µm "
            f"range {radial['worst_range_ratio']:.2f}× (target ≤ 1.5×: "
            f"{_met(max(ours['ratio'], radial['worst_range_ratio']) <= 1.5)})",
            f"  {radial['best_polynomial_rmse'] / ours['rmse']:.1f}× below the best polynomial "
            f"(target ≥ 5×: {_met(radial['best_polynomial_rmse'] >= 5 * ours['rmse'])}); the "
            f"converged physics inversion {1e6 * inv['rmse']:.2f} µm at "
            f"{radial['inversion_latency_s'] / radial['ours_onnx_latency_s']:.0f}× the latency",
            f"  in-domain test rows flagged: {100 * radial['false_alarm']:.2f} %",
            *_spread_lines(radial),
            "  report runs/radial/bench/report.md, plots runs/radial/bench/error_vs_latency.png "
            "and runs/radial/bench/error_vs_d.png",
            f"  time: {stages.line('radial')}"]
    if results.get("onset"):
        lines += _onset_lines(results["onset"], stages)
    if results.get("texture"):
        lines += _texture_lines(results["texture"], stages)
    if stages.times.get(WARM):
        lines.append(f"{WARM} (kernels compiled and datasets generated ahead, in a lane of "
                     f"their own): {stages.line(WARM)}")
    lines.append(f"total: {duration(time.perf_counter() - stages.start)}")
    return "\n".join(lines)


def _export_and_predict_records(stages: Stages, slice_: str, ckpt: Path, model: Path,
                                data: Path, predict_records, calibration_file) -> dict:
    """Export a time-domain slice, write two test records as ``model/rec.npz`` (e, i,
    sample_rate_hz) and their devices' calibration as ``model/cal.npz`` with the task's
    ``calibration_file(path, scene, records) -> path`` (``--calibration``: onset's T at the
    probe and HUE(0), texture's T on its ``calibration_hz``), print ``wtml predict`` on them;
    returns the test shard."""
    from wtml.data import dataset_scene, load_shards, read_manifest
    from wtml.data.datamodule import split_shards
    from wtml.exporters.common import export_model

    stages.begin(slice_, f"export {model.name}",
                 f"wtml export --checkpoint {ckpt} --out {model}")
    for kind, path in export_model(ckpt, model).items():
        print(f"{kind}: {path}")
    test = load_shards(data, split_shards(read_manifest(data)["n_shards"], 1, 1)["test"])
    sample = model / "rec.npz"
    scene = dataset_scene(data)
    np.savez(sample, e=test["e"][:2], i=test["i"][:2],
             sample_rate_hz=scene.acquisition.sample_rate_hz)
    calibration = calibration_file(model / "cal.npz", scene,
                                   {k: v[:2] for k, v in test.items()})
    stages.begin(slice_, "predict", f"wtml predict --model {model} --input {sample} "
                                    f"--calibration {calibration}")
    print(format_predictions(predict_records(model, sample, calibration=calibration)))
    return test


def run_onset(stages: Stages, *, max_epochs: int | None = None) -> dict:
    """The onset slice end to end; returns its bench summary."""
    from wtml.bench.onset import run_bench
    from wtml.exporters.onset import calibration_file
    from wtml.runtime.onset import predict_records

    data, model, bench = ONSET_DATA, Path("export/onset"), Path("runs/onset/bench")
    _generate(stages, "onset", ONSET_SCENE, data)
    ckpt = _train(stages, "onset", "configs/onset.yaml", data, max_epochs)
    test = _export_and_predict_records(stages, "onset", ckpt, model, data, predict_records,
                                       calibration_file)
    print("true: gap " + ", ".join(f"{g:.4g} m" for g in test["gap"][:2]) + "; onsets "
          + ", ".join(f"{t:.4f}" for t in test["onset"][:2].ravel() if np.isfinite(t)) + " s")
    stages.begin("onset", "bench", f"wtml bench onset --out {bench} --free-records 50 "
                                   f"--variant-records 8 --transfer-records {TRANSFER_RECORDS} "
                                   f"--independent-records {INDEPENDENT_RECORDS} "
                                   f"--device-records {DEVICE_RECORDS['onset']}")
    print(run_bench(data, model, bench, free_records=50, variant_records=8,
                    transfer_records=TRANSFER_RECORDS, independent_records=INDEPENDENT_RECORDS,
                    device_records=DEVICE_RECORDS["onset"]))
    stages.end()
    return json.loads((bench / "summary.json").read_text())


def _onset_lines(onset: dict, stages: Stages) -> list[str]:
    by = {m["name"]: m for m in onset["methods"]}
    dec, thesis = by["decoder (ONNX)"], by["thesis pipeline (ONNX)"]
    rmse, free = dec["rows"][-1]["rmse"], dec["free"]
    six = max(r["per_core"] for r in onset["simulator"] if r["modes"] >= 6 and r["threads"] == 1)
    return [
        f"onset ({onset['n_test']} test records, decoder ONNX):",
        f"  location RMSE {1e6 * rmse:.3f} µm (target ≤ 0.1 µm: {_met(rmse <= 1e-7)}); thesis "
        f"pipeline {1e6 * thesis['rows'][-1]['rmse']:.3f} µm (target ours ≤ half: "
        f"{_met(rmse <= thesis['rows'][-1]['rmse'] / 2)}); Cramér–Rao bound "
        f"{1e6 * onset['reference'][-1]['rows'][-1]['rmse']:.2g} µm",
        f"  F1 at ±1 ms {dec['f1']:.3f} (target in the main job ≥ 0.95: "
        f"{_met(dec['f1'] >= 0.95)}; at full size ≥ 0.99); Fig 5.22 R² {dec['fig522_r2']:.4f}",
        f"  free whisking, {free['seconds']:.0f} s: {free['walls']} walls and "
        f"{free['contacts']} contacts reported (target none: {_met(dec['false_per_s'] == 0)}), "
        f"{100 * free['flagged']:.0f} % flagged out of domain (target 0: "
        f"{_met(free['flagged'] == 0)})",
        f"  streaming (stream.onnx, {onset['streaming']['chunk_ms']:.1f} ms chunks): detection "
        f"delay p50 {onset['streaming']['delay_ms_p50']:.1f} ms (aim ≤ 5 ms: "
        f"{_met(onset['streaming']['delay_ms_p50'] <= 5)}); after the last chunk, gap within "
        f"{1e6 * onset['streaming']['gap_max_diff_m']:.1e} µm of the offline graph",
        "  domain flag on untrained drives: " + ", ".join(
            f"{k} {100 * v:.0f} %" for k, v in onset["domain_flag"].items())
        + f"; held-out test rows flagged {100 * onset['false_alarm_held_out']:.1f} %",
        *_onset_transfer_lines(onset["transfer"]),
        *_onset_device_lines(onset),
        "  simulator: " + ", ".join(
            f"{r['modes']} modes {r['per_core']:.0f}×" for r in onset["simulator"]
            if r["threads"] == 1)
        + f" real time per core (target ≥ 1000× at ~6 modes: {_met(six >= 1000)})",
        "  report runs/onset/bench/report.md, plots runs/onset/bench/*.png",
        f"  time: {stages.line('onset')}"]


def _onset_device_lines(onset: dict) -> list[str]:
    """The decoder over the device spread against the nominal device (issue 21 §1's target:
    location RMSE within 1.5×), and the class of parameter that limits it."""
    sm = onset.get("device_summary")
    if not sm:
        return []
    nom, spr = sm["nominal"], sm["spread"]
    records = onset["device_spread"][0]["records"]
    return [f"  device spread ({records} fresh records per row): nominal device "
            f"{1e6 * nom['rmse']:.3f} µm, F1 {nom['f1']:.2f}; {sm['spread_name']} "
            f"{1e6 * spr['rmse']:.3f} µm ({sm['ratio']:.2f}×; target ≤ 1.5×: "
            f"{_met(sm['ratio'] <= 1.5)}), F1 {spr['f1']:.2f}, flagged "
            f"{100 * spr['flagged']:.0f} %, {100 * spr['within_2sigma']:.0f} % within 2σ; "
            f"limited by {sm['limit']}: {1e6 * sm['limit_rmse']:.3f} µm"]


def _onset_transfer_lines(rows: list[dict]) -> list[str]:
    """The decoder on each contact law alone and on the independent simulator against the
    issue's targets: location RMSE ≤ 0.1 µm and ≤ 1.5× the in-family row, |error| ≤ 2σ for
    ≥ 90 % of in-domain records, and the worst acquisition effect."""
    dec = {r["name"]: r["methods"][0] for r in rows}
    family = dec["the trained scene (in family)"]
    laws = [r for r in rows if r["kind"] in ("held out", "independent")
            or r["name"].startswith("contact law")]
    ok = all(dec[r["name"]]["rmse"] <= min(1e-7, 1.5 * family["rmse"])
             and dec[r["name"]]["within_2sigma"] >= 0.9 for r in laws)
    worst = max((r for r in rows if r["kind"] == "acquisition"),
                key=lambda r: dec[r["name"]]["rmse"])
    cells = ", ".join(
        f"{r['name'].removeprefix('contact law ').replace(' alone', '')} "
        f"{1e6 * dec[r['name']]['rmse']:.3f} µm ({100 * dec[r['name']]['within_2sigma']:.0f} % "
        f"in 2σ, F1 {dec[r['name']]['f1']:.2f})" for r in laws)
    return [f"  transfer ({rows[0]['records']} fresh records per row): in family "
            f"{1e6 * family['rmse']:.3f} µm; {cells} (targets ≤ 0.1 µm, ≤ 1.5× in family, "
            f"≥ 90 % within 2σ: {_met(ok)}); worst acquisition effect: {worst['name']} "
            f"{1e6 * dec[worst['name']]['rmse']:.3f} µm"]


def run_texture(stages: Stages, *, max_epochs: int | None = None) -> dict:
    """The texture slice end to end; returns its bench summary."""
    from wtml.bench.texture import run_bench
    from wtml.data import dataset_scene
    from wtml.exporters.texture import calibration_file
    from wtml.runtime.texture import predict_records

    data, fepa = Path("datasets/texture"), FEPA_DATA
    model, bench = Path("export/texture"), Path("runs/texture/bench")
    _generate(stages, "texture", TEXTURE_SCENE, data)
    _generate(stages, "texture", FEPA_SCENE, fepa)
    ckpt = _train(stages, "texture", "configs/texture.yaml", data, max_epochs)
    test = _export_and_predict_records(stages, "texture", ckpt, model, data, predict_records,
                                       calibration_file)
    names = dataset_scene(data).class_names()
    print("true: " + ", ".join(f"{names[g]} ({1e6 * d:.1f} µm)"
                               for g, d in zip(test["grade"][:2], test["grain_m"][:2],
                                               strict=True)))
    stages.begin("texture", "bench", f"wtml bench texture --out {bench} "
                                     f"--transfer-records {TRANSFER_RECORDS} "
                                     f"--device-records {DEVICE_RECORDS['texture']} "
                                     f"--no-fresh-minirocket")
    report = run_bench(data, fepa, ckpt, model, bench, transfer_records=TRANSFER_RECORDS,
                       device_records=DEVICE_RECORDS["texture"], oracle_file=TEXTURE_ORACLES,
                       fresh_minirocket=False)
    print(report.split("\n\nConfusion matrices")[0])
    stages.end()
    return json.loads((bench / "summary.json").read_text())


def _texture_lines(s: dict, stages: Stages) -> list[str]:
    from wtml.bench.resampling import span

    by = {m["name"]: m for m in s["methods"]}
    dec, cues = by["decoder (ONNX)"], by["thesis cues (ONNX)"]
    peer = by["MiniRocket (aeon)"]
    kin = by["kinetic signature (peak nearest v/d)"]
    inter = next(r for r in s["unseen"]["pooled"]
                 if r["name"] == "decoder (ONNX)" and r["range"] == "interpolated")
    extra = next(r for r in s["unseen"]["pooled"]
                 if r["name"] == "decoder (ONNX)" and r["range"] == "extrapolated")
    short = min((r for r in s["by_window"] if r["name"] == "decoder graph (torch)"),
                key=lambda r: r["window_s"])
    return [
        f"texture ({s['n_test_windows']} windows of {s['window_s']:g} s from "
        f"{s['n_test_records']} records of held-out specimens, decoder ONNX):",
        f"  accuracy {100 * dec['accuracy']:.1f} % (95 % interval {span(dec['interval'])} over "
        f"{s['n_test_specimens']} specimens; target ≥ 99 %: "
        f"{_met(dec['accuracy'] >= 0.99)}; under the scene's prior the amplitude oracle "
        f"{100 * s['oracle']['accuracy']:.1f} %, the every-grain oracle "
        f"{100 * s['grain_oracle']['accuracy']:.1f} %); MiniRocket {100 * peer['accuracy']:.1f} % "
        f"(target above it: {_met(dec['accuracy'] > peer['accuracy'])}, by "
        f"{100 * s['decoder_minus_peer']['difference']:.1f} points, 95 % interval "
        f"{span(s['decoder_minus_peer']['interval'], signed=True)}); thesis cues "
        f"{100 * cues['accuracy']:.1f} %",
        *([f"  {bands['name']}: {100 * by[bands['name']]['accuracy']:.1f} % (target above it: "
           f"{_met(bands['difference'] > 0)}, by {100 * bands['difference']:.1f} points, 95 % "
           f"interval {span(bands['interval'], signed=True)})"]
          if (bands := s.get("decoder_minus_bands")) else []),
        f"  kinetic signature {100 * kin['accuracy']:.1f} % (chance 20 %; target near chance: "
        f"{_met(kin['accuracy'] <= 0.3)})",
        f"  unseen FEPA grades, grain size RMS {inter['rms_pct']:.1f} % inside the trained "
        f"range (target ≤ 10 %: {_met(inter['rms_pct'] <= 10)}), {extra['rms_pct']:.1f} % "
        f"outside it, of which {100 * extra['flagged']:.0f} % flagged",
        f"  {1e3 * dec['latency_s']:.1f} ms per window at batch 1 (MiniRocket "
        f"{1e3 * peer['latency_s']:.0f} ms); {short['window_s']:g} s windows "
        f"{100 * short['accuracy']:.1f} %",
        *_texture_transfer_lines(s["transfer"]),
        *_texture_device_lines(s),
        "  report runs/texture/bench/report.md, plots runs/texture/bench/*.png",
        f"  time: {stages.line('texture')}"]


def _texture_device_lines(s: dict) -> list[str]:
    """The decoder on the nominal device, over the trained spread and on the class that
    limits it (target: error rate within 1.5× the nominal one)."""
    from wtml.bench.texture_transfer import DEVICE_TARGET

    rows, v = s["device_spread"], s["device_verdict"]
    dec = [r["methods"][0] for r in rows]
    limit = next((r for r in rows if r["name"] == v["limit"]), None)
    return [f"  device spread ({rows[0]['records']} fresh records per row, paired): nominal "
            f"device {100 * dec[0]['accuracy']:.1f} %, {rows[1]['name']} "
            f"{100 * dec[1]['accuracy']:.1f} % ({100 * dec[1].get('flagged', 0):.0f} % "
            f"flagged; error {v['ratios'][1]:.2f}× the nominal, target ≤ {DEVICE_TARGET:g}×: "
            f"{_met(v['met'])}); "
            + (f"worst class alone {limit['name'].removesuffix(' alone')}: "
               f"{100 * limit['methods'][0]['accuracy']:.1f} % (paired rows; compare with "
               "their intervals in the report)" if limit
               else "no class alone below the nominal device")]


def _texture_transfer_lines(rows: list[dict]) -> list[str]:
    """The decoder's accuracy on the trained scene beside each friction law alone and each
    other held-out row (the pre-sliding compliance, more viscous friction; target: every
    held-out row within 3 points of the in-family accuracy, on a few records: the report's
    intervals say what the verdicts are worth)."""
    acc = {r["name"]: r["methods"][0]["accuracy"] for r in rows}
    n = rows[0]["records"]
    family = acc["the trained scene (in family)"]
    shown = [r for r in rows if r["name"].startswith("friction law") or r["kind"] == "held out"]
    held = [r for r in shown if r["kind"] == "held out"]
    line = (f"  transfer ({n} fresh records per row): in family {100 * family:.1f} %; "
            + ", ".join(f"{r['name'].removeprefix('friction law ').replace(' alone', '')} "
                        f"{100 * acc[r['name']]:.1f} %" for r in shown))
    verdicts = [f"{r['name']}: {_met(acc[r['name']] >= family - 0.03)}" for r in held]
    return [line + (f" (target: held out within 3 points: {'; '.join(verdicts)})"
                    if verdicts else "")]


LANES = 2
"""Slices of the main job run side by side, one thread each (see :func:`run_all`)."""
LOGS = Path("runs/pipeline")
"""Where each slice run in a lane writes its log (``<task>.log``)."""
TEXTURE_ORACLES = LOGS / "texture.oracles.json"
"""The texture bench's oracles, computed ahead by the warm-up (:func:`warm_texture`)."""
WARM = "warm-up"
"""The job that does the slices' warm parts ahead, their JIT kernels compiled and datasets
generated (:func:`run_all`), its log ``warm-up.log`` and its line of the summary."""
BENCH_LOCK = "bench.lock"
"""The file in :data:`LOGS` that the lanes' ``bench`` stages take turns on (:class:`Stages`):
side by side, the texture and radial benches peaked at 3.1 GB together (27 Nov)."""
PRELOAD = ["numpy", "scipy.signal", "sklearn.ensemble", "onnxruntime", "torch", "lightning",
           "wtml.training", "wtml.fork_server"]
"""Modules the slices' processes start with: imported once, by the fork server they are forked
from (each slice imported them afresh, ~8 s, when it was spawned from a bare interpreter);
the last freezes them (:mod:`wtml.fork_server`)."""


def run_slice(task: str | Task, max_epochs: int | None = None, echo: TextIO | None = None,
              bench_lock: Path | None = None) -> tuple[dict, dict[str, float]]:
    """One slice of the main job (the ``pipeline`` part of ``task``, a registered task's name
    or a :class:`wtml.tasks.Task`): its results and its stages' times (s); ``echo`` and
    ``bench_lock``: :class:`Stages`'."""
    spec = TASKS[task] if isinstance(task, str) else task
    stages = Stages(echo, bench_lock)
    result = spec.load("pipeline")(stages, max_epochs=max_epochs)
    stages.end()
    return result, stages.times.get(spec.name, {})


@contextmanager
def _logged(path: Path) -> Iterator[TextIO]:
    """This process's stdout and stderr (file descriptors 1 and 2: the libraries' output too)
    into ``path``; yields the terminal's stdout, for progress lines."""
    path.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    terminal = os.fdopen(os.dup(saved[0]), "w", buffering=1)
    with open(path, "w") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            yield terminal
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            terminal.close()


@contextmanager
def _threads(threads: int) -> Iterator[None]:
    """This process computing on ``threads`` threads (torch, BLAS, onnxruntime, the stepper:
    :data:`wtml.cores.THREADS_ENV`)."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(threads)
    with capped(threads), threadpool_limits(threads):
        yield


def _lane_slice(spec: Task, max_epochs: int | None, threads: int, log: Path | None
                ) -> tuple[dict, dict[str, float]]:
    """A slice in a process of its own, on ``threads`` threads, its output into ``log``
    (None: to the terminal)."""
    with _threads(threads):
        if log is None:
            return run_slice(spec, max_epochs)
        with _logged(log) as terminal:
            return run_slice(spec, max_epochs, terminal, log.parent / BENCH_LOCK)


def _lane_warm(specs: list[Task], threads: int, log: Path) -> dict[str, float]:
    """Each task's warm part (:attr:`wtml.tasks.Task.warm`) in a process of its own, on
    ``threads`` threads, its output into ``log``; returns each one's seconds."""
    times = {}
    with _threads(threads), _logged(log) as terminal:
        for spec in specs:
            print(f"{time.strftime('%H:%M:%S')} {WARM}: {spec.name}", file=terminal, flush=True)
            start = time.perf_counter()
            spec.load("warm")()
            times[spec.name] = time.perf_counter() - start
            print(f"{WARM}: {spec.name}'s done in {duration(times[spec.name])}")
    return times


def warm_onset() -> None:
    """The onset slice's work ahead: its dataset generated (:func:`generate_locked`), which
    compiles the scene's stepper for the shipped scene's own signatures (a default scene
    compiles others), and the independent simulator's kernels compiled on one record (numba,
    into its cache on disk)."""
    from wtml.bench.onset_transfer import independent_variant
    from wtml.scenes import load_scene

    generate_locked(ONSET_SCENE, ONSET_DATA)
    independent_variant(load_scene(ONSET_SCENE)).make(1, np.random.default_rng(0))


def warm_texture() -> None:
    """The texture slice's work ahead: the unseen FEPA grades' dataset its bench reads
    generated (:func:`generate_locked`; first: the slice reaches it within a minute), then
    its MiniRocket peer compiled (aeon's kernels, by numba, into its cache on disk: ~25 s on
    one core in a fresh environment), fitted and run on a few random windows as its bench
    fits and runs it (float32 ``(n, 2, window)``), then its bench's oracles computed into
    :data:`TEXTURE_ORACLES` (:func:`wtml.bench.texture.cached_oracles`: ~30 s that lay on
    the path that ends last)."""
    from wtml.baselines.texture_peers import MiniRocketPeer
    from wtml.bench.texture import ORACLE_DRAWS, cached_oracles
    from wtml.scenes import load_scene

    generate_locked(FEPA_SCENE, FEPA_DATA)
    x = np.random.default_rng(0).standard_normal((10, 2, 256)).astype(np.float32)
    MiniRocketPeer(84).fit_stacked(x.copy(), np.arange(10) % 5).predict_stacked(x)
    cached_oracles(load_scene(TEXTURE_SCENE), ORACLE_DRAWS, TEXTURE_ORACLES)


def run_all(task: str = "all", *, max_epochs: int | None = None, lanes: int = LANES) -> str:
    """The main job for ``task`` (``"all"``, or one of :data:`wtml.tasks.TASKS`); prints and
    returns the closing summary.

    One slice runs in this process. More than one run each in a process of its own (forked
    from a server that imported :data:`PRELOAD` once), which returns all its memory when it
    ends. With ``lanes`` > 1 (and as many cores), that many run side by side, in the order
    predicted to end first (:func:`wtml.lanes.lane_order`), each on ``cores // lanes``
    threads: most of a slice's work (the trainers' steps on small batches, the stepper, the
    benches' small calls) gains little from a second thread. Their ``bench`` stages take
    turns (:data:`BENCH_LOCK`). Each writes its log to :data:`LOGS` ``/<task>.log``, printed
    whole when it ends, and a line per stage as it goes. ``lanes`` 1: one after another on
    every core, printing as they go.

    With lanes, what the slices would do when they first need it and that waits on nothing
    else (the tasks' ``warm`` parts: onset's steppers compiled and its dataset generated,
    texture's MiniRocket compiled and its FEPA set generated) is done first, by a
    :data:`WARM` job that holds one lane while the first slice starts in another
    (:func:`wtml.lanes.makespan` replays it): in the 29 Nov main job that work lay on the
    path that ends last (texture's bench, then onset), and the lane that took radial had a
    minute or more to spare while radial's bench waited for texture's.

    Raises:
        ValueError: ``lanes`` < 1.
    """
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from multiprocessing import get_context

    if lanes < 1:
        raise ValueError(f"--lanes: must be at least 1, got {lanes}")
    stages, results = Stages(), {}
    names = [spec.name for spec in TASKS.values() if task in (spec.name, "all")]
    if len(names) == 1:
        results[names[0]], stages.times[names[0]] = run_slice(names[0], max_epochs)
    else:
        lanes = min(lanes, len(names), available_cores())
        threads = max(1, available_cores() // lanes)
        context = get_context("forkserver")
        context.set_forkserver_preload(PRELOAD)
        warm = [TASKS[n] for n in names if TASKS[n].warm] if lanes > 1 else []
        order = lane_order({n: TASKS[n].pipeline_s for n in names},
                           {n: TASKS[n].bench_s for n in names}, lanes,
                           sum(spec.warm_s for spec in warm))
        warm.sort(key=lambda spec: order.index(spec.name))  # the first slice's work first
        if lanes > 1:
            first = (f"{WARM} ({', '.join(spec.name for spec in warm)}) first, " if warm
                     else "")
            print(f"{len(names)} slices in {lanes} lanes of {threads} thread(s), {first}in "
                  f"the order that ends first ({', '.join(order)}); each slice's log: "
                  f"{LOGS}/<slice>.log, printed when it ends", flush=True)
        with ProcessPoolExecutor(lanes, mp_context=context, max_tasks_per_child=1,
                                 initializer=watch_parent, initargs=(os.getpid(),)) as pool:
            running = {}
            if warm:  # submitted first: the pool's first free lane takes it
                running[pool.submit(_lane_warm, warm, threads, LOGS / f"{WARM}.log")] = WARM
            for name in order:
                running[pool.submit(_lane_slice, TASKS[name], max_epochs, threads,
                                    LOGS / f"{name}.log" if lanes > 1 else None)] = name
            while running:
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    name = running.pop(future)
                    log = LOGS / f"{name}.log"
                    if lanes > 1 and log.is_file():
                        print(log.read_text(), end="", flush=True)
                    if future.exception() is not None:
                        pool.shutdown(cancel_futures=True)
                    if name == WARM:
                        stages.times[WARM] = future.result()
                    else:
                        results[name], stages.times[name] = future.result()
        results = {name: results[name] for name in names}
    text = summary(results, stages)
    print(text)
    sys.stdout.flush()
    return text
