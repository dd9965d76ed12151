"""``python -m fabkit`` and the console script's entry point run the command line."""

from __future__ import annotations

import runpy
import sys

import pytest

import fabkit


def test_python_dash_m_fabkit_prints_the_version_and_exits_0(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["fabkit", "--version"])
    with pytest.raises(SystemExit) as exited:
        runpy.run_module("fabkit", run_name="__main__")
    assert exited.value.code == 0
    assert fabkit.__version__ in capsys.readouterr().out


def test_the_entry_point_exits_with_the_commands_code(monkeypatch, capsys):
    from fabkit.entry import run

    monkeypatch.setattr(sys, "argv", ["fabkit", "spec", "no-such-spec.toml"])
    with pytest.raises(SystemExit) as exited:
        run()
    assert exited.value.code == 2
    assert capsys.readouterr().err.startswith("fabkit: error: ")
