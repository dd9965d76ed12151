"""Safe user expressions: a whitelist parser and a numpy evaluator with exact derivatives.

The text is parsed by Python's :func:`ast.parse` (which builds a syntax tree and
executes nothing) and every node is checked against a whitelist:

* numbers, the declared variable names, ``pi`` and ``e``;
* ``+ - * / ** ^`` (``^`` means power), unary minus and plus, parentheses;
* calls of ``exp log sqrt sin cos tan arcsin arccos arctan sinh cosh tanh abs`` with
  one positional argument, and ``arctan2(y, x)`` with two.

Anything else (attribute access, subscripts, other calls, lambdas, strings,
comprehensions, comparisons, ...) is refused with a :class:`FabkitError` naming
the offending token. The result is an :class:`Expression`: a small tree of the allowed
operations, evaluated on numpy arrays node by node, with first and second derivatives
by forward-mode automatic differentiation (exact up to rounding, like a symbolic
derivative evaluated in floating point). Nothing is ever ``eval``-ed or compiled, and no
computer algebra runs on user input, so the cost of a value or a derivative is bounded
by the size of the tree: a product of 100 factors differentiates twice in time linear
in its length, where a symbolic second derivative would hold 100^3 terms. The tree and its
evaluation are in :mod:`fabkit.problem.expr_tree`.

Hostile input is bounded before the tree is built (see ``docs/spec.md#limits``): the
text length (:data:`MAX_LENGTH`), the number of nodes (:data:`MAX_NODES`) and the nesting
depth (:data:`MAX_DEPTH`; a chain of ``+`` and ``-``, or of ``*`` and ``/``, is one
level). Every constant part (``log(0)``, ``1/0``, ``sqrt(-1)``, ``exp(1000)``,
``2**2**2**2**2``, a 400-digit integer) is computed in floating point as it is built and
refused unless it is a finite real number.
"""

from __future__ import annotations

import ast
import math
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from fabkit.errors import FabkitError
from fabkit.problem.expr_tree import UNARY, Array, Evaluator, Node, const_node, op_node

MAX_LENGTH = 2000
"""Longest expression text accepted, in characters."""
MAX_NODES = 500
"""Most nodes (numbers, names, operations, calls) in an expression's syntax tree."""
MAX_DEPTH = 32
"""Deepest nesting of an expression; a chain of + and -, or of * and /, is one level."""

FUNCTIONS = frozenset(UNARY) | {"arctan2"}
ARITY = {"arctan2": 2}
"""Functions taking other than one argument (arctan2(y, x): the angle of (x, y))."""
CONSTANTS = {"pi": math.pi, "e": math.e}
RESERVED = FUNCTIONS | frozenset(CONSTANTS)

_SUM = "sum"
_PRODUCT = "product"
_FAMILIES = {ast.Add: _SUM, ast.Sub: _SUM, ast.Mult: _PRODUCT, ast.Div: _PRODUCT}
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

    ``names`` fixes the argument order of :meth:`__call__`; ``where`` names the spec key
    or option it came from, for error messages. ``derivative`` holds the indices of the
    variables it is differentiated by (at most two; see :meth:`diff`).
    """

    text: str
    names: tuple[str, ...]
    tree: Node = field(compare=False, repr=False)
    where: str = "expression"
    derivative: tuple[int, ...] = ()

    def __call__(self, *values: Array | float) -> Array:
        """Evaluate on arrays (broadcast together); returns a float array of their shape.

        Values may be NaN or infinite where the expression is (``log(x)`` at x <= 0);
        the callers check finiteness where they need it.
        """
        active = tuple(dict.fromkeys(self.derivative))
        value, grad, hess = self._jets(values, active, len(self.derivative))
        if not self.derivative:
            return value
        first = active.index(self.derivative[0])
        if len(self.derivative) == 1:
            return grad[first]
        return hess[first, active.index(self.derivative[1])]

    def jets(
        self, *values: Array | float, wrt: Sequence[str], order: int = 2
    ) -> tuple[Array, Array, Array]:
        """Value (P), gradient (k, P) and Hessian (k, k, P) by the k names ``wrt``, from
        arrays broadcast to the shape P; order 1 leaves the Hessian zero."""
        indices = tuple(self.names.index(n) for n in wrt)
        return self._jets(values, indices, order)

    def _jets(self, values, active: tuple[int, ...], order: int):
        if len(values) != len(self.names):
            raise TypeError(f"expected {len(self.names)} values for {self.names}")
        arrays = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in values))
        shape = arrays[0].shape if arrays else ()
        evaluator = Evaluator(tuple(arrays), {a: i for i, a in enumerate(active)}, order)
        with np.errstate(all="ignore"):
            jet = evaluator.jet(self.tree)
        k = len(active)
        value = np.broadcast_to(np.asarray(jet.value, dtype=float), shape).copy()
        grad = np.zeros((k, *shape)) if jet.grad is None else np.broadcast_to(jet.grad, (k, *shape))
        hess = np.zeros((k, k, *shape))
        if order == 2 and jet.hess is not None:
            hess = np.broadcast_to(jet.hess, (k, k, *shape))
        return value, np.array(grad, dtype=float), np.array(hess, dtype=float)

    def diff(self, name: str) -> Expression:
        """The derivative with respect to the declared variable ``name`` (up to order 2)."""
        if len(self.derivative) == 2:
            raise ValueError("derivatives beyond the second are not available")
        index = self.names.index(name)
        return Expression(
            f"d({self.text})/d{name}", self.names, self.tree, self.where, (*self.derivative, index)
        )

    def depends_on(self, name: str) -> bool:
        """Whether ``name`` occurs in the expression (after constant parts are computed)."""
        return self.names.index(name) in self.tree.variables

    @property
    def is_constant(self) -> bool:
        return not self.tree.variables


def parse(
    text: str,
    names: Sequence[str],
    where: str = "expression",
    constants: Mapping[str, float] = MappingProxyType({}),
) -> Expression:
    """Parse ``text`` as an expression in the variables ``names``.

    ``where`` names the spec field in error messages (e.g. ``"material.lambda2"``).
    ``constants`` are further names with a fixed value (a spec's parameters), computed
    into the tree like ``pi``.
    Raises :class:`FabkitError` for anything outside the whitelist, beyond the limits
    (:data:`MAX_LENGTH`, :data:`MAX_NODES`, :data:`MAX_DEPTH`) or with a constant part
    that is not a finite real number.
    """
    names = tuple(names)
    for name in (*names, *constants):
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
    source = text.replace("^", "**").strip()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)
            tree = ast.parse(source, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise FabkitError(
            f"{where}: cannot parse '{shorten(text)}': {_syntax_reason(exc)}"
        ) from None
    _check_size(tree.body, where)
    builder = _Builder({n: i for i, n in enumerate(names)}, where, text, source, dict(constants))
    return Expression(text, names, builder.build(tree.body), where)


def _syntax_reason(exc: BaseException) -> str:
    if isinstance(exc, SyntaxError):
        return exc.msg
    if isinstance(exc, RecursionError | MemoryError):
        return "nested too deeply"
    return str(exc)


def shorten(text: str, length: int = 60) -> str:
    """``text`` cut to ``length`` characters (ending in "...") for a one-line message."""
    return text if len(text) <= length else text[: length - 3] + "..."


def _family(node: ast.AST) -> str | None:
    """``"sum"`` for + and -, ``"product"`` for * and /, else None."""
    return _FAMILIES.get(type(node.op)) if isinstance(node, ast.BinOp) else None


def _check_size(root: ast.AST, where: str) -> None:
    """Refuse a syntax tree with more than MAX_NODES nodes or deeper than MAX_DEPTH levels.

    Walks the tree with an explicit stack, so even a tree nested a thousand levels deep
    is measured without recursion.
    """
    count, deepest = 0, 0
    stack = [(root, 1)]
    while stack:
        node, depth = stack.pop()
        count += isinstance(node, ast.expr)
        deepest = max(deepest, depth)
        for child in ast.iter_child_nodes(node):
            chained = _family(node) is not None and _family(node) == _family(child)
            level = chained or not isinstance(child, ast.expr)
            stack.append((child, depth if level else depth + 1))
    if count > MAX_NODES:
        raise FabkitError(
            f"{where}: expression too large: {count} nodes (numbers, names, operations, "
            f"calls), more than {MAX_NODES}; see docs/spec.md#limits"
        )
    if deepest > MAX_DEPTH:
        raise FabkitError(
            f"{where}: expression nested too deeply: {deepest} levels, more than {MAX_DEPTH}; "
            "see docs/spec.md#limits"
        )


def _chain(node: ast.BinOp) -> list[tuple[ast.AST, bool]]:
    """The operands of a chain of + and - (or * and /), each with whether it is
    subtracted (divided), left to right; iterative, so a long chain costs no recursion."""
    family, operands = _family(node), []
    stack: list[tuple[ast.AST, bool]] = [(node, False)]
    while stack:
        item, inverted = stack.pop()
        if _family(item) == family:
            stack.append((item.right, inverted != isinstance(item.op, ast.Sub | ast.Div)))
            stack.append((item.left, inverted))
        else:
            operands.append((item, inverted))
    return operands


@dataclass(frozen=True)
class _Builder:
    """Turns a checked syntax tree into a :class:`Node` tree, computing constant parts."""

    variables: dict[str, int]
    where: str
    text: str
    source: str
    constants: dict[str, float]

    def refuse(self, what: str) -> FabkitError:
        allowed = ", ".join([*self.variables, *self.constants, "pi", "e"])
        return FabkitError(
            f"{self.where}: {what} is not allowed in '{shorten(self.text)}' (names allowed: "
            f"{allowed}; "
            "see docs/spec.md#expressions)"
        )

    def constant(self, node: ast.AST, compute: Callable[[], complex | float]) -> Node:
        """A constant part computed in floating point; refused unless finite and real."""
        try:
            with np.errstate(all="ignore"):
                value = complex(compute())
        except (OverflowError, ZeroDivisionError):
            value = complex(math.inf)
        if not (math.isfinite(value.real) and math.isfinite(value.imag)):
            raise FabkitError(f"{self.where}: {self.part(node)} is not finite (in '{self.short}')")
        if abs(value.imag) > 1e-12 * max(1.0, abs(value.real)):
            raise FabkitError(
                f"{self.where}: {self.part(node)} is not a real number (in '{self.short}')"
            )
        return const_node(value.real)

    def part(self, node: ast.AST) -> str:
        """The text of ``node``, shortened for a message."""
        return shorten(ast.get_source_segment(self.source, node) or self.text, 40)

    @property
    def short(self) -> str:
        return shorten(self.text)

    def build(self, node: ast.AST) -> Node:
        if isinstance(node, ast.Constant):
            return self.number(node)
        if isinstance(node, ast.Name):
            return self.name(node.id)
        if isinstance(node, ast.UnaryOp):
            return self.unary(node)
        if isinstance(node, ast.BinOp):
            return self.binary(node)
        if isinstance(node, ast.Call):
            return self.call(node)
        raise self.refuse(_TOKEN_NAMES.get(type(node), f"'{type(node).__name__}'"))

    def number(self, node: ast.Constant) -> Node:
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.refuse(f"the literal {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise self.refuse(f"the number {value!r}")
        if isinstance(value, int) and abs(value) > sys.float_info.max:
            raise FabkitError(
                f"{self.where}: the integer {shorten(str(value), 20)} ({len(str(value))} digits) "
                f"is too large for a float (in '{shorten(self.text)}')"
            )
        return self.constant(node, lambda: float(value))

    def name(self, identifier: str) -> Node:
        if identifier in self.variables:
            index = self.variables[identifier]
            return Node("var", index=index, variables=frozenset([index]))
        if identifier in self.constants:
            return const_node(float(self.constants[identifier]))
        if identifier in CONSTANTS:
            return const_node(CONSTANTS[identifier])
        if identifier in FUNCTIONS:
            raise self.refuse(f"the function name '{identifier}' without an argument")
        raise self.refuse(f"the name '{identifier}'")

    def unary(self, node: ast.UnaryOp) -> Node:
        if not isinstance(node.op, ast.USub | ast.UAdd):
            raise self.refuse(_OPERATOR_NAMES.get(type(node.op), "this operator"))
        operand = self.build(node.operand)
        if isinstance(node.op, ast.UAdd):
            return operand
        if operand.kind == "const":
            return const_node(-operand.value)
        return op_node("neg", operand)

    def binary(self, node: ast.BinOp) -> Node:
        if isinstance(node.op, ast.BitXor | ast.Pow):
            return self.power(node, self.build(node.left), self.build(node.right))
        family = _family(node)
        if family is None:
            raise self.refuse(_OPERATOR_NAMES.get(type(node.op), "this operator"))
        operands = []
        for item, inverted in _chain(node):
            operand = self.build(item)
            if inverted and family == _SUM:
                operand = (
                    const_node(-operand.value)
                    if operand.kind == "const"
                    else op_node("neg", operand)
                )
            elif inverted:
                if operand.kind == "const" and operand.value == 0:
                    divisor = self.part(item)
                    what = "" if divisor == "0" else f" ({divisor} = 0)"
                    raise FabkitError(
                        f"{self.where}: division by zero{what} in '{shorten(self.text)}'"
                    )
                operand = self.inverse(item, operand)
            operands.append(operand)
        return self.combine(node, family, operands)

    def inverse(self, node: ast.AST, operand: Node) -> Node:
        if operand.kind == "const":
            return self.constant(node, lambda: 1.0 / operand.value)
        return op_node("recip", operand)

    def combine(self, node: ast.AST, family: str, operands: list[Node]) -> Node:
        """A sum or product; its constant operands are computed into one number first."""
        constants = [o.value for o in operands if o.kind == "const"]
        others = [o for o in operands if o.kind != "const"]
        if family == _SUM:
            number = self.constant(node, lambda: math.fsum(constants))
            neutral = 0.0
        else:
            number = self.constant(node, lambda: math.prod(constants))
            neutral = 1.0
        if not others:
            return number
        if number.value != neutral:
            others.insert(0, number)
        return (
            others[0] if len(others) == 1 else op_node("add" if family == _SUM else "mul", *others)
        )

    def power(self, node: ast.BinOp, base: Node, exponent: Node) -> Node:
        """A power; a constant one is computed in floating point (complex, to see a
        negative base to a fractional power)."""
        if base.kind == "const" and exponent.kind == "const":
            return self.constant(node, lambda: complex(base.value) ** complex(exponent.value))
        if exponent.kind == "const" and exponent.value == 0:
            return const_node(1.0)
        if exponent.kind == "const" and exponent.value == 1:
            return base
        return op_node("pow", base, exponent)

    def call(self, node: ast.Call) -> Node:
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            callee = node.func.id if isinstance(node.func, ast.Name) else "an expression"
            raise self.refuse(f"calling '{callee}'")
        name = node.func.id
        arity = ARITY.get(name, 1)
        if node.keywords or len(node.args) != arity:
            raise self.refuse(f"'{name}' with other than {arity} argument(s)")
        arguments = [self.build(a) for a in node.args]
        if any(a.kind != "const" for a in arguments):
            return op_node(name, *arguments)
        values = [a.value for a in arguments]
        if name == "arctan2":
            return self.constant(node, lambda: np.arctan2(*values))
        return self.constant(node, lambda: UNARY[name](np.asarray(values[0]))[0])
