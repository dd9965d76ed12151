"""``fabkit optimise``: search the initial data of a spec for the most coverage.

:func:`optimise` reads the spec and the varied keys (:mod:`fabkit.optimise.space`),
evaluates the spec as given (the start: the paper's initial data for the examples), runs
the search (:mod:`fabkit.optimise.search`) on a pool, solves the best candidate again on
the spec's own grid with the ordinary solver and checks it, and writes beside ``--out``
(``best.toml``):

* ``best.toml``: the spec with the best values (a spec like any other);
* ``best.search.json``: the figures: start and best objective, their ratio, the best
  values, the best design's check, the evaluations (computed and replayed), the time and
  the evaluations per second, the budget and the pool;
* ``best.search.png``: the objective over the evaluations; ``best.sheets.png``: the flat
  sheet of the spec as given beside the best one;
* ``best.checkpoint.json``: the checkpoint (unless ``checkpoint`` names another file).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from fabkit.design.check import Tolerances, check_design
from fabkit.design.design import Design
from fabkit.design.solver import solve
from fabkit.design.summary import realised_areas
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.files.shipped import user_or_example
from fabkit.files.tomlfile import read_toml
from fabkit.optimise.objective import Evaluation, Limits, Objective, evaluate_batch, score
from fabkit.optimise.search import (
    Budget,
    Checkpoint,
    DaskPool,
    LocalPool,
    Progress,
    Result,
    fingerprint,
    run_search,
)
from fabkit.optimise.space import Space, search_space
from fabkit.optimise.tomlout import dumps
from fabkit.problem.spec import Spec, build_spec


@dataclass(frozen=True)
class Job:
    """One search: the spec file, the ``--vary`` keys, the objective (None: the spec's),
    the process's limits (None: none), the check's tolerances a candidate must pass, the
    budget, the pool (``dask``: a scheduler address or ``local``, None for a local process
    pool of ``workers``) and the files."""

    spec: str
    out: str
    varies: tuple[str, ...] = ()
    objective: str | None = None
    limits: Limits | None = None
    tolerances: Tolerances = Tolerances()
    budget: Budget = Budget()
    workers: int = 0
    dask: str | None = None
    checkpoint: str | None = None


@dataclass(frozen=True)
class Outcome:
    """What :func:`optimise` found and wrote: the summary data and the files."""

    summary: dict[str, Any]
    files: tuple[Path, ...]


def outputs(out: str | Path) -> dict[str, Path]:
    """The files a search writes beside ``out`` (``best.toml`` -> ``best.search.json``...)."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "spec": out,
        "summary": stem.with_suffix(".search.json"),
        "progress": stem.with_suffix(".search.png"),
        "sheets": stem.with_suffix(".sheets.png"),
        "checkpoint": stem.with_suffix(".checkpoint.json"),
    }


def optimise(job: Job, report: Callable[[str], None] = lambda line: None) -> Outcome:
    """Run the search of ``job``; ``report`` gets one line per generation."""
    files = outputs(job.out)
    if files["spec"].suffix != ".toml":
        raise FabkitError(f"--out {job.out}: the best spec is written as TOML (.toml)")
    path = user_or_example(job.spec)
    table = read_toml(path, "spec")
    base_dir = path.resolve().parent
    given = build_spec(table, base_dir, str(path))
    space = search_space(table, base_dir, job.varies)
    spec = space.spec()
    kind = job.objective or spec.optimise.objective
    objective = Objective(kind, job.limits, job.tolerances)
    spec_json = spec.to_json()
    checkpoint = Checkpoint(
        Path(job.checkpoint) if job.checkpoint else files["checkpoint"],
        fingerprint(spec_json, space, objective),
    )
    checkpoint.load()  # refuse a checkpoint of another search before any work
    pool = _pool(job)
    try:
        (start,) = evaluate_batch(given.to_json(), (), [()], objective)
        result = run_search(
            space, spec_json, objective, job.budget, pool, checkpoint, start.value,
            lambda progress: report(progress_line(progress)),
        )  # fmt: skip
        workers = pool.workers
    finally:
        pool.close()
    _refuse_nothing_counted(result, objective, checkpoint.path)
    best_table = _with_absolute_files(space.table_at(result.best), base_dir)
    best = build_spec(best_table, base_dir)
    solved = solve(best).design
    summary = _summary(job, space, objective, start, result, best, solved, given, workers)
    _write_spec(files["spec"], best_table, summary)
    _write_json(files["summary"], summary)
    from fabkit.optimise.pictures import search_picture, sheets_picture

    search_picture(result, start.value, kind, files["progress"])
    sheets_picture(solve(given).design, solved, summary, files["sheets"])
    written = (files["spec"], files["summary"], files["progress"], files["sheets"])
    return Outcome(summary, (*written, checkpoint.path))


def _pool(job: Job) -> LocalPool | DaskPool:
    workers = job.workers or os.cpu_count() or 1
    if job.dask:
        return DaskPool(job.dask, workers)
    return LocalPool(workers)


def _refuse_nothing_counted(result: Result, objective: Objective, checkpoint: Path) -> None:
    """A search in which no candidate (the spec as given included) counted anything has no
    best to write (differential evolution stops on a population that scores 0 throughout):
    one line saying why, and how to go on."""
    if result.evaluation.value > 0:
        return
    t = objective.tolerances
    limits = " and the process's limits" if objective.limits is not None else ""
    raise FabkitError(
        f"no candidate counted: none of the {len(result.history)} designs passed the check "
        f"(isometry median {t.isometry_median:g}, p95 {t.isometry_p95:g}, curvature median "
        f"{t.curvature_median:g}){limits}, so the search had nothing to follow; nothing "
        f"written but the checkpoint {checkpoint}: widen the --vary bounds, draw more first "
        "candidates (--popsize) or loosen the tolerances"
    )


def progress_line(progress: Progress) -> str:
    """One line after a generation."""
    computed = progress.evaluations - progress.replayed
    rate = computed / progress.seconds if progress.seconds > 0 else 0.0
    against = (
        f"{progress.best / progress.start:.2f}x the start"
        if progress.start > 0
        else "the start counts 0"
    )
    return (
        f"generation {progress.generation}/{progress.generations}: {progress.evaluations} "
        f"evaluations ({progress.replayed} from the checkpoint), best {progress.best:.4g} "
        f"({against}), {rate:.1f} evaluations/s"
    )


def _with_absolute_files(table: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """The table with data file paths made absolute (the best spec is written elsewhere)."""
    for surface in table.get("surfaces", []):
        geometry = surface.get("geometry", {})
        if isinstance(geometry.get("file"), str):
            geometry["file"] = str((base_dir / geometry["file"]).resolve())
    return table


def _summary(
    job: Job,
    space: Space,
    objective: Objective,
    start: Evaluation,
    result: Result,
    best: Spec,
    solved: Design,
    given: Spec,
    workers: int,
) -> dict[str, Any]:
    """The figures of a search (``best.search.json``); ``solved``: the best spec's design
    on its own full grid (the ordinary solve)."""
    check = check_design(solved, objective.tolerances, spec=best)
    final = score(solved, best, objective)
    ratio = result.evaluation.value / start.value if start.value > 0 else None
    return {
        "spec": str(job.spec),
        "objective": objective.kind,
        "process_limits": None if objective.limits is None else _limits(objective.limits),
        "check_tolerances": asdict(objective.tolerances),
        "start": {"value": start.value, "areas": start.areas, "points": start.points},
        "best": {
            "value": result.evaluation.value,
            "areas": result.evaluation.areas,
            "points": result.evaluation.points,
            "parameters": {d.key: v for d, v in zip(space.dimensions, result.best, strict=True)},
        },
        "ratio": ratio,
        "best_solved_again": {
            "value": final.value,
            "areas": final.areas,
            "realised_areas_design_json": realised_areas(solved, best),
            "valid_points": int(solved.valid.sum()),
            "check": check.to_dict(),
        },
        "bounds": {d.key: [d.low, d.high] for d in space.dimensions},
        "budget": asdict(job.budget) | {"asked": job.budget.evaluations(len(space.names))},
        "evaluations": len(result.history),
        "replayed": result.replayed,
        "computed": result.computed,
        "generations": result.generations,
        "seconds": round(result.seconds, 3),
        "evaluations_per_second": round(result.rate, 2),
        "pool": {"kind": "dask" if job.dask else "local", "address": job.dask, "workers": workers},
        "grid": {"step": given.solver.step, "diagonals": given.solver.diagonals},
        "max_strain": given.solver.max_strain,
    }


def _limits(limits: Limits) -> dict[str, Any]:
    return {
        "eps_ranges": [list(r) for r in limits.ranges],
        "joint_regions": [[i, j] for i, j, _ in limits.regions],
        "min_width_design_units": limits.min_width,
    }


def _write_spec(path: Path, table: dict[str, Any], summary: dict[str, Any]) -> None:
    ratio = summary["ratio"]
    header = (
        f"Written by fabkit optimise from {summary['spec']}: objective {summary['objective']} "
        f"{summary['best']['value']:.6g} (the spec as given: {summary['start']['value']:.6g}"
        + (f", {ratio:.3g}x" if ratio else "")
        + ")."
    )
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(table, header), encoding="utf-8")


def _write_json(path: Path, data: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
