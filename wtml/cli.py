"""The ``wtml`` console script.

Subcommands: ``walkthrough`` (the thesis's calibration), ``presets``, ``fidelity``, ``generate``,
``evaluate``, ``export``, ``predict``, ``stream`` (an onset export on a live acquisition),
``bench fluid|radial|onset|texture|texture-rate|texture-scale|device|runtime``, ``device``,
``calibrate`` and ``pipeline`` (all of them in a row). Bad input ends a command with one line
on stderr and exit code 2.
Training runs through LightningCLI: ``python train.py fit --config configs/fluid.yaml``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import os
import re
import sys
import textwrap
from pathlib import Path

from wtml import __version__
from wtml.tasks import TASKS

PACKAGE = Path(__file__).resolve().parent
"""wtml's own source folder: an error raised by code there is one of its checks."""

_EXPECTS = {"int": "a whole number", "float": "a number"}


class _Parser(argparse.ArgumentParser):
    """argparse with one line for a bad command line (exit 2): the option and what it expects,
    instead of the usage dump."""

    def error(self, message: str) -> None:  # argparse's hook; it must not return
        match = re.match(r"argument (\S+): invalid (\w+) value: (.*)$", message)
        if match:
            option, kind, value = match.groups()
            message = (f"argument {option}: expects {_EXPECTS.get(kind, kind)}, got "
                       f"{value[:80]}")
        message = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _number(low: float, high: float, kind: type = float):
    """An argparse ``type`` for a number in ``[low, high]`` (``kind`` int: a whole one)."""
    what = "a whole number" if kind is int else "a number"

    def parse(text: str) -> float | int:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expects {what} in [{low:g}, {high:g}], got "
                                             f"{text[:80]!r}") from None
        if not low <= value <= high:  # NaN fails too
            raise argparse.ArgumentTypeError(f"expects {what} in [{low:g}, {high:g}], got "
                                             f"{text[:80]!r}")
        return value

    parse.__name__ = kind.__name__
    return parse


COUNT = _number(0, 10**7, int)
"""A number of records or samples (0: none)."""
THREADS = _number(1, 1024, int)
SCALE = _number(1e-12, 1e12)
"""A channel's scale (V per V, A per V) or an interface's full scale (V)."""
RATE = _number(1e-3, 1e12)
"""A sampling rate (Hz)."""
TRAINING_STACK = ("torch", "lightning", "numba", "sklearn", "scipy", "onnx", "onnxscript",
                  "matplotlib", "skrf", "tqdm", "jsonargparse", "aeon", "ruptures")
"""Modules that ``pip install wtml`` (the device runtime) does not bring."""


def _walkthrough(args: argparse.Namespace) -> int:
    from wtml.walkthrough import format_report, plot_walkthrough, run_walkthrough

    for name, value, low, high in (("--frequency", args.frequency, 1e-3, 1e4),
                                   ("--repeats", args.repeats, 1, 1000),
                                   ("--seed", args.seed, 0, 2**63 - 1)):
        if not low <= value <= high:  # NaN fails too
            raise ValueError(f"argument {name}: expects a number in [{low:g}, {high:g}], got "
                             f"{value!r}")

    result = run_walkthrough(frequency_hz=args.frequency, noise=args.noise,
                             repeats=args.repeats, seed=args.seed)
    print(format_report(result, noise=args.noise, repeats=args.repeats))
    if args.plot:
        plot_walkthrough(result, args.plot)
        print(f"plot: {args.plot}")
    return 0


def _fidelity(args: argparse.Namespace) -> int:
    from wtml.fidelity import report
    from wtml.scenes import load_scene

    print(report(load_scene(args.texture), load_scene(args.onset)))
    return 0


def _presets(args: argparse.Namespace) -> int:
    from wtml.physics.beam_presets import fidelity_table, format_fidelity

    print(format_fidelity(fidelity_table()))
    return 0


def _device(args: argparse.Namespace) -> int:
    from wtml.devices import device_hash, load_device, shipped_devices

    if args.action == "list":
        for name in shipped_devices():
            d = load_device(name)
            print(f"{name:14s} {d.kind:7s} {device_hash(d)[:12]}  {d.provenance.source[:60]}")
        return 0
    if args.action == "fit":
        return _device_fit(args)
    d = load_device(args.device)
    print(f"device {d.name} ({d.kind}), sha256 {device_hash(d)}")
    print(f"provenance: {d.provenance.source or 'not stated'}")
    if d.kind == "lumped":
        t = d.transducer()
        print(f"c0 {t.c0:.4g} F, phi {t.phi:.4g} N/V, m {t.m:.4g} kg, k {t.k:.4g} N/m, "
              f"c {t.c:.4g} N s/m, f0 {d.f0:.4g} Hz, Q {d.q:g}, tan_delta {t.tan_delta:g}")
        return 0
    from wtml.physics.beam_presets import build

    tr = build(d)
    modes = ", ".join(f"{f:.2f}" for f in tr.natural_frequencies(3))
    print(f"natural frequencies (tip free, short circuit): {modes} Hz")
    print(f"static tip displacement per volt {1e6 * tr.static_tip_displacement_per_volt():.4g}"
          f" um/V, clamped capacitance {1e9 * abs(tr.capacitance):.4g} nF, length "
          f"{1e3 * tr.length:.4g} mm")
    return 0


def _device_fit(args: argparse.Namespace) -> int:
    from wtml.device_fit import fit, format_report, write_outputs
    from wtml.physics.measured import load_measurements

    contacts = []
    for text in args.contact or ():
        parts = text.split(":")
        try:
            distance = float(parts[0]) * 1e-3
        except ValueError:
            distance = math.nan
        if len(parts) not in (2, 3) or not math.isfinite(distance):
            raise ValueError(f"--contact {text!r}: write DISTANCE_MM:FILE or "
                             "DISTANCE_MM:FILE:STIFFNESS_N_PER_M (distance from the tip)")
        contacts.append((distance, parts[1], *parts[2:]))
    m = load_measurements(args.sweep, sigma=args.sigma, clamped=args.clamped,
                          contacts=tuple(contacts), hue0=args.hue0,
                          tip_velocity=args.tip_velocity)
    if args.loads:
        from wtml.device_calibration import load_sweeps

        m = dataclasses.replace(m, loads=load_sweeps(args.loads, sigma=args.sigma))
    device, result = fit(args.device, m, free=args.free)
    print(format_report(device, result))
    fitted = write_outputs(device, result, Path(args.out), name=args.name,
                           plot=None if args.plot is None else Path(args.plot),
                           report=None if args.report is None else Path(args.report))
    print(f"fitted device {fitted.name} written to {args.out}"
          + (f"; Bode plot {args.plot}" if args.plot else "")
          + (f"; report {args.report}" if args.report else ""))
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from wtml.device_calibration import calibrate, format_summary

    _, summary = calibrate(args.device, args.loads, out=args.out, hue0=args.hue0)
    print(format_summary(summary))
    return 0


def _whole_number(option: str, text: str | None) -> int | None:
    """An option's whole number, parsed here (not by argparse, whose refusal is a usage dump):
    a bad one is the command's one-line error."""
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{option}: must be a whole number, got {text!r:.40}") from None


def _generate(args: argparse.Namespace) -> int:
    from wtml.data import generate
    from wtml.scenes import load_scene

    shards, shard = _whole_number("--shards", args.shards), _whole_number("--shard", args.shard)
    m = generate(load_scene(args.config), args.out, shards=shards, shard=shard,
                 progress=not args.quiet)
    state = "complete" if m["complete"] else f"{len(m['shards'])}/{m['n_shards']} shards"
    print(f"{args.out}: {m['samples']} samples, {m['n_shards']} shards, {state}, "
          f"scene {m['scene_hash'][:12]}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from wtml.bench.evaluate import evaluate

    print(evaluate(args.checkpoint, args.data))
    return 0


def _export(args: argparse.Namespace) -> int:
    from wtml.exporters.common import export_model

    for kind, path in export_model(args.checkpoint, args.out).items():
        print(f"{kind}: {path}")
    return 0


def _predict(args: argparse.Namespace) -> int:
    from wtml.cores import capped

    with capped(args.threads):  # every session it opens
        return _predict_rows(args)


def _predict_rows(args: argparse.Namespace) -> int:
    from wtml.runtime.predict import (
        InputError,
        check_device,
        domain_warning,
        format_predictions,
        task_of,
    )

    task = task_of(args.model)
    if args.device is not None:
        check_device(args.model, args.device)
    from wtml.runtime.instruments import load_profile

    spec = TASKS[task]
    profile = load_profile(args.profile, group=args.group, e_channel=args.e_channel,
                           i_channel=args.i_channel, e_scale=args.e_scale,
                           i_scale=args.i_scale, full_scale_v=args.full_scale_v,
                           sample_rate_hz=args.sample_rate)
    if spec.reads == "recordings":
        if args.reference is not None:
            raise InputError(f"--reference {args.reference}: this {task} export takes no "
                             "reference")
        rows = spec.load("rows")(args.model, args.input, calibration=args.calibration,
                                 profile=profile)
    else:
        if profile is not None:
            recordings = ", ".join(t.name for t in TASKS.values() if t.reads == "recordings")
            raise InputError(f"--profile and the recording options read recordings "
                             f"({recordings}); a {task} export takes Ze measurements")
        rows = spec.load("rows")(args.model, args.input, calibration=args.calibration,
                                 reference=args.reference)
    if args.out:
        with open(args.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({k: int(v) if isinstance(v, bool) else v for k, v in r.items()}
                        for r in rows)
        print(f"{len(rows)} predictions written to {args.out}")
    else:
        print(format_predictions(rows))
    warning = domain_warning(rows)
    if warning:
        print(f"wtml predict: {warning}", file=sys.stderr)
    return 0


def _stream(args: argparse.Namespace) -> int:
    from wtml.runtime.predict import InputError
    from wtml.runtime.stream import Streamer

    def emit(event) -> None:
        print(event.line(), flush=True)

    streamer = Streamer(args.model, args.calibration, chunk_samples=args.chunk_samples,
                        e_scale=args.e_scale, i_scale=args.i_scale,
                        sample_rate_hz=args.sample_rate, threads=args.threads,
                        first_alone=args.first_alone)
    if args.input != "-" and Path(args.input).is_dir():
        raise InputError(f"--input {args.input}: is a folder; give a file or named pipe of "
                         "float32 (e, i) pairs, or - for stdin")
    # a file or a named pipe (an acquisition program writing into it), opened once the model
    # is ready; stdin by default
    source = sys.stdin.buffer if args.input == "-" else open(args.input, "rb")  # noqa: SIM115
    try:
        with source:
            summary = streamer.run(source, emit)
    except BrokenPipeError:  # the reader of our output has gone (| head): stop quietly
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115  (Python flushes stdout at exit)
        return 0
    print(f"wtml stream: {summary.text()}", file=sys.stderr)
    return 130 if summary.interrupted else 1 if summary.stopped else 0


def _bench_runtime(args: argparse.Namespace) -> int:
    from wtml.bench.runtime import run_runtime_bench

    print(run_runtime_bench(args.out, model=args.model, records=args.records,
                            repeats=args.repeats, venv=args.runtime_venv))
    return 0


def _frontier(args: argparse.Namespace) -> int:
    """``wtml bench all`` and ``wtml bench TASK --frontier``."""
    from wtml.bench.suite import run_frontiers

    names = (args.only or list(TASKS)) if args.task == "all" else [args.task]
    out = args.out or ("runs/frontier" if args.task == "all" else f"runs/{args.task}/frontier")
    data = {} if args.task == "all" else {args.task: args.data}
    print(run_frontiers(names, out, variants=args.variants, data=data, threads=args.threads,
                        latency_repeats=args.latency_repeats, max_epochs=args.max_epochs))
    return 0


def _out(args: argparse.Namespace) -> str:
    """The bench's folder: ``--out``, else ``runs/<task>/bench``."""
    return args.out or f"runs/{args.task}/bench"


def _bench(args: argparse.Namespace) -> int:
    if args.frontier:
        return _frontier(args)
    from wtml.bench.fluid import run_bench

    print(run_bench(args.data, args.checkpoint, args.model, _out(args), threads=args.threads,
                    device_records=args.device_records))
    return 0


def _bench_radial(args: argparse.Namespace) -> int:
    if args.frontier:
        return _frontier(args)
    from wtml.bench.radial import run_bench

    print(run_bench(args.data, args.checkpoint, args.thesis_checkpoint, args.model,
                    args.thesis_model, _out(args), invalid_dir=args.invalid,
                    spread_dir=args.spread_data, spread_model_dir=args.spread_model,
                    spread_scene=args.spread_scene, threads=args.threads,
                    max_samples=args.max_samples, spread_samples=args.spread_samples))
    return 0


def _bench_device(args: argparse.Namespace) -> int:
    from wtml.bench.device import NOISES, run_device_bench

    print(run_device_bench(args.out, start=args.start, tasks=tuple(args.task or
                                                                   ("radial", "onset", "fluid")),
                           samples=args.samples, epochs=args.epochs,
                           test_records=args.test_records, onset_samples=args.onset_samples,
                           onset_epochs=args.onset_epochs,
                           onset_test_records=args.onset_test_records,
                           fluid_samples=args.fluid_samples, fluid_epochs=args.fluid_epochs,
                           fluid_test_records=args.fluid_test_records,
                           noises=tuple(args.noise or NOISES), repeats=args.repeats,
                           threads=args.threads))
    return 0


def _bench_onset(args: argparse.Namespace) -> int:
    if args.frontier:
        return _frontier(args)
    from wtml.bench.onset import run_bench

    print(run_bench(args.data, args.model, _out(args), free_records=args.free_records,
                    variant_records=args.variant_records, repeats=args.repeats,
                    transfer_records=args.transfer_records,
                    independent_records=args.independent_records,
                    device_records=args.device_records))
    return 0


def _bench_texture(args: argparse.Namespace) -> int:
    if args.frontier:
        return _frontier(args)
    from wtml.bench.texture import run_bench

    print(run_bench(args.data, args.fepa, args.checkpoint, args.model, _out(args),
                    peer_kernels=args.peer_kernels,
                    ablation_records=args.ablation_records,
                    transfer_records=args.transfer_records,
                    device_records=args.device_records, fresh_minirocket=args.fresh_minirocket))
    return 0


def _bench_stability(args: argparse.Namespace) -> int:
    from wtml.bench.stability import run_stability

    print(run_stability(args.models, args.out, records=args.records, seed=args.seed,
                        threads=args.threads, tasks=tuple(args.tasks or ()) or None))
    return 0


def _bench_models(args: argparse.Namespace) -> int:
    from wtml.bench.model_cost import run_models

    print(run_models(args.models, args.out, records=args.records,
                     radial_records=args.radial_records, threads=args.threads))
    return 0


# ---------------------------------------------------- wtml bench coverage (issue 25 §4)


def _bench_coverage(args: argparse.Namespace) -> int:
    from wtml.bench.coverage import run_coverage

    tasks = {t: {"data": f"datasets/{t}", "checkpoint": f"runs/{t}/checkpoints/last.ckpt",
                 "model": f"export/{t}"} for t in (args.only or TASKS)}
    if "radial" in tasks:
        tasks["radial"]["invalid"] = args.invalid
    records = {"fluid": args.records, "radial": args.records, "onset": args.time_records,
               "texture": args.time_records, "independent": args.independent_records}
    print(run_coverage(tasks, args.out, records=records, seed=args.seed, threads=args.threads,
                       sbi_simulations=args.sbi_simulations, sbi_epochs=args.sbi_epochs,
                       only_rows=args.rows))
    return 0


def _coverage_parser(be_sub) -> None:
    """``wtml bench coverage``'s options."""
    bc = be_sub.add_parser("coverage", help="honest uncertainty: every decoder's interval "
                           "coverage and the classifier's calibration", formatter_class=_Help,
                           description="Per regression decoder, the coverage of its 68.27 % "
                                       "and 95 % intervals (±1σ and ±1.96σ raw; ±1σ and ± "
                                       "the export's fitted 95 % width recalibrated) overall "
                                       "and per range of the target, before and after its "
                                       "export's recalibration, on the test shard, fresh "
                                       "records and the held-out physics of the transfer "
                                       "benches; the texture classifier's expected "
                                       "calibration error and reliability curve; beside the "
                                       "fluid decoder, the exact Bayes posterior's intervals "
                                       "(the best achievable) and sbi's neural posterior "
                                       "estimation (the [sbi] extra). Reads datasets/<task>, "
                                       "runs/<task>/checkpoints/last.ckpt and export/<task>.")
    bc.add_argument("--only", choices=list(TASKS), action="append", default=None,
                    help="the tasks (repeat; default all)")
    bc.add_argument("--out", default="runs/coverage",
                    help="report.md, summary.json and reliability.png go here")
    bc.add_argument("--records", type=COUNT, default=2000,
                    help="fresh fluid and radial records per row")
    bc.add_argument("--time-records", type=COUNT, default=24,
                    help="fresh onset and texture records per held-out row")
    bc.add_argument("--independent-records", type=_number(0, 10**4, int), default=8,
                    help="records of the independent simulator (onset; 0: none)")
    bc.add_argument("--invalid", default="datasets/radial_invalid",
                    help="the invalid-contact dataset (a radial row where it exists)")
    bc.add_argument("--sbi-simulations", type=_number(0, 10**7, int), default=10000,
                    help="simulations of sbi's NPE on the fluid scene (0: none)")
    bc.add_argument("--sbi-epochs", type=_number(1, 10**4, int), default=50,
                    help="NPE's most training epochs")
    bc.add_argument("--seed", type=_number(0, 2**32 - 1, int), default=2025,
                    help="the fresh records' seed (another draw of every row: is a ✗ there "
                         "again?)")
    bc.add_argument("--rows", action="append", default=None, metavar="TEXT",
                    help="only the rows whose names hold this text, case-insensitive, and "
                         "their tasks' test shards (repeat; default every row): one row on "
                         "many records, e.g. --only texture --rows 'in family' "
                         "--time-records 3000")
    bc.add_argument("--threads", type=THREADS, default=2, help="torch and onnxruntime threads")
    bc.set_defaults(func=_bench_coverage)


# ----------------------------------------------- wtml bench texture-rate (issue 25 §3)


def _bench_texture_rate(args: argparse.Namespace) -> int:
    from wtml.bench.texture_rate import run_rate

    print(run_rate(args.out, scenes=(args.low, args.high), train_specimens=args.train,
                   test_specimens=args.test, window_s=args.window,
                   oracle_draws=args.oracle_draws, per_grade=args.per_grade))
    return 0


def _texture_rate_parser(be_sub) -> None:
    """``wtml bench texture-rate``'s options."""
    br = be_sub.add_parser("texture-rate", help="the texture task at 51.2 and 204.8 kS/s: "
                           "the band-power peer on paired specimens", formatter_class=_Help,
                           description="Simulates the same training and held-out specimens "
                                       "at both scenes' rates (paired draws), trains the "
                                       "band-power peer at each and scores it on the held-out "
                                       "specimens' windows: accuracy with its interval over "
                                       "the specimens, the paired difference, P320/P280 "
                                       "confusion, the peer on the faster records' bands "
                                       "below the slower Nyquist, and the oracles.")
    br.add_argument("--low", default="configs/scenes/texture.yaml",
                    help="the slower rate's scene")
    br.add_argument("--high", default="configs/scenes/texture_pxi.yaml",
                    help="the faster rate's scene (the same but the acquisition)")
    br.add_argument("--train", type=_number(5, 10**6, int), default=640,
                    help="training specimens (one record each)")
    br.add_argument("--test", type=_number(5, 10**6, int), default=200,
                    help="held-out specimens (one record each)")
    br.add_argument("--window", type=_number(0.01, 10.0), default=0.25,
                    help="window length, s")
    br.add_argument("--per-grade", type=_number(1, 100, int), default=4,
                    help="specimens per grade simulated at once (memory)")
    br.add_argument("--oracle-draws", type=COUNT, default=100_000,
                    help="draws of each oracle's prior")
    br.add_argument("--out", default="runs/texture/rate",
                    help="report.md, summary.json and rate.png go here")
    br.set_defaults(func=_bench_texture_rate)


# ---------------------------------------------- wtml bench texture-scale (issue 25 §3)


def _bench_texture_scale(args: argparse.Namespace) -> int:
    from wtml.bench.texture_scale import run_scale

    given = {key: getattr(args, key) for key in ("scene", "sizes", "test_specimens",
                                                 "recipes", "minirocket_sizes",
                                                 "minirocket_kernels")
             if getattr(args, key) is not None}  # None: run_scale's defaults
    print(run_scale(args.out, workers=args.workers, work=args.work,
                    deadline_s=args.deadline_s, epochs=args.epochs,
                    oracle_draws=args.oracle_draws, **given))
    return 0


def _sizes(text: str) -> list[int]:
    """An argparse ``type``: comma-separated whole numbers in [1, 10**7], ascending."""
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or sizes != sorted(set(sizes)) or not 1 <= sizes[0] <= sizes[-1] <= 10**7:
        raise argparse.ArgumentTypeError(f"expects distinct whole numbers in [1, 1e7], "
                                         f"ascending, separated by commas, got {text[:80]!r}")
    return sizes


def _texture_scale_parser(be_sub) -> None:
    """``wtml bench texture-scale``'s options (the study's own defaults where None: the
    parser imports no training stack)."""
    bs = be_sub.add_parser("texture-scale", help="texture accuracy against training-set "
                           "size: the decoders' recipes and the band-power peer",
                           formatter_class=_Help,
                           description="Generates nested training sets and a held-out set "
                                       "of the texture scene (worker processes; complete "
                                       "shards are kept, so a second run resumes), trains "
                                       "each decoder recipe (on CUDA where there is one) and "
                                       "the band-power peer at every size and scores them "
                                       "on every whole window of the held-out specimens: "
                                       "accuracy with its interval over the specimens, "
                                       "P320/P280 confusion, paired differences (each "
                                       "decoder minus the peer, each size minus the "
                                       "smallest) and the oracles; optionally MiniRocket "
                                       "at some of the sizes (--minirocket-sizes).")
    bs.add_argument("--scene", default=None, help="the texture scene both sets are drawn "
                    "from, only its name, seed, samples and shards changed (default: "
                    "configs/scenes/texture.yaml)")
    bs.add_argument("--sizes", type=_sizes, default=None,
                    help="training specimens of each row, comma-separated, whole shards (40 "
                         "specimens each in the shipped scene; default: 640,2560,5120,10240)")
    bs.add_argument("--test-specimens", type=_number(1, 10**7, int), default=None,
                    help="held-out specimens, whole shards (default: 480)")
    bs.add_argument("--recipes", nargs="+", default=None,
                    help="the decoders' training configs, of one feature layer (the same "
                         "window_s and band_frame_s; default: configs/texture.yaml "
                         "configs/variants/texture_full.yaml)")
    bs.add_argument("--epochs", type=_number(1, 10**6, int), default=None,
                    help="every recipe's epochs (default: each config's max_epochs)")
    bs.add_argument("--minirocket-sizes", type=_sizes, default=None,
                    help="sizes, each one of --sizes, comma-separated, at which MiniRocket "
                         "is fitted too on every whole training window (default: none; on "
                         "CPU ~1 min per 1280 windows per core; its memory grows with the "
                         "windows: ~2.6 GB per 10240, 21.2 GB at 81920)")
    bs.add_argument("--minirocket-kernels", type=_number(84, 10**6, int), default=None,
                    help="MiniRocket's kernels (default: 10000, as wtml bench texture)")
    bs.add_argument("--workers", type=_number(1, 1024, int), default=None,
                    help="generation processes (default: the available cores)")
    bs.add_argument("--work", default="datasets/texture_scale",
                    help="the shards and the peer's features (kept for the next run)")
    bs.add_argument("--deadline-s", type=_number(1e-3, 1e7), default=None,
                    help="seconds from the start: a row estimated to end after them is "
                         "skipped, and none begins after them (default: none)")
    bs.add_argument("--oracle-draws", type=_number(100, 10**7, int), default=100_000,
                    help="draws of each oracle's prior")
    bs.add_argument("--out", default="runs/texture/scale",
                    help="report.md, summary.json and scale.png go here")
    bs.set_defaults(func=_bench_texture_scale)


# ------------------------------------------------------------------------------------------


def _pipeline(args: argparse.Namespace) -> int:
    from wtml.pipeline import run_all

    run_all(args.task, max_epochs=args.max_epochs, lanes=args.lanes)
    return 0


def _recording_options(group) -> None:
    """``wtml predict``'s options for instruments' recordings (the profile's keys)."""
    group.add_argument("--profile", default=None,
                       help="a YAML recording profile (keys: group, e_channel, i_channel, "
                            "e_scale, i_scale, full_scale_v, sample_rate_hz)")
    group.add_argument("--group", default=None, help="TDMS: the group of the two channels")
    group.add_argument("--e-channel", default=None,
                       help="the voltage's channel: TDMS channel or CSV column name, WAV "
                            "channel index (default: e, or WAV channel 0)")
    group.add_argument("--i-channel", default=None,
                       help="the current's channel (default: i, or WAV channel 1)")
    group.add_argument("--e-scale", type=SCALE, default=None,
                       help="V per recorded volt of e (default 1)")
    group.add_argument("--i-scale", type=SCALE, default=None,
                       help="A per recorded volt of i: the I-V converter's")
    group.add_argument("--full-scale-v", type=SCALE, default=None,
                       help="integer samples (WAV PCM, raw TDMS): the volts at full scale; "
                            "required for them, never assumed")
    group.add_argument("--sample-rate", type=RATE, default=None,
                       help="Hz, for a file without its own rate (a CSV of sample indices)")


class _Help(argparse.RawDescriptionHelpFormatter):
    """Each option's default in its help (unless the help already says it, or there is none
    to show); descriptions and epilogs keep their line breaks."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.required or action.default in (None, False,
                                                                        argparse.SUPPRESS):
            return text
        return f"{text} (default: %(default)s)"


def _bench_options(parser: argparse.ArgumentParser, task: str) -> None:
    """The options every ``wtml bench TASK`` has, with the pipeline's folders as defaults."""
    parser.add_argument("--data", default=f"datasets/{task}", help="dataset folder")
    parser.add_argument("--checkpoint", default=f"runs/{task}/checkpoints/last.ckpt",
                        help="the decoder's checkpoint")
    parser.add_argument("--model", default=f"export/{task}", help="the export folder")
    parser.add_argument("--out", default=None,
                        help=f"report.md, summary.json and plots go here (default: "
                             f"runs/{task}/bench, with --frontier runs/{task}/frontier)")
    parser.add_argument("--threads", type=THREADS, default=2,
                        help="torch and onnxruntime threads")
    _frontier_options(parser, every=False)


def _frontier_options(parser: argparse.ArgumentParser, *, every: bool) -> None:
    """The frontier's options (``wtml bench all``; ``wtml bench TASK --frontier``)."""
    if not every:
        parser.add_argument("--frontier", action="store_true",
                            help="instead: the task's speed-accuracy frontier (every method "
                                 "and decoder variant, onnxruntime's quantisations, the best "
                                 "method per latency budget, a Pareto plot)")
    parser.add_argument("--variants", default="configs/frontier.yaml",
                        help="the frontier's decoder variants: task -> variant -> training "
                             "config (each trained and exported where it is missing or stale)")
    parser.add_argument("--latency-repeats", type=_number(1, 10**6, int), default=2000,
                        help="frontier: calls at batch 1 per latency (each measurement stops "
                             "after 3 s)")
    parser.add_argument("--max-epochs", type=_number(1, 10**6, int), default=None,
                        help="frontier: override the variants' epochs (default: their configs')")


def build_parser() -> argparse.ArgumentParser:
    from wtml.runtime.predict import INPUT_FORMATS

    parser = _Parser(
        prog="wtml", formatter_class=_Help,
        description="Decoding a piezoelectric whisker transducer: physics, decoders, devices. "
                    "Training: python train.py fit --config configs/<task>.yaml")
    parser.add_argument("--version", action="version", version=f"wtml {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def verb(name: str, help: str, description: str | None = None, **kw):
        return sub.add_parser(name, help=help, formatter_class=_Help,
                              description=textwrap.fill(description or help, 88), **kw)

    walk = verb("walkthrough", "simulate the thesis's calibration of the macro WT (Tables 4.3-4.4)",
                "Least-squares calibration of the macro WT (lumped preset) at 36 Hz with the "
                "82x1x0.3 mm steel cantilever at 71-81 mm, validated at 70-80 mm.")
    walk.add_argument("--frequency", type=float, default=36.0,
                      help="excitation frequency, Hz")
    walk.add_argument("--noise", type=float, default=2e-4,
                      help="relative std of one Ze measurement (2e-4 = 0.02 %%)")
    walk.add_argument("--repeats", type=int, default=5,
                      help="measurements averaged per load (5, as in the thesis)")
    walk.add_argument("--seed", type=int, default=0,
                      help="seed of the noise")
    walk.add_argument("--plot", metavar="PNG", default=None,
                      help="also save a plot of Zm and the errors here")
    walk.set_defaults(func=_walkthrough)

    cal = verb("calibrate", "a device's T from its own measured loads (least squares)",
               "The least-squares calibration of physics.md §4 on measured loads: T(ω) at the "
               "loads' frequencies from the calibration loads, its Zm error on the validation "
               "loads, and the device model's T against it; stored beside the device file as "
               "<name>.calibration.npz (what wtml predict --calibration reads) and .json.")
    cal.add_argument("--device", required=True, help="the device (a shipped name or a file)")
    cal.add_argument("--loads", required=True,
                     help="CSV: frequency_hz, load, validation (0/1), zm_re, zm_im (N s/m), "
                          "ze_re, ze_im (ohm); one row per load and frequency")
    cal.add_argument("--out", default=None,
                     help="folder for the calibration (default: the device file's)")
    cal.add_argument("--hue0", type=float, default=None, metavar="M_PER_V",
                     help="the measured HUE(0), the tip's static displacement per volt (m/V), "
                          "stored with T: an onset scene on this calibration needs it")
    cal.set_defaults(func=_calibrate)

    pre = verb("presets", "the beam presets against the thesis (fidelity table)")
    pre.set_defaults(func=_presets)

    dev = verb("device", "device files: the shipped ones, and what a device file builds",
               "A device file (configs/devices/<name>.yaml, or your own) describes a "
               "transducer; a scene's `device:` names it. `list` shows the shipped ones, "
               "`show` builds one and prints its identity and resonances.")
    dev_sub = dev.add_subparsers(dest="action", metavar="ACTION", required=True)
    dev_sub.add_parser("list", help="the shipped device files", formatter_class=_Help
                       ).set_defaults(func=_device)
    show = dev_sub.add_parser("show", help="one device: identity, resonances",
                              formatter_class=_Help)
    show.add_argument("device", help="a shipped name (micro) or a device file's path")
    show.set_defaults(func=_device)
    dfit = dev_sub.add_parser(
        "fit", help="fit a device file to measurements: a new device file", formatter_class=_Help,
        description=textwrap.fill(
            "Least squares of the device's free parameters (its identify.free block, or "
            "--free) on log|Ze| and phase of the measured sweeps (and HUE(0), tip velocity, "
            "contacts at known places), each parameter's standard error, the resonances "
            "measured against fitted (and a rational fit's poles); refused, naming the "
            "parameter, where a standard error exceeds its range.", 88))
    dfit.add_argument("--device", required=True, help="the starting device (name or file)")
    dfit.add_argument("--sweep", required=True,
                      help="Ze with the tip free: .csv (frequency_hz, re_ohm, im_ohm or "
                           "magnitude_ohm, phase_deg) or Touchstone .s1p")
    dfit.add_argument("--clamped", default=None, help="Ze with the tip clamped (same formats)")
    dfit.add_argument("--contact", action="append", metavar="MM:FILE[:K]",
                      help="Ze with a pin MM mm from the tip (rigid, or K N/m); repeat")
    dfit.add_argument("--hue0", type=float, default=None,
                      help="static tip displacement per volt, m/V")
    dfit.add_argument("--loads", default=None, metavar="CSV",
                      help="Ze under tip loads of known Zm: wtml calibrate's loads file (every "
                           "load, calibration and validation, fitted at --sigma)")
    dfit.add_argument("--tip-velocity", default=None,
                      help="tip velocity per volt: .csv (frequency_hz, re, im in m/s/V)")
    dfit.add_argument("--sigma", type=float, default=1e-3,
                      help="relative uncertainty of each Ze point")
    dfit.add_argument("--free", action="append", metavar="NAME=LOW:HIGH",
                      help="a free parameter and its factor range (overrides the file's)")
    dfit.add_argument("--name", default=None, help="the fitted device's name")
    dfit.add_argument("--out", required=True, help="the fitted device file (.yaml)")
    dfit.add_argument("--plot", default=None, help="Bode plot, measured against fitted (PNG)")
    dfit.add_argument("--report", default=None, help="the fit's report (JSON)")
    dfit.set_defaults(func=_device)

    fid = verb("fidelity", "every reproduction of a thesis number in one report",
               "The presets' resonances, the calibration walkthrough's errors (Tables "
               "4.3-4.4), glycerol-water against Tables 6.1-6.2, the onset slice's Figure "
               "5.22 (the thesis's pipeline), and texture: the friction law fitted to Table "
               "4.10, the RMS tip speeds, |F| and |V| against grain size, Zm, and the "
               "kinetic-signature table (spectral peaks beside v/d and the modes).")
    fid.add_argument("--texture", default="configs/scenes/texture.yaml",
                     help="the texture scene whose friction law is reported")
    fid.add_argument("--onset", default="configs/scenes/onset.yaml",
                     help="the onset scene of Figure 5.22")
    fid.set_defaults(func=_fidelity)

    gen = verb("generate", "simulate a scene into dataset shards (resumable)",
               "Simulate a scene into checksummed shards. Re-running skips complete shards, "
               "remakes damaged ones and removes what an interrupted run left behind. A folder "
               "holds one scene's shards (its scene.json): generating another scene into it "
               "is refused.")
    gen.add_argument("--config", required=True, help="scene YAML, e.g. configs/scenes/fluid.yaml")
    gen.add_argument("--out", required=True, help="dataset folder, e.g. datasets/fluid")
    gen.add_argument("--shards", metavar="N", default=None,
                     help="number of shards (default: the scene's 'shards')")
    gen.add_argument("--shard", metavar="K", default=None,
                     help="make only this shard index, for parallel jobs (then one run "
                          "without --shard completes the manifest)")
    gen.add_argument("--quiet", action="store_true", help="no progress bar")
    gen.set_defaults(func=_generate)

    ev = verb("evaluate", "a checkpoint's accuracy on its dataset's test shard, beside the "
                          "classical path (fluid: by viscosity decade; radial: by range of d)")
    ev.add_argument("--checkpoint", required=True, help="a last.ckpt of python train.py fit")
    ev.add_argument("--data", required=True, help="its dataset folder (the test shard is used)")
    ev.set_defaults(func=_evaluate)

    ex = verb("export", "checkpoint -> model.onnx (decoder) and classical.onnx, with the "
                        "trained domain inside both graphs")
    ex.add_argument("--checkpoint", required=True, help="a last.ckpt of python train.py fit")
    ex.add_argument("--out", required=True, help="folder, e.g. export/fluid")
    ex.set_defaults(func=_export)

    pr = verb("predict", "run an export folder with onnxruntime on measured data (any task)",
              "Decoder and classical path side by side, one row per measurement, with "
              "in_domain (1: inside the trained domain), domain_score (<= 1 inside) and the "
              "flags of each doubtful answer; a warning counts the rows out of domain.",
              epilog=INPUT_FORMATS)
    pr.add_argument("--model", required=True, help="an export folder (model.onnx and "
                                                   "classical.onnx), e.g. export/fluid")
    pr.add_argument("--input", required=True, help=".csv or .npz (formats below)")
    pr.add_argument("--calibration", default=None,
                    help="fluid, onset and texture: the device's calibration, .npz with "
                         "frequency_hz and t (its calibrated T there); onset also hue0 (m/V)")
    pr.add_argument("--reference", default=None,
                    help="radial exports: the free whisker's Ze of the device (.npz, below)")
    pr.add_argument("--device", default=None,
                    help="the device the measurements come from (a device file, or a shipped "
                         "name): refused unless the export was trained for it")
    pr.add_argument("--out", default=None,
                    help="write the rows as CSV here (default: print a table)")
    pr.add_argument("--threads", type=THREADS, default=None,
                    help="onnxruntime threads (default: every core this process may use, at "
                         "most $WTML_THREADS; N replaces that for this command); beside another "
                         "busy process, 1 keeps its speed where more wait on each other "
                         "(docs/frontier.md, 'Two threads beside a busy process')")
    rec = pr.add_argument_group(
        "recordings from instruments (onset, texture: .tdms, .wav, .csv)",
        "how to read an instrument's file: a YAML recording profile (--profile) with the keys "
        "below, each option overriding the profile's")
    _recording_options(rec)
    pr.set_defaults(func=_predict)

    st = verb("stream", "an onset export's streaming graph on a live acquisition (stdin)",
              "Reads interleaved little-endian float32 (e, i) sample pairs at the model's rate "
              "from standard input or a file, in fixed chunks, carries the graph's state across "
              "chunks and prints each contact as soon as it is decided: its onset, then its "
              "detachment; each line gives when the frame that decided it ended (decided_s, "
              "signal time) and the wall time from the arrival of the read that held it "
              "(latency_ms). The stream is read as records of the trained length one after "
              "the other, each from a fresh state: after each, a 'record' line gives the "
              "wall's location (gap_m; sigma_m: its 68 % half-width, sigma_95_m: its 95 % one), "
              "the domain flag, how far it and the record before locate the wall apart "
              "(apart_sigma, in their sigma) and whether that is over the export's limit "
              "(apart=1: a wall that moved; in_domain=0, as for a record after one out of "
              "its domain). The first record is held until the second ends and judged with "
              "it (its line then, decided_s the second's end), unless --first-alone. An export "
              "without that limit answers the first record only (exit 1); one whose graph's "
              "chunks do not make whole records is refused. The end of the input or Ctrl-C "
              "closes the open contact; a summary (real-time factor, per-chunk latency, "
              "records, the seconds after the last whole record, not answered) goes to "
              "stderr. Contacts are not capped (a stream is not a record).")
    st.add_argument("--model", required=True, help="an onset export folder (stream.onnx)")
    st.add_argument("--calibration", default=None,
                    help="the device's calibration: .npz with frequency_hz [the probe's], t "
                         "(1, 2, 2) and hue0 (m/V), as wtml predict takes")
    st.add_argument("--input", default="-", help="a file of float32 pairs, or - for stdin")
    st.add_argument("--chunk-samples", type=_number(1, 10**9, int), default=None,
                    help="sample pairs per read, a whole multiple of the graph's chunk "
                         "(default: the graph's chunk)")
    st.add_argument("--e-scale", type=SCALE, default=1.0, help="V per recorded unit of e")
    st.add_argument("--i-scale", type=SCALE, default=1.0,
                    help="A per recorded unit of i (the I-V converter's A per V)")
    st.add_argument("--sample-rate", type=RATE, default=None,
                    help="the acquisition's rate (Hz), checked against the model's")
    st.add_argument("--threads", type=THREADS, default=1, help="onnxruntime threads")
    st.add_argument("--first-alone", action="store_true",
                    help="print the first record's answer at its end, judged alone (a floor "
                         "that moves goes unseen in it), instead of one record later, judged "
                         "with the second")
    st.set_defaults(func=_stream)

    be = verb("bench", "speed and accuracy of every method of a task, side by side; the "
                       "device runtime's costs (bench runtime)")
    be_sub = be.add_subparsers(dest="task", metavar="TASK", required=True)
    bf = be_sub.add_parser("fluid", help="the fluid slice", formatter_class=_Help,
                           description="Every fluid method on the test shard: accuracy by "
                                       "viscosity decade, the Bayes posterior mean and the "
                                       "Cramér-Rao bound, latency and throughput; the "
                                       "device-spread table (nominal device, the whole spread, "
                                       "each parameter alone).")
    _bench_options(bf, "fluid")
    bf.add_argument("--device-records", type=COUNT, default=1000,
                    help="fresh records per row of the device-spread table")
    bf.set_defaults(func=_bench)

    br = be_sub.add_parser("radial", help="the radial slice", formatter_class=_Help,
                           description="Every radial method on the test shard: RMSE by range "
                                       "of d against the Cramér-Rao bound, latency and "
                                       "throughput, invalid contacts; a device-spread "
                                       "table with the spread-trained variant.")
    _bench_options(br, "radial")
    br.add_argument("--invalid", default="datasets/radial_invalid",
                    help="the invalid-contact dataset (thesis §5.5.4)")
    br.add_argument("--thesis-checkpoint", default="runs/radial_thesis/checkpoints/last.ckpt",
                    help="the thesis decoder's checkpoint")
    br.add_argument("--thesis-model", default="export/radial_thesis",
                    help="the thesis decoder's export folder")
    br.add_argument("--max-samples", type=_number(1, 10**8, int), default=10000,
                    help="benchmark the first this many test samples")
    br.add_argument("--spread-data", default="datasets/radial_spread",
                    help="the spread-trained decoder's dataset: its test shard is the "
                         "device-spread table's spread row")
    br.add_argument("--spread-model", default="export/radial_spread",
                    help="the spread-trained decoder's export folder (a column where it exists)")
    br.add_argument("--spread-scene", default="configs/scenes/radial_spread.yaml",
                    help="without --spread-data's folder, draw the spread's records from this "
                         "scene file")
    br.add_argument("--spread-samples", type=COUNT, default=2000,
                    help="fresh records per parameter-alone row of the device-spread table")
    br.set_defaults(func=_bench_radial)

    bo = be_sub.add_parser("onset", help="the contact-onset slice", formatter_class=_Help,
                           description="Every onset method on the test shard: location error "
                                       "by range of g, onset/detachment time error, F1 at "
                                       "±1 ms, false contacts in free whisking, domain flag on "
                                       "untrained drives, Figure 5.22, latency, the streaming "
                                       "graph's delay; the transfer and device-spread "
                                       "tables; the modal convergence table and the "
                                       "simulator's speed.")
    _bench_options(bo, "onset")
    bo.add_argument("--free-records", type=COUNT, default=50,
                    help="records of 2 s of free whisking (no wall) for false contacts")
    bo.add_argument("--variant-records", type=COUNT, default=16,
                    help="records per untrained-drive variant for the domain flag")
    bo.add_argument("--repeats", type=_number(1, 10**4, int), default=3,
                    help="records per wall position of Figure 5.22 (15 positions)")
    bo.add_argument("--transfer-records", type=COUNT, default=32,
                    help="fresh records per row of the transfer table (each contact law alone, "
                         "the held-out one included; each acquisition effect alone)")
    bo.add_argument("--independent-records", type=COUNT, default=8,
                    help="records of the independent simulator (its row of the transfer "
                         "table; 0: none)")
    bo.add_argument("--device-records", type=COUNT, default=32,
                    help="fresh records per row of the device-spread table (the nominal device, "
                         "the trained spread, each class of issue 21's spread alone; 0: none)")
    bo.set_defaults(func=_bench_onset)

    bu = be_sub.add_parser("runtime", help="the device runtime: cold start, memory, latency, "
                           "installed size", formatter_class=_Help,
                           description="wtml predict on one onset record as a device runs it: "
                                       "cold start (wall time) and peak memory of the whole "
                                       "command in a lean runtime install (numpy, onnxruntime, "
                                       "pyyaml) and in the full install, beside the same "
                                       "command with the training stack imported first (what "
                                       "wtml predict cost before the runtime was split off); "
                                       "per-record latency of each graph; the streaming "
                                       "graph's per-chunk latency and real-time factor on one "
                                       "core; the installed size of each install.")
    bu.add_argument("--model", default="export/onset", help="an onset export folder")
    bu.add_argument("--out", default="runs/runtime_bench",
                    help="report.md, summary.json and the record go here")
    bu.add_argument("--records", type=_number(1, 10**4, int), default=64,
                    help="records for the per-record latency")
    bu.add_argument("--repeats", type=_number(1, 100, int), default=5,
                    help="cold starts of each command (the median is reported)")
    bu.add_argument("--runtime-venv", default=None,
                    help="the runtime install's venv: made (pip install of this checkout, no "
                         "extras) or reused (default: <out>/runtime-venv)")
    bu.set_defaults(func=_bench_runtime)

    bs = be_sub.add_parser("stability", help="every method at the extremes of its task",
                           formatter_class=_Help,
                           description="Every method of every exported task on fresh records "
                                       "at the extremes of its task: the middle of the trained "
                                       "domain, the ends of its ranges and beyond them, free and "
                                       "clamped tips, contacts far softer or stiffer than "
                                       "trained, near resonance: each method's error against "
                                       "its mid-domain error and the share its domain flag "
                                       "marks; and the classical path in float32 (its ONNX "
                                       "graph) against float64 (numpy) on the same inputs.")
    bs.add_argument("--models", default="export",
                    help="the folder holding each task's export (<models>/<task>)")
    bs.add_argument("--out", default="runs/stability",
                    help="report.md and summary.json go here")
    bs.add_argument("--records", type=_number(2, 10**6, int), default=48,
                    help="fresh records per condition")
    bs.add_argument("--seed", type=_number(0, 2**32 - 1, int), default=2025,
                    help="seed of the conditions' records")
    bs.add_argument("--task", dest="tasks", choices=list(TASKS), action="append",
                    default=None,
                    help="a task to run (repeat; default every task with an export)")
    bs.add_argument("--threads", type=THREADS, default=2, help="onnxruntime threads")
    bs.set_defaults(func=_bench_stability)

    bm = be_sub.add_parser("models", help="what each scene models and what that costs",
                           formatter_class=_Help,
                           description="Per scene, the cheaper models it could use against "
                                       "its own: radial's 2x2 path against the beam path (speed, "
                                       "the Ze it gives, the decoder's and the polynomial's "
                                       "error); onset's and texture's modal orders 1, 3, 6, 14 "
                                       "(truncation error over the scene's band, simulator "
                                       "time per second of signal, the current's difference, "
                                       "the shipped decoder's error on each order's records); "
                                       "and what n_modes: auto picks for each scene.")
    bm.add_argument("--models", default="export",
                    help="the folder holding each task's export (<models>/<task>)")
    bm.add_argument("--out", default="runs/models", help="report.md and summary.json go here")
    bm.add_argument("--records", type=_number(5, 10**5, int), default=32,
                    help="onset and texture records per modal order")
    bm.add_argument("--radial-records", type=_number(10, 10**7, int), default=2000,
                    help="radial contacts for the beam and 2x2 paths")
    bm.add_argument("--threads", type=THREADS, default=2, help="onnxruntime threads")
    bm.set_defaults(func=_bench_models)

    bd = be_sub.add_parser("device", help="what fitting one's own device costs the radial, "
                           "onset and fluid decoders", formatter_class=_Help,
                           description="A hidden true device is measured (simulated) and "
                                       "fitted (radial and onset: a beam near --start, with "
                                       "wtml device fit's least squares; fluid: the lumped "
                                       "fluid device and its sphere, wtml.physics."
                                       "identify_lumped), and each task's decoder trained on "
                                       "the fitted device is tested on the true device's "
                                       "records, beside one trained on the true device, the "
                                       "spread-trained decoder and the classical path, per "
                                       "measurement noise and measurement set.")
    bd.add_argument("--start", default="micro", help="the device the fit starts from")
    bd.add_argument("--out", default="runs/device_bench",
                    help="report.md, summary.json, datasets and runs go here")
    bd.add_argument("--task", choices=("radial", "onset", "fluid"), action="append",
                    default=None, help="the tasks (repeat; default all three)")
    bd.add_argument("--samples", type=COUNT, default=60000, help="radial samples per dataset")
    bd.add_argument("--epochs", type=_number(2, 1000, int), default=14,
                    help="epochs per radial decoder")
    bd.add_argument("--test-records", type=COUNT, default=2000,
                    help="radial records of the true device to test on")
    bd.add_argument("--onset-samples", type=COUNT, default=384, help="onset records per dataset")
    bd.add_argument("--onset-epochs", type=_number(2, 1000, int), default=60,
                    help="epochs per onset decoder")
    bd.add_argument("--onset-test-records", type=COUNT, default=64,
                    help="onset records of the true device to test on")
    bd.add_argument("--fluid-samples", type=COUNT, default=24000,
                    help="fluid samples per dataset")
    bd.add_argument("--fluid-epochs", type=_number(2, 1000, int), default=60,
                    help="epochs per fluid decoder")
    bd.add_argument("--fluid-test-records", type=COUNT, default=4000,
                    help="fluid records of the true device to test on")
    bd.add_argument("--noise", type=_number(1e-7, 0.1, float), action="append",
                    default=None, help="relative noise of the radial rows' sweeps (repeat; "
                                       "default 1e-3, 1e-4 and 1e-5; the onset rows fit a "
                                       "sweep alone and with HUE(0) and pins at 1e-4, the "
                                       "fluid rows at 1e-3 and 1e-4)")
    bd.add_argument("--repeats", type=_number(1, 100, int), default=3,
                    help="draws of the radial measurements per set and noise (onset: one)")
    bd.add_argument("--threads", type=_number(1, 1024, int), default=2,
                    help="torch threads")
    bd.set_defaults(func=_bench_device)

    bt = be_sub.add_parser("texture", help="the texture slice", formatter_class=_Help,
                           description="Every texture method on held-out specimens: accuracy "
                                       "and confusion (decoder, thesis cues, MiniRocket, "
                                       "kinetic signature, the amplitude oracle), accuracy "
                                       "against window length and each nuisance, grain size "
                                       "on unseen FEPA grades, the cue ablation, the transfer "
                                       "table (held-out physics), the device-spread table "
                                       "(nominal device, the trained spread, each class of "
                                       "parameter alone), latency.")
    bt.add_argument("--data", default="datasets/texture", help="the thesis grades' dataset")
    bt.add_argument("--fepa", default="datasets/texture_fepa",
                    help="the unseen FEPA grades' dataset (configs/scenes/texture_fepa.yaml)")
    bt.add_argument("--checkpoint", default="runs/texture/checkpoints/last.ckpt",
                    help="the decoder's checkpoint (its graph at other window lengths)")
    bt.add_argument("--model", default="export/texture", help="the export folder")
    bt.add_argument("--out", default=None,
                    help="report.md, summary.json and plots go here (default: "
                         "runs/texture/bench, with --frontier runs/texture/frontier)")
    bt.add_argument("--threads", type=THREADS, default=2,
                    help="frontier: torch and onnxruntime threads")
    _frontier_options(bt, every=False)
    bt.add_argument("--peer-kernels", type=_number(84, 10**6, int), default=10000,
                    help="MiniRocket's kernels")
    bt.add_argument("--ablation-records", type=COUNT, default=40,
                    help="fresh records per ablation variant")
    bt.add_argument("--transfer-records", type=COUNT, default=24,
                    help="fresh records per row of the transfer table (each friction law "
                         "alone, the held-out one included; each acquisition effect alone)")
    bt.add_argument("--device-records", type=COUNT, default=24,
                    help="fresh records per row of the device-spread table")
    bt.add_argument("--no-fresh-minirocket", dest="fresh_minirocket", action="store_false",
                    help="MiniRocket on the test shard only, not on the transfer and device "
                         "rows (there it takes twice the other methods' time together; the "
                         "main job's small tables; by default on every table)")
    bt.set_defaults(func=_bench_texture)
    _texture_rate_parser(be_sub)
    _texture_scale_parser(be_sub)
    _coverage_parser(be_sub)

    ba = be_sub.add_parser("all", help="every task's speed-accuracy frontier, one report",
                           formatter_class=_Help,
                           description="For every task: its decoder variants (tiny, default, "
                                       "large: --variants), onnxruntime's int8 (dynamic, "
                                       "static) and float16 quantisations of each, the "
                                       "classical path, the peers and the best achievable, on "
                                       "the same held-out data in one run: the task's metric "
                                       "with its interval, p50 latency at batch 1, throughput, "
                                       "model size, the ONNX session's memory; per budget of "
                                       "10 us, 100 us, 1 ms and 10 ms (per sample, or per "
                                       "second of signal) the most accurate method; a Pareto "
                                       "plot per task. Needs the main job's datasets.")
    ba.add_argument("--out", default=None,
                    help="report.md, summary.json, plots and the variants' exports (default: "
                         "runs/frontier)")
    ba.add_argument("--only", choices=list(TASKS), action="append", default=None,
                    help="these tasks only (repeat; default: all)")
    ba.add_argument("--threads", type=THREADS, default=2, help="torch and onnxruntime threads")
    _frontier_options(ba, every=True)
    ba.set_defaults(func=_frontier)

    pl = verb("pipeline", "the main job: generate, train, export, predict, bench, summary")
    pl.add_argument("task", nargs="?", choices=["all", *TASKS],
                    default="all",
                    help="which slice")
    pl.add_argument("--max-epochs", type=_number(1, 10**6, int), default=None,
                    help="override the training configs' epochs (default: the configs')")
    pl.add_argument("--lanes", type=_number(1, 64, int), default=2,
                    help="slices run side by side, one thread each of the cores, after a "
                         "warm-up in one lane that compiles their JIT kernels and generates "
                         "the datasets only one slice reads (default 2; 1: one after another "
                         "on every core, printing as they go)")
    pl.set_defaults(func=_pipeline)
    return parser


def _is_a_check(err: BaseException) -> bool:
    """Whether ``err`` is bad input rather than a bug: an :class:`OSError` (a file that
    cannot be opened or written), or a :class:`ValueError` raised by wtml's own code (its
    checks: FileError, SchemaError, InputError, ...). A ValueError raised inside a library
    (numpy, onnxruntime, torch) is input that wtml failed to check: a bug, whose traceback is
    kept."""
    if isinstance(err, OSError) or type(err).__module__.split(".")[0] == "wtml":
        return True
    if not isinstance(err, ValueError):
        return False
    tb, last = err.__traceback__, None
    while tb is not None:
        last, tb = tb.tb_frame.f_code.co_filename, tb.tb_next
    return last is not None and Path(last).resolve().is_relative_to(PACKAGE)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except ModuleNotFoundError as err:
        if (err.name or "").split(".")[0] not in TRAINING_STACK:
            raise
        print(f"wtml {args.command}: error: needs {err.name}, which this install lacks (pip "
              f"install wtml brings the device runtime only: predict, stream); pip install "
              f"'wtml[train]' for the whole stack", file=sys.stderr)
        return 2
    except (ValueError, OSError) as err:
        if not _is_a_check(err):
            raise
        # bad input: one line that says what, not a traceback
        text = " ".join(str(err).split()) or type(err).__name__
        print(f"wtml {args.command}: error: {text}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
