"""Simulations kept on disk by everything they depend on, so no sheet is simulated twice.

A simulation (:func:`fabkit.mechanics.simulate.simulate`) is a deterministic function of
its inputs (the flat mesh, the reference metrics as made and under the stimulus, the
thickness, Poisson's ratio, the settings and start) and of the code that computes it. A
verdict simulates every target from six starts, and a second ``fabkit run`` of the same
spec (another output folder, another port) asks for the very same simulations: each
result is kept under the SHA-256 of all of its inputs, the text of the solver's modules
and the numpy and scipy versions, so a hit is the result the solver would give, bit for
bit, and any change of input or code misses.

Where: ``$FABKIT_CACHE`` (a folder; ``off`` keeps nothing), else
``$XDG_CACHE_HOME/fabkit/simulations``, else ``~/.cache/fabkit/simulations``. At most
:data:`KEEP` results are kept (the oldest go). A result that cannot be read is computed
again; one that cannot be written is not kept: the cache never changes a result nor
stops a command.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np
import scipy

from fabkit.mechanics import mesh, shell
from fabkit.mechanics import simulate as solver
from fabkit.mechanics.simulate import Settings, Simulation

CACHE_ENV = "FABKIT_CACHE"
KEEP = 4000
"""Most results kept (about 15 kB each on an 800-triangle mesh)."""


def _code_digest() -> bytes:
    """What the result depends on besides its inputs: the solver's modules and versions."""
    digest = hashlib.sha256(f"numpy {np.__version__} scipy {scipy.__version__}".encode())
    for module in (solver, shell, mesh):
        digest.update(Path(module.__file__).read_bytes())
    return digest.digest()


_CODE = _code_digest()


def folder() -> Path | None:
    """The cache folder (None: ``FABKIT_CACHE=off``)."""
    given = os.environ.get(CACHE_ENV, "")
    if given.lower() == "off":
        return None
    if given:
        return Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "fabkit" / "simulations"


def key(*inputs: object) -> str:
    """The SHA-256 (hex) of ``inputs`` (arrays by dtype, shape and bytes; settings and
    numbers by their repr) and of the solver's code."""
    digest = hashlib.sha256(_CODE)
    for item in inputs:
        if isinstance(item, np.ndarray):
            array = np.ascontiguousarray(item)
            digest.update(f"{array.dtype.str}{array.shape}".encode())
            digest.update(array.tobytes())
        else:
            digest.update(repr(item).encode())
    return digest.hexdigest()


def simulation_key(
    points: np.ndarray,
    triangles: np.ndarray,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    settings: Settings,
    start_metrics: np.ndarray | None,
) -> str:
    """The key of a simulation from the flat sheet (seeded as ``settings`` says)."""
    made = np.eye(2) if start_metrics is None else np.asarray(start_metrics, dtype=float)
    return key(
        np.asarray(points, dtype=float),
        np.asarray(triangles),
        np.asarray(metrics, dtype=float),
        made,
        float(thickness),
        float(poisson),
        settings,
    )


def load(name: str) -> Simulation | None:
    """The result kept under ``name`` (None if there is none, or it cannot be read)."""
    where = folder()
    if where is None:
        return None
    try:
        with np.load(where / f"{name}.npz", allow_pickle=False) as kept:
            return Simulation(
                kept["positions"].copy(),
                float(kept["energy"]),
                int(kept["iterations"]),
                bool(kept["converged"]),
                float(kept["seconds"]),
            )
    except (OSError, KeyError, ValueError):
        return None


def store(name: str, result: Simulation) -> None:
    """Keep ``result`` under ``name`` (written whole or not at all; errors ignored)."""
    where = folder()
    if where is None:
        return
    try:
        where.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".part.npz", dir=where)
        os.close(fd)
        try:
            np.savez(
                tmp,
                positions=result.positions,
                energy=result.energy,
                iterations=result.iterations,
                converged=result.converged,
                seconds=result.seconds,
            )
            os.replace(tmp, where / f"{name}.npz")
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        _prune(where)
    except OSError:
        return


def _prune(where: Path) -> None:
    """Remove the oldest results beyond :data:`KEEP`."""
    kept = list(where.glob("*.npz"))
    if len(kept) <= KEEP:
        return
    kept.sort(key=lambda path: (path.stat().st_mtime_ns, path.name))
    for path in kept[: len(kept) - KEEP]:
        path.unlink(missing_ok=True)
