"""fabkit optimise on a Dask LocalCluster (processes on the loopback interface, 2 workers)
finds the same best, from the same candidates, as a local pool of one process."""

from __future__ import annotations

import json

import pytest

from fabkit.optimise.run import outputs
from tests.test_optimise import coarse_spec_file

ARGS = (
    "--vary", "initial.eps[0]=0.2:0.7", "--vary", "initial.slope[0]=-1:1",
    "--generations", "2", "--popsize", "2", "--seed", "5", "--batch", "3",
)  # fmt: skip


@pytest.mark.slow
def test_dask_local_finds_the_same_best_as_one_local_process(tmp_path, run_cli):
    spec = coarse_spec_file(tmp_path)
    results = {}
    for name, pool in (
        ("local", ("--workers", "1")),
        ("dask", ("--dask", "local", "--workers", "2")),
    ):
        out = tmp_path / name / "best.toml"
        code, text, err = run_cli("optimise", spec, "--out", out, *ARGS, *pool)
        assert code == 0, err
        assert "generation 2/2" in err  # progress on stderr
        summary = json.loads(outputs(out)["summary"].read_text())
        checkpoint = json.loads(outputs(out)["checkpoint"].read_text())
        results[name] = summary, sorted(json.dumps(r) for r in checkpoint["evaluations"])
    (local, local_evaluations), (dask, dask_evaluations) = results["local"], results["dask"]
    assert dask["pool"] == {"kind": "dask", "address": "local", "workers": 2}
    assert local["pool"]["workers"] == 1
    assert dask["best"] == local["best"]
    assert dask_evaluations == local_evaluations
    assert (tmp_path / "local" / "best.toml").read_text() == (
        tmp_path / "dask" / "best.toml"
    ).read_text()
