"""The adjoint gradient of a simulated sheet's distance to its target, through the shell's
metrics and the material law, against simulations of perturbed sheets; and the
refinement that uses it bringing a layered sheet nearer every target from every start."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.design.layers import layered
from fabkit.mechanics import refine
from fabkit.mechanics.adjoint import aligned_distance, metric_gradient
from fabkit.mechanics.fabricated import (
    SheetFields,
    design_fields,
    sheet_metrics,
    sheet_metrics_gradient,
    sheet_problem,
)
from fabkit.mechanics.mesh import design_mesh
from fabkit.mechanics.refine import refine_layering
from fabkit.mechanics.shell import Sheet, build_shell
from fabkit.mechanics.simulate import Settings, minimise
from fabkit.mechanics.verdict import design_verdict, target_shapes
from tests.conftest import coarse_design

UNBOUNDED = np.array([[-np.inf, np.inf]])
"""Fig. 1's one feature, with no process range."""


@pytest.fixture(scope="module")
def fig1():
    return coarse_design()


@pytest.fixture(scope="module")
def layered_fig1(fig1):
    """Fig. 1 (coarse) in two layers carrying the whole first-order layering, 2 % of its
    flat diameter thick: the bump is missed (about 5 %)."""
    return layered(fig1, 2, 0.02, UNBOUNDED)[0]


def _equilibrium(design, surface):
    fields = [design_fields(design.layer(k)) for k in range(design.layers)]
    problem = sheet_problem(design, fields, surface, design.layering.thickness, stride=1)
    mesh = problem.mesh
    target = problem.coarse.problem.targets[surface].surface.embed(
        mesh.sample(problem.coarse.r[surface])
    )
    return problem, problem.run(Settings()).positions, target


def test_the_distance_gradient_is_the_derivative_of_the_aligned_distance():
    rng = np.random.default_rng(3)
    points, target = rng.normal(size=(40, 3)), rng.normal(size=(40, 3))
    distance = aligned_distance(points, target, 2.0)
    change = rng.normal(size=points.shape)
    h = 1e-6
    up = aligned_distance(points + h * change, target, 2.0).value
    down = aligned_distance(points - h * change, target, 2.0).value
    assert np.sum(distance.gradient * change) == pytest.approx((up - down) / (2 * h), rel=1e-6)
    # a rigid motion of the points changes nothing
    assert aligned_distance(points @ np.linalg.qr(change[:3])[0] + 1.0, target, 2.0).value == (
        pytest.approx(distance.value)
    )


@pytest.mark.parametrize("surface", [1, 2])
def test_the_adjoint_predicts_how_the_equilibrium_moves_with_the_metrics(layered_fig1, surface):
    problem, x, target = _equilibrium(layered_fig1, surface)
    sheet = Sheet.build(problem.mesh.points, problem.mesh.triangles)
    distance = aligned_distance(x, target, problem.patch_size)
    gradient = metric_gradient(sheet, problem.metrics, problem.thickness, 0.5, x, distance.gradient)
    centres = problem.mesh.points[problem.mesh.triangles].mean(1)
    change = np.zeros_like(problem.metrics)
    rng = np.random.default_rng(surface)
    for layer in range(2):
        for i, j in ((0, 0), (0, 1), (1, 1)):
            a = rng.normal(size=3)
            wave = a[0] * np.sin(4 * centres[:, 0] + a[1]) * np.cos(3 * centres[:, 1] + a[2])
            change[layer, :, i, j] = change[layer, :, j, i] = wave
    change *= 1e-5 * np.abs(problem.metrics).max()
    predicted = np.sum(gradient[..., 0] * change[..., 0, 0]) + np.sum(
        gradient[..., 1] * change[..., 0, 1] + gradient[..., 2] * change[..., 1, 1]
    )
    moved = []
    for sign in (1.0, -1.0):
        shell = build_shell(sheet, problem.metrics + sign * change, problem.thickness, 0.5)
        y, _, converged = minimise(shell, x, 1e-10 * sheet.edge_length(), 200, exact=True)
        assert converged
        moved.append(aligned_distance(y, target, problem.patch_size).value)
    measured = (moved[0] - moved[1]) / 2
    assert abs(predicted) > 1e-6 * distance.value  # the change does move the sheet
    assert predicted == pytest.approx(measured, rel=0.01)


def test_the_metrics_gradient_through_the_material_law_is_exact(fig1):
    mesh = design_mesh(fig1)
    n0 = mesh.sample(fig1.n[0])
    theta = np.arctan2(n0[:, 1], n0[:, 0])
    eps = mesh.sample(np.moveaxis(fig1.eps, 0, -1)).reshape(len(theta), -1).T
    rng = np.random.default_rng(0)
    weights = rng.normal(size=(len(mesh.triangles), 3))

    def quantity(t: np.ndarray, e: np.ndarray) -> float:
        metric = sheet_metrics(fig1, mesh, 2, t, e)
        parts = (metric[:, 0, 0], metric[:, 0, 1], metric[:, 1, 1])
        return float(sum(np.sum(w * m) for w, m in zip(weights.T, parts, strict=True)))

    d_theta, d_eps = sheet_metrics_gradient(fig1, mesh, 2, theta, eps, weights)
    turn, move = rng.normal(size=theta.shape), rng.normal(size=eps.shape)
    h = 1e-6
    measured = (
        quantity(theta + h * turn, eps + h * move) - quantity(theta - h * turn, eps - h * move)
    ) / (2 * h)
    assert np.sum(d_theta * turn) + np.sum(d_eps * move) == pytest.approx(measured, rel=1e-6)


@pytest.mark.slow
def test_refining_brings_the_farthest_target_nearer_from_every_start(layered_fig1):
    before = design_verdict(layered_fig1, stride=2)
    refined = refine_layering(layered_fig1, UNBOUNDED, stride=2)
    after = design_verdict(refined.design, stride=2)
    worst_before = max(s.rms for s in before.shapes)
    assert worst_before > 0.06  # the bump, the first-order layering's miss
    assert max(s.rms for s in after.shapes) < 0.8 * worst_before, after.lines()
    assert not any(s.mirrored for s in after.shapes)  # no side traded for a distance
    # what the refinement reports is what the verdict finds, from every start
    for shape, rms in zip(after.shapes, refined.after, strict=True):
        assert [end.rms for end in shape.starts] == pytest.approx([rms] * 6, abs=0.002)
    assert refined.before == pytest.approx([s.rms for s in before.shapes], abs=1e-6)


@pytest.mark.slow
def test_refined_as_printed_the_sheet_forms_with_its_error_and_with_it_turned_over(
    layered_fig1, monkeypatch
):
    """A print that turns every layer's director by a smooth few degrees and leaves a
    corner of the sheet unmade: refined with that error in the loop, the sheet printed with
    the same error is nearer its targets, judged as a print is (the error added, and turned
    over, on the sheet that was made); the figures reported are the worse of the two, and
    before refining they are the verdict's (the refinement once meshed the whole designed
    sheet: Fig. 1's bump 1.20 % where the verdict on the print found 3.05 %)."""
    corner = np.quantile(design_mesh(layered_fig1).points, 0.85, axis=0)

    def printed(design, k: int) -> SheetFields:
        own = design_fields(design.layer(k))

        def made(p: np.ndarray) -> np.ndarray:
            return own.made(p) & ~np.all(p > corner, axis=1)

        return SheetFields(
            lambda p: own.theta(p) + 0.05 * np.sin(3 * p[:, 0] + k), own.features, made
        )

    def judged(design):
        made = [printed(design, k) for k in range(2)]
        designed = [design_fields(design.layer(k)) for k in range(2)]
        return target_shapes(design, made, [1, 2], 0.02, stride=1, designed=designed)

    made = [printed(layered_fig1, k) for k in (0, 1)]
    monkeypatch.setattr(refine, "ROUNDS", 2)  # 0.81 of the worst RMS, as 4 rounds give 0.82
    refined = refine_layering(layered_fig1, UNBOUNDED, stride=1, fabricated=[(layered_fig1, made)])
    before, after = judged(layered_fig1), judged(refined.design)
    assert max(s.rms for s in after) < 0.9 * max(s.rms for s in before)
    # the figures are the dome start's (the worse is the error as printed, not turned over,
    # here), as the verdict finds them; the verdict's own figure is the worst of six starts
    dome = [[s.starts[0].rms for s in shapes] for shapes in (before, after)]
    assert [s.starts[0].start for s in before] == ["dome", "dome"]
    assert refined.before == pytest.approx(dome[0], abs=1e-6)
    # after: the worse of the error and the error turned over from the dome start; the
    # refinement sees no other start (here random-1 ends 1 % farther from the bump)
    assert all(a >= d - 1e-6 for a, d in zip(refined.after, dome[1], strict=True))
