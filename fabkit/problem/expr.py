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
in its length, where a symbolic second derivative would hold 100^3 terms.

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

MAX_LENGTH = 2000
"""Longest expression text accepted, in characters."""
MAX_NODES = 500
"""Most nodes (numbers, names, operations, calls) in an expression's syntax tree."""
MAX_DEPTH = 32
"""Deepest nesting of an expression; a chain of + and -, or of * and /, is one level."""

Array = np.ndarray
Unary = Callable[[Array], tuple[Array, Callable[[], Array], Callable[[], Array]]]


def _unary(f, f1, f2) -> Unary:
    """A function with its first and second derivatives, each computed only when asked."""
    return lambda u: (f(u), lambda: f1(u), lambda: f2(u))


def _sec2(u: Array) -> Array:
    return 1.0 / np.cos(u) ** 2


UNARY: dict[str, Unary] = {
    "exp": _unary(np.exp, np.exp, np.exp),
    "log": _unary(np.log, lambda u: 1.0 / u, lambda u: -1.0 / u**2),
    "sqrt": _unary(np.sqrt, lambda u: 0.5 / np.sqrt(u), lambda u: -0.25 / u**1.5),
    "sin": _unary(np.sin, np.cos, lambda u: -np.sin(u)),
    "cos": _unary(np.cos, lambda u: -np.sin(u), lambda u: -np.cos(u)),
    "tan": _unary(np.tan, _sec2, lambda u: 2.0 * _sec2(u) * np.tan(u)),
    "arcsin": _unary(
        np.arcsin, lambda u: 1.0 / np.sqrt(1.0 - u**2), lambda u: u / (1.0 - u**2) ** 1.5
    ),
    "arccos": _unary(
        np.arccos, lambda u: -1.0 / np.sqrt(1.0 - u**2), lambda u: -u / (1.0 - u**2) ** 1.5
    ),
    "arctan": _unary(np.arctan, lambda u: 1.0 / (1.0 + u**2), lambda u: -2.0 * u / (1 + u**2) ** 2),
    "sinh": _unary(np.sinh, np.cosh, np.sinh),
    "cosh": _unary(np.cosh, np.sinh, np.cosh),
    "tanh": _unary(
        np.tanh,
        lambda u: 1.0 - np.tanh(u) ** 2,
        lambda u: -2.0 * np.tanh(u) * (1.0 - np.tanh(u) ** 2),
    ),
    "abs": _unary(np.abs, np.sign, np.zeros_like),
}
"""The one-argument functions: value, first and second derivative (abs'' = 0 off 0)."""
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


# --------------------------------------------------------------------------- the tree


@dataclass(frozen=True, eq=False)
class Node:
    """One operation of a parsed expression.

    ``kind`` is ``const`` (``value``), ``var`` (``index`` into the declared names),
    ``neg``, ``add``, ``mul``, ``recip`` (1/x), ``pow``, or a function name; ``args`` are
    the operands. ``variables`` are the indices of the names the node depends on.
    """

    kind: str
    args: tuple[Node, ...] = ()
    value: float = 0.0
    index: int = -1
    variables: frozenset[int] = frozenset()


def _const(value: float) -> Node:
    return Node("const", value=value)


def _op(kind: str, *args: Node) -> Node:
    return Node(kind, args, variables=frozenset().union(*(a.variables for a in args)))


@dataclass(frozen=True)
class Jet:
    """A value (shape P) with its gradient (k, *P) and Hessian (k, k, *P) with respect to
    the k active variables; None stands for zero (a constant has neither). ``used`` (k,)
    marks the active variables the value depends on (None: all): the other rows of the
    gradient and Hessian are zero by structure, and stay zero whatever they multiply."""

    value: Array
    grad: Array | None = None
    hess: Array | None = None
    used: Array | None = None


def _plus(a: Array | None, b: Array | None) -> Array | None:
    if a is None:
        return b
    return a if b is None else a + b


def _keep(product: Array, mask: Array | None) -> Array:
    """``product`` with the entries outside ``mask`` (k,) or (k, k) set to zero where they
    are not finite: they are zero by structure, and 0 * inf must stay 0 (d/dy of
    x * (1/y) at y = 0 is -x/y^2, not NaN)."""
    if mask is None or mask.all() or np.isfinite(product).all():
        return product
    return np.where(mask.reshape(mask.shape + (1,) * (product.ndim - mask.ndim)), product, 0.0)


def _pair(a: Jet, b: Jet) -> Array | None:
    """The (k, k) mask of Hessian entries two jets can make non-zero together."""
    if a.used is None and b.used is None:
        return None
    ua = np.ones(len(a.grad), dtype=bool) if a.used is None else a.used
    ub = np.ones(len(b.grad), dtype=bool) if b.used is None else b.used
    return ua[:, None] & ub[None, :]


def _grad_times(jet: Jet, factor: Array) -> Array | None:
    """The jet's gradient times ``factor``, its structural zeros kept."""
    return None if jet.grad is None else _keep(jet.grad * factor, jet.used)


def _hess_times(jet: Jet, factor: Array) -> Array | None:
    """The jet's Hessian times ``factor``, its structural zeros kept."""
    if jet.hess is None:
        return None
    return _keep(jet.hess * factor, None if jet.used is None else _pair(jet, jet))


def _outer(a: Jet, b: Jet, factor: Array | None = None) -> Array | None:
    """``factor`` a' b'^T (k, k, *P) of two jets' gradients, structural zeros kept."""
    if a.grad is None or b.grad is None:
        return None
    product = a.grad[:, None] * b.grad[None, :]
    if factor is not None:
        product = product * factor
    return _keep(product, _pair(a, b))


@dataclass(frozen=True)
class _Evaluator:
    """Evaluates a tree on arrays, with derivatives up to ``order`` in the ``active``
    variables (their positions in the gradient)."""

    values: tuple[Array, ...]
    active: dict[int, int]
    order: int

    def jet(self, node: Node) -> Jet:
        kind = node.kind
        if kind == "const":
            return Jet(np.asarray(node.value))
        if kind == "var":
            return self.variable(node.index)
        return self.structural(node, self.operation(node, [self.jet(a) for a in node.args]))

    def structural(self, node: Node, jet: Jet) -> Jet:
        """The jet with ``used`` set from the node's variables, and the rows of the others
        zeroed (they are zero by structure, also where a factor was infinite)."""
        if jet.grad is None or all(v in node.variables for v in self.active):
            return jet
        used = np.array([v in node.variables for v in self.active])
        grad = _keep(jet.grad, used)
        hess = None if jet.hess is None else _keep(jet.hess, used[:, None] & used[None, :])
        return Jet(jet.value, grad, hess, used)

    def operation(self, node: Node, args: list[Jet]) -> Jet:
        kind = node.kind
        if kind == "add":
            total = args[0]
            for term in args[1:]:
                total = Jet(
                    total.value + term.value,
                    _plus(total.grad, term.grad),
                    _plus(total.hess, term.hess),
                )
            return total
        if kind == "mul":
            product = args[0]
            for factor in args[1:]:
                product = self.multiply(product, factor)
            return product
        if kind == "neg":
            (u,) = args
            grad = None if u.grad is None else -u.grad
            return Jet(-u.value, grad, None if u.hess is None else -u.hess, u.used)
        if kind == "recip":
            return self.chain(args[0], _RECIPROCAL)
        if kind == "pow":
            return self.power(node, *args)
        if kind == "arctan2":
            return self.arctan2(*args)
        return self.chain(args[0], UNARY[kind])

    def variable(self, index: int) -> Jet:
        value = self.values[index]
        if index not in self.active or self.order == 0:
            return Jet(value)
        grad = np.zeros((len(self.active),) + (1,) * value.ndim)
        grad[self.active[index]] = 1.0
        return Jet(value, grad, None, np.arange(len(self.active)) == self.active[index])

    def multiply(self, a: Jet, b: Jet) -> Jet:
        """(ab)' = a'b + ab' and (ab)'' = a''b + a'b'^T + b'a'^T + ab''."""
        grad = _plus(_grad_times(a, b.value), _grad_times(b, a.value))
        hess = None
        if self.order == 2:
            cross = _outer(a, b)
            hess = _plus(_hess_times(a, b.value), _hess_times(b, a.value))
            hess = _plus(hess, _plus(cross, None if cross is None else np.swapaxes(cross, 0, 1)))
        return Jet(a.value * b.value, grad, hess, _union(a.used, b.used, a, b))

    def chain(self, u: Jet, function: Unary) -> Jet:
        """f(u): f'(u) u' and f''(u) u' u'^T + f'(u) u''."""
        value, first, second = function(u.value)
        if u.grad is None:
            return Jet(value)
        f1 = first()
        hess = None
        if self.order == 2:
            hess = _plus(_outer(u, u, second()), _hess_times(u, f1))
        return Jet(value, _grad_times(u, f1), hess, u.used)

    def power(self, node: Node, base: Jet, exponent: Jet) -> Jet:
        """u ** v: by c u^(c-1) for an exponent without derivative, else with both partials
        v u^(v-1) and u^v log(u) (so 0 ** v has derivative 0 by u for v > 1)."""
        if exponent.grad is None:
            c = float(node.args[1].value) if node.args[1].kind == "const" else exponent.value
            return self.chain(base, _power(c))
        u, v = base.value, exponent.value
        value = np.power(u, v)
        log = np.log(u)

        def second() -> tuple[Array, Array, Array]:
            return (
                v * (v - 1) * np.power(u, v - 2),
                np.power(u, v - 1) * (1 + v * log),
                value * log**2,
            )

        return self.binary(base, exponent, value, (v * np.power(u, v - 1), value * log), second)

    def arctan2(self, y: Jet, x: Jet) -> Jet:
        """The angle of (x, y): partials x/r^2 by y and -y/r^2 by x."""
        r2 = x.value**2 + y.value**2

        def second() -> tuple[Array, Array, Array]:
            fyy = -2.0 * x.value * y.value / r2**2
            return fyy, (y.value**2 - x.value**2) / r2**2, -fyy

        value = np.arctan2(y.value, x.value)
        return self.binary(y, x, value, (x.value / r2, -y.value / r2), second)

    def binary(
        self,
        u: Jet,
        v: Jet,
        value: Array,
        first: tuple[Array, Array],
        second: Callable[[], tuple[Array, Array, Array]],
    ) -> Jet:
        """f(u, v) from its partials ``first`` = (f_u, f_v) and ``second()`` = (f_uu, f_uv,
        f_vv): grad f_u u' + f_v v', Hessian f_uu u'u'^T + f_uv (u'v'^T + v'u'^T)
        + f_vv v'v'^T + f_u u'' + f_v v''."""
        if u.grad is None and v.grad is None:
            return Jet(value)
        fu, fv = first
        grad = _plus(_grad_times(u, fu), _grad_times(v, fv))
        hess = None
        if self.order == 2:
            fuu, fuv, fvv = second()
            mixed = _outer(u, v, fuv)
            if mixed is not None:
                mixed = mixed + np.swapaxes(mixed, 0, 1)
            hess = _plus(_outer(u, u, fuu), _outer(v, v, fvv))
            hess = _plus(_plus(hess, mixed), _plus(_hess_times(u, fu), _hess_times(v, fv)))
        return Jet(value, grad, hess, _union(u.used, v.used, u, v))


def _union(a: Array | None, b: Array | None, jet_a: Jet, jet_b: Jet) -> Array | None:
    """The variables two jets depend on together (None: all, or unknown)."""
    if jet_a.grad is None:
        return b
    if jet_b.grad is None:
        return a
    return None if a is None or b is None else a | b


_RECIPROCAL = _unary(lambda u: 1.0 / u, lambda u: -1.0 / u**2, lambda u: 2.0 / u**3)


def _power(c: Array | float) -> Unary:
    """u ** c for a constant c; the derivative terms with a zero coefficient are zero
    (so x**1 has u'' = 0 at x = 0, not 0 * inf)."""
    c = np.asarray(c, dtype=float)

    def first(u: Array) -> Array:
        return np.where(c == 0, 0.0, c * np.power(u, c - 1))

    def second(u: Array) -> Array:
        coefficient = c * (c - 1)
        return np.where(coefficient == 0, 0.0, coefficient * np.power(u, c - 2))

    return _unary(lambda u: np.power(u, c), first, second)


# --------------------------------------------------------------------------- expressions


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
        evaluator = _Evaluator(tuple(arrays), {a: i for i, a in enumerate(active)}, order)
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
        return _const(value.real)

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
            return _const(float(self.constants[identifier]))
        if identifier in CONSTANTS:
            return _const(CONSTANTS[identifier])
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
            return _const(-operand.value)
        return _op("neg", operand)

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
                operand = _const(-operand.value) if operand.kind == "const" else _op("neg", operand)
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
        return _op("recip", operand)

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
        return others[0] if len(others) == 1 else _op("add" if family == _SUM else "mul", *others)

    def power(self, node: ast.BinOp, base: Node, exponent: Node) -> Node:
        """A power; a constant one is computed in floating point (complex, to see a
        negative base to a fractional power)."""
        if base.kind == "const" and exponent.kind == "const":
            return self.constant(node, lambda: complex(base.value) ** complex(exponent.value))
        if exponent.kind == "const" and exponent.value == 0:
            return _const(1.0)
        if exponent.kind == "const" and exponent.value == 1:
            return base
        return _op("pow", base, exponent)

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
            return _op(name, *arguments)
        values = [a.value for a in arguments]
        if name == "arctan2":
            return self.constant(node, lambda: np.arctan2(*values))
        return self.constant(node, lambda: UNARY[name](np.asarray(values[0]))[0])
