"""The design file: the contract between the solver and every stage after it.

``design.npz`` (``np.savez_compressed``, no pickles) holds, with S surfaces, N
features, k stimuli and an (nu, nv) material grid:

======== =============== ===========================================================
key      shape           meaning
======== =============== ===========================================================
format   0-d str         ``fabkit-design/2`` (files without it are format 1: the same
                         arrays, perhaps without ``error``)
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
                         ``solver.tolerance`` (see docs/solver.md); NaN where not estimated
                         (files written before this key existed read as all NaN)
stimuli  (S, k)          stimulus of every surface
spec     0-d str         the normalised spec as JSON (a design file is self-describing)
======== =============== ===========================================================

Everything is NaN outside ``valid``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from fabkit.atomic import atomic_path, check_name
from fabkit.errors import FabkitError
from fabkit.limits import DESIGN_FEATURES, DESIGN_NODES, DESIGN_SURFACES, MAGNITUDE
from fabkit.npzfile import ArrayHeader, check_magnitude, read_npz
from fabkit.problem.spec import Spec, spec_from_json
from fabkit.readfile import parse_json

FORMAT = "fabkit-design/2"
"""The format tag this version writes; a file without a tag is format 1 and still read."""
KEYS = ("u", "v", "valid", "alpha", "beta", "eps", "r", "n", "error", "stimuli", "spec")
OPTIONAL = ("error", "format")
"""Keys a design file written before they existed lacks: ``error`` reads as NaN there
(not estimated), no ``format`` means format 1."""


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

    @cached_property
    def problem(self) -> Spec:
        """The spec this design solves, rebuilt once from the embedded JSON ``spec``."""
        return spec_from_json(self.spec)

    def knowing(self, spec: Spec) -> Design:
        """This design with :attr:`problem` set to ``spec``, the spec it was solved from,
        so that the embedded JSON is not parsed again; returns the design itself."""
        self.__dict__["problem"] = spec  # what the cached property would store
        return self

    @property
    def step(self) -> float:
        """Grid step in u and v (design units)."""
        return float(self.u[1] - self.u[0]) if len(self.u) > 1 else 0.0

    def save(self, path: str | Path) -> None:
        """Write ``design.npz`` atomically (no half-written file on failure)."""
        arrays = {key: getattr(self, key) for key in KEYS if key != "spec"}
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez_compressed(handle, format=np.array(FORMAT), spec=np.array(self.spec), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Design:
        """Read and check a design file; a corrupt, foreign or hostile file is a one-line
        error, refused before any array is read when its headers already tell (see
        :mod:`fabkit.npzfile`; sizes within :data:`fabkit.limits.DESIGN_NODES` and
        ARCHIVE_BYTES). Values outside ``valid`` are set to NaN, as the contract says."""
        path = Path(path)
        if not path.is_file():
            raise FabkitError(f"design file '{path}' does not exist")
        arrays = read_npz(
            path,
            f"{path}: cannot read design file",
            text=("spec", "format"),
            keys=lambda found: _check_keys(found, path),
            check=lambda headers: _check_headers(headers, path),
        )
        spec = str(arrays.pop("spec"))
        _check_format(str(arrays.pop("format", "")), path)
        valid = arrays["valid"]
        arrays.setdefault("error", np.full(valid.shape, np.nan))
        for key in ("alpha", "beta", "eps", "r", "n"):
            mask = valid[..., None] if key in ("r", "n") else valid
            arrays[key] = np.where(mask, arrays[key], np.nan)
        design = cls(**arrays, spec=spec)
        design.check_values(path)
        check_names(spec, path)
        return design

    def check_shapes(self, where: str | Path = "design") -> None:
        """Refuse arrays whose shapes do not fit the contract."""
        shapes = {key: getattr(self, key).shape for key in KEYS if key != "spec"}
        _check_shapes(shapes, where)
        if self.valid.dtype != bool:
            raise FabkitError(f"{where}: 'valid' must be boolean")

    def check_values(self, where: str | Path = "design") -> None:
        """Refuse non-numeric arrays, a grid that is not uniform, a design without a solved
        point, and non-finite or implausible (beyond MAGNITUDE) values at valid points."""
        for key in ("u", "v", "alpha", "beta", "eps", "r", "n", "error", "stimuli"):
            if getattr(self, key).dtype.kind not in "biuf":
                raise FabkitError(f"{where}: '{key}' is not numeric")
        if not self.valid.any():
            raise FabkitError(
                f"{where}: the design has no solved point (grid {len(self.u)} x {len(self.v)})"
            )
        for key in ("u", "v"):
            _check_axis(getattr(self, key), key, where)
        checks = {
            "stimuli": self.stimuli,
            "alpha": self.alpha[self.valid],
            "beta": self.beta[self.valid],
            "eps": self.eps[:, self.valid],
            "r": self.r[:, self.valid],
            "n": self.n[:, self.valid],
        }
        error = self.error[self.valid]
        if np.isinf(error).any() or (error < 0).any():
            raise FabkitError(f"{where}: 'error' must be a non-negative estimate or NaN")
        for key, values in checks.items():
            if not np.isfinite(values).all():
                raise FabkitError(f"{where}: '{key}' has non-finite values (at valid points)")
            check_magnitude(values, key, where)
        for key in ("alpha", "beta"):
            if not (checks[key] > 0).all():
                raise FabkitError(f"{where}: '{key}' must be positive at valid points")


def _check_keys(found: set[str], path: Path) -> None:
    """Refuse a file that is not a design from its member names alone."""
    missing = [key for key in KEYS if key not in found and key not in OPTIONAL]
    if missing:
        raise FabkitError(f"{path}: not a fabkit design file (no '{missing[0]}' array)")
    unknown = sorted(found - set(KEYS) - set(OPTIONAL))
    if unknown:
        raise FabkitError(f"{path}: not a fabkit design file (unknown array '{unknown[0]}')")


def _check_format(tag: str, path: Path) -> None:
    """Refuse a design file tagged with a format this version does not read."""
    if tag and tag != FORMAT:
        raise FabkitError(
            f"{path}: a design file of format '{tag[:40]}', this fabkit reads {FORMAT} "
            "(or untagged format 1)"
        )


def _check_headers(headers: Mapping[str, ArrayHeader], path: Path) -> None:
    """Refuse a design file from its array headers alone: dtypes and shapes, and its grid,
    surface and feature counts within the limits."""
    if headers["valid"].dtype.kind != "b":
        raise FabkitError(f"{path}: 'valid' must be boolean")
    _check_shapes({key: h.shape for key, h in headers.items() if key != "spec"}, path)


def _check_shapes(shapes: Mapping[str, tuple[int, ...]], where: str | Path) -> None:
    """The shapes of a design's arrays fit together (module docstring) and the limits."""
    for key, dims in (("u", 1), ("v", 1), ("stimuli", 2), ("eps", 3)):
        if len(shapes[key]) != dims:
            raise FabkitError(f"{where}: '{key}' has shape {shapes[key]}, expected {dims}-d")
    (nu,), (nv,) = shapes["u"], shapes["v"]
    surfaces, stimuli = shapes["stimuli"]
    features = shapes["eps"][0]
    if nu * nv > DESIGN_NODES:
        raise FabkitError(
            f"{where}: the design grid {nu} x {nv} has {nu * nv} nodes, more than the limit of "
            f"{DESIGN_NODES} nodes"
        )
    counts = {"surfaces": (surfaces, DESIGN_SURFACES), "features": (features, DESIGN_FEATURES)}
    counts["stimulus components"] = (stimuli, DESIGN_FEATURES)
    for name, (count, limit) in counts.items():
        if count > limit:
            raise FabkitError(f"{where}: {count} {name}, more than the limit of {limit}")
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
        if key in shapes and tuple(shapes[key]) != shape:
            raise FabkitError(f"{where}: '{key}' has shape {tuple(shapes[key])}, expected {shape}")


def _check_axis(values: np.ndarray, key: str, where: str | Path) -> None:
    """``values`` (n,) must be a finite, increasing, uniform grid containing 0."""
    steps = np.diff(values)
    ok = len(values) >= 2 and bool(np.isfinite(values).all()) and steps.min() > 0
    ok = ok and np.abs(values).max() <= MAGNITUDE
    ok = ok and np.ptp(steps) <= 1e-6 * steps.mean() and np.abs(values).min() <= 1e-6 * steps[0]
    if not ok:
        raise FabkitError(
            f"{where}: '{key}' must be an increasing uniform grid containing 0, of at least "
            f"2 finite values within +-{MAGNITUDE:g}"
        )


def check_names(spec: str, where: str | Path) -> None:
    """Refuse an embedded spec whose JSON nests too deep or whose surface names could not
    safely be part of a file name (see :func:`fabkit.atomic.check_name`)."""
    table = parse_json(spec, f"{where}: embedded spec")
    surfaces = table.get("surfaces") if isinstance(table, dict) else None
    for index, surface in enumerate(surfaces if isinstance(surfaces, list) else []):
        if isinstance(surface, dict) and "name" in surface:
            check_name(surface["name"], f"{where}: surfaces[{index}].name")
