"""The documentation stays true: the CLI reference and the README's two commands."""

from __future__ import annotations

import re

from fabkit.clidoc import reference
from tests.conftest import ROOT


def test_cli_reference_is_up_to_date():
    assert (ROOT / "docs" / "cli.md").read_text() == reference(), (
        "regenerate with: python -m fabkit.clidoc > docs/cli.md"
    )


def test_readme_has_exactly_two_quickstart_commands():
    readme = (ROOT / "README.md").read_text()
    quickstart = readme.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    commands = re.findall(r"```sh\n(.*?)\n```", quickstart, flags=re.S)
    assert len(commands) == 2
    assert commands[0].startswith("pip install -e . && fabkit run examples/two_shapes.toml")
    assert commands[1] == "pip install -e '.[test]' && pytest"
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci  # CI runs the test command verbatim, and the suite runs the
    # main command verbatim from a wheel (tests/test_packaging.py)


def test_readme_links_resolve():
    readme = (ROOT / "README.md").read_text()
    for link in re.findall(r"\]\(((?:docs|examples)/[^)#]+)", readme):
        assert (ROOT / link).exists(), link
