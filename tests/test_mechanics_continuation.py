"""The continuation ramp, and the verdict on a sheet as fabricated with its print's error
turned over: a side that the error chose is no programmed side."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.mechanics.fabricated import SheetFields, design_fields, sheet_problem, turned_over
from fabkit.mechanics.simulate import (
    STARTS,
    Settings,
    curved,
    ramp,
    ramp_part,
    ramp_words,
    simulate,
)
from fabkit.mechanics.verdict import embedded_targets, target_shapes, turned_starts
from tests.conftest import coarse_design


def test_a_curved_sheet_is_ramped_slowly_and_a_flat_one_in_equal_steps():
    shares = ramp(Settings())
    assert shares[0] == pytest.approx(1 / 256) and shares[-1] == 1.0
    assert np.allclose(shares[1:] / shares[:-1], 4.0)
    assert list(ramp(Settings(), natural=False)) == [0.5, 1.0]
    assert ramp_words(Settings()) == (
        "5 ramp steps from 1/256 of the stimulus, each 4x the last "
        "(2 equal steps for a sheet without natural curvature)"
    )
    assert list(ramp(Settings(steps=1))) == [1.0]
    one = np.eye(2)[None].repeat(3, 0)
    assert not curved(one) and not curved(np.stack([one, one]))
    assert curved(np.stack([one, 1.01 * one]))


def test_a_first_step_outside_the_stimulus_is_a_one_line_error():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(FabkitError, match=r"first step: expected a share .* got 0$"):
        simulate(
            points, np.array([[0, 1, 2]]), np.eye(2)[None], 0.1, settings=Settings(first_step=0)
        )


def _layers(design, delta: float) -> list[SheetFields]:
    """The design's fields as two layers whose feature differs by 2 ``delta`` (the top
    layer's the larger): a natural curvature the design did not ask for."""
    own = design_fields(design)

    def moved(sign: float) -> SheetFields:
        return SheetFields(own.theta, lambda p: own.features(p) + sign * delta, own.made)

    return [moved(-1.0), moved(1.0)]


@pytest.fixture(scope="module")
def fig1():
    return coarse_design()


def test_turning_the_error_over_reflects_the_metrics_about_the_design(fig1):
    printed = _layers(fig1, 0.02)
    thickness = 0.02
    problem = sheet_problem(fig1, printed, 1, thickness, stride=2)
    exact = turned_over(problem, [design_fields(fig1)] * 2)
    designed = sheet_problem(fig1, [design_fields(fig1)] * 2, 1, thickness, stride=2)
    assert np.allclose(exact.metrics + problem.metrics, 2 * designed.metrics)
    assert np.allclose(exact.start_metrics + problem.start_metrics, 2 * designed.start_metrics)
    same = turned_over(problem, printed)  # a print without error turns into itself
    assert np.allclose(same.metrics, problem.metrics)


@pytest.mark.slow
def test_a_side_the_print_error_chose_flips_with_it_and_a_programmed_one_does_not(fig1):
    # Fig. 1's design has one layer: its sides are not programmed. Printed in two layers
    # whose feature differs a little, the sheet bends to the side that difference favours
    # from every start (the continuation ramp erases the start). As fabricated, with that
    # difference as the print's error, half the starts run with it turned over and end on
    # the other side: the verdict says the side is the error's. With the same difference
    # designed (programmed), turning the error over changes nothing: one side from all.
    printed = _layers(fig1, 0.005)
    thickness = 0.02
    surfaces = embedded_targets(fig1)
    error = target_shapes(fig1, printed, surfaces, thickness, designed=[design_fields(fig1)] * 2)
    programmed = target_shapes(fig1, printed, surfaces, thickness, designed=printed)
    turned = set(turned_starts())
    assert turned == {"dome-down", "saddle-down", "random-2"}
    for shape in error:
        sides = {
            over: {end.mirrored for end in shape.starts if end.turned == over}
            for over in (False, True)
        }
        assert len(sides[False]) == 1 and len(sides[True]) == 1  # one side per sheet
        assert sides[False] != sides[True]  # the two prints bend opposite ways
        assert not shape.formed
    for shape in programmed:
        assert len({end.mirrored for end in shape.starts}) == 1  # one side from every start
        assert {end.start for end in shape.starts if end.turned} == turned
    sphere = error[0]
    assert not sphere.starts[0].mirrored  # the error favours the sphere's own side
    assert "its side is the print's error's, not the design's: 3 of 6 starts end" in sphere.line()
    assert STARTS[0] not in turned


def test_a_ramp_run_in_parts_is_the_ramp_bit_for_bit(fig1):
    problem = sheet_problem(fig1, _layers(fig1, 0.005), 1, 0.02, stride=2)
    mesh = problem.mesh
    args = (mesh.points, mesh.triangles, problem.metrics, 0.02, 0.5, Settings(seed="saddle"))
    whole = simulate(*args, start_metrics=problem.start_metrics)
    first = ramp_part(*args, None, problem.start_metrics, 0, 1)
    rest = ramp_part(*args, first.positions, problem.start_metrics, 1, None)
    assert np.array_equal(rest.positions, whole.positions)
    assert first.iterations + rest.iterations == whole.iterations


def test_starts_that_relax_alike_share_the_rest_of_the_ramp(fig1, monkeypatch):
    """Every start of a layered sheet relaxes to one state at the first ramp step; the
    rest runs once per group of starts (of a sheet: the error turned over is another),
    its lead's result that of a whole ramp from its start."""
    from fabkit.mechanics import verdict

    found = []
    group = verdict._groups
    monkeypatch.setattr(verdict, "_groups", lambda *args: found.append(group(*args)) or found[-1])
    monkeypatch.setenv("FABKIT_CACHE", "off")
    printed = _layers(fig1, 0.005)
    shapes = target_shapes(fig1, printed, [1], 0.02, designed=[design_fields(fig1)] * 2)
    (groups,) = found
    turned = [k for k, s in enumerate(STARTS) if s in turned_starts()]
    assert sorted(groups.values()) == sorted([[k for k in range(6) if k not in turned], turned])
    problem = sheet_problem(fig1, printed, 1, 0.02, stride=verdict.grid_stride(fig1))
    mesh = problem.mesh
    lead = simulate(
        mesh.points, mesh.triangles, problem.metrics, 0.02, 0.5, Settings(),
        start_metrics=problem.start_metrics,
    )  # fmt: skip
    (shape,) = shapes
    assert shape.starts[0].rms == pytest.approx(
        verdict.compare(problem.coarse, problem.simulation(lead), problem.patch_size).rms, abs=1e-12
    )
