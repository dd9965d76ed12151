"""Forming benchmark: which targets the sheet as fabricated forms, from every start, by size.

Run from the repository root: ``python benchmarks/forming.py`` (about 30 minutes on a
2-core machine; ``--sizes``, ``--specs``, ``--layers`` change the grid). For every
example spec that prints and every size it runs ``fabkit run SPEC --size S`` with no
layer option, as issue 35's acceptance asks (the run chooses its layers; ``--layers K``
passes one on; ``--refine`` refines them against the simulation, minutes a run;
``--prints K`` judges K prints, the lines shifted, each target its worst print), on the
README's route (marlin_diw_pneumatic, verified from the G-code),
and prints, per target, how many
of the six starts (``fabkit.mechanics.simulate.STARTS``) form it as fabricated, the
worst RMS (% of the patch diameter) and why the others miss it (M: the mirror image, N:
not converged, F: farther than the limit); then the run's wall time, and with ``--refine``
the verdict on every print it judged in memory. The table is the
one in docs/layers.md. Exit code 1 if a run fails (a target not formed is a figure, not
a failure: issue 35 is open).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SPECS = ("two_shapes.toml", "three_shapes.toml", "ball_hypar.toml", "bowl_saddle_trough.toml")
"""The example specs that print (examples/README.md)."""


def run(
    spec: str, size: float, layers: int | None, refine: bool, folder: Path, prints: int = 1
) -> tuple[dict, float]:
    """``fabkit run`` of one spec at one size (``layers`` None: no layer option; ``refine``:
    with ``--refine``; ``prints``: ``--prints``); its report.json and wall time (s)."""
    out = folder / f"{Path(spec).stem}-{size:g}-{layers}"
    command = [sys.executable, "-m", "fabkit", "run", spec, "--size", f"{size:g}", "--out"]
    command += [str(out), "--overwrite", *(("--layers", str(layers)) if layers else ())]
    command += ["--refine"] if refine else []
    command += ["--prints", str(prints)] if prints > 1 else []
    started = time.monotonic()
    subprocess.run(command, check=True, capture_output=True, cwd=ROOT)
    return json.loads((out / "report.json").read_text()), time.monotonic() - started


def cell(target: dict) -> str:
    """``6/6 0.74 %`` or ``4/6 1.25 % M2`` (2 starts end as the mirror image)."""
    starts = target["starts"]
    formed = sum(s["formed"] for s in starts)
    why = {
        "M": sum(s["mirror_image"] for s in starts),
        "N": sum(not s["converged"] and not s["mirror_image"] for s in starts),
        "F": sum(s["converged"] and not s["mirror_image"] and not s["formed"] for s in starts),
    }
    reasons = "".join(f" {k}{v}" for k, v in why.items() if v)
    return f"{formed}/{len(starts)} {target['rms_pct']:.2f} %{reasons}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--specs", nargs="+", default=list(SPECS))
    parser.add_argument("--sizes", nargs="+", type=float, default=[40, 50, 60, 70, 80])
    parser.add_argument("--layers", type=int, default=None)
    parser.add_argument("--refine", action="store_true", help="fabkit run --refine")
    parser.add_argument("--prints", type=int, default=1, help="fabkit run --prints")
    args = parser.parse_args()
    option = f" --layers {args.layers}" if args.layers else ""
    option += " --refine" if args.refine else ""
    option += f" --prints {args.prints}" if args.prints > 1 else ""
    print(
        f"fabkit run SPEC --size S{option}: the sheet as fabricated, per "
        "target: starts formed of 6, worst RMS (% of the patch diameter), M mirror image, "
        "N not converged, F farther than the limit"
    )
    with tempfile.TemporaryDirectory() as folder:
        for spec in args.specs:
            for size in args.sizes:
                try:
                    example = f"examples/{spec}"
                    figures, seconds = run(
                        example, size, args.layers, args.refine, Path(folder), args.prints
                    )
                except subprocess.CalledProcessError as exc:
                    print(f"{spec} {size:g} mm: FAILED: {exc.stderr.decode().strip()[-200:]}")
                    return 1
                verdict = figures["verdicts"][-1]  # with --prints: each target's worst print
                cells = "; ".join(f"{t['target']} {cell(t)}" for t in verdict["targets"])
                layers = figures["verify"]["verdict"].get("layers", 1)
                print(f"{spec} {size:g} mm, {layers} layers: {cells} ({seconds:.0f} s)", flush=True)
                for k, judged in enumerate(figures.get("layers", {}).get("prints", []), 1):
                    print(f"    print {k} (in memory): {judged['headline']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
