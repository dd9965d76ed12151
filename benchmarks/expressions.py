"""Expression speed on hostile input: the limits of docs/spec.md#limits, measured.

For each expression, prints the time to read it (or refuse it), and to evaluate it with
its gradient and Hessian on 1000 points; then the time to build a metric and a
parametric surface from such expressions and evaluate their geometry, and to classify a
material law that computer algebra took minutes over.

    python benchmarks/expressions.py
"""

from __future__ import annotations

import time

import numpy as np

from fabkit.errors import FabkitError
from fabkit.problem.expr import MAX_NODES, parse
from fabkit.problem.material import Material
from fabkit.problem.surfaces.analytic import Metric, Parametric

FUNCTIONS = ("sin", "cos", "exp", "tanh", "log", "sqrt", "sinh", "arctan")


def nested(depth: int, a: str = "x", b: str = "y") -> str:
    """Functions of sums and products nested ``depth`` deep."""
    text = f"({a}+{b})"
    for k in range(depth):
        name = FUNCTIONS[k % len(FUNCTIONS)]
        text = f"{name}({text}*{a}+{b})" if k % 3 == 0 else f"{name}({text})"
    return text


def largest_sum(part: str) -> str:
    """As many copies of ``part`` summed as the node limit allows."""
    parts = [part]
    while True:
        candidate = "+".join([*parts, part])
        try:
            parse(candidate, ("x", "y"))
        except FabkitError:
            return "+".join(parts)
        parts.append(part)


def deepest() -> str:
    """The deepest :func:`nested` expression the depth limit accepts."""
    depth = 1
    while True:
        try:
            parse(nested(depth + 1), ("x", "y"))
        except FabkitError:
            return nested(depth)
        depth += 1


CASES = {
    "150 nested exp": "exp(" * 150 + "x" + ")" * 150,
    "power tower 2**2**2**2**2": "2**2**2**2**2",
    "400-digit integer": "1" + "0" * 400,
    "sum of 600 terms": "+".join(["x"] * 600),
    "(x+1)**1000000": "(x+1)**1000000",
    "23 nested functions": nested(23),
    "product of 119 factors": "*".join(f"(x+{k})" for k in range(1, 120)),
    "deepest nest accepted": deepest(),
    "8 functions deep, summed to the limit": largest_sum(nested(8)),
    "sum of 125 products x*y (499 nodes)": "+".join(["x*y"] * ((MAX_NODES + 1) // 4)),
}


def timed(function) -> tuple[float, object]:
    started = time.perf_counter()
    result = function()
    return time.perf_counter() - started, result


def main() -> None:
    points = np.random.default_rng(0).uniform(0.1, 0.5, (2, 1000))
    print(f"{'expression':42s} {'chars':>6s} {'read':>9s} {'jets x1000':>11s}")
    texts = {}
    for name, text in CASES.items():
        try:
            seconds, expression = timed(lambda text=text: parse(text, ("x", "y")))
        except FabkitError as error:
            print(f"{name:42s} {len(text):6d} refused: {str(error)[:60]}")
            continue
        texts[name] = text
        jets, _ = timed(lambda e=expression: e.jets(*points, wrt=("x", "y")))
        print(f"{name:42s} {len(text):6d} {seconds * 1e3:7.2f} ms {jets * 1e3:8.2f} ms")

    r = points.T
    for name in ("product of 119 factors", "8 functions deep, summed to the limit"):
        ab = texts[name].replace("exp", "EXP").replace("x", "a").replace("y", "b")
        ab = ab.replace("EXP", "exp")
        seconds, _ = timed(
            lambda ab=ab: Metric(
                "m", tuple(parse(t, ("a", "b")) for t in (f"1 + ({ab})**2", "0", "1"))
            ).geometry(r)
        )
        print(f"metric surface, g11 from '{name}': {seconds * 1e3:.1f} ms")
        seconds, _ = timed(
            lambda ab=ab: Parametric(
                "p", tuple(parse(t, ("a", "b")) for t in ("a", "b", ab))
            ).geometry(r)
        )
        print(f"parametric surface, z = '{name}': {seconds * 1e3:.1f} ms")

    for law in ("(1+L*eps)**1000", "exp(L*eps)*(1+eps)**999999"):
        material = Material(("eps",), ("L",), parse("1", ("eps", "L")), parse(law, ("eps", "L")))
        seconds, classes = timed(lambda m=material: m.classify(np.array([[1.0], [2.0]])))
        print(f"classify lambda2 = {law}: {classes} in {seconds * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
