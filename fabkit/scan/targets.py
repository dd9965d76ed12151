"""What a scan is compared with: a target surface at the part's printed size, in mm, and
the simulated sheet where a run made one.

From a run's folder (``fabkit run --out``): its report.json names the folder of the
shapes (``as_fabricated/``, or ``as_designed/`` when the machine file was not simulated)
where every target's surface placed as the sheet lies (``<target>_target.ply``) and the
simulated sheet (``<target>.ply``) are, in mm; the patch diameter is the verdict's.
From a design alone (``design.npz``): the target embedded over the design's grid points in
its part at ``size_mm`` (the part's longest side), cut as ``fabkit run`` cuts it for a
process (its road width sets the minimum width, the sheet's thickness, its layers' height
times the design's layers, the trim), its diameter that of those points.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.readfile import read_limited
from fabkit.limits import SCAN_BYTES


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in mm: ``vertices_mm`` (V, 3), ``triangles`` (F, 3)."""

    vertices_mm: np.ndarray
    triangles: np.ndarray


@dataclass(frozen=True, eq=False)
class Target:
    """Target ``name``'s surface (``mesh``, mm) and its patch diameter (mm: the largest
    distance between two of its points, what the verdict's percentages are shares of);
    ``sheet``: the simulated sheet placed on it (``sheet_what``: "as fabricated" or "as
    designed") and ``tolerance``, the limit the run's verdict held it to (a share of the
    diameter), both None without a run."""

    name: str
    mesh: Mesh
    diameter_mm: float
    sheet: Mesh | None = None
    sheet_what: str = ""
    tolerance: float | None = None

    @property
    def extent_mm(self) -> float:
        """The diagonal of the target's bounding box (mm)."""
        return float(np.linalg.norm(np.ptp(self.mesh.vertices_mm, axis=0)))


def run_target(folder: str | Path, name: str | None) -> Target:
    """Target ``name`` (None: the run's only one) of the run in ``folder`` (module
    docstring)."""
    folder = Path(folder)
    report = _report(folder)
    shapes = report.get("shapes") or {}
    entries = {entry.get("target"): entry for entry in shapes.get("targets", [])}
    if not entries:
        raise FabkitError(
            f"{folder}: the run wrote no shapes of the sheet (was it run with --no-simulate?): "
            "compare with --design design.npz --size MM instead"
        )
    name = _chosen(name, list(entries), str(folder))
    entry = entries[name]
    target = _mesh(folder, entry.get("target_mesh"))
    sheet = _mesh(folder, entry.get("mesh"))
    figures = _verdict_figures(report, shapes.get("what"), name)
    diameter, limit = figures.get("patch_diameter_mm"), figures.get("limit_pct")
    return Target(
        name,
        target,
        diameter if _number(diameter, 1e6) else _diameter(target.vertices_mm),
        sheet,
        str(shapes.get("what", "")),
        limit / 100 if _number(limit, 100) else None,
    )


def _number(value: object, below: float) -> bool:
    """``value`` is a number above 0 and below ``below`` (a figure of a report)."""
    return isinstance(value, (int, float)) and 0 < value < below


def design_target(
    path: str | Path,
    name: str | None,
    size_mm: float,
    road_width_mm: float,
    layer_height_mm: float,
) -> Target:
    """Target ``name`` (None: the design's only one) of the design in ``path`` at
    ``size_mm``, its part cut for a process of ``road_width_mm`` and ``layer_height_mm``
    (module docstring)."""
    from fabkit.design.design import Design
    from fabkit.field.part import PartRequest, part_of_size
    from fabkit.mechanics.mesh import design_mesh
    from fabkit.mechanics.verdict import embedded_targets

    if not (np.isfinite(size_mm) and size_mm > 0):
        raise FabkitError(f"--size {size_mm:g}: expected a positive finite number of mm")
    design = Design.load(path)
    surfaces = {design.problem.targets[s].name: s for s in embedded_targets(design)}
    if not surfaces:
        raise FabkitError(f"{path}: the design has no target embedded in 3D to compare with")
    name = _chosen(name, list(surfaces), str(path))
    options = PartRequest().for_process(road_width_mm, design.layers * layer_height_mm)
    part = part_of_size(design, size_mm, options)
    mesh = design_mesh(design, part)
    surface = design.problem.targets[surfaces[name]].surface
    points = surface.embed(mesh.sample(design.r[surfaces[name]])) * part.mm_per_unit
    return Target(name, Mesh(points, mesh.triangles), _diameter(points))


def _report(folder: Path) -> dict:
    path = folder / "report.json"
    if not folder.is_dir():
        raise FabkitError(f"{folder}: no such folder (give the --out folder of a fabkit run)")
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FabkitError(f"{folder}: no report.json (is it the folder of a fabkit run?)") from None
    except (OSError, ValueError) as exc:
        raise FabkitError(f"{path}: cannot read it ({exc})") from None
    if not isinstance(report, dict):
        raise FabkitError(f"{path}: not a fabkit run's report")
    return report


def _chosen(name: str | None, names: list[str], where: str) -> str:
    """``name``, which must be one of ``names``; None: the only one."""
    if name is None and len(names) == 1:
        return names[0]
    if name not in names:
        asked = "give --target NAME" if name is None else f"--target {name}: not a target"
        raise FabkitError(f"{where}: {asked} (its targets: {', '.join(names)})")
    return name


def _mesh(folder: Path, name: object) -> Mesh:
    """The mesh a run wrote into ``folder`` as ``name`` (its report's word), read as the
    scan is (within :data:`~fabkit.limits.SCAN_BYTES`)."""
    import trimesh

    if not isinstance(name, str) or not name.endswith(".ply"):
        raise FabkitError(f"{folder}/report.json: a shape's mesh is not named (damaged?)")
    path = folder / name
    if folder.resolve() not in path.resolve().parents:
        raise FabkitError(f"{folder}/report.json: the mesh {name} lies outside the run's folder")
    data = read_limited(path, "the run's mesh", SCAN_BYTES)
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type="ply", process=False, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds on a damaged file
        raise FabkitError(f"{path}: cannot read the run's mesh ({type(exc).__name__})") from None
    vertices = np.asarray(mesh.vertices, dtype=float)
    triangles = np.asarray(mesh.faces, dtype=np.int64)
    if len(triangles) == 0 or not np.isfinite(vertices).all():
        raise FabkitError(f"{path}: the run's mesh is empty or damaged")
    return Mesh(vertices, triangles)


def _verdict_figures(report: dict, what: object, name: str) -> dict:
    """The figures the run's verdict on the sheet ``what`` gave target ``name`` (report.json's
    ``verdicts``; empty where they are not there)."""
    for verdict in report.get("verdicts") or []:
        if isinstance(verdict, dict) and verdict.get("what") == what:
            for shape in verdict.get("targets") or []:
                if isinstance(shape, dict) and shape.get("target") == name:
                    return shape
    return {}


def _diameter(points: np.ndarray) -> float:
    from fabkit.mechanics.simulate import diameter

    return diameter(points)
