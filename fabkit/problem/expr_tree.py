"""The tree of a parsed expression and its evaluation with exact derivatives.

A :class:`Node` is one allowed operation (a number, a variable, a sum, a product, a
reciprocal, a power or a function of :data:`UNARY` or ``arctan2``). The
:class:`Evaluator` computes a tree on numpy arrays node by node, each node's value as a
:class:`Jet` with its gradient and Hessian by forward-mode automatic differentiation,
keeping the entries that are zero by structure zero (0 * inf stays 0). The parser that
builds the trees, and the :class:`~fabkit.problem.expr.Expression` that evaluates them,
are in :mod:`fabkit.problem.expr`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

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


def const_node(value: float) -> Node:
    return Node("const", value=value)


def op_node(kind: str, *args: Node) -> Node:
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
class Evaluator:
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
        v u^(v-1) and u^v log(u) (so 0 ** v has derivative 0 by u for v > 1); the terms
        with a zero coefficient are zero, as for a constant exponent (u ** x at x = 0 has
        derivative 0 by u also where u = 0, whether x is differentiated or not)."""
        if exponent.grad is None:
            c = float(node.args[1].value) if node.args[1].kind == "const" else exponent.value
            return self.chain(base, _power(c))
        u, v = base.value, exponent.value
        value = np.power(u, v)
        log = np.log(u)

        def second() -> tuple[Array, Array, Array]:
            coefficient = v * (v - 1)
            fuu = np.where(coefficient == 0, 0.0, coefficient * np.power(u, v - 2))
            return fuu, np.power(u, v - 1) * (1 + v * log), value * log**2

        fu = np.where(v == 0, 0.0, v * np.power(u, v - 1))  # as a constant exponent's
        return self.binary(base, exponent, value, (fu, value * log), second)

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
