"""The whitelist expression parser: what it accepts, what it refuses, that it runs nothing,
that its derivatives are exact, and that hostile input is refused quickly."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.problem.expr import MAX_DEPTH, MAX_LENGTH, MAX_NODES, parse
from tests.attack import run_bounded


def test_values_and_derivatives():
    expression = parse("exp(L*eps) + 2^eps - sqrt(abs(-L)) / pi", ("eps", "L"))
    eps, stimulus = np.array([0.0, 0.5]), np.array([1.0, 2.0])
    expected = np.exp(stimulus * eps) + 2**eps - np.sqrt(stimulus) / np.pi
    assert np.allclose(expression(eps, stimulus), expected)
    derivative = expression.diff("eps")
    assert np.allclose(
        derivative(eps, stimulus), stimulus * np.exp(stimulus * eps) + np.log(2) * 2**eps
    )
    second = derivative.diff("eps")
    assert np.allclose(
        second(eps, stimulus), stimulus**2 * np.exp(stimulus * eps) + np.log(2) ** 2 * 2**eps
    )


def test_jets_give_the_gradient_and_the_hessian():
    expression = parse("x**3*y + sin(x*y) + arctan2(y, x) + x^y", ("x", "y"))
    x, y = np.array([0.7, 1.3]), np.array([0.4, -0.9])
    value, grad, hess = expression.jets(x, y, wrt=("x", "y"))
    r2 = x**2 + y**2
    assert np.allclose(value, x**3 * y + np.sin(x * y) + np.arctan2(y, x) + x**y)
    assert np.allclose(
        grad[0], 3 * x**2 * y + y * np.cos(x * y) - y / r2 + y * x ** (y - 1), rtol=1e-12
    )
    assert np.allclose(grad[1], x**3 + x * np.cos(x * y) + x / r2 + np.log(x) * x**y)
    xx = 6 * x * y - y**2 * np.sin(x * y) + 2 * x * y / r2**2 + y * (y - 1) * x ** (y - 2)
    xy = (
        3 * x**2
        + np.cos(x * y)
        - x * y * np.sin(x * y)
        + (y**2 - x**2) / r2**2
        + x ** (y - 1) * (1 + y * np.log(x))
    )
    yy = -(x**2) * np.sin(x * y) - 2 * x * y / r2**2 + np.log(x) ** 2 * x**y
    assert np.allclose(hess, [[xx, xy], [xy, yy]], rtol=1e-12)


def test_derivative_by_a_name_not_in_the_expression_is_exactly_zero():
    expression = parse("sqrt(y) + x", ("x", "y"))
    value, grad, hess = expression.jets(np.array([1.0]), np.array([0.0]), wrt=("x", "y"))
    assert grad[0] == [1.0] and hess[0, 0] == [0.0]
    assert np.isinf(grad[1]).all()
    assert expression.diff("x").diff("x")(1.0, -1.0) == 0.0


def test_x_to_the_first_power_has_no_spurious_nan_at_zero():
    assert parse("x^1 + x^2", ("x",)).diff("x").diff("x")(0.0) == 2.0


def test_arctan2_takes_two_arguments():
    angle = parse("arctan2(y, x)", ("x", "y"))
    assert np.allclose(angle(np.array([-1.0, 0.0]), np.array([0.0, 1.0])), [np.pi, np.pi / 2])
    with pytest.raises(FabkitError, match="other than 2"):
        parse("arctan2(y)", ("x", "y"))


def test_abs_has_a_second_derivative():
    # sympy's was DiracDelta, which numpy could not evaluate
    height = parse("abs(x)*y", ("x", "y"))
    _, grad, hess = height.jets(np.array([-2.0, 3.0]), np.array([1.0, 1.0]), wrt=("x", "y"))
    assert grad[0].tolist() == [-1.0, 1.0] and np.all(hess[0, 0] == 0)


def test_constant_broadcasts_to_input_shape():
    assert parse("1/2", ("t",))(np.zeros((3, 2))).shape == (3, 2)
    assert parse("1/2", ("t",)).is_constant and not parse("t", ("t",)).is_constant


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
        ("x // 2", "'//'"),
        ("exp", "without an argument"),
        ("1j * x", "literal"),
    ],
)
def test_refusals_name_the_token(text, token):
    with pytest.raises(FabkitError, match="not allowed") as info:
        parse(text, ("x",), "field")
    message = str(info.value)
    assert token in message and "\n" not in message and message.startswith("field:")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("log(0)", "field: log(0) is not finite"),
        ("x + log(0)", "field: log(0) is not finite"),
        ("sqrt(-1)*x", "field: sqrt(-1) is not finite"),
        ("arcsin(2) + x", "field: arcsin(2) is not finite"),
        ("exp(1000)", "field: exp(1000) is not finite"),
        ("1e308*10", "field: 1e308*10 is not finite"),
        ("2**2**2**2**2", "field: 2**2**2**2**2 is not finite"),
        ("9**9**9", "field: 9**9**9 is not finite"),
        ("pi**pi**pi**pi", "is not finite"),
        ("(-8)**(1/3)", "field: (-8)**(1/3) is not a real number"),
        ("1/0", "field: division by zero in '1/0'"),
        ("x/(2 - 2)", "division by zero (2 - 2 = 0)"),
        ("1" + "0" * 400, "is too large for a float"),
        ("x*" + "9" * 320, "(320 digits) is too large for a float"),
    ],
)
def test_constant_parts_must_be_finite_real_numbers(text, message):
    with pytest.raises(FabkitError, match="field: ") as info:
        parse(text, ("x",), "field")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_constant_parts_are_computed_once():
    expression = parse("x*(2**10 - 1000) + sin(pi/2)", ("x",))
    assert expression(3.0) == pytest.approx(73.0)
    assert parse("2^3^2", ()).tree.value == 2**9


def test_limits_are_exact():
    terms = (MAX_NODES + 1) // 2  # n terms: n names and n - 1 operations
    chain = "+".join(["x"] * terms)
    assert parse(chain, ("x",))(1.0) == terms
    with pytest.raises(FabkitError, match=f"expression too large: {2 * terms + 1} nodes"):
        parse(chain + "+x", ("x",))
    deep = "sin(" * (MAX_DEPTH - 1) + "x" + ")" * (MAX_DEPTH - 1)
    assert np.isfinite(parse(deep, ("x",)).diff("x").diff("x")(0.3))
    with pytest.raises(FabkitError, match=f"nested too deeply: {MAX_DEPTH + 1} levels"):
        parse("sin(" + deep + ")", ("x",))
    with pytest.raises(FabkitError, match=f"longer than {MAX_LENGTH}"):
        parse("x" + " " * MAX_LENGTH, ("x",))


def test_a_chain_of_plus_or_times_is_one_level():
    polynomial = " + ".join(f"{k}*x**{k}" for k in range(60))  # 60 terms, depth 4
    expression = parse(polynomial, ("x",))
    assert expression.diff("x").diff("x")(1.0) == pytest.approx(
        sum(k * k * (k - 1) for k in range(60))
    )


def test_a_long_product_differentiates_exactly_and_quickly():
    # symbolically, its second derivative holds about 100^3 terms (minutes in sympy)
    factors = np.arange(1, 101) / 100
    text = "*".join(f"(x+{c})" for c in factors)
    x = np.array([0.253, -0.5037])
    (value, grad, hess), _ = run_bounded(lambda: parse(text, ("x",)).jets(x, wrt=("x",)), seconds=5)
    inverse = 1 / (x[:, None] + factors)
    assert np.allclose(value, np.prod(x[:, None] + factors, axis=1))
    assert np.allclose(grad[0], value * inverse.sum(axis=1))
    assert np.allclose(hess[0, 0], value * (inverse.sum(axis=1) ** 2 - (inverse**2).sum(axis=1)))


@pytest.mark.parametrize("text", ["", "   ", "1 +", "(((", "x" * 3000, "(" * 300 + "x" + ")" * 300])
def test_malformed_is_a_one_line_error(text):
    with pytest.raises(FabkitError) as info:
        parse(text, ("x",))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "text",
    [
        "exp(" * 150 + "x" + ")" * 150,
        "x**" * 400 + "x",
        "-" * 1900 + "x",
        "+".join(["x"] * 900),
        "*".join(["(x+1)"] * 300),
        "1" + "0" * 1999,
    ],
)
def test_hostile_text_is_refused_quickly(text):
    (result, seconds) = run_bounded(lambda: _outcome(text), seconds=2)
    assert result == "refused"


def _outcome(text: str) -> str:
    try:
        parse(text, ("x",))
    except FabkitError as error:
        assert "\n" not in str(error)
        return "refused"
    return "parsed"


# --------------------------------------------------------------------------- properties

NAMES = ("x", "y")
FUNCTIONS = [
    "exp",
    "log",
    "sqrt",
    "sin",
    "cos",
    "tan",
    "arcsin",
    "arccos",
    "arctan",
    "sinh",
    "cosh",
    "tanh",
    "abs",
]
LEAVES = st.one_of(
    st.sampled_from(["x", "y", "pi", "e"]),
    st.integers(min_value=0, max_value=10**30).map(str),
    st.floats(min_value=0, max_value=1e308, allow_nan=False).map(repr),
    st.sampled_from(["0", "1", "0.5", "1e-300", "1e308", "10**400"]),
)


def _grow(children):
    return st.one_of(
        st.tuples(children, st.sampled_from(["+", "-", "*", "/", "**", "^"]), children).map(
            lambda t: f"({t[0]}){t[1]}({t[2]})"
        ),
        st.tuples(st.sampled_from(["-", "+"]), children).map(lambda t: f"{t[0]}({t[1]})"),
        st.tuples(st.sampled_from(FUNCTIONS), children).map(lambda t: f"{t[0]}({t[1]})"),
        st.tuples(children, children).map(lambda t: f"arctan2({t[0]}, {t[1]})"),
    )


GRAMMAR = st.recursive(LEAVES, _grow, max_leaves=60)
"""Random texts of the whitelist grammar: every operation, function and odd number."""


def _evaluate(text: str) -> str:
    try:
        expression = parse(text, NAMES, "k")
    except FabkitError as error:
        message = str(error)
        assert message.startswith("k: ") and "\n" not in message
        return "refused"
    x, y = np.array([0.3, -1.7, 0.0, 2.5]), np.array([0.2, 0.4, -3.0, 0.0])
    assert expression(x, y).shape == (4,) and expression(x, y).dtype == float
    value, grad, hess = expression.jets(x, y, wrt=NAMES)
    assert value.shape == (4,) and grad.shape == (2, 4) and hess.shape == (2, 2, 4)
    assert np.array_equal(value, expression(x, y), equal_nan=True)
    assert np.array_equal(grad[1], expression.diff("y")(x, y), equal_nan=True)
    assert np.array_equal(hess[0, 1], hess[1, 0], equal_nan=True)
    return "parsed"


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(GRAMMAR)
@example("(arctan2(x, -(y)))**(x)")  # 0 ** 0 by y: 0 with x differentiated or not
def test_any_text_of_the_grammar_parses_to_an_evaluable_expression_or_is_refused(text):
    """Either an Expression whose values and jets are float arrays of the right shapes, or
    a one-line FabkitError naming the key; never another exception; within 2 s."""
    run_bounded(lambda: _evaluate(text), seconds=2)


SMOOTH = st.recursive(
    st.sampled_from(["x", "y", "0.5", "2", "pi"]),
    lambda children: st.one_of(
        st.tuples(children, st.sampled_from(["+", "-", "*"]), children).map(
            lambda t: f"({t[0]}){t[1]}({t[2]})"
        ),
        st.tuples(children, st.sampled_from(["2", "3"])).map(lambda t: f"({t[0]})**{t[1]}"),
        st.tuples(st.sampled_from(["sin", "cos", "tanh", "arctan"]), children).map(
            lambda t: f"{t[0]}({t[1]})"
        ),
        children.map(lambda c: f"exp(sin({c}))"),
        children.map(lambda c: f"1/(2 + sin({c}))"),
    ),
    max_leaves=12,
)
"""Random smooth expressions (no singularity), to check derivatives against differences."""


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(SMOOTH, st.floats(-1.5, 1.5), st.floats(-1.5, 1.5))
def test_derivatives_match_finite_differences(text, x, y):
    expression = parse(text, NAMES)
    value, grad, hess = expression.jets(np.array(x), np.array(y), wrt=NAMES)
    h = 1e-6
    for i, step in enumerate(np.eye(2) * h):
        plus = expression.jets(np.array(x + step[0]), np.array(y + step[1]), wrt=NAMES)
        minus = expression.jets(np.array(x - step[0]), np.array(y - step[1]), wrt=NAMES)
        scale = 1 + abs(value) + np.abs(grad).max() + np.abs(hess).max()
        assert (plus[0] - minus[0]) / (2 * h) == pytest.approx(grad[i], abs=1e-5 * scale)
        difference = (plus[1] - minus[1]) / (2 * h)
        assert difference == pytest.approx(hess[:, i], abs=1e-5 * scale)


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


@pytest.mark.slow
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
    finally:
        os.chdir(before)
        assert list(folder.iterdir()) == []
