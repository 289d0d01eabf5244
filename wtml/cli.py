"""The ``wtml`` console script.

Subcommands: ``walkthrough`` (the thesis's calibration), ``generate``, ``evaluate``,
``export``, ``predict``, ``bench fluid`` and ``pipeline`` (all of them in a row).
Training runs through LightningCLI: ``python train.py fit --config configs/fluid.yaml``.
"""

from __future__ import annotations

import argparse
import csv
import sys

from wtml import __version__


def _walkthrough(args: argparse.Namespace) -> int:
    from wtml.walkthrough import format_report, plot_walkthrough, run_walkthrough

    result = run_walkthrough(frequency_hz=args.frequency, noise=args.noise,
                             repeats=args.repeats, seed=args.seed)
    print(format_report(result, noise=args.noise, repeats=args.repeats))
    if args.plot:
        plot_walkthrough(result, args.plot)
        print(f"plot: {args.plot}")
    return 0


def _presets(args: argparse.Namespace) -> int:
    from wtml.physics.beam_presets import fidelity_table, format_fidelity

    print(format_fidelity(fidelity_table()))
    return 0


def _generate(args: argparse.Namespace) -> int:
    from wtml.data import generate
    from wtml.scenes import load_scene

    m = generate(load_scene(args.config), args.out, shards=args.shards, shard=args.shard,
                 progress=not args.quiet)
    state = "complete" if m["complete"] else f"{len(m['shards'])}/{m['n_shards']} shards"
    print(f"{args.out}: {m['samples']} samples, {m['n_shards']} shards, {state}, "
          f"scene {m['scene_hash'][:12]}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from wtml.baselines import ClassicalFluid
    from wtml.bench.accuracy import by_decade, format_decades, relative_errors
    from wtml.data import dataset_scene, load_shards, read_manifest
    from wtml.data.datamodule import split_shards
    from wtml.decoders.fluid import TorchFluid, load_fluid_net

    manifest = read_manifest(args.data)
    data = load_shards(args.data, split_shards(manifest["n_shards"], 1, 1)["test"])
    scene = dataset_scene(args.data)
    net, _ = load_fluid_net(args.checkpoint)
    for p in (TorchFluid(net), ClassicalFluid(scene.calibrated_t(), scene.excitation.omega,
                                              scene.sphere.radius)):
        err = relative_errors(p.predict(data["ze"]), data["eta"], data["rho"])
        print(format_decades(f"{p.name} on the test shard of {args.data}",
                             by_decade(err, data["eta"])) + "\n")
    return 0


def _export(args: argparse.Namespace) -> int:
    from wtml.runtime.export import export_model

    for kind, path in export_model(args.checkpoint, args.out).items():
        print(f"{kind}: {path}")
    return 0


def _predict(args: argparse.Namespace) -> int:
    from wtml.pipeline import format_predictions
    from wtml.runtime.predict import predict_file

    rows = predict_file(args.model, args.input)
    if args.out:
        with open(args.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"{len(rows)} predictions written to {args.out}")
    else:
        print(format_predictions(rows))
    return 0


def _bench(args: argparse.Namespace) -> int:
    from wtml.bench.fluid import run_bench

    print(run_bench(args.data, args.checkpoint, args.model, args.out, threads=args.threads))
    return 0


def _bench_radial(args: argparse.Namespace) -> int:
    from wtml.bench.radial import run_bench

    print(run_bench(args.data, args.checkpoint, args.thesis_checkpoint, args.model,
                    args.thesis_model, args.out, invalid_dir=args.invalid,
                    threads=args.threads, max_samples=args.max_samples))
    return 0


def _pipeline(args: argparse.Namespace) -> int:
    from wtml.pipeline import run_pipeline, run_radial

    if args.task in ("fluid", "all"):
        run_pipeline(max_epochs=args.max_epochs)
    if args.task in ("radial", "all"):
        run_radial(max_epochs=args.max_epochs)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wtml",
        description="Decoding a piezoelectric whisker transducer: physics, decoders, devices.")
    parser.add_argument("--version", action="version", version=f"wtml {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    walk = sub.add_parser(
        "walkthrough",
        help="simulate the thesis's calibration of the macro WT and print Table 4.3/4.4",
        description="Least-squares calibration of the macro WT (lumped preset) at 36 Hz with "
                    "the 82x1x0.3 mm steel cantilever at 71-81 mm, validated at 70-80 mm.")
    walk.add_argument("--frequency", type=float, default=36.0, help="Hz (default 36)")
    walk.add_argument("--noise", type=float, default=2e-4,
                      help="relative std of one Ze measurement (default 2e-4 = 0.02%%)")
    walk.add_argument("--repeats", type=int, default=5,
                      help="measurements averaged per load (default 5, as in the thesis)")
    walk.add_argument("--seed", type=int, default=0)
    walk.add_argument("--plot", metavar="PNG", help="also save a plot of Zm and errors here")
    walk.set_defaults(func=_walkthrough)

    pre = sub.add_parser("presets", help="the beam presets against the thesis (fidelity table)")
    pre.set_defaults(func=_presets)

    gen = sub.add_parser("generate", help="simulate a scene into dataset shards (resumable)")
    gen.add_argument("--config", required=True, help="scene YAML, e.g. configs/scenes/fluid.yaml")
    gen.add_argument("--out", required=True, help="dataset folder, e.g. datasets/fluid")
    gen.add_argument("--shards", type=int, help="number of shards (default: the scene's)")
    gen.add_argument("--shard", type=int, help="make only this shard (parallel jobs)")
    gen.add_argument("--quiet", action="store_true", help="no progress bar")
    gen.set_defaults(func=_generate)

    ev = sub.add_parser("evaluate", help="accuracy by viscosity decade, decoder vs classical")
    ev.add_argument("--checkpoint", required=True)
    ev.add_argument("--data", required=True, help="dataset folder (its test shard is used)")
    ev.set_defaults(func=_evaluate)

    ex = sub.add_parser("export", help="checkpoint -> model.onnx and classical.onnx")
    ex.add_argument("--checkpoint", required=True)
    ex.add_argument("--out", required=True, help="folder, e.g. export/fluid")
    ex.set_defaults(func=_export)

    pr = sub.add_parser("predict", help="η and ρ from measured Ze (or e(t), i(t)) with ONNX")
    pr.add_argument("--model", required=True, help="an export folder")
    pr.add_argument("--input", required=True, help=".npz or .csv (see wtml.runtime.predict)")
    pr.add_argument("--out", help="write a CSV here instead of printing")
    pr.set_defaults(func=_predict)

    be = sub.add_parser("bench", help="speed and accuracy of every method, side by side")
    be_sub = be.add_subparsers(dest="task", metavar="TASK", required=True)
    bf = be_sub.add_parser("fluid", help="the fluid slice")
    bf.add_argument("--data", default="datasets/fluid")
    bf.add_argument("--checkpoint", default="runs/fluid/checkpoints/last.ckpt")
    bf.add_argument("--model", default="export/fluid")
    bf.add_argument("--out", default="runs/fluid/bench")
    bf.add_argument("--threads", type=int, default=2)
    bf.set_defaults(func=_bench)

    br = be_sub.add_parser("radial", help="the radial slice")
    br.add_argument("--data", default="datasets/radial")
    br.add_argument("--invalid", default="datasets/radial_invalid",
                    help="the invalid-contact dataset (thesis §5.5.4)")
    br.add_argument("--checkpoint", default="runs/radial/checkpoints/last.ckpt")
    br.add_argument("--thesis-checkpoint", default="runs/radial_thesis/checkpoints/last.ckpt")
    br.add_argument("--model", default="export/radial")
    br.add_argument("--thesis-model", default="export/radial_thesis")
    br.add_argument("--out", default="runs/radial/bench")
    br.add_argument("--threads", type=int, default=2)
    br.add_argument("--max-samples", type=int, default=10000,
                    help="benchmark the first this many test samples (the physics inversion "
                         "runs ~900 samples/s)")
    br.set_defaults(func=_bench_radial)

    pl = sub.add_parser("pipeline", help="the main job: generate, train, export, predict, bench")
    pl.add_argument("task", nargs="?", choices=["all", "fluid", "radial"], default="all",
                    help="which slice (default: both)")
    pl.add_argument("--max-epochs", type=int, help="override the training configs' epochs")
    pl.set_defaults(func=_pipeline)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as err:  # bad input: say what, not a traceback
        print(f"wtml {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
