"""``fabkit calibrate SAMPLES.csv --out material.toml``: a material table from samples."""

from __future__ import annotations

import argparse

from fabkit.commands import add_command


def _names(text: str) -> tuple[str, ...]:
    """A comma-separated list of names (argparse type)."""
    return tuple(name.strip() for name in text.split(",") if name.strip())


def _numbers(text: str) -> tuple[float, ...]:
    """A comma-separated list of numbers (argparse type)."""
    try:
        return tuple(float(value) for value in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 0 or 0,0, got {text!r}") from None


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "calibrate")
    parser.add_argument(
        "samples",
        help="CSV, one row per sample: a column per feature and per stimulus, lambda1, "
        "lambda2, optionally lambda1_sd, lambda2_sd (docs/calibrate.md)",
    )
    parser.add_argument("--out", required=True, help="the material table to write (.toml)")
    parser.add_argument(
        "--spec",
        help="a spec whose [material] names the features and stimuli and whose surfaces[0] "
        "gives the flat stimulus; it is validated with the table, and the report says "
        "where its stimuli and initial eps lie against the samples",
    )
    parser.add_argument(
        "--features", type=_names, help="the feature columns, comma-separated (e.g. eps)"
    )
    parser.add_argument(
        "--stimuli", type=_names, help="the stimulus columns, comma-separated (e.g. L)"
    )
    parser.add_argument(
        "--flat",
        type=_numbers,
        help="the stimulus at which the sheet is made, one value per stimulus (lambda1 = "
        "lambda2 = 1 there; default: the spec's surfaces[0], else 0)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.calibrate import calibrate, report_lines

    calibration = calibrate(
        args.samples,
        args.out,
        features=args.features,
        stimuli=args.stimuli,
        spec_path=args.spec,
        flat=args.flat,
    )
    print("\n".join(report_lines(calibration)))
    print(f"wrote {args.out}")
    return 0
