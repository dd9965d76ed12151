"""Shared helpers: the example specs as editable tables, and a CLI runner."""

from __future__ import annotations

import copy
import os
import tomllib
from pathlib import Path

import pytest
from hypothesis import settings

from fabkit.cli import main

# CI explores the same property-test examples on every run (a fixed seed per test), so that
# a red CI means a change broke something; runs elsewhere explore new examples each time.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("FABKIT_CI"):
    settings.load_profile("ci")

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def example_table(name: str) -> dict:
    """An example spec as nested dicts, to edit in a test and pass to build_spec."""
    with open(EXAMPLES / name, "rb") as handle:
        return copy.deepcopy(tomllib.load(handle))


@pytest.fixture
def fig1() -> dict:
    return example_table("two_shapes.toml")


@pytest.fixture
def fig3() -> dict:
    return example_table("three_shapes.toml")


@pytest.fixture
def run_cli(capsys):
    """Run ``fabkit ARGS``; returns (exit code, stdout, stderr)."""

    def run(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return run
