"""The whitelist expression parser: what it accepts, what it refuses, and that it runs nothing."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.expr import parse


def test_values_and_symbolic_derivatives():
    expression = parse("exp(L*eps) + 2^eps - sqrt(abs(-L)) / pi", ("eps", "L"))
    eps, stimulus = np.array([0.0, 0.5]), np.array([1.0, 2.0])
    expected = np.exp(stimulus * eps) + 2**eps - np.sqrt(stimulus) / np.pi
    assert np.allclose(expression(eps, stimulus), expected)
    derivative = expression.diff("eps")
    assert np.allclose(
        derivative(eps, stimulus), stimulus * np.exp(stimulus * eps) + np.log(2) * 2**eps
    )


def test_arctan2_takes_two_arguments():
    angle = parse("arctan2(y, x)", ("x", "y"))
    assert np.allclose(angle(np.array([-1.0, 0.0]), np.array([0.0, 1.0])), [np.pi, np.pi / 2])
    with pytest.raises(FabkitError, match="other than 2"):
        parse("arctan2(y)", ("x", "y"))


def test_constant_broadcasts_to_input_shape():
    assert parse("1/2", ("t",))(np.zeros((3, 2))).shape == (3, 2)


@pytest.mark.parametrize(
    ("text", "token"),
    [
        ("__import__('os').system('touch x')", "calling"),
        ("().__class__", "attribute"),
        ("open('f')", "calling 'open'"),
        ("[x for x in y]", "comprehension"),
        ("lambda: 0", "lambda"),
        ("x.real", "attribute"),
        ("x[0]", "subscript"),
        ("'text'", "literal"),
        ("x if x else 1", "if"),
        ("x < 1", "comparison"),
        ("y + 1", "name 'y'"),
        ("sin(x, x)", "other than 1 argument"),
        ("9**9**9", "power too large"),
        ("x // 2", "'//'"),
        ("exp", "without an argument"),
    ],
)
def test_refusals_name_the_token(text, token):
    with pytest.raises(FabkitError, match="not allowed") as info:
        parse(text, ("x",), "field")
    message = str(info.value)
    assert token in message and "\n" not in message and message.startswith("field:")


@pytest.mark.parametrize("text", ["", "   ", "1 +", "(((", "x" * 3000])
def test_malformed_is_a_one_line_error(text):
    with pytest.raises(FabkitError) as info:
        parse(text, ("x",))
    assert "\n" not in str(info.value)


TOKENS = st.sampled_from(
    [
        "x",
        "y",
        "1",
        "2.5",
        "+",
        "-",
        "*",
        "/",
        "**",
        "^",
        "(",
        ")",
        ".",
        "[",
        "]",
        ",",
        "'",
        "__import__",
        "open",
        "os",
        "system",
        "lambda",
        ":",
        "for",
        "in",
        "exp",
        "sin",
        "pi",
        "e",
        "__class__",
        "touch",
        "eval",
        "if",
        "else",
        " ",
    ]
)


@settings(max_examples=400, deadline=None)
@given(st.lists(TOKENS, min_size=1, max_size=14))
def test_fuzz_parses_to_a_function_or_refuses(tmp_path_factory, tokens):
    folder = tmp_path_factory.mktemp("fuzz")
    before = os.getcwd()
    os.chdir(folder)
    try:
        try:
            expression = parse("".join(tokens), ("x", "y"))
        except FabkitError:
            return
        values = expression(np.array([0.3, 1.7]), np.array([0.2, 0.4]))
        assert values.shape == (2,)
        assert expression.sympy.free_symbols <= set(expression.symbols)
    finally:
        os.chdir(before)
        assert list(folder.iterdir()) == []
