"""The search: scipy's differential evolution over the space, evaluated in batches on a
pool of worker processes (a local process pool, or a Dask cluster), with a checkpoint.

Differential evolution with ``updating="deferred"`` and ``vectorized=True`` asks for a
whole population at a time, and its sequence of candidates is fixed by the seed and the
values it gets back. The population is cut into batches of ``Budget.batch`` candidates in
its order (the cut does not depend on the workers), each batch is one task
(:func:`fabkit.optimise.objective.evaluate_batch`) and the pool schedules the tasks: the
same seed gives the same candidates, the same values and the same best on one worker or
many, locally or on Dask.

Every evaluated batch is added to the checkpoint (a JSON file, rewritten atomically) as
soon as it returns. A stopped search run again with the same checkpoint replays: the
candidates it has are answered from it (the seed reproduces them), the others are evaluated.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from fabkit.design.check import Tolerances
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.files.readfile import read_json
from fabkit.optimise.objective import Evaluation, Objective, evaluate_batch
from fabkit.optimise.space import Space

CHECKPOINT_FORMAT = 2
"""Version of the checkpoint file's format."""
CONNECT_SECONDS = 10
"""How long ``--dask ADDRESS`` waits for the scheduler to answer."""
CHECKPOINT_BYTES = 1 << 28
"""Largest checkpoint read (about half a million evaluations of a dozen parameters)."""


@dataclass(frozen=True)
class Budget:
    """How long a search runs: ``generations`` of differential evolution with a population
    of ``popsize`` candidates per dimension (scipy's meaning), from ``seed``; ``batch``
    candidates are solved together in one task."""

    generations: int = 30
    popsize: int = 10
    seed: int = 0
    batch: int = 8

    def population(self, dimensions: int) -> int:
        """Candidates per generation (scipy's rule: ``popsize`` per dimension, at least 5)."""
        return max(5, self.popsize * dimensions)

    def evaluations(self, dimensions: int) -> int:
        """Candidates the search asks for: the first population and one per generation."""
        return self.population(dimensions) * (self.generations + 1)


class Pool(Protocol):
    """Where the batches run: ``submit(fn, *args)`` returns a future, ``as_completed``
    yields the futures as they finish (concurrent.futures or dask.distributed)."""

    workers: int

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any: ...

    def as_completed(self, futures: Sequence[Any]) -> Iterator[Any]: ...


@dataclass(frozen=True)
class Progress:
    """What a search has done after a generation (for the progress line)."""

    generation: int
    generations: int
    evaluations: int
    replayed: int
    best: float
    start: float
    seconds: float


@dataclass(frozen=True)
class Result:
    """A finished search: the best point and its evaluation, every evaluation in the order
    the search asked for them (``history``), how many came from the checkpoint, the
    evaluations computed per second of wall time, and the generations run."""

    best: tuple[float, ...]
    evaluation: Evaluation
    history: tuple[tuple[tuple[float, ...], Evaluation], ...]
    replayed: int
    seconds: float
    generations: int

    @property
    def computed(self) -> int:
        return len(self.history) - self.replayed

    @property
    def rate(self) -> float:
        return self.computed / self.seconds if self.seconds > 0 else math.nan


class Checkpoint:
    """Every evaluation of a search, in one JSON file rewritten atomically
    (:func:`fabkit.files.atomic.atomic_path`) after every batch: a stopped search leaves the last
    complete file, never a half-written one. It names what was searched (a fingerprint of
    the spec, the space and the objective) so that another search cannot reuse it."""

    def __init__(self, path: Path, fingerprint: str):
        self.path, self.fingerprint = Path(path), fingerprint
        self.records: list[dict[str, Any]] = []
        self.loaded: dict[tuple[float, ...], Evaluation] | None = None

    def load(self) -> dict[tuple[float, ...], Evaluation]:
        """The evaluations kept (none without a file), read once; a file of another search
        is refused."""
        if self.loaded is None:
            self.loaded = self._read() if self.path.exists() else {}
        return dict(self.loaded)

    def _read(self) -> dict[tuple[float, ...], Evaluation]:
        data = read_json(self.path, "checkpoint", CHECKPOINT_BYTES)
        if not isinstance(data, dict) or data.get("fabkit_optimise") != CHECKPOINT_FORMAT:
            raise FabkitError(f"{self.path}: not a fabkit optimise checkpoint")
        if data.get("fingerprint") != self.fingerprint:
            raise FabkitError(
                f"{self.path}: this checkpoint belongs to another search (other spec, "
                "parameters, bounds or objective); remove it or give another --checkpoint"
            )
        records = data.get("evaluations")
        if not isinstance(records, list):
            raise FabkitError(f"{self.path}: no list 'evaluations'")
        found = {}
        for number, record in enumerate(records):
            try:
                point = tuple(float(v) for v in record["x"])
                found[point] = Evaluation(**record["evaluation"])
            except (KeyError, TypeError, ValueError):
                raise FabkitError(
                    f"{self.path}: evaluations[{number}] is not an evaluation record"
                ) from None
        self.records = list(records)
        return found

    def append(self, records: Sequence[tuple[tuple[float, ...], Evaluation]]) -> None:
        """Add evaluations and write the whole file again (atomically)."""
        self.records += [{"x": list(p), "evaluation": asdict(e)} for p, e in records]
        data = {
            "fabkit_optimise": CHECKPOINT_FORMAT,
            "fingerprint": self.fingerprint,
            "evaluations": self.records,
        }
        with atomic_path(self.path) as tmp:
            tmp.write_text(json.dumps(data, separators=(",", ":")) + "\n", encoding="utf-8")


def fingerprint(spec_json: str, space: Space, objective: Objective) -> str:
    """What makes evaluations of two searches the same: the spec, the varied names and
    their bounds, and the objective with its limits and its check tolerances (written
    only when they are not the check's defaults)."""
    limits = objective.limits
    search = {
        "spec": json.loads(spec_json),
        "names": space.names,
        "bounds": space.bounds,
        "objective": objective.kind,
        "limits": None
        if limits is None
        else [
            limits.ranges,
            [(i, j, ring.tolist()) for i, j, ring in limits.regions],
            limits.min_width,
        ],
    }
    if objective.tolerances != Tolerances():  # a default search keeps the print it had
        search["tolerances"] = asdict(objective.tolerances)
    text = json.dumps(search, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


class Evaluator:
    """Answers a population of candidates: from the checkpoint where it can, else by
    batches on the pool; records every new evaluation in the checkpoint."""

    def __init__(
        self,
        spec_json: str,
        names: Sequence[str],
        objective: Objective,
        pool: Pool,
        checkpoint: Checkpoint,
        batch: int,
    ):
        self.spec_json, self.names, self.objective = spec_json, tuple(names), objective
        self.pool, self.checkpoint, self.batch = pool, checkpoint, batch
        self.known = checkpoint.load()
        self.history: list[tuple[tuple[float, ...], Evaluation]] = []
        self.replayed = 0

    def __call__(self, points: Sequence[tuple[float, ...]]) -> list[Evaluation]:
        batches = [list(points[k : k + self.batch]) for k in range(0, len(points), self.batch)]
        pending = {}
        for batch in batches:
            if all(p in self.known for p in batch):
                self.replayed += len(batch)
            else:
                future = self.pool.submit(
                    evaluate_batch, self.spec_json, self.names, batch, self.objective
                )
                pending[future] = batch
        for future in self.pool.as_completed(list(pending)):
            records = list(zip(pending[future], future.result(), strict=True))
            self.checkpoint.append(records)
            self.known.update(records)
        answers = [self.known[p] for p in points]
        self.history.extend(zip(points, answers, strict=True))
        return answers


def run_search(
    space: Space,
    spec_json: str,
    objective: Objective,
    budget: Budget,
    pool: Pool,
    checkpoint: Checkpoint,
    start_value: float,
    report: Callable[[Progress], None] = lambda progress: None,
) -> Result:
    """Maximise the objective over the space by differential evolution (scipy); the first
    population holds the spec's own values. ``start_value`` is the objective of the spec
    as given (for the progress lines)."""
    from scipy.optimize import differential_evolution

    evaluator = Evaluator(spec_json, space.names, objective, pool, checkpoint, budget.batch)
    started = time.perf_counter()
    generation = [0]

    def negative(population: np.ndarray) -> np.ndarray:
        points = [tuple(float(v) for v in column) for column in population.T]
        return -np.array([e.value for e in evaluator(points)])

    def after_generation(intermediate_result) -> None:
        generation[0] += 1
        report(
            Progress(
                generation[0],
                budget.generations,
                len(evaluator.history),
                evaluator.replayed,
                -float(intermediate_result.fun),
                start_value,
                time.perf_counter() - started,
            )
        )

    outcome = differential_evolution(
        negative,
        space.bounds,
        maxiter=budget.generations,
        popsize=budget.popsize,
        tol=0.0,
        polish=False,
        updating="deferred",
        vectorized=True,
        rng=budget.seed,
        x0=np.clip(space.start, *np.array(space.bounds).T),
        callback=after_generation,
    )
    best = tuple(float(v) for v in outcome.x)
    return Result(
        best,
        evaluator.known[best],
        tuple(evaluator.history),
        evaluator.replayed,
        time.perf_counter() - started,
        generation[0],
    )


def local_pool(workers: int) -> LocalPool:
    """A pool of ``workers`` local processes (started afresh: safe beside threads)."""
    return LocalPool(workers)


class LocalPool:
    """concurrent.futures' process pool as a :class:`Pool`."""

    def __init__(self, workers: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self.workers = workers
        context = multiprocessing.get_context("spawn")
        self.executor = ProcessPoolExecutor(max_workers=workers, mp_context=context)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        return self.executor.submit(fn, *args)

    def as_completed(self, futures: Sequence[Future]) -> Iterator[Future]:
        from concurrent.futures import as_completed

        return as_completed(futures)

    def close(self) -> None:
        self.executor.shutdown(cancel_futures=True)


class DaskPool:
    """A dask.distributed client as a :class:`Pool`: ``address`` of a scheduler, or
    ``local`` for a LocalCluster of ``workers`` single-threaded worker processes on the
    loopback interface. Dask schedules the batches."""

    def __init__(self, address: str, workers: int):
        import logging

        from distributed import Client, LocalCluster

        self.cluster = None
        if address == "local":
            try:
                self.cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            except (OSError, RuntimeError, TimeoutError) as exc:
                raise FabkitError(f"--dask local: cannot start a LocalCluster ({exc})") from None
            self.client = Client(self.cluster)
        else:
            try:
                self.client = Client(address, timeout=CONNECT_SECONDS)
            except OSError as exc:
                raise FabkitError(f"--dask {address}: cannot reach the scheduler ({exc})") from None
        self.workers = len(self.client.scheduler_info()["workers"])

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self.client.submit(fn, *args, pure=False)

    def as_completed(self, futures: Sequence[Any]) -> Iterator[Any]:
        from distributed import as_completed

        return as_completed(futures)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
