"""Attack rows for expressions and fields (issue 15, points 2 and 3).

Hostile expressions (deep nesting, power towers, huge integers, laws that computer algebra
took minutes over, constants that are not finite), fields that are not finite where the
sheet needs them (material laws, heights, initial curves, stimuli, directors, eps,
director grids, swimmer layers), and solver grids too large to allocate. Every row must
be refused in one line naming the key, within the time bound, writing nothing. See
:mod:`tests.attack` for what each row asserts.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.attack import assert_refused, case, edited, write_texts
from tests.conftest import EXAMPLES

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

TWO = EXAMPLES / "two_shapes.toml"
SWIMMER = EXAMPLES / "swimmer.toml"
NESTED = "exp(" * 150 + "x" + ")" * 150
HUGE = "1" + "0" * 400
TOWER = "2**2**2**2**2"
LONG_SUM = "+".join(["x"] * 600)
PRODUCT = "*".join(f"(x+{k})" for k in range(1, 120))  # 119 factors: within the limits

LAW = 'lambda2  = "exp(L*eps)"'
HEIGHT = 'z = "exp(-(x**2 + y**2/4))"'
SPECS = {
    "law_log0": (LAW, 'lambda2 = "exp(L*eps) + log(0)"'),
    "law_div0": (LAW, 'lambda2 = "exp(L*eps)/(L-L)"'),
    "law_div_zero": (LAW, 'lambda2 = "exp(L*eps)/(2*0)"'),
    "law_sqrt": (LAW, 'lambda2 = "exp(L*eps) + sqrt(-1)*L"'),
    "law_nested": (LAW, f'lambda2 = "exp(L*eps) + {NESTED.replace("x", "eps")}"'),
    "law_tower": (LAW, f'lambda2 = "exp(L*eps) * {TOWER}"'),
    "law_huge": (LAW, f'lambda2 = "exp(L*eps) + {HUGE}*L"'),
    "law_long": (LAW, f'lambda2 = "exp(L*eps) + {LONG_SUM.replace("x", "L")}"'),
    "law_deep_sum": (LAW, 'lambda2 = "exp(L*eps) + L*' + "(1+eps*" * 20 + "eps" + ")" * 20 + '"'),
    # sympy.simplify took minutes on this 32-character law (it expands (1+eps)**999999)
    "law_simplify": (LAW, 'lambda2 = "exp(L*eps)*(1+eps)**999999"'),
    # and 5 s on this one, which the solver then refuses at the start point
    "law_power": (LAW, 'lambda2 = "(1+L*eps)**1000"'),
    # its symbolic second derivative would hold 119^3 terms; exp overflows at the start
    "law_product": (LAW, f'lambda2 = "exp(L*eps*{PRODUCT.replace("x", "eps")})"'),
    "law_start": (LAW, 'lambda2 = "exp(L*eps) + log(1 - L/2)"'),
    "law_inf_slope": (LAW, 'lambda2 = "exp(L*eps) + L*(L-1)*abs(eps-0.5)**0.5"'),
    "height_log": (HEIGHT, 'z = "log(x)"'),
    "height_sqrt": (HEIGHT, 'z = "sqrt(x - 100)"'),
    "height_pole": (HEIGHT, 'z = "1/(x*x + y*y)"'),
    "height_product": (HEIGHT, f'z = "log(x)*{PRODUCT}"'),
    "height_metric": (
        'geometry = { kind = "graph", ' + HEIGHT + " }",
        'geometry = { kind = "metric", g11 = "1", g22 = "log(a)" }',
    ),
    "height_parametric": (
        'geometry = { kind = "graph", ' + HEIGHT + " }",
        'geometry = { kind = "parametric", x = "a", y = "b", z = "sqrt(a)*'
        + PRODUCT.replace("x", "b")
        + '" }',
    ),
    "curve_t0": ('u_curve = ["t", "0"]', 'u_curve = ["t", "sqrt(-t**2)"]'),
    "curve_const": ('u_curve = ["t", "0"]', 'u_curve = ["t", "log(0)"]'),
    "eps_t0": ('eps   = ["1/2"]', 'eps   = ["log(t)"]'),
    "eps_first_step": ('eps   = ["1/2"]', 'eps   = ["0.4 + 0.1*sqrt(1 - (t/0.01)**2)"]'),
    "slope_div0": ('slope = ["1/2"]', 'slope = ["1/0"]'),
    "stimulus_log": ("stimulus = [2]", 'stimulus = ["log(0)"]'),
    "start_sqrt": ("start = [0.0, 0.0]", 'start = ["sqrt(-1)", 0.0]'),
    "director_div0": (
        "director = [1.0, 0.0]                             # chart",
        'director = ["1/0", 0.0] #',
    ),
    "diagonals": ("diagonals = 200", "diagonals = 20000"),
    "surface_name": ('name = "sphere"', 'name = "x/../../name"'),
}


SWIMMER_SPECS = {
    "swim_director": ('director = "phi"', 'director = "sqrt(x - 100)"'),
    "swim_law": ('lambda1 = "1 - 0.2*L2"', 'lambda1 = "1 - 0.2*L2 + 0.1*log(1 - L2)"'),
    "swim_nested": ('director = "phi"', f'director = "{NESTED}"'),
}
DIRECTOR_FILES = {
    "dir_log": '[director]\ntheta = "log(r)"\nshape = "disc:10"\n',
    "dir_eps": '[director]\ntheta = "phi"\nshape = "disc:10"\neps = "1/(x - 1)"\n',
    "dir_grid_nan": '[director]\ngrid = "nan.npz"\n',
    "dir_grid_3d": '[director]\ngrid = "cube.npz"\n',
    "dir_grid_pixel": '[director]\ngrid = "pixel.npz"\n',
    "dir_grid_complex": '[director]\ngrid = "complex.npz"\n',
    "dir_grid_npy": '[director]\ngrid = "plain.npy"\n',
}


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    """Hostile inputs, made once: spec and swimmer variants, director files and grids."""
    two, swimmer = TWO.read_text(), SWIMMER.read_text()
    texts = {
        **{name: edited(two, old, new) for name, (old, new) in SPECS.items()},
        **{name: edited(swimmer, old, new) for name, (old, new) in SWIMMER_SPECS.items()},
        **DIRECTOR_FILES,
    }
    paths = write_texts(folder, texts, ".toml")
    theta = np.zeros((8, 8))
    mask = np.ones((8, 8), dtype=bool)
    np.savez(
        folder / "nan.npz", theta=np.where(np.eye(8) > 0, np.nan, 0.0), mask=mask, pixel_mm=1.0
    )
    np.savez(folder / "cube.npz", theta=np.zeros((4, 4, 4)), mask=mask, pixel_mm=1.0)
    np.savez(folder / "pixel.npz", theta=theta, mask=mask, pixel_mm=np.ones(3))
    np.savez(folder / "complex.npz", theta=theta + 1j, mask=mask, pixel_mm=1.0)
    np.save(folder / "plain.npy", theta)
    return {**paths, "baromorph": str(EXAMPLES / "directors" / "baromorph.toml")}


COARSE = "--step 0.1 --diagonals 30"
SHEET = "--shape disc:10 --out {out}"

CASES = [
    # ------------------------------------------------------------------ material laws
    case(
        "spec {law_log0}",
        "is not finite",
        "material.lambda2",
        "log(0)",
        outputs=(),
        id="expr-law-log0",
    ),
    case(
        "spec {law_div_zero}",
        "division by zero",
        "material.lambda2",
        outputs=(),
        id="expr-law-div0",
    ),
    case(
        "spec {law_div0}",
        "must equal 1 at the flat sheet's stimulus",
        "it is inf",
        outputs=(),
        id="expr-law-div-variable",
    ),
    case("spec {law_sqrt}", "is not finite", "sqrt(-1)", outputs=(), id="expr-law-sqrt"),
    case(
        "spec {law_nested}",
        "nested too deeply",
        "material.lambda2",
        outputs=(),
        id="expr-law-nested",
    ),
    case("spec {law_tower}", "is not finite", "2**2**2**2**2", outputs=(), id="expr-law-tower"),
    case(
        "spec {law_huge}",
        "is too large for a float",
        "material.lambda2",
        outputs=(),
        id="expr-law-huge-int",
    ),
    case(
        "spec {law_long}",
        "expression too large",
        "material.lambda2",
        outputs=(),
        id="expr-law-long",
    ),
    case(
        "spec {law_deep_sum}",
        "nested too deeply",
        "material.lambda2",
        outputs=(),
        id="expr-law-parens",
    ),
    case(
        "spec {law_simplify}",
        "must equal 1 at the flat sheet's stimulus",
        outputs=(),
        id="expr-law-simplify",
    ),
    case(
        f"solve {{law_power}} --out {{out}}/d.npz {COARSE}",
        "inconsistent initial data at the start point",
        id="expr-law-power",
    ),
    case(
        "spec {law_product}",
        "not finite at the start point",
        "material.lambda2",
        outputs=(),
        id="expr-law-product",
    ),
    case(
        "spec {law_start}",
        "not finite at the start point",
        "material.lambda2",
        outputs=(),
        id="expr-law-start",
    ),
    case(
        "spec {law_inf_slope}",
        "not finite at the start point",
        "material.lambda2",
        outputs=(),
        id="expr-law-slope",
    ),
    case("run {law_log0} --out {out}", "is not finite", "material.lambda2", id="expr-run-law"),
    case("run {law_start} --out {out}", "not finite at the start point", id="expr-run-law-start"),
    # ------------------------------------------------------------------ heights and surfaces
    case(
        "spec {height_log}",
        "not finite at the start point",
        "surfaces[2].geometry.z",
        outputs=(),
        id="expr-height-log",
    ),
    case(
        "spec {height_sqrt}",
        "not finite at the start point",
        "surfaces[2].geometry.z",
        outputs=(),
        id="expr-height-sqrt",
    ),
    case(
        "spec {height_pole}",
        "not finite at the start point",
        "surfaces[2].geometry.z",
        outputs=(),
        id="expr-height-pole",
    ),
    case(
        "spec {height_product}",
        "not finite at the start point",
        "surfaces[2].geometry.z",
        outputs=(),
        id="expr-height-product",
    ),
    case(
        "spec {height_metric}",
        "not finite at the start point",
        "geometry.g22",
        outputs=(),
        id="expr-height-metric",
    ),
    case(
        "spec {height_parametric}",
        "not finite at the start point",
        "geometry.z",
        outputs=(),
        id="expr-height-parametric",
    ),
    case("run {height_log} --out {out}", "not finite at the start point", id="expr-run-height"),
    # ------------------------------------------------------------------ initial data, vectors
    case(
        "spec {curve_t0}", "not finite at t = 0", "initial.u_curve", outputs=(), id="expr-curve-t0"
    ),
    case(
        "spec {curve_const}", "is not finite", "initial.u_curve", outputs=(), id="expr-curve-const"
    ),
    case("spec {eps_t0}", "not finite at t = 0", "initial.eps[0]", outputs=(), id="expr-eps-t0"),
    case(
        f"solve {{eps_first_step}} --out {{out}}/d.npz {COARSE}",
        "not finite at the first grid step",
        "initial.eps[0]",
        id="expr-eps-first-step",
    ),
    case(
        f"run {{eps_first_step}} --out {{out}} {COARSE}",
        "not finite at the first grid step",
        id="expr-run-eps-first-step",
    ),
    case(
        "spec {slope_div0}",
        "division by zero",
        "initial.slope[0]",
        outputs=(),
        id="expr-slope-div0",
    ),
    case(
        "spec {stimulus_log}",
        "is not finite",
        "surfaces[2].stimulus",
        outputs=(),
        id="expr-stimulus",
    ),
    case("spec {start_sqrt}", "is not finite", "surfaces[2].start", outputs=(), id="expr-start"),
    case(
        "spec {director_div0}",
        "division by zero",
        "surfaces[1].director",
        outputs=(),
        id="expr-vector",
    ),
    case(
        "spec {surface_name}",
        "must be 1-64 letters",
        "surfaces[1].name",
        outputs=(),
        id="expr-surface-name",
    ),
    # ------------------------------------------------------------------ solver grid size
    case(
        "spec {diagonals}",
        "the solver would need about",
        "solver.diagonals 20000",
        outputs=(),
        id="expr-grid-spec",
    ),
    case(
        "solve {spec} --out {out}/d.npz --diagonals 20000",
        "the solver would need about",
        "--diagonals 20000",
        id="expr-grid-solve",
    ),
    case(
        "run {spec} --out {out} --diagonals 20000",
        "the solver would need about",
        "--diagonals 20000",
        id="expr-grid-run",
    ),
    case(
        "solve {spec} --out {out}/d.npz --step 1e-300",
        "rounding error swamps",
        "--step 1e-300",
        id="expr-grid-step-tiny",
    ),
    case(
        "solve {spec} --out {out}/d.npz --step 1e300 --diagonals 30",
        "the grid would reach",
        id="expr-grid-reach",
    ),
    # ------------------------------------------------------------------ directors and eps
    case(
        f"toolpath --director sqrt(x-100) {SHEET}",
        "not finite at",
        "--director",
        id="expr-director-nan",
    ),
    case(
        f"toolpath --director 1/(x-x) {SHEET}",
        "not finite at",
        "--director",
        id="expr-director-pole",
    ),
    case(
        f"toolpath --director log(r) {SHEET}",
        "not finite at",
        "--director: not finite at 1 of",
        id="expr-director-centre",
    ),
    case(
        f"toolpath --director phi --eps log(0) {SHEET}",
        "is not finite",
        "--eps",
        id="expr-eps-log0",
    ),
    case(
        f"toolpath --director phi --eps log(x) {SHEET}",
        "not finite at",
        "--eps",
        id="expr-eps-half",
    ),
    case(
        f"toolpath --director phi --eps 1/x {SHEET}", "not finite at", "--eps", id="expr-eps-line"
    ),
    case(
        f"toolpath --director {NESTED} {SHEET}",
        "nested too deeply",
        "--director",
        id="expr-director-nested",
    ),
    case(
        f"toolpath --director {TOWER} {SHEET}",
        "is not finite",
        "--director",
        id="expr-director-tower",
    ),
    case(
        f"toolpath --director {HUGE} {SHEET}",
        "is too large for a float",
        "--director",
        id="expr-director-huge",
    ),
    case(
        f"toolpath --director {LONG_SUM} {SHEET}", "expression too large", id="expr-director-long"
    ),
    case(
        f"toolpath --director {'x+' * 1100}x {SHEET}", "longer than 2000", id="expr-director-length"
    ),
    case(
        "channels --director sqrt(x-100) --shape disc:10 --baromorph {baromorph} --out {out}",
        "not finite at",
        "--director",
        id="expr-channels-director",
    ),
    case("toolpath {dir_log} --out {out}", "not finite at", "director.theta", id="expr-file-theta"),
    case("toolpath {dir_eps} --out {out}", "not finite at", "director.eps", id="expr-file-eps"),
    case("toolpath {dir_grid_nan} --out {out}", "theta is not finite at", id="expr-grid-file-nan"),
    case("toolpath {dir_grid_3d} --out {out}", "must be a 2-D array", id="expr-grid-file-3d"),
    case("toolpath {dir_grid_pixel} --out {out}", "must be a 0-D array", id="expr-grid-file-pixel"),
    case(
        "toolpath {dir_grid_complex} --out {out}",
        "expected real numbers",
        id="expr-grid-file-complex",
    ),
    case("toolpath {dir_grid_npy} --out {out}", "not an .npz archive", id="expr-grid-file-npy"),
    # ------------------------------------------------------------------ swimmer
    case(
        "swimmer {swim_director} --out {out}",
        "not finite at",
        "layers[0].director",
        id="expr-swimmer-director",
    ),
    case(
        "swimmer {swim_law} --out {out}",
        "not finite at the stimulus",
        "layers[0].lambda1",
        id="expr-swimmer-law",
    ),
    case(
        "swimmer {swim_nested} --out {out}",
        "nested too deeply",
        "layers[0].director",
        id="expr-swimmer-nested",
    ),
]


@pytest.mark.parametrize("bad", CASES)
def test_hostile_expressions_and_fields_are_refused(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
