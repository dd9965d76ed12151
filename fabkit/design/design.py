"""The design file: the contract between the solver and every stage after it.

``design.npz`` (``np.savez_compressed``, no pickles) holds, with S surfaces, N
features, k stimuli and an (nu, nv) material grid:

======== =============== ===========================================================
key      shape           meaning
======== =============== ===========================================================
u, v     (nu,), (nv,)    uniform material grids containing 0 (design units)
valid    (nu, nv) bool   solved points
alpha    (nu, nv)        arc-length scale of u-curves on the flat sheet
beta     (nu, nv)        arc-length scale of v-curves on the flat sheet
eps      (N, nu, nv)     designable features
r        (S, nu, nv, 2)  chart coordinates on surface s; r[0] is the flat-sheet point
n        (S, nu, nv, 2)  director image, chart components, unit in surface s's metric
error    (nu, nv)        the solver's error estimate of every point (dimensionless): the
                         largest relative difference of alpha lambda1 and beta lambda2 (on
                         every surface) between the marches at step h and h/2; at most
                         ``solver.tolerance`` (see docs/solver.md)
stimuli  (S, k)          stimulus of every surface
spec     0-d str         the normalised spec as JSON (a design file is self-describing)
======== =============== ===========================================================

Everything is NaN outside ``valid``.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.atomic import atomic_path
from fabkit.errors import FabkitError

KEYS = ("u", "v", "valid", "alpha", "beta", "eps", "r", "n", "error", "stimuli", "spec")


@dataclass(frozen=True)
class Design:
    """A solved design on the material grid (see the module docstring for shapes)."""

    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    eps: np.ndarray
    r: np.ndarray
    n: np.ndarray
    error: np.ndarray
    stimuli: np.ndarray
    spec: str

    @property
    def step(self) -> float:
        """Grid step in u and v (design units)."""
        return float(self.u[1] - self.u[0]) if len(self.u) > 1 else 0.0

    def save(self, path: str | Path) -> None:
        """Write ``design.npz`` atomically (no half-written file on failure)."""
        arrays = {key: getattr(self, key) for key in KEYS if key != "spec"}
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez_compressed(handle, spec=np.array(self.spec), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Design:
        """Read and check a design file; a corrupt or foreign file is a one-line error."""
        path = Path(path)
        if not path.is_file():
            raise FabkitError(f"design file '{path}' does not exist")
        if not zipfile.is_zipfile(path):
            raise FabkitError(f"{path}: cannot read design file (not an .npz archive)")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [k for k in KEYS if k not in data.files]
                if missing:
                    raise FabkitError(f"{path}: not a fabkit design file (no '{missing[0]}' array)")
                arrays = {k: data[k] for k in KEYS}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise FabkitError(f"{path}: cannot read design file ({exc})") from None
        arrays["spec"] = str(arrays["spec"])
        design = cls(**arrays)
        design.check_shapes(path)
        design.check_values(path)
        return design

    def check_shapes(self, where: str | Path = "design") -> None:
        """Refuse arrays whose shapes do not fit the contract."""
        nu, nv = len(self.u), len(self.v)
        surfaces, features = self.stimuli.shape[0], self.eps.shape[0]
        expected = {
            "valid": (nu, nv),
            "alpha": (nu, nv),
            "beta": (nu, nv),
            "eps": (features, nu, nv),
            "r": (surfaces, nu, nv, 2),
            "n": (surfaces, nu, nv, 2),
            "error": (nu, nv),
        }
        for key, shape in expected.items():
            if getattr(self, key).shape != shape:
                raise FabkitError(
                    f"{where}: '{key}' has shape {getattr(self, key).shape}, expected {shape}"
                )
        if self.valid.dtype != bool:
            raise FabkitError(f"{where}: 'valid' must be boolean")

    def check_values(self, where: str | Path = "design") -> None:
        """Refuse non-numeric arrays, and non-finite values on the grid or at valid points."""
        for key in ("u", "v", "alpha", "beta", "eps", "r", "n", "error", "stimuli"):
            if not np.issubdtype(getattr(self, key).dtype, np.number):
                raise FabkitError(f"{where}: '{key}' is not numeric")
        checks = {
            "u": self.u,
            "v": self.v,
            "stimuli": self.stimuli,
            "alpha": self.alpha[self.valid],
            "beta": self.beta[self.valid],
            "eps": self.eps[:, self.valid],
            "r": self.r[:, self.valid],
            "n": self.n[:, self.valid],
            "error": self.error[self.valid],
        }
        for key, values in checks.items():
            if not np.isfinite(values).all():
                raise FabkitError(f"{where}: '{key}' has non-finite values (at valid points)")
