"""The verdict on which shape a sheet takes: several starts, and one figure per target."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.mechanics import verdict
from fabkit.mechanics.simulate import STARTS, Settings, seeded
from fabkit.mechanics.verdict import StartEnd, design_verdict
from tests.conftest import coarse_design


def test_the_starts_are_distinct_and_come_in_pairs_of_either_sign():
    points = np.random.default_rng(0).uniform(-1, 1, (200, 2))
    lifted = {start: seeded(points, Settings(seed=start))[:, 2] for start in STARTS}
    assert np.allclose(lifted["dome"], -lifted["dome-down"])
    heights = np.array(list(lifted.values()))
    radius = np.max(np.linalg.norm(points - points.mean(0), axis=1))
    assert np.allclose(np.abs(heights).max(axis=1), 0.05 * radius, rtol=0.1)  # 5 % of it
    correlation = np.corrcoef(heights)
    assert (correlation[~np.eye(len(STARTS), dtype=bool)] < 0.999).all()  # no two alike


def test_a_side_the_metric_leaves_open_is_not_formed_whatever_the_order_of_the_starts():
    # Fig. 1 programmed by its metric alone: the sphere ends as itself from some starts and
    # as its mirror image from others. It is formed from no order of the starts, and the
    # verdict says which starts went where.
    design = coarse_design()
    verdict = design_verdict(design)
    sphere = verdict.shapes[0]
    mirrored = [end.start for end in sphere.starts if end.mirrored]
    assert 0 < len(mirrored) < len(STARTS)
    assert not sphere.formed and not verdict.formed
    verb = "ends" if len(mirrored) == 1 else "end"  # "1 of 6 starts ends", "2 ... end"
    assert f"its side is not programmed: {len(mirrored)} of 6 starts {verb} as its mirror" in (
        sphere.line()
    )
    turned = design_verdict(design, starts=STARTS[::-1])
    for one, other in zip(verdict.shapes, turned.shapes, strict=True):
        assert one.formed == other.formed and one.rms == other.rms
        assert sorted(one.starts, key=lambda e: e.start) == sorted(
            other.starts, key=lambda e: e.start
        )


def test_the_worst_start_gives_the_figures_and_a_missed_one_comes_first():
    ends = (
        StartEnd("dome", 0.01, 0.02, False, True),
        StartEnd("dome-down", 0.012, 0.03, True, True),
        StartEnd("saddle", 0.02, 0.05, False, True),
    )
    from fabkit.mechanics.verdict import worst

    assert worst(ends, 0.03).start == "dome-down"  # mirrored: missed, though nearer
    assert worst(ends[::2], 0.03).start == "saddle"  # both formed: the farther one


@pytest.mark.slow
def test_a_mirrored_start_of_a_sheet_without_natural_curvature_is_reflected_exactly(
    monkeypatch,
):
    # one layer: z -> -z leaves the energy unchanged, so from the dome down the sheet ends
    # in the mirror image of where it ends from the dome up; reflected, not simulated
    monkeypatch.setenv("FABKIT_CACHE", "off")
    design = coarse_design()
    reflected = design_verdict(design)
    monkeypatch.setattr(verdict, "_mirror_sources", lambda calls: {})
    simulated = design_verdict(design)
    for one, other in zip(reflected.shapes, simulated.shapes, strict=True):
        for a, b in zip(one.starts, other.starts, strict=True):
            assert a.start == b.start and a.mirrored == b.mirrored
            assert a.rms == pytest.approx(b.rms, rel=1e-9) and a.converged == b.converged
