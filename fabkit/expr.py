"""Safe user expressions: a whitelist parser that builds sympy trees, never ``eval``.

The text is parsed by Python's :func:`ast.parse` (which builds a syntax tree and
executes nothing) and every node is checked against a whitelist:

* numbers, the declared variable names, ``pi`` and ``e``;
* ``+ - * / ** ^`` (``^`` means power), unary minus and plus, parentheses;
* calls of ``exp log sqrt sin cos tan arcsin arccos arctan sinh cosh tanh abs`` with
  one positional argument, and ``arctan2(y, x)`` with two.

Anything else (attribute access, subscripts, other calls, lambdas, strings,
comprehensions, comparisons, ...) is refused with a :class:`FabkitError` naming
the offending token. The result is an :class:`Expression`: a sympy expression
that can be differentiated symbolically and turned into a vectorised numpy
function.
"""

from __future__ import annotations

import ast
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import sympy as sp

from fabkit.errors import FabkitError

MAX_LENGTH = 2000
"""Longest expression text accepted, in characters."""

FUNCTIONS: dict[str, Callable[[sp.Expr], sp.Expr]] = {
    "exp": sp.exp,
    "log": sp.log,
    "sqrt": sp.sqrt,
    "sin": sp.sin,
    "cos": sp.cos,
    "tan": sp.tan,
    "arcsin": sp.asin,
    "arccos": sp.acos,
    "arctan": sp.atan,
    "sinh": sp.sinh,
    "cosh": sp.cosh,
    "tanh": sp.tanh,
    "abs": sp.Abs,
    "arctan2": sp.atan2,
}
ARITY = {"arctan2": 2}
"""Functions taking other than one argument (arctan2(y, x): the angle of (x, y))."""
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi, "e": sp.E}
RESERVED = frozenset(FUNCTIONS) | frozenset(CONSTANTS)

_BINARY = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
}
_TOKEN_NAMES = {
    ast.Attribute: "attribute access '.'",
    ast.Subscript: "subscript '[]'",
    ast.Lambda: "'lambda'",
    ast.ListComp: "list comprehension",
    ast.SetComp: "set comprehension",
    ast.DictComp: "dict comprehension",
    ast.GeneratorExp: "generator expression",
    ast.List: "list '[...]'",
    ast.Tuple: "tuple '(..., ...)'",
    ast.Dict: "dict '{...}'",
    ast.Set: "set '{...}'",
    ast.Compare: "comparison",
    ast.BoolOp: "'and'/'or'",
    ast.IfExp: "'if ... else'",
    ast.Starred: "'*' unpacking",
    ast.NamedExpr: "':='",
    ast.JoinedStr: "f-string",
    ast.Await: "'await'",
    ast.Yield: "'yield'",
    ast.YieldFrom: "'yield from'",
    ast.Slice: "slice ':'",
}
_OPERATOR_NAMES = {
    ast.FloorDiv: "'//'",
    ast.Mod: "'%'",
    ast.MatMult: "'@'",
    ast.LShift: "'<<'",
    ast.RShift: "'>>'",
    ast.BitOr: "'|'",
    ast.BitAnd: "'&'",
    ast.Invert: "'~'",
    ast.Not: "'not'",
}


@dataclass(frozen=True)
class Expression:
    """A parsed expression in the declared variables.

    ``names`` fixes the argument order of :meth:`__call__` and :attr:`numpy`.
    """

    text: str
    names: tuple[str, ...]
    sympy: sp.Expr = field(compare=False)

    @cached_property
    def symbols(self) -> tuple[sp.Symbol, ...]:
        return tuple(sp.Symbol(n, real=True) for n in self.names)

    @cached_property
    def numpy(self) -> Callable[..., np.ndarray]:
        """Vectorised numpy function of the declared names, in order."""
        return sp.lambdify(self.symbols, self.sympy, modules="numpy")

    def __call__(self, *values: np.ndarray | float) -> np.ndarray:
        """Evaluate on arrays (broadcast together); returns a float array of their shape."""
        if len(values) != len(self.names):
            raise TypeError(f"expected {len(self.names)} values for {self.names}")
        arrays = [np.asarray(v, dtype=float) for v in values]
        shape = np.broadcast_shapes(*(a.shape for a in arrays)) if arrays else ()
        with np.errstate(all="ignore"):
            out = np.asarray(self.numpy(*arrays), dtype=float)
        return np.broadcast_to(out, shape).copy() if out.shape != shape else out

    def diff(self, name: str) -> Expression:
        """The symbolic derivative with respect to the declared variable ``name``."""
        symbol = self.symbols[self.names.index(name)]
        derivative = sp.diff(self.sympy, symbol)
        return Expression(f"d({self.text})/d{name}", self.names, derivative)

    @property
    def is_constant(self) -> bool:
        return not (self.sympy.free_symbols & set(self.symbols))


def parse(text: str, names: Sequence[str], where: str = "expression") -> Expression:
    """Parse ``text`` as an expression in the variables ``names``.

    ``where`` names the spec field in error messages (e.g. ``"material.lambda2"``).
    Raises :class:`FabkitError` for anything outside the whitelist.
    """
    names = tuple(names)
    for name in names:
        if not name.isidentifier() or name in RESERVED:
            raise FabkitError(f"{where}: '{name}' cannot be used as a variable name")
    if isinstance(text, bool | int | float):
        text = repr(float(text))
    if not isinstance(text, str):
        raise FabkitError(f"{where}: expected an expression string, got {type(text).__name__}")
    if len(text) > MAX_LENGTH:
        raise FabkitError(f"{where}: expression longer than {MAX_LENGTH} characters")
    if not text.strip():
        raise FabkitError(f"{where}: empty expression")
    source = text.replace("^", "**")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)
            tree = ast.parse(source.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise FabkitError(f"{where}: cannot parse '{text}': {_syntax_reason(exc)}") from None
    symbols = {n: sp.Symbol(n, real=True) for n in names}
    try:
        expression = _Builder(symbols, where, text).build(tree.body)
    except RecursionError:
        raise FabkitError(f"{where}: expression nested too deeply") from None
    return Expression(text, names, expression)


def _syntax_reason(exc: BaseException) -> str:
    if isinstance(exc, SyntaxError):
        return exc.msg
    if isinstance(exc, RecursionError | MemoryError):
        return "nested too deeply"
    return str(exc)


@dataclass(frozen=True)
class _Builder:
    symbols: dict[str, sp.Symbol]
    where: str
    text: str

    def refuse(self, what: str) -> FabkitError:
        allowed = ", ".join([*self.symbols, "pi", "e"])
        return FabkitError(
            f"{self.where}: {what} is not allowed in '{self.text}' (names allowed: {allowed}; "
            "see docs/spec.md#expressions)"
        )

    def build(self, node: ast.AST) -> sp.Expr:
        if isinstance(node, ast.Constant):
            return self.number(node.value)
        if isinstance(node, ast.Name):
            return self.name(node.id)
        if isinstance(node, ast.UnaryOp):
            return self.unary(node)
        if isinstance(node, ast.BinOp):
            return self.binary(node)
        if isinstance(node, ast.Call):
            return self.call(node)
        raise self.refuse(_TOKEN_NAMES.get(type(node), f"'{type(node).__name__}'"))

    def number(self, value: object) -> sp.Expr:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.refuse(f"the literal {value!r}")
        if not math.isfinite(value):
            raise self.refuse(f"the number {value!r}")
        if isinstance(value, int) and abs(value) <= 10**9:
            return sp.Integer(value)
        return sp.Float(float(value))

    def name(self, identifier: str) -> sp.Expr:
        if identifier in self.symbols:
            return self.symbols[identifier]
        if identifier in CONSTANTS:
            return CONSTANTS[identifier]
        if identifier in FUNCTIONS:
            raise self.refuse(f"the function name '{identifier}' without an argument")
        raise self.refuse(f"the name '{identifier}'")

    def unary(self, node: ast.UnaryOp) -> sp.Expr:
        operand = self.build(node.operand)
        if isinstance(node.op, ast.USub):
            return -operand
        if isinstance(node.op, ast.UAdd):
            return operand
        raise self.refuse(_OPERATOR_NAMES.get(type(node.op), "this operator"))

    def binary(self, node: ast.BinOp) -> sp.Expr:
        if isinstance(node.op, ast.BitXor | ast.Pow):
            return self.power(self.build(node.left), self.build(node.right))
        combine = _BINARY.get(type(node.op))
        if combine is None:
            raise self.refuse(_OPERATOR_NAMES.get(type(node.op), "this operator"))
        return combine(self.build(node.left), self.build(node.right))

    def power(self, base: sp.Expr, exponent: sp.Expr) -> sp.Expr:
        """A power; a numeric one is computed in floating point so it cannot blow up."""
        if base.is_number and exponent.is_number:
            try:
                value = complex(base) ** complex(exponent)
            except (OverflowError, ZeroDivisionError, TypeError, ValueError):
                raise self.refuse("a power too large to compute") from None
            if not (math.isfinite(value.real) and math.isfinite(value.imag)):
                raise self.refuse("a power too large to compute")
            if abs(value.imag) > 1e-12 * max(1.0, abs(value.real)):
                raise self.refuse("a power with a complex value")
            return sp.Float(value.real)
        if exponent.is_number and abs(float(exponent)) > 1e6:
            raise self.refuse("an exponent larger than 1e6")
        return sp.Pow(base, exponent)

    def call(self, node: ast.Call) -> sp.Expr:
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            callee = node.func.id if isinstance(node.func, ast.Name) else "an expression"
            raise self.refuse(f"calling '{callee}'")
        arity = ARITY.get(node.func.id, 1)
        if node.keywords or len(node.args) != arity:
            raise self.refuse(f"'{node.func.id}' with other than {arity} argument(s)")
        return FUNCTIONS[node.func.id](*(self.build(a) for a in node.args))
