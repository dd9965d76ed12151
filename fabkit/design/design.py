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
layering (2,)            (format 3 only) a sheet of ``count`` equal layers: [count,
                         thickness] (thickness: the whole sheet's, design units)
turn     (nu, nv)        (format 3) the flat director's turn per unit height (rad per
                         design unit)
slope    (N, nu, nv)     (format 3) each feature's change per unit height (per design unit)
======== =============== ===========================================================

Everything is NaN outside ``valid``. A design of one layer is format 2 (what an older
fabkit reads); a layered one (:class:`Layering`, :mod:`fabkit.design.layers`) format 3.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path, check_name
from fabkit.files.npzfile import ArrayHeader, check_magnitude, read_npz
from fabkit.files.readfile import parse_json
from fabkit.limits import DESIGN_FEATURES, DESIGN_NODES, DESIGN_SURFACES, MAGNITUDE
from fabkit.problem.spec import Spec, spec_from_json

FORMAT = "fabkit-design/2"
"""The format tag of a one-layer design; a file without a tag is format 1 and still read."""
LAYERED_FORMAT = "fabkit-design/3"
"""The format tag of a layered design (it carries :data:`LAYER_KEYS`)."""
KEYS = ("u", "v", "valid", "alpha", "beta", "eps", "r", "n", "error", "stimuli", "spec")
LAYER_KEYS = ("layering", "turn", "slope")
OPTIONAL = ("error", "format", *LAYER_KEYS)
"""Keys a design file written before they existed lacks: ``error`` reads as NaN there
(not estimated), no ``format`` means format 1; the layer keys come all together or not."""
MAX_LAYERS = 64
"""Most layers a design may ask for (a sheet of more is no thin sheet any more)."""


@dataclass(frozen=True)
class Layering:
    """A sheet of ``count`` equal layers, ``thickness`` thick in all (design units).

    Layer k (0 at the bottom, the flat sheet's -normal side) lies at mid-height
    z_k = (k - (count - 1) / 2) * thickness / count from the mid-surface; its flat
    director is the design's turned by z_k * ``turn`` (nu, nv; rad per design unit) and
    its features are the design's + z_k * ``slope`` (N, nu, nv; per design unit). The
    layers' mean metric is the design's (to first order in z) and their spread through
    the thickness gives the sheet a natural curvature (:mod:`fabkit.design.layers`).
    """

    count: int
    thickness: float
    turn: np.ndarray
    slope: np.ndarray

    @property
    def heights(self) -> np.ndarray:
        """Mid-heights (count,) of the layers from the mid-surface, bottom first."""
        return (np.arange(self.count) - (self.count - 1) / 2) * self.thickness / self.count


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
    layering: Layering | None = None

    @cached_property
    def problem(self) -> Spec:
        """The spec this design solves, rebuilt once from the embedded JSON ``spec``."""
        return spec_from_json(self.spec)

    @cached_property
    def second_forms(self) -> np.ndarray:
        """(S, 3, nu, nv) second fundamental forms (II_uu, II_uv, II_vv) of every surface
        at the grid points, in material coordinates (u, v), with the surface's normal
        X_u x X_v; NaN where not solved or not embedded (the flat sheet: 0). Computed once
        per design (every layering of it asks for them: :mod:`fabkit.design.layers`)."""
        forms = np.full((len(self.problem.targets), 3, *self.valid.shape), np.nan)
        forms[0] = np.where(self.valid, 0.0, np.nan)
        for k, target in enumerate(self.problem.targets[1:], start=1):
            with np.errstate(all="ignore"):
                points = target.surface.embed(np.where(self.valid[..., None], self.r[k], 0.0))
            if points is None:
                continue
            points = np.where(self.valid[..., None], points, np.nan)
            x_u = _grid_derivative(points, self.step, 0)
            x_v = _grid_derivative(points, self.step, 1)
            normal = np.cross(x_u, x_v)
            normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
            x_uu = _grid_derivative(x_u, self.step, 0)
            x_uv = 0.5 * (_grid_derivative(x_u, self.step, 1) + _grid_derivative(x_v, self.step, 0))
            x_vv = _grid_derivative(x_v, self.step, 1)
            for i, second in enumerate((x_uu, x_uv, x_vv)):
                forms[k, i] = np.sum(second * normal, axis=-1)
        return forms

    def knowing(self, spec: Spec) -> Design:
        """This design with :attr:`problem` set to ``spec``, the spec it was solved from,
        so that the embedded JSON is not parsed again; returns the design itself."""
        self.__dict__["problem"] = spec  # what the cached property would store
        return self

    def with_layering(self, layering: Layering | None) -> Design:
        """This design in the given layers."""
        return self._derived(layering=layering)

    def _derived(self, **changes: Any) -> Design:
        """This design with ``changes`` (dataclass fields), carrying the parsed spec when
        it was parsed already, so that it is not parsed again."""
        derived = replace(self, **changes)
        if "problem" in self.__dict__:
            derived.knowing(self.problem)
        return derived

    @property
    def step(self) -> float:
        """Grid step in u and v (design units)."""
        return float(self.u[1] - self.u[0]) if len(self.u) > 1 else 0.0

    def layer(self, k: int) -> Design:
        """Layer ``k`` (0 = bottom) of a layered design, as a one-layer design: its own
        flat director (``n[0]``) and features; the other arrays are the design's."""
        layering = self.layering
        if layering is None or not 0 <= k < layering.count:
            raise FabkitError(f"design: no layer {k} (the design has {self.layers} layer(s))")
        z = layering.heights[k]
        turn = z * layering.turn
        n0 = self.n[0]
        cos, sin = np.cos(turn), np.sin(turn)
        turned = np.stack(
            [cos * n0[..., 0] - sin * n0[..., 1], sin * n0[..., 0] + cos * n0[..., 1]], -1
        )
        n = self.n.copy()
        n[0] = turned
        return self._derived(n=n, eps=self.eps + z * layering.slope, layering=None)

    @property
    def layers(self) -> int:
        """How many layers the sheet is made of (1 without a layering)."""
        return 1 if self.layering is None else self.layering.count

    def save(self, path: str | Path) -> None:
        """Write ``design.npz`` atomically (no half-written file on failure)."""
        arrays = {key: getattr(self, key) for key in KEYS if key != "spec"}
        tag = FORMAT
        if self.layering is not None:
            layering = self.layering
            arrays["layering"] = np.array([layering.count, layering.thickness], dtype=float)
            arrays["turn"], arrays["slope"] = layering.turn, layering.slope
            tag = LAYERED_FORMAT
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez_compressed(handle, format=np.array(tag), spec=np.array(self.spec), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Design:
        """Read and check a design file; a corrupt, foreign or hostile file is a one-line
        error, refused before any array is read when its headers already tell (see
        :mod:`fabkit.files.npzfile`; sizes within :data:`fabkit.limits.DESIGN_NODES` and
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
        _check_format(str(arrays.pop("format", "")), path, LAYER_KEYS[0] in arrays)
        valid = arrays["valid"]
        arrays.setdefault("error", np.full(valid.shape, np.nan))
        for key in ("alpha", "beta", "eps", "r", "n", "turn", "slope"):
            if key in arrays:
                mask = valid[..., None] if key in ("r", "n") else valid
                arrays[key] = np.where(mask, arrays[key], np.nan)
        layering = _layering(arrays, path)
        design = cls(**arrays, spec=spec, layering=layering)
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
    layered = [key for key in LAYER_KEYS if key in found]
    if layered and len(layered) < len(LAYER_KEYS):
        absent = next(key for key in LAYER_KEYS if key not in found)
        raise FabkitError(f"{path}: a layered design without its '{absent}' array")


def _check_format(tag: str, path: Path, layered: bool) -> None:
    """Refuse a design file tagged with a format this version does not read, or whose
    tag does not say what it holds (layers need format 3)."""
    if tag and tag not in (FORMAT, LAYERED_FORMAT):
        raise FabkitError(
            f"{path}: a design file of format '{tag[:40]}', this fabkit reads {FORMAT}, "
            f"{LAYERED_FORMAT} (layered) or untagged format 1"
        )
    if layered != (tag == LAYERED_FORMAT):
        raise FabkitError(
            f"{path}: format '{tag or 1}' {'with' if layered else 'without'} layer arrays"
        )


def _layering(arrays: dict[str, np.ndarray], path: Path) -> Layering | None:
    """The layering the arrays carry (taken out of ``arrays``), checked; None if none."""
    if LAYER_KEYS[0] not in arrays:
        return None
    header, turn, slope = (arrays.pop(key) for key in LAYER_KEYS)
    if header.shape != (2,) or header.dtype.kind not in "iuf" or not np.isfinite(header).all():
        raise FabkitError(f"{path}: 'layering' must hold [count, thickness]")
    count, thickness = float(header[0]), float(header[1])
    if count != int(count) or not 2 <= count <= MAX_LAYERS or not 0 < thickness <= MAGNITUDE:
        raise FabkitError(
            f"{path}: 'layering' must be 2 to {MAX_LAYERS} layers of a positive thickness, "
            f"got {count:g} layers, thickness {thickness:g}"
        )
    valid = arrays["valid"]
    for key, values, shape in (
        ("turn", turn, valid.shape),
        ("slope", slope, arrays["eps"].shape),
    ):
        if values.shape != shape or values.dtype.kind not in "iuf":
            raise FabkitError(f"{path}: '{key}' has shape {values.shape}, expected {shape}")
        inside = values[..., valid]
        if not np.isfinite(inside).all():
            raise FabkitError(f"{path}: '{key}' has non-finite values (at valid points)")
        check_magnitude(inside, key, path)
    return Layering(int(count), thickness, turn.astype(float), slope.astype(float))


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
        "layering": (2,),
        "turn": (nu, nv),
        "slope": (features, nu, nv),
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
    safely be part of a file name (see :func:`fabkit.files.atomic.check_name`)."""
    table = parse_json(spec, f"{where}: embedded spec")
    surfaces = table.get("surfaces") if isinstance(table, dict) else None
    for index, surface in enumerate(surfaces if isinstance(surfaces, list) else []):
        if isinstance(surface, dict) and "name" in surface:
            check_name(surface["name"], f"{where}: surfaces[{index}].name")


def _grid_derivative(values: np.ndarray, step: float, axis: int) -> np.ndarray:
    """d values / d (u or v) (axis 0 or 1 of (nu, nv, ...)): central where both
    neighbours are finite, else one-sided; NaN where neither neighbour is."""
    moved = np.moveaxis(values, axis, 0)
    ahead = np.full_like(moved, np.nan)
    behind = np.full_like(moved, np.nan)
    ahead[:-1] = (moved[1:] - moved[:-1]) / step
    behind[1:] = (moved[1:] - moved[:-1]) / step
    central = 0.5 * (ahead + behind)
    out = np.where(np.isfinite(central), central, np.where(np.isfinite(ahead), ahead, behind))
    return np.moveaxis(out, 0, axis)
