"""The ``wtml`` console script. Subcommands grow with the decoding tasks."""

from __future__ import annotations

import argparse
import sys

from wtml import __version__


def _walkthrough(args: argparse.Namespace) -> int:
    from wtml.walkthrough import format_report, run_walkthrough

    result = run_walkthrough(frequency_hz=args.frequency, noise=args.noise,
                             repeats=args.repeats, seed=args.seed)
    print(format_report(result, noise=args.noise, repeats=args.repeats))
    if args.plot:
        from wtml.walkthrough import plot_walkthrough

        plot_walkthrough(result, args.plot)
        print(f"plot: {args.plot}")
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
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except ValueError as err:  # bad input: say what, not a traceback
        print(f"wtml {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
