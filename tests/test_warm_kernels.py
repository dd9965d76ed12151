"""``fabkit run`` compiles the shell's numba kernels in its worker while it solves
(:func:`fabkit.mechanics.simulate.warm_kernels`): that helps only if the warm-up compiles
every kernel with the argument types a real simulation passes, so that the run's own
simulations compile nothing more (a first run after an install: 49.8 -> 45.6 s for the
README's main command, README.md)."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.conftest import ROOT

CHECK = """
import numba
from fabkit.mechanics import kernels
from fabkit.mechanics.simulate import warm_kernels
from tests.conftest import coarse_design
from fabkit.design.layers import layered
from fabkit.mechanics.verdict import design_verdict

def signatures():
    return {
        name: set(kernel.signatures)
        for name, kernel in vars(kernels).items()
        if isinstance(kernel, numba.core.registry.CPUDispatcher)
    }

warm_kernels()
warmed = signatures()
sheet = layered(coarse_design("two_shapes.toml"), 2, 0.05)[0]
design_verdict(sheet, 0.05, starts=("dome",))
added = {name: sigs - warmed[name] for name, sigs in signatures().items() if sigs - warmed[name]}
assert not added, f"compiled after the warm-up: {added}"
print(",".join(sorted(name for name, sigs in warmed.items() if sigs)))
"""


def test_after_the_warm_up_a_layered_sheet_s_simulation_compiles_no_kernel():
    done = subprocess.run(
        [sys.executable, "-c", CHECK],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "FABKIT_CACHE": "off", "FABKIT_WORKERS": "1"},
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    warmed = set(done.stdout.strip().split(","))
    assert {"fold_angles", "add_face_blocks", "face_energies", "gradient"} <= warmed
