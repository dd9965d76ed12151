"""Every command's bad-input paths: one line ``fabkit: error: ...``, exit code 2, no output.

Each row of :data:`CASES` is one bad input of one command. The test asserts that the
command exits with code 2, prints exactly one line on stderr that starts with
``fabkit: error:`` and names the problem (every listed substring), prints no traceback,
creates none of the outputs the command was asked for (and no ``*.part`` file), and
leaves a file that was in the way untouched. The first substring of every row is a
phrase that docs/troubleshooting.md lists with its fix (a test checks that too).

Placeholders in braces are input files made once per module (:func:`files`) or paths
in the test's own folder (``{out}``, ``{missing}``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.toolpath.job import ToolpathJob, run_job
from fabkit.writers.export import export
from tests.attack import assert_refused, case, edited, write_texts
from tests.conftest import EXAMPLES, coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

TWO = EXAMPLES / "two_shapes.toml"
SWIMMER = EXAMPLES / "swimmer.toml"
SIM = "sim://marlin?baud=0&time_scale=0"
DIW = "marlin_diw_pneumatic"
NOBODY = "127.0.0.1:1"  # a loopback port nobody listens on (tcpmux, not served)


CASES = [
    # ------------------------------------------------------------------ spec
    case("spec {missing}.toml", "does not exist", outputs=(), id="spec-missing"),
    case("spec {garbage}", "cannot read spec file", outputs=(), id="spec-garbage"),
    case("spec {bad_toml}", "not valid TOML", outputs=(), id="spec-bad-toml"),
    case("spec {wrong_json}", "not valid TOML", outputs=(), id="spec-json"),
    case("spec {unknown_key}", "unknown key", "colour", outputs=(), id="spec-unknown-key"),
    case(
        "spec {unknown_surface}",
        "geometry.kind: expected one of",
        "got 'torus'",
        outputs=(),
        id="spec-unknown-surface",
    ),
    case(
        "spec {nan_radius}",
        "expected a positive finite number",
        "surfaces[1].geometry.radius",
        outputs=(),
        id="spec-nan-radius",
    ),
    case(
        "spec {nan_stimulus}",
        "expected a finite number",
        "surfaces[2].stimulus",
        outputs=(),
        id="spec-nan-stimulus",
    ),
    case(
        "spec {unsafe}",
        "is not allowed in",
        "'__import__'",
        "material.lambda2",
        outputs=(),
        id="spec-unsafe-expression",
    ),
    case(
        "spec {unknown_name}",
        "is not allowed in",
        "'foo'",
        "surfaces[2].geometry.z",
        outputs=(),
        id="spec-unknown-name",
    ),
    case(
        "spec {one_target}",
        "[[surfaces]] tables",
        "surfaces: expected 3",
        outputs=(),
        id="spec-too-few-surfaces",
    ),
    case("spec", "the following arguments are required", outputs=(), id="spec-no-file"),
    # ------------------------------------------------------------------ solve
    case("solve {missing}.toml --out {out}.npz", "does not exist", id="solve-missing"),
    case("solve {unsafe} --out {out}.npz", "is not allowed in", id="solve-unsafe-expression"),
    case("solve {spec} --out {out}.txt", "must end in .npz", id="solve-out-suffix"),
    case("solve {spec} --out {out}.npz --step -1", "solver.step: expected", id="solve-step-neg"),
    case("solve {spec} --out {out}.npz --step nan", "solver.step: expected", id="solve-step-nan"),
    case("solve {spec} --out {out}.npz --step 0", "solver.step: expected", id="solve-step-zero"),
    case(
        "solve {spec} --out {out}.npz --diagonals 0",
        "solver.diagonals: expected",
        id="solve-diagonals-zero",
    ),
    case(
        "solve {spec} --out {out}.npz --step abc",
        "invalid float value",
        "--step",
        id="solve-step-text",
    ),
    case(
        "solve {spec} --out {out}.npz --quadrants 1;x",
        "argument --",
        "--quadrants: expected",
        id="solve-quadrants-text",
    ),
    case(
        "solve {spec} --out {out}.npz --quadrants 2,2",
        "solver.quadrants: expected",
        id="solve-quadrants-bad",
    ),
    case(
        "solve {spec} --out {blocker}/design.npz --step 0.1 --diagonals 30",
        "exists and is not a folder",
        outputs=(),
        id="solve-out-under-file",
    ),
    # ------------------------------------------------------------------ check
    case("check {missing}.npz", "does not exist", outputs=(), id="check-missing"),
    case("check {garbage}", "cannot read design file", outputs=(), id="check-garbage"),
    case("check {truncated}", "cannot read design file", outputs=(), id="check-truncated"),
    case("check {wrong_json}", "cannot read design file", outputs=(), id="check-json"),
    case("check {npy}", "cannot read design file", outputs=(), id="check-npy"),
    case("check {toolpath}", "not a fabkit design file", outputs=(), id="check-toolpath"),
    case("check {nan_design}", "has non-finite values", "'alpha'", outputs=(), id="check-nan"),
    case(
        "check {design} --isometry-median nan",
        "expected a positive finite number",
        "--isometry-median",
        outputs=(),
        id="check-tolerance-nan",
    ),
    case(
        "check {design} --isometry-p95 -1",
        "expected a positive finite number",
        "--isometry-p95",
        outputs=(),
        id="check-tolerance-negative",
    ),
    case(
        "check {design} --region 0",
        "expected a positive finite number",
        "--region",
        outputs=(),
        id="check-region-zero",
    ),
    # ------------------------------------------------------------------ plot
    case("plot {missing}.npz --out {out}", "does not exist", id="plot-missing"),
    case("plot {garbage} --out {out}", "cannot read design file", id="plot-garbage"),
    case("plot {truncated} --out {out}", "cannot read design file", id="plot-truncated"),
    case(
        "plot {design} --out {out} --mesh-format xyz",
        "invalid choice",
        "--mesh-format",
        id="plot-mesh-format",
    ),
    case(
        "plot {design} --out {blocker}",
        "exists and is not a folder",
        outputs=(),
        id="plot-out-is-file",
    ),
    # ------------------------------------------------------------------ toolpath
    case("toolpath {missing}.npz --size 60 --out {out}", "does not exist", id="toolpath-missing"),
    case(
        "toolpath {garbage} --size 60 --out {out}",
        "cannot read design file",
        id="toolpath-garbage",
    ),
    case(
        "toolpath {truncated} --size 60 --out {out}",
        "cannot read design file",
        id="toolpath-truncated",
    ),
    case(
        "toolpath {bad_toml} --out {out}",
        "not valid TOML",
        id="toolpath-director-bad-toml",
    ),
    case("toolpath {wrong_json} --out {out}", "expected a design .npz", id="toolpath-json"),
    case(
        "toolpath {design} --size 60 --scale 10 --out {out}",
        "not allowed with argument",
        id="toolpath-design-size-and-scale",
    ),
    *[
        case(
            f"toolpath {{design}} --size {size} --out {{out}}",
            "expected a positive finite number",
            "--size",
            id=f"toolpath-size-{size}",
        )
        for size in ("-5", "nan", "0")
    ],
    case(
        "toolpath {design} --size 5000 --out {out}",
        "road widths of",
        "give a smaller --size",
        id="toolpath-size-too-large",
    ),
    case(
        "toolpath {design} --size 60 --road-width -1 --out {out}",
        "must be a positive number",
        "road_width_mm",
        id="toolpath-road-width",
    ),
    case(
        "toolpath {design} --size 60 --layer-height 0 --out {out}",
        "must be a positive number",
        "layer_height_mm",
        id="toolpath-layer-height",
    ),
    case(
        "toolpath {design} --size 60 --layers 0 --out {out}",
        "cannot be split evenly",
        "--layers",
        id="toolpath-layers-zero",
    ),
    case(
        "toolpath {design} --size 60 --end-inset nan --out {out}",
        "--end-inset",
        id="toolpath-end-inset",
    ),
    case(
        "toolpath {design} --size 60 --ignore-feature eps5 --out {out}",
        "not a feature of the input",
        "--ignore-feature eps5",
        id="toolpath-feature",
    ),
    case(
        "toolpath {design} --size 60 --machine nope --out {out}",
        "unknown machine",
        "'nope'",
        id="toolpath-unknown-machine",
    ),
    case(
        "toolpath {design} --size 60 --process {missing}.toml --out {out}",
        "does not exist",
        "process file",
        id="toolpath-process-missing",
    ),
    case(
        "toolpath {design} --size 60 --process {bad_toml} --out {out}",
        "not valid TOML",
        id="toolpath-process-bad-toml",
    ),
    case(
        "toolpath {design} --size 60 --out {blocker}",
        "exists and is not a folder",
        outputs=(),
        id="toolpath-out-is-file",
    ),
    case(
        "toolpath --director __import__('os') --shape disc:10 --out {out}",
        "is not allowed in",
        "--director:",
        id="toolpath-director-unsafe",
    ),
    case(
        "toolpath --director phi --shape disc:10 --eps nan --out {out}",
        "is not allowed in",
        "--eps:",
        id="toolpath-eps-nan",
    ),
    case(
        "toolpath --director phi --shape blob:10 --out {out}",
        "unknown shape",
        "--shape",
        id="toolpath-unknown-shape",
    ),
    case(
        "toolpath --director phi --shape disc:nan --out {out}",
        "positive number(s)",
        "--shape",
        id="toolpath-shape-nan",
    ),
    case(
        "toolpath --director phi --shape disc:1e308 --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "'disc'",
        "got 1e+308",
        id="toolpath-shape-overflow",
    ),
    case(
        "toolpath --director phi --shape disc:1e-320 --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "got 1e-320",
        id="toolpath-shape-subnormal",
    ),
    case(
        "toolpath --director phi --shape square:inf --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "'square'",
        id="toolpath-shape-infinite",
    ),
    case(
        "toolpath --director phi --shape rect:10,1e-320 --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "'rect'",
        id="toolpath-shape-rect-subnormal",
    ),
    case(
        "toolpath --director phi --shape annulus:1,1e200 --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "'annulus'",
        id="toolpath-shape-annulus-huge",
    ),
    case(
        "toolpath --director phi --shape ellipse:1e308,1e-308 --out {out}",
        "sizes must be between 0.001 and 1e+06 mm",
        "'ellipse'",
        id="toolpath-shape-ellipse-extremes",
    ),
    case("toolpath --director phi --out {out}", "--director needs --shape", id="toolpath-no-shape"),
    case("toolpath --out {out}", "give a design.npz or director .toml input", id="toolpath-none"),
    case(
        "toolpath {design} --size 60 --pattern zigzag --out {out}",
        "invalid choice",
        "--pattern",
        id="toolpath-pattern",
    ),
    # ------------------------------------------------------------------ channels
    case(
        "channels {missing}.npz --baromorph {channels} --size 60 --out {out}",
        "does not exist",
        id="channels-missing",
    ),
    case(
        "channels {garbage} --baromorph {channels} --size 60 --out {out}",
        "cannot read design file",
        id="channels-garbage",
    ),
    case(
        "channels {design} --baromorph {missing}.toml --size 60 --out {out}",
        "does not exist",
        "baromorph file",
        id="channels-settings-missing",
    ),
    case(
        "channels {design} --baromorph {bad_toml} --size 60 --out {out}",
        "not valid TOML",
        id="channels-settings-bad-toml",
    ),
    case(
        "channels {design} --baromorph {spec} --size 60 --out {out}",
        "baromorph: missing (expected a table)",
        id="channels-settings-no-table",
    ),
    case(
        "channels {design} --baromorph {channels} --size -60 --out {out}",
        "expected a positive finite number",
        "--size",
        id="channels-size",
    ),
    case(
        "channels {design} --baromorph {channels} --size 60 --out {blocker}",
        "exists and is not a folder",
        outputs=(),
        id="channels-out-is-file",
    ),
    # ------------------------------------------------------------------ export
    case(
        f"export {{missing}}.npz --machine {DIW} --format gcode -o {{out}}.gcode",
        "does not exist",
        outputs=("{out}.gcode",),
        id="export-missing",
    ),
    case(
        f"export {{garbage}} --machine {DIW} --format gcode -o {{out}}.gcode",
        "cannot read",
        outputs=("{out}.gcode",),
        id="export-garbage",
    ),
    case(
        f"export {{truncated_toolpath}} --machine {DIW} --format gcode -o {{out}}.gcode",
        "cannot read",
        outputs=("{out}.gcode",),
        id="export-truncated",
    ),
    case(
        f"export {{wrong_json}} --machine {DIW} --format gcode -o {{out}}.gcode",
        "not a toolpath file",
        outputs=("{out}.gcode",),
        id="export-json",
    ),
    case(
        "export {toolpath} --machine nope --format gcode -o {out}.gcode",
        "unknown machine",
        "'nope'",
        outputs=("{out}.gcode",),
        id="export-unknown-machine",
    ),
    case(
        "export {toolpath} --machine {missing}.toml --format gcode -o {out}.gcode",
        "does not exist",
        "machine profile",
        outputs=("{out}.gcode",),
        id="export-machine-file-missing",
    ),
    case(
        "export {toolpath} --machine {bad_toml} --format gcode -o {out}.gcode",
        "not valid TOML",
        outputs=("{out}.gcode",),
        id="export-machine-bad-toml",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format gcode -o {{out}}.gcode --offset 500,500",
        "outside the envelope",
        outputs=("{out}.gcode",),
        id="export-move-out-of-range",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format gcode -o {{out}}.gcode --offset nan,0",
        "finite numbers",
        "offset",
        outputs=("{out}.gcode",),
        id="export-offset-nan",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format gcode -o {{out}}.gcode --offset 1",
        "argument --",
        "--offset: expected X,Y",
        outputs=("{out}.gcode",),
        id="export-offset-short",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format stl -o {{out}}.stl",
        "invalid choice",
        "--format",
        outputs=("{out}.stl",),
        id="export-format",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format gcode -o {{blocker}}/sheet.gcode",
        "exists and is not a folder",
        outputs=(),
        id="export-out-under-file",
    ),
    case(
        f"export {{toolpath}} --machine {DIW} --format gcode -o {{folder}}",
        "a folder of that name exists",
        outputs=(),
        id="export-out-is-folder",
    ),
    case(
        f"export {{design}} --machine {DIW} --format gcode -o {{out}}.gcode",
        "G-code is written from a toolpath",
        outputs=("{out}.gcode",),
        id="export-design-to-gcode",
    ),
    case(
        "export {design} --machine dmd_photoalign --format laser -o {out} --size -20",
        "expected a positive finite number",
        "--size",
        id="export-laser-size",
    ),
    case(
        "export {design} --machine dmd_photoalign --format laser -o {out} --size 5 --bins 0",
        "bins must be",
        id="export-laser-bins",
    ),
    case(
        "export {design} --machine dmd_photoalign --format laser -o {out} --size 5 --dose nan",
        "dose must be",
        id="export-laser-dose-nan",
    ),
    case(
        "export {design} --machine dmd_photoalign --format laser -o {blocker} --size 5",
        "exists and is not a folder",
        outputs=(),
        id="export-laser-out-is-file",
    ),
    case(
        "export {design} --machine laser_cutter --format dxf -o {out}.dxf --size 60 "
        "--inlet-radius nan",
        "inlet radius must be",
        outputs=("{out}.dxf",),
        id="export-dxf-inlet-nan",
    ),
    case(
        "export {design} --machine laser_cutter --format dxf -o {out}.dxf --size 60 "
        "--geometry {wrong_json}",
        "geometry file",
        outputs=("{out}.dxf",),
        id="export-dxf-geometry",
    ),
    # ------------------------------------------------------------------ machines
    case("machines extra", "unrecognized arguments", outputs=(), id="machines-extra-argument"),
    # ------------------------------------------------------------------ send
    case(
        f"send {{missing}}.gcode --port {SIM} --machine {DIW}",
        "cannot read G-code file",
        outputs=(),
        id="send-missing",
    ),
    case(
        f"send {{garbage}} --port {SIM} --machine {DIW}",
        "non-ASCII byte",
        outputs=(),
        id="send-garbage",
    ),
    case(
        f"send {{gcode}} --port {SIM} --machine nope",
        "unknown machine",
        outputs=(),
        id="send-unknown-machine",
    ),
    case(
        f"send {{far_gcode}} --port {SIM} --machine {DIW}",
        "outside the envelope",
        "X=500.000",
        outputs=(),
        id="send-move-out-of-range",
    ),
    case(
        f"send {{fast_gcode}} --port {SIM} --machine {DIW}",
        "exceeds [limits]",
        outputs=(),
        id="send-feed-too-fast",
    ),
    case(
        f"send {{gcode}} --port /dev/fabkit-no-such-port --machine {DIW}",
        "cannot open port",
        "/dev/fabkit-no-such-port",
        outputs=(),
        id="send-no-such-device",
    ),
    case(
        f"send {{gcode}} --port http://localhost/printer --machine {DIW}",
        "cannot open port",
        "http",
        outputs=(),
        id="send-unsupported-url",
    ),
    case(
        f"send {{gcode}} --port sim://nope --machine {DIW}",
        "cannot open port",
        "sim://nope",
        outputs=(),
        id="send-unknown-emulator",
    ),
    case(
        f"send {{gcode}} --port sim://grbl --machine {DIW}",
        "emulates a grbl machine but profile",
        outputs=(),
        id="send-protocol-mismatch",
    ),
    case(f"send {{gcode}} --machine {DIW}", "--port is required", outputs=(), id="send-no-port"),
    case(
        f"send {{gcode}} --port {SIM} --machine {DIW} --resume-from 0",
        "is outside",
        "--resume-from 0",
        outputs=(),
        id="send-resume-from-zero",
    ),
    case(
        f"send {{gcode}} --port sim://marlin --machine {DIW} --baud -5",
        "expected a positive baud rate",
        "--baud -5",
        outputs=(),
        id="send-baud-negative",
    ),
    case(
        f"send {{gcode}} --port {SIM} --machine {DIW} --log {{blocker}}/log.txt",
        "cannot write log file",
        outputs=(),
        id="send-log-under-file",
    ),
    # ------------------------------------------------------------------ send --host
    case(
        f"send {{gcode}} --host ftp://{NOBODY}",
        "expected octoprint+http://HOST:PORT",
        outputs=(),
        id="send-host-scheme",
    ),
    case(
        "send {gcode} --host octoprint+http://fabkit:secret@127.0.0.1",
        "put no credentials in the URL",
        outputs=(),
        id="send-host-credentials",
    ),
    case(
        f"send {{gcode}} --host octoprint+http://{NOBODY} --api-key KEY",
        "cannot reach",
        "Connection refused",
        outputs=(),
        id="send-host-refused",
    ),
    case(
        f"send {{gcode}} --host moonraker+http://{NOBODY}",
        "runs Klipper but machine",
        "marlin_diw_pneumatic is flavour marlin",
        outputs=(),
        id="send-host-moonraker-marlin",
    ),
    case(
        f"send {{gcode}} --host octoprint+http://{NOBODY} --machine grbl_diw --force",
        "streams to Marlin-protocol firmware",
        outputs=(),
        id="send-host-octoprint-grbl",
    ),
    case(
        f"send {{gcode}} --host octoprint+http://{NOBODY} --baud 9600",
        "is for a serial port, not a printer host",
        "--baud",
        outputs=(),
        id="send-host-baud",
    ),
    case(
        f"send {{gcode}} --port {SIM} --api-key KEY",
        "is for a printer host (--host), not a serial port",
        "--api-key",
        outputs=(),
        id="send-port-api-key",
    ),
    case(
        f"send {{gcode}} --port {SIM} --no-start",
        "is for a printer host (--host), not a serial port",
        "--no-start",
        outputs=(),
        id="send-port-no-start",
    ),
    case(
        f"send {{gcode}} --port {SIM} --host octoprint+http://{NOBODY}",
        "not allowed with argument",
        outputs=(),
        id="send-port-and-host",
    ),
    case(
        f"send {{gcode}} --host octoprint+http://{NOBODY} --api-key-file {{missing}}",
        "cannot read --api-key-file",
        outputs=(),
        id="send-host-key-file-missing",
    ),
    case(
        f"send {{gcode}} --host octoprint+http://{NOBODY} --api-key-file {{empty_key}}",
        "is empty or holds blanks or control characters",
        outputs=(),
        id="send-host-key-file-empty",
    ),
    case(
        "run {spec} --out {out} --send http://fabkit:secret@127.0.0.1",
        "put no credentials in the URL",
        id="run-send-host-credentials",
    ),
    case(
        f"run {{spec}} --out {{out}} --send {SIM} --api-key KEY",
        "are for --send to a printer host",
        id="run-send-port-api-key",
    ),
    # ------------------------------------------------------------------ simulate
    case("simulate {missing}.npz --stimulus 1", "does not exist", id="simulate-missing"),
    case("simulate {garbage} --stimulus 1", "cannot read design file", id="simulate-garbage"),
    case(
        "simulate {design} --stimulus nope",
        "expected a surface name",
        "--stimulus nope",
        id="simulate-unknown-surface",
    ),
    case(
        "simulate {design} --stimulus 1 --thickness -1 --out {out}.ply",
        "--thickness -1: expected a positive finite length (mm)",
        outputs=("{out}.ply",),
        id="simulate-thickness",
    ),
    case(
        "simulate {design} --stimulus 1 --poisson nan --out {out}.ply",
        "poisson ratio must lie in",
        outputs=("{out}.ply",),
        id="simulate-poisson-nan",
    ),
    case(
        "simulate {design} --stimulus 1 --steps 0 --out {out}.ply",
        "at least one ramp step",
        outputs=("{out}.ply",),
        id="simulate-steps",
    ),
    case(
        "simulate {design} --stimulus 1 --max-iterations 0 --out {out}.ply",
        "at least one Newton iteration",
        outputs=("{out}.ply",),
        id="simulate-max-iterations",
    ),
    case(
        "simulate {design} --stimulus 1 --out {out}.txt",
        "mesh format must be one of",
        outputs=("{out}.txt",),
        id="simulate-out-format",
    ),
    # ------------------------------------------------------------------ energy
    case("energy", "give a design file, --cycle", outputs=(), id="energy-nothing"),
    case("energy {missing}.npz", "does not exist", outputs=(), id="energy-missing"),
    case("energy {garbage}", "cannot read design file", outputs=(), id="energy-garbage"),
    case(
        "energy {design} --youngs nan",
        "Young's modulus must be positive",
        outputs=(),
        id="energy-youngs",
    ),
    case(
        "energy {design} --poisson 0.6",
        "Poisson ratio must lie in",
        outputs=(),
        id="energy-poisson",
    ),
    case(
        "energy {design} --thickness 0",
        "thickness must be positive",
        outputs=(),
        id="energy-thickness",
    ),
    case(
        "energy --cycle {out}.txt",
        "the cycle plot is written as .png",
        outputs=("{out}.txt",),
        id="energy-cycle-suffix",
    ),
    case(
        "energy --cycle {out}.png --epsilon nan",
        "expected a finite non-zero number above -1",
        "--epsilon",
        outputs=("{out}.png",),
        id="energy-epsilon-nan",
    ),
    case(
        "energy --cycle {out}.png --area -1",
        "expected a positive finite number",
        "--area",
        outputs=("{out}.png",),
        id="energy-area",
    ),
    case(
        "energy --cycle {blocker}/cycle.png",
        "exists and is not a folder",
        outputs=(),
        id="energy-cycle-under-file",
    ),
    # ------------------------------------------------------------------ swimmer
    case("swimmer {missing}.toml --out {out}", "does not exist", id="swimmer-missing"),
    case("swimmer {bad_toml} --out {out}", "not valid TOML", id="swimmer-bad-toml"),
    case("swimmer {spec} --out {out}", "unknown key", "initial: unknown", id="swimmer-design-spec"),
    case(
        "swimmer {swimmer_unsafe} --out {out}",
        "is not allowed in",
        "layers[0].director",
        id="swimmer-unsafe-expression",
    ),
    case(
        "swimmer {swimmer} --out {out} --stations 0",
        "expected a positive integer",
        "stations",
        id="swimmer-stations",
    ),
    case(
        "swimmer {swimmer} --out {blocker}",
        "exists and is not a folder",
        outputs=(),
        id="swimmer-out-is-file",
    ),
    # ------------------------------------------------------------------ run
    case("run {missing}.toml --out {out}", "does not exist", id="run-missing"),
    case("run {garbage} --out {out}", "cannot read spec file", id="run-garbage"),
    case("run {bad_toml} --out {out}", "not valid TOML", id="run-bad-toml"),
    case("run {unknown_key} --out {out}", "unknown key", "colour", id="run-unknown-key"),
    case(
        "run {unknown_surface} --out {out}",
        "geometry.kind: expected one of",
        "got 'torus'",
        id="run-unknown-surface",
    ),
    case(
        "run {nan_radius} --out {out}",
        "expected a positive finite number",
        "radius",
        id="run-nan",
    ),
    case("run {unsafe} --out {out}", "is not allowed in", "__import__", id="run-unsafe"),
    *[
        case(
            f"run {{spec}} --out {{out}} --size {size}",
            "expected a positive finite number",
            "--size",
            id=f"run-size-{size}",
        )
        for size in ("-5", "nan", "0")
    ],
    case(
        "run {spec} --out {out} --size 5000",
        "does not fit the envelope",
        "--size 5000",
        id="run-size-too-large",
    ),
    case("run {spec} --out {out} --layers 0", "expected 1 to 64 layers", id="run-layers-zero"),
    case(
        "run {spec} --out {out} --strict --no-simulate",
        "--no-simulate with --strict",
        id="run-strict-not-simulated",
    ),
    case(
        "run {spec} --out {out} --refine --no-simulate",
        "--refine with --no-simulate",
        id="run-refine-not-simulated",
    ),
    case(
        "run {spec} --out {out} --refine --layers 1",
        "--refine with --layers 1: it refines the differences between layers",
        id="run-refine-one-layer",
    ),
    case(
        "run {spec} --out {out} --layers 2 --machine dmd_photoalign",
        "make one layer",
        "laser writers such as dmd_photoalign",
        id="run-layers-laser-writer",
    ),
    case(
        "run {spec} --out {out} --layers 2 --baromorph {channels}",
        "make one layer",
        "a baromorph's channels",
        id="run-layers-baromorph",
    ),
    case(
        "run {spec} --out {out} --form-tolerance 0",
        "expected a percentage between 0 and 100",
        id="run-form-tolerance",
    ),
    case("solve {spec} --out {out}.npz --layers 99", "expected 1 to 64 layers", id="solve-layers"),
    case("run {spec} --out {out} --step 0", "solver.step: expected", id="run-step-zero"),
    case("run {spec} --out {out} --diagonals -1", "solver.diagonals: expected", id="run-diag"),
    case("run {spec} --out {out} --step abc", "invalid float value", id="run-step-text"),
    case("run {spec} --out {out} --machine nope", "unknown machine", id="run-unknown-machine"),
    case(
        "run {spec} --out {out} --machine {bad_toml}",
        "not valid TOML",
        id="run-machine-bad-toml",
    ),
    case(
        "run {spec} --out {out} --process {missing}.toml",
        "does not exist",
        "process file",
        id="run-process-missing",
    ),
    case(
        "run {spec} --out {out} --baromorph {missing}.toml",
        "does not exist",
        "baromorph file",
        id="run-baromorph-missing",
    ),
    case(
        "run {spec} --out {out} --baromorph {channels} --format gcode",
        "writes DXF only",
        id="run-baromorph-gcode",
    ),
    case(
        "run {spec} --out {out} --machine dmd_photoalign --format gcode",
        "is a laser writer",
        id="run-laser-gcode",
    ),
    case("run {spec} --out {out} --format stl", "invalid choice", id="run-format"),
    case(
        f"run {{spec}} --out {{out}} --format dxf --send {SIM}",
        "--send needs --format gcode",
        id="run-send-without-gcode",
    ),
    case(
        "run {spec} --out {blocker}",
        "exists and is not a folder",
        outputs=(),
        id="run-out-is-file",
    ),
    case(
        "run {spec} --out {blocker}/run",
        "exists and is not a folder",
        outputs=(),
        id="run-out-under-file",
    ),
    # Before the solve: the device does not exist (the port itself is opened only at the end)
    case(
        "run {spec} --out {out} --send /dev/fabkit-no-such-port",
        "cannot open port",
        "/dev/fabkit-no-such-port: no such device",
        id="run-send-no-such-device",
    ),
    case(
        "run {spec} --out {out} --send {blocker}",
        "cannot open port",
        "blocker: not a serial device",
        id="run-send-not-a-device",
    ),
    case(
        "run {spec} --out {out} --send sim://marlin?dialect=teacup",
        "cannot open port",
        "dialect='teacup'",
        id="run-send-bad-sim-option",
    ),
    case(
        "run {spec} --out {out} --send nosuchscheme://x",
        "cannot open port",
        "nosuchscheme://x: bad URL",
        id="run-send-bad-url",
    ),
    # A device that fails only when opened, at the end: the run's files are complete,
    # report.json is not written.
    case(
        "run {spec} --out {out} --step 0.1 --diagonals 30 --size 20 --send /dev/null",
        "cannot open port",
        "/dev/null: not a serial device",
        outputs=("{out}/report.json", "{out}/report.html"),
        id="run-send-not-a-serial-device-at-the-end",
        seconds=40.0,  # a whole (coarse) run before the port: about 6 s alone
        slow=True,
    ),
]


@pytest.fixture(scope="module")
def files(folder) -> dict[str, str]:
    """Bad and good inputs, made once: a coarse Fig. 1 design, a small toolpath, ..."""
    coarse_design().save(folder / "design.npz")
    arrays = dict(np.load(folder / "design.npz"))
    arrays["alpha"] = np.where(arrays["valid"], np.nan, arrays["alpha"])
    np.savez(folder / "nan_design.npz", **arrays)
    np.save(folder / "heights.npy", np.zeros((3, 3)))
    run_job(ToolpathJob(director="arctan2(y, x)", shape="disc:5", out=str(folder / "toolpath")))
    toolpath = folder / "toolpath" / "toolpath.npz"
    export(toolpath, DIW, "gcode", folder / "sheet.gcode")
    data = (folder / "design.npz").read_bytes()
    (folder / "truncated.npz").write_bytes(data[: len(data) // 2])
    data = toolpath.read_bytes()
    (folder / "truncated_toolpath.npz").write_bytes(data[: len(data) // 2])
    (folder / "garbage.npz").write_bytes(b"\x00\x01garbage\xff\xfe" * 8)
    (folder / "wrong.json").write_text(json.dumps({"not": "what fabkit wants"}))
    (folder / "bad.toml").write_text("[material\nfeatures = \n")
    (folder / "far.gcode").write_text("G90\nG1 X500 Y10 F600\n")
    (folder / "fast.gcode").write_text("G90\nG1 X10 Y10 F6000000\n")
    (folder / "folder").mkdir()
    (folder / "empty.key").write_text("\n")
    two = TWO.read_text()
    specs = {
        "unknown_key": edited(two, 'name = "flat"\n', 'name = "flat"\ncolour = "red"\n'),
        "unknown_surface": edited(two, 'kind = "sphere"', 'kind = "torus"'),
        "nan_radius": edited(two, "radius = 1.0", "radius = nan"),
        "nan_stimulus": edited(two, "stimulus = [2]", "stimulus = [nan]"),
        "unsafe": edited(two, '"exp(L*eps)"', "\"__import__('os')\""),
        "unknown_name": edited(two, 'y**2/4))"', 'y**2/4)) + foo"'),
        "one_target": two.split('[[surfaces]]\nname = "bump"')[0]
        + "[initial]"
        + two.split("[initial]")[1],
        "swimmer_unsafe": edited(
            SWIMMER.read_text(), 'director = "phi"', "director = \"__import__('os')\""
        ),
    }
    return {
        **write_texts(folder, specs, ".toml"),
        "design": str(folder / "design.npz"),
        "nan_design": str(folder / "nan_design.npz"),
        "npy": str(folder / "heights.npy"),
        "toolpath": str(toolpath),
        "gcode": str(folder / "sheet.gcode"),
        "truncated": str(folder / "truncated.npz"),
        "truncated_toolpath": str(folder / "truncated_toolpath.npz"),
        "garbage": str(folder / "garbage.npz"),
        "wrong_json": str(folder / "wrong.json"),
        "bad_toml": str(folder / "bad.toml"),
        "far_gcode": str(folder / "far.gcode"),
        "fast_gcode": str(folder / "fast.gcode"),
        "folder": str(folder / "folder"),
        "empty_key": str(folder / "empty.key"),
    }


@pytest.mark.parametrize("bad", CASES)
def test_bad_input_is_one_line_and_writes_nothing(bad, files, run_cli, tmp_path):
    assert_refused(bad, files, tmp_path, run_cli)


def test_an_operating_system_error_is_one_line(run_cli, monkeypatch):
    def refuse(*_):
        raise PermissionError(13, "Permission denied", "/somewhere/sheet.gcode")

    monkeypatch.setattr("fabkit.commands.machines.machine_table", refuse)
    code, _, err = run_cli("machines")
    assert code == 2
    assert err == "fabkit: error: /somewhere/sheet.gcode: Permission denied\n"
