"""Which part of a print's error moves its sheet off a target: the layers' mean or their
difference, the director or the features.

Run from the repository root on the output folder of a ``fabkit run`` that printed a
layered G-code (``design.npz`` and ``sheet.gcode``)::

    fabkit run examples/three_shapes.toml --out /tmp/fig3
    python benchmarks/print_error.py /tmp/fig3

The layers are read back as ``fabkit verify`` reads them, and each layer's error (its
read-back director and features less its designed ones) split into the layers' mean and
each layer's difference from it. The sheet is then judged as a run judges the sheet as
fabricated (every start, half of them with the error turned over) with the designed
layers plus a part of the error, one line per part:

* ``none``: the sheet as designed (on the printed mesh);
* ``mean``, ``difference``: the layers' mean error, or their differences from it only;
* ``mean director``, ``mean features``: the mean error of one kind only;
* ``difference director``, ``difference features``: the differences of one kind only;
* ``all``: the whole error (the run's verdict as fabricated).

A difference between the layers is a natural curvature the design did not ask for (it
bends the sheet and may choose its side); the mean is a metric error. Per target: formed
(+) or not (-) from every start, and the RMS range over the starts (% of the patch
diameter).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fabkit.field.flat import director_angle
from fabkit.mechanics.fabricated import SheetFields, design_fields
from fabkit.mechanics.verdict import embedded_targets, target_shapes
from fabkit.verify.machine_file import VerifyOptions, read_back

PARTS = {
    "none": (0, 0, 0, 0),
    "mean": (1, 0, 1, 0),
    "difference": (0, 1, 0, 1),
    "mean director": (1, 0, 0, 0),
    "mean features": (0, 0, 1, 0),
    "difference director": (0, 1, 0, 0),
    "difference features": (0, 0, 0, 1),
    "all": (1, 1, 1, 1),
}
"""Which parts of the error each line adds: (director mean, director difference,
features mean, features difference), each 0 or 1."""


def with_error(
    own: list[SheetFields], made: list[SheetFields], weights: tuple[int, int, int, int]
) -> list[SheetFields]:
    """The designed layers ``own`` plus the parts of the read-back layers' (``made``) error
    that ``weights`` names (:data:`PARTS`)."""

    def split(errors: list[np.ndarray], k: int, mean_w: int, diff_w: int) -> np.ndarray:
        mean = np.mean(errors, axis=0)
        return mean_w * mean + diff_w * (errors[k] - mean)

    pairs = list(zip(made, own, strict=True))

    def layer(k: int) -> SheetFields:
        def theta(points: np.ndarray) -> np.ndarray:
            errors = [director_angle(m.theta(points) - o.theta(points)) for m, o in pairs]
            return own[k].theta(points) + split(errors, k, weights[0], weights[1])

        def features(points: np.ndarray) -> np.ndarray:
            errors = [m.features(points) - o.features(points) for m, o in pairs]
            return own[k].features(points) + split(errors, k, weights[2], weights[3])

        return SheetFields(theta, features, made[0].made)

    return [layer(k) for k in range(len(own))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a fabkit run's output folder")
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=list(PARTS))
    args = parser.parse_args()
    options = VerifyOptions()
    reading = read_back(args.out / "design.npz", args.out / "sheet.gcode", options)
    design, made = reading.design, reading.fields(options)
    if design.layering is None or len(made) < 2:
        raise SystemExit("print_error: the run printed one layer: there is no difference to split")
    own = [design_fields(design.layer(k)) for k in range(design.layers)]
    own = [SheetFields(o.theta, o.features, made[0].made) for o in own]
    scale = float(reading.flat.mm_per_unit)
    print(f"{args.out}: {len(made)} layers read back; per target: formed from every start, RMS")
    for name in args.parts:
        started = time.perf_counter()
        shapes = target_shapes(
            design,
            with_error(own, made, PARTS[name]),
            embedded_targets(design),
            reading.thickness_mm / scale,
            part=reading.flat.part,
            mm_per_unit=scale,
            designed=own,
        )
        figures = "; ".join(_figure(shape) for shape in shapes)
        print(f"{name:>21}: {figures} ({time.perf_counter() - started:.0f} s)", flush=True)


def _figure(shape) -> str:
    rms = [100 * end.rms for end in shape.starts]
    return f"{shape.target} {'+' if shape.formed else '-'} {min(rms):.2f}-{max(rms):.2f} %"


if __name__ == "__main__":
    main()
