"""``fabkit calibrate``: a material table fitted to samples, and a spec that uses it.

Samples are drawn from Fig. 1's law (lambda1 = 1, lambda2 = exp(L eps)) with 0.5 %
Gaussian noise; the table recovers the law within that noise, its derivatives agree with
finite differences, and a spec using it solves Fig. 1 (coarse) and passes the check.
Every bad input is one line, exit 2, and no table written.
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fabkit.calibrate import calibrate
from fabkit.design.check import check_design
from fabkit.design.design import Design
from fabkit.design.solver import solve
from fabkit.errors import FabkitError
from fabkit.problem.material_table import TableMaterial
from fabkit.problem.spec import build_spec, spec_from_json
from tests.conftest import EXAMPLES, example_table

NOISE = 0.005
"""Relative standard deviation of the measured stretches."""
LEVELS = (0.0, 0.5, 1.0, 1.5, 2.0)
"""The stimuli at which the samples are measured."""


def fig1_samples(count: int = 300, seed: int = 1, noise: float = NOISE, spread: bool = True):
    """Rows (eps, L, lambda1, lambda2[, lambda1_sd, lambda2_sd]) of Fig. 1's law, eps in
    [0, 1] and L at :data:`LEVELS`, with relative Gaussian noise."""
    rng = np.random.default_rng(seed)
    eps = rng.uniform(0.0, 1.0, count)
    stimulus = rng.choice(LEVELS, count)
    law = np.exp(stimulus * eps)
    lambda1 = 1 + rng.normal(0, noise, count)
    lambda2 = law * (1 + rng.normal(0, noise, count))
    columns = [eps, stimulus, lambda1, lambda2]
    if spread:
        columns += [np.full(count, noise), noise * law]
    return np.stack(columns, axis=1)


def write_csv(path, header: str, rows) -> str:
    lines = [header] + [",".join(f"{v:.8g}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


FIG1_HEADER = "eps,L,lambda1,lambda2,lambda1_sd,lambda2_sd"


@pytest.fixture(scope="module")
def fig1_table(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calibrate")
    samples = write_csv(folder / "samples.csv", FIG1_HEADER, fig1_samples())
    out = folder / "material.toml"
    calibration = calibrate(samples, out, features=["eps"], stimuli=["L"])
    return calibration, out


def test_recovers_fig1_law_within_the_noise(fig1_table):
    calibration, _ = fig1_table
    material = calibration.material
    low, high = material.box[0]
    eps = np.linspace(low, high, 201)[None]
    stimuli = np.array([[s] for s in np.linspace(0, 2, 9)])
    response = material.response(eps, stimuli)
    law = np.exp(stimuli * eps)
    error = np.abs(response.lambda2 / law - 1).max()
    assert error < NOISE, error  # measured 0.0031 (300 samples, seed 1)
    assert np.abs(response.lambda1 - 1).max() < 1e-12  # no effect found: exactly constant
    slope_error = np.abs(response.l2_e[:, 0] - stimuli).max()
    assert slope_error < 0.03 * 2, slope_error  # d log lambda2 / d eps = L: measured 0.057
    assert calibration.fits[0].directions == (0, 0)
    assert calibration.fits[1].directions == (1, 1)
    for residual in calibration.residuals:
        assert 0.8 < residual.spread_rms < 1.2  # scattered as stated


def test_table_derivatives_agree_with_finite_differences(fig1_table):
    material = fig1_table[0].material
    eps = np.array([[0.2, 0.45, 0.8]])
    stimuli = np.array([[0.7], [2.0]])
    h = 1e-5
    response = material.response(eps, stimuli)
    plus, minus = (material.response(eps + d, stimuli) for d in (h, -h))
    slope = (np.log(plus.lambda2) - np.log(minus.lambda2)) / (2 * h)
    np.testing.assert_allclose(response.l2_e[:, 0], slope, atol=1e-7)
    curvature = (plus.l2_e[:, 0] - minus.l2_e[:, 0]) / (2 * h)
    np.testing.assert_allclose(response.l2_ee[:, 0, 0], curvature, atol=1e-6)


def test_spec_with_the_table_solves_fig1_and_passes_the_check(fig1_table, tmp_path):
    _, table_file = fig1_table
    designs = {}
    for name in ("expressions", "table"):
        table = example_table("two_shapes.toml")
        table["solver"].update(step=0.1, diagonals=40)
        if name == "table":
            table["material"] = {"table": str(table_file)}
        designs[name] = solve(build_spec(table, EXAMPLES)).design
        report = check_design(designs[name])
        assert report.passed, report.table()
    expressions, fitted = designs["expressions"], designs["table"]
    assert fitted.valid.sum() >= 0.9 * expressions.valid.sum()  # measured 103 of 107
    both = expressions.valid & fitted.valid
    assert np.abs(fitted.eps[:, both] - expressions.eps[:, both]).max() < 0.02
    path = tmp_path / "design.npz"
    fitted.save(path)
    material = Design.load(path).problem.material
    assert isinstance(material, TableMaterial)
    np.testing.assert_array_equal(material.log2, fig1_table[0].material.log2)


def test_the_normalised_spec_holds_the_table_itself(fig1_table):
    table = example_table("two_shapes.toml")
    table["material"] = {"table": str(fig1_table[1]), "features": ["eps"]}
    spec = build_spec(table, EXAMPLES)
    assert spec.normalised["material"]["table"]["knots"]["L"][0] == 0.0
    again = spec_from_json(spec.to_json())
    np.testing.assert_array_equal(again.material.log2, spec.material.log2)
    assert again.classes == ("across",)


def test_acting_both_ways_is_refused_in_the_spec_check_words(tmp_path, run_cli):
    rows = fig1_samples(spread=False)
    rows[:, 2] = np.exp(rows[:, 1] * rows[:, 0])  # lambda1 = lambda2 = exp(L eps)
    samples = write_csv(tmp_path / "both.csv", "eps,L,lambda1,lambda2", rows)
    table = example_table("two_shapes.toml")
    table["material"]["lambda1"] = "exp(L*eps)"
    with pytest.raises(FabkitError) as spec_error:
        build_spec(table, EXAMPLES)
    out = tmp_path / "material.toml"
    code, _, err = run_cli("calibrate", samples, "--features", "eps", "--stimuli", "L",
                           "--out", out)  # fmt: skip
    assert code == 2 and err == f"fabkit: error: {spec_error.value}\n"
    assert not out.exists()


def test_two_features_two_stimuli(tmp_path):
    """Fig. 3's law: lambda1 = exp(L1 eps1), lambda2 = exp(L2 eps2)."""
    rng = np.random.default_rng(3)
    count = 700
    eps = rng.uniform(0, 1, (count, 2))
    stimuli = rng.choice([0.0, 1.0, 2.0], (count, 2))
    law = np.exp(stimuli * eps)
    measured = law * (1 + rng.normal(0, NOISE, (count, 2)))
    rows = np.concatenate([eps, stimuli, measured], axis=1)
    samples = write_csv(tmp_path / "fig3.csv", "eps1,eps2,L1,L2,lambda1,lambda2", rows)
    calibration = calibrate(samples, None, features=["eps1", "eps2"], stimuli=["L1", "L2"])
    material = calibration.material
    assert material.classify(np.array([[0.5, 0.0], [2.0, 0.0], [0.0, 2.0]])) == (
        "along",
        "across",
    )
    grid = np.stack(np.meshgrid(*[np.linspace(a, b, 11) for a, b in material.box[:2]]))
    grid = grid.reshape(2, -1)
    points = np.array([[1.0, 1.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    response = material.response(grid, points)
    error1 = np.abs(response.lambda1 / np.exp(points[:, :1] * grid[0]) - 1).max()
    error2 = np.abs(response.lambda2 / np.exp(points[:, 1:] * grid[1]) - 1).max()
    assert max(error1, error2) < 2 * NOISE, (error1, error2)  # measured 0.0043, 0.0045


def test_spec_reports_coverage_and_refuses_a_stimulus_outside(fig1_table, tmp_path, run_cli):
    samples = write_csv(tmp_path / "samples.csv", FIG1_HEADER, fig1_samples())
    out = tmp_path / "material.toml"
    code, text, err = run_cli("calibrate", samples, "--spec", EXAMPLES / "two_shapes.toml",
                              "--out", out)  # fmt: skip
    assert code == 0, err
    assert "L: the spec's stimuli 0 to 2, inside" in text
    assert "eps: the spec's initial eps 0.5 to 0.5" in text
    assert "lambda2: increases in eps, increases in L" in text
    table = example_table("two_shapes.toml")
    table["material"] = {"table": str(out)}
    table["surfaces"][2]["stimulus"] = [3]
    with pytest.raises(FabkitError, match=r"stimulus L = 3 is outside the table's range \[0, 2\]"):
        build_spec(table, EXAMPLES)


def _rows(**changes):
    rows = fig1_samples(count=60, spread=False)
    for name, value in changes.items():
        rows[:, ["eps", "L", "lambda1", "lambda2"].index(name)] = value(rows)
    return rows


NOISY = np.random.default_rng(0)

BAD_CSV = {
    "missing column": ("eps,L,lambda1", "no column 'lambda2'"),
    "unknown column": ("eps,L,lambda1,lambda2,T", "unknown column 'T'"),
    "twice": ("eps,L,lambda1,lambda1,lambda2", "column 'lambda1' appears twice"),
    "empty": ("", "empty (expected a header row"),
    "header only": ("eps,L,lambda1,lambda2\n", "no samples below the header"),
    "short row": ("eps,L,lambda1,lambda2\n0.1,1,1\n", "row 2: 3 values for 4 columns"),
    "empty cell": ("eps,L,lambda1,lambda2\n0.1,,1,1\n", "row 2, column L: empty"),
    "nan": ("eps,L,lambda1,lambda2\n0.1,nan,1,1\n", "row 2, column L: expected a finite"),
    "text": ("eps,L,lambda1,lambda2\n0.1,x,1,1\n", "row 2, column L: not a number: 'x'"),
    "negative": ("eps,L,lambda1,lambda2\n0.1,1,-1,1\n", "column lambda1: expected a positive"),
    "too few": (_rows()[:20], "too few samples to fit: 20"),
    "one value": (_rows(eps=lambda r: np.full(len(r), 0.5)), "column eps takes the one value 0.5"),
    "not monotone": (
        _rows(lambda2=lambda r: np.exp(r[:, 1] * (r[:, 0] - 0.5) ** 2)),
        "lambda2 is not monotone in eps",
    ),
    "noisy": (
        _rows(lambda2=lambda r: np.exp(r[:, 1] * r[:, 0] + NOISY.normal(0, 0.8, len(r)))),
        "lambda2 scatters about the fit",
    ),
}


@pytest.mark.parametrize("case", BAD_CSV, ids=str)
def test_bad_samples_one_line_nothing_written(case, tmp_path, run_cli):
    content, says = BAD_CSV[case]
    path = tmp_path / "samples.csv"
    if isinstance(content, str):
        path.write_text(content)
    else:
        write_csv(path, "eps,L,lambda1,lambda2", content)
    out = tmp_path / "material.toml"
    code, _, err = run_cli("calibrate", path, "--features", "eps", "--stimuli", "L",
                           "--out", out)  # fmt: skip
    assert code == 2, err
    assert err.startswith("fabkit: error: ") and err.count("\n") == 1, err
    assert says in err, err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["samples.csv"]


def test_a_spreadsheet_csv_reads(tmp_path):
    """A byte order mark, CRLF line ends, comment and blank lines, spaces around cells."""
    lines = [", ".join(f"{v:.8g}" for v in row) for row in fig1_samples(count=60)]
    text = "\ufeff# made on 2026-12-06\r\n" + FIG1_HEADER + "\r\n\r\n" + "\r\n".join(lines)
    path = tmp_path / "samples.csv"
    path.write_bytes(text.encode("utf-8"))
    assert calibrate(path, None, features=["eps"], stimuli=["L"]).samples == 60


def test_noisier_than_the_stated_spread_is_refused(tmp_path, run_cli):
    rows = fig1_samples(noise=0.05)
    rows[:, 5] = NOISE * np.exp(rows[:, 1] * rows[:, 0])  # states 0.5 %, scatters 5 %
    samples = write_csv(tmp_path / "samples.csv", FIG1_HEADER, rows)
    code, _, err = run_cli("calibrate", samples, "--features", "eps", "--stimuli", "L",
                           "--out", tmp_path / "m.toml")  # fmt: skip
    assert code == 2 and "times its stated spread lambda2_sd" in err, err


@pytest.mark.parametrize(
    "args, says",
    [
        ((), "which columns are features?"),
        (("--features", "eps", "--stimuli", "L", "--flat", "5"), "stimulus L = 5 is outside"),
        (("--features", "eps", "--stimuli", "eps"), "--stimuli: names that are not features"),
    ],
)
def test_bad_options_one_line(args, says, tmp_path, run_cli):
    samples = write_csv(tmp_path / "samples.csv", FIG1_HEADER, fig1_samples(count=60))
    out = tmp_path / "m.toml"
    code, _, err = run_cli("calibrate", samples, *args, "--out", out)
    assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    "edit, says",
    [
        (lambda t: t.pop("knots"), "material.toml: knots: missing"),
        (lambda t: t["knots"].update(L=[0, 1, 2]), "material.toml: knots.L: expected a clamped"),
        (lambda t: t["lambda2"].update(log=[0.0]), "material.toml: lambda2.log: expected an array"),
        (lambda t: t.update(flat=[7.0]), "flat: stimulus L = 7 is outside"),
    ],
)
def test_bad_table_file_one_line(edit, says, fig1_table, tmp_path):
    from fabkit.calibrate import _toml

    content = fig1_table[0].material.to_table()
    edit(content)
    lines = [f"{k} = {_toml(v)}" for k, v in content.items() if not isinstance(v, dict)]
    for key, value in content.items():
        if isinstance(value, dict):
            lines += [f"[{key}]", *(f"{k} = {_toml(v)}" for k, v in value.items())]
    (tmp_path / "material.toml").write_text("\n".join(lines) + "\n")
    table = example_table("two_shapes.toml")
    table["material"] = {"table": "material.toml"}
    with pytest.raises(FabkitError) as error:
        build_spec(table, tmp_path)
    assert says in str(error.value) and "\n" not in str(error.value), str(error.value)


def test_a_stimulus_acting_both_ways_is_left_free(tmp_path):
    """exp(L eps) over eps of both signs rises with L at eps > 0 and falls at eps < 0."""
    rows = fig1_samples(count=400, seed=5)
    rows[:, 0] = 1.5 * rows[:, 0] - 0.5  # eps in [-0.5, 1]
    law = np.exp(rows[:, 1] * rows[:, 0])
    rows[:, 3], rows[:, 5] = law * (1 + np.random.default_rng(6).normal(0, NOISE, 400)), NOISE * law
    samples = write_csv(tmp_path / "samples.csv", FIG1_HEADER, rows)
    calibration = calibrate(samples, None, features=["eps"], stimuli=["L"])
    assert calibration.fits[1].directions == (1, None)
    material = calibration.material
    eps = np.linspace(*material.box[0], 201)[None]
    stimuli = np.linspace(0, 2, 9)[:, None]
    error = np.abs(material.response(eps, stimuli).lambda2 / np.exp(stimuli * eps) - 1).max()
    assert error < NOISE, error  # measured 0.0028


def test_the_example_spec_uses_its_table(run_cli):
    code, text, err = run_cli("spec", EXAMPLES / "calibrate" / "two_shapes_table.toml")
    assert code == 0, err
    assert "material: table of log(lambda1), log(lambda2), cubic B-splines (4 x 4)" in text
    assert "eps: acts across the director" in text


def test_initial_eps_outside_the_table_is_refused():
    table = example_table("two_shapes.toml")
    table["material"] = {"table": "calibrate/material.toml"}
    table["initial"]["eps"] = ["1.5"]
    with pytest.raises(FabkitError, match=r"initial.eps: eps = 1.5 at the start point is outside"):
        build_spec(table, EXAMPLES)


def test_a_spec_written_back_keeps_its_table():
    """``fabkit optimise`` writes its best spec from the normalised tables."""
    from fabkit.optimise.tomlout import dumps

    table = example_table("two_shapes.toml")
    table["material"] = {"table": "calibrate/material.toml"}
    spec = build_spec(table, EXAMPLES)
    again = build_spec(tomllib.loads(dumps(spec.normalised)), EXAMPLES)
    np.testing.assert_array_equal(again.material.log2, spec.material.log2)
