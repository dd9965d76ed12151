"""Worker processes: the pool that spreads a verdict's simulations over the cores."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from fabkit.background import WORKERS_ENV, parallel_map


def test_calls_come_back_in_order_with_their_progress(monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, "2")
    seen = []
    out = parallel_map(
        "math:hypot", [(3, 4), (5, 12), (8, 15)], progress=lambda d, t: seen.append((d, t))
    )
    assert out == [5.0, 13.0, 17.0]
    assert seen == [(1, 3), (2, 3), (3, 3)]


def test_one_worker_calls_here(monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, "1")
    assert parallel_map("os:getpid", [(), ()]) == [__import__("os").getpid()] * 2


def test_a_script_that_calls_at_its_top_level_needs_no_main_guard(tmp_path):
    # spawned workers would run such a script again (and start workers from there): they
    # are started without the caller's __main__
    script = tmp_path / "top_level.py"
    script.write_text(
        textwrap.dedent(
            """
            import os
            from fabkit.background import parallel_map
            pids = parallel_map("os:getpid", [()] * 4)
            print(len(set(pids) - {os.getpid()}))
            """
        )
    )
    result = subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        timeout=60,
        env={**__import__("os").environ, WORKERS_ENV: "2"},
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() in {"1", "2"}  # worker processes, not the script's own


def test_a_worker_stops_at_once_while_a_large_task_waits_for_it(tmp_path):
    # Pool.terminate() alone hangs for ever here: the feeder thread, still pickling a task
    # larger than the pipe holds when the pool drains the pipe, then blocks writing it to
    # a busy worker (a Ctrl-C just after the run handed the toolpath preview to the
    # picture worker)
    script = tmp_path / "stop.py"
    script.write_text(
        textwrap.dedent(
            """
            import time
            from fabkit.background import worker
            try:
                with worker() as background:
                    background.start("time:sleep", 10.0)
                    time.sleep(0.5)  # the worker is busy
                    background.start("builtins:len", list(range(3_000_000)))  # slow to pickle
                    start = time.perf_counter()
                    raise KeyboardInterrupt
            except KeyboardInterrupt:
                print(f"stopped in {time.perf_counter() - start:.1f} s")
            """
        )
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    assert float(done.stdout.split()[2]) < 5.0


def test_a_ctrl_c_while_workers_start_is_answered_after_and_never_reaches_them(tmp_path):
    # the caller once ignored SIGINT while it started a worker: a Ctrl-C that came in
    # those milliseconds was lost and the run went on (tests/test_interrupt.py, under load)
    script = tmp_path / "held.py"
    script.write_text(
        textwrap.dedent(
            """
            import os, signal
            from fabkit.background import _sigint_held, worker
            try:
                with _sigint_held():
                    os.kill(os.getpid(), signal.SIGINT)  # held: nothing happens here
                    print("held", flush=True)
            except KeyboardInterrupt:
                print("answered after", flush=True)
            with worker() as background:
                pid = background.start("os:getpid").get()
                os.kill(pid, signal.SIGINT)  # the worker ignores it and goes on
                print("worker", background.start("math:hypot", 3, 4).get(), flush=True)
            """
        )
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["held", "answered after", "worker 5.0"]
