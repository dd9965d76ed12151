"""A layered sheet: the design's metric as the layers' mean, its targets' curvature in
their spread.

A metric does not fix a shape: a target's mirror image has the same metric and bending
energy, and a target may have isometric neighbours of lower bending energy, so a sheet
programmed with the metric alone may buckle into one of those (Fig. 3's wavy sheet does).
What selects the target is a natural curvature b̄ equal to its second fundamental form
II: then the target is a state of zero energy. A sheet whose layers have different
reference metrics has one.

Through the thickness (height z from the mid-surface, -H/2 to H/2) the 3D reference
metric of a Kirchhoff-Love sheet is ḡ(z) = ā - 2 z b̄ (to first order); a sheet whose
layers have metrics ā_k takes the ā and b̄ that fit them best in that sense (its elastic
energy is the integral of |g(z) - ḡ(z)|² over z), the least-squares line through them:

    ā = mean over z of ā(z),   b̄ = -1/2 * slope = -6 / H³ * integral of z ā(z) dz.

Two layers of thicknesses h1 (bottom) and h2 (top), H = h1 + h2:

    ā = (h1 ā_b + h2 ā_t) / H,   b̄ = 3 h1 h2 (ā_b - ā_t) / H³,

so for equal layers b̄ = 3 / (4 H) (ā_b - ā_t), Timoshenko's bimetal curvature
3 Δε / (2 H) for a strain mismatch Δε (ā_b - ā_t = 2 Δε). (The brief's general form,
6 h1 h2 (ā_b - ā_t) / H³, is twice this; its equal-layer form agrees with this one when
its h is the whole thickness. ``tests/test_design_layers.py`` simulates a bilayer strip
with :mod:`fabkit.mechanics.shell`, which integrates every layer through its own
thickness, and finds this curvature within 2 %.) For K equal layers whose metrics vary
linearly in z, ā_k = ā + z_k D, the fit gives ā exactly and

    b̄ = -c_K D,   c_K = (K² - 1) / (2 K²)   (3/8 for two layers, 1/2 for many).

The layering. At every grid point the design gives the flat director and features and
so, at every stimulus, the metric in material coordinates (u, v):
A = diag(α λ1, β λ2)² (λ1 along the director, λ2 across). A layer at height z has its
director turned by z t and its features moved by z s (t and s are what is chosen, per
unit height); to first order

    dA/dt = α β (λ1² - λ2²) [[0, 1], [1, 0]],
    dA/ds_i = diag(2 α² λ1² ∂ log λ1 / ∂ eps_i, 2 β² λ2² ∂ log λ2 / ∂ eps_i),

so D = dA/dt t + Σ dA/ds_i s_i and b̄ = -c_K D at each target's stimulus, while the
layers' mean metric stays the design's (the error is second order in z, reported). In
the frame of the target's own lengths (components divided by α λ1, β λ2) t and s are
chosen by weighted least squares over the targets: the off-diagonal part of every
target's II fixes t, the diagonal parts fix s (a feature acting along the director
reaches II_uu, one acting across II_vv). An unknown shared by targets that want
opposite signs at a point (Fig. 1's one feature, where the bump's flank curves the
other way from the sphere) is left at zero there, and one whose best value would bend a
target to its wrong side is held at zero and the others solved again: the layers never
push a target towards another shape. With bounds on the features (a process's range),
a feature whose layers would leave them is scaled back likewise. The flat sheet
(λ1 = λ2 = 1, no feature has an effect) stays flat.

II of each target comes from its embedding (:meth:`Surface.embed`) at the design's grid
points, by finite differences in (u, v) (central where both neighbours are solved, else
one-sided); an intrinsic target (metric only) asks for no curvature.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabkit.design.design import MAX_LAYERS, Design, Layering
from fabkit.errors import FabkitError

TINY = 1e-12
SHARED_TURN_DEG = 2.0
"""Largest turn (degrees) between a layering's bottom and top layers that is printed
along one set of lines, turned per layer (:mod:`fabkit.toolpath.plan`); layers turned
further are planned apart, and their roads' wander (about a degree) differs between
them, a twist no design asked for. The first-order layering turns the layers a fraction
of a degree; the refinement (:mod:`fabkit.mechanics.refine`) keeps within it."""
EXPLAINED = 0.5
"""A target asked for its curvature that gets less than this share of it is told why."""
REACHES = 1e-6
"""A lever reaches a component of a target's curvature where its effect (per unit
height, in the target's own lengths) is larger than this."""
COMPONENTS = (
    "along the director, which no feature reaches at its stimulus",
    "twist, which no shear reaches (the stimulus stretches both ways alike)",
    "across the director, which no feature reaches at its stimulus",
)
"""II's components in the material frame (uu, uv, vv), and what would reach them."""
REMEDIES = (
    "a feature acting along the director at its stimulus",
    "a stimulus that stretches along and across the director unequally",
    "a feature acting across the director at its stimulus",
)


@dataclass(frozen=True)
class Reach:
    """Why the layers give a target little of its curvature (shapes (S, 3), shares of
    the target's |II|² over its solved points, by component uu, uv, vv):
    ``out_of_reach``: in a component no lever reaches at its stimulus (a feature acting
    along the director for uu, a shear for the twist, a feature across for vv);
    ``held_back``: reached, but at points where another target needs the opposite bend
    from every lever that reaches it (the layers then leave it at zero);
    ``opposed`` (S, S): the share of target k's |II|² held back by target j."""

    out_of_reach: np.ndarray
    held_back: np.ndarray
    opposed: np.ndarray

    def unreachable(self, k: int) -> float:
        """The share of target k's curvature out of reach or held back."""
        return float(self.out_of_reach[k].sum() + self.held_back[k].sum())

    def why(self, k: int, names: tuple[str, ...], limited: np.ndarray) -> str:
        """``45% of its curvature is along the director, which no feature reaches at its
        stimulus; 50% is held back where saddle needs the opposite bend from the same
        lever; what would change it: ...`` (``limited`` as :class:`LayeringReport`'s)."""
        reasons, remedies = [], []
        for c, share in enumerate(self.out_of_reach[k]):
            if share >= 0.05:
                reasons.append(f"{share:.0%} of its curvature is {COMPONENTS[c]}")
                remedies.append(REMEDIES[c])
        held = float(self.held_back[k].sum())
        if held >= 0.05:
            others = [names[j] for j in np.argsort(-self.opposed[k]) if self.opposed[k, j] >= 0.05]
            reasons.append(
                f"{held:.0%} is held back where {' and '.join(others)} need"
                f"{'s' if len(others) == 1 else ''} the opposite bend from the same lever"
            )
            remedies.append(
                "a second feature for that bend, or one whose effect changes sign between "
                "the stimuli"
            )
        if np.max(limited, initial=0.0) >= 0.05:
            reasons.append(f"the features' ranges cap it at {np.max(limited):.0%} of the points")
            remedies.append("a wider feature range")
        if not reasons:
            reasons.append("the levers reach it, but their fit to every target gives it little")
            remedies.append("more layers or a larger size")
        return f"{'; '.join(reasons)}; what would change it: {', or '.join(remedies)}"

    def to_dict(self, names: tuple[str, ...]) -> dict:
        """report.json's ``out_of_reach`` and ``held_back`` per target and component."""

        def table(values: np.ndarray) -> dict:
            return {
                names[k]: dict(zip(("uu", "uv", "vv"), map(float, values[k]), strict=True))
                for k in range(1, len(names))
            }

        return {"out_of_reach": table(self.out_of_reach), "held_back": table(self.held_back)}


@dataclass(frozen=True)
class LayeringReport:
    """How well the layers program each target's curvature (shapes (S,), the flat sheet's
    entries NaN).

    ``matched``: 1 - |b̄ - II| / |II| over the target's solved points (norms in the
    target's own lengths; 1 is all of II, 0 nothing or worse); ``right_side``: the share
    of points where b̄ bends towards the target's side, not its mirror image's (where II
    is not negligible); ``limited``: per feature (N,), the share of points where its
    bounds scaled its slope down; ``metric_error``: the largest relative difference
    between the layers' mean metric and the design's, over stimuli and points, and
    ``metric_error_p99`` its 99th percentile over the points (one point where the shear
    nearly vanishes can ask for a large turn: the largest alone would hide that the rest
    agree); ``reach``: why a target got little of its curvature (:class:`Reach`).
    """

    names: tuple[str, ...]
    matched: np.ndarray
    right_side: np.ndarray
    limited: np.ndarray
    metric_error: float
    weights: np.ndarray
    metric_error_p99: float = 0.0
    reach: Reach | None = None

    def lines(self) -> list[str]:
        """One line per target, for the command line."""
        out = []
        for k in range(1, len(self.names)):
            name, matched, side = self.names[k], self.matched[k], self.right_side[k]
            why = self.why(k)
            if self.weights[k] > 0:
                line = (
                    f"{name}: {max(0.0, matched):.0%} of its curvature programmed, bending to "
                    f"its side at {side:.0%} of the points"
                )
                line += f"; why: {why}" if why else ""
            else:
                line = (
                    f"{name}: its curvature not asked for (the metric alone reaches its shape "
                    f"or its mirror image); the layers give it {max(0.0, matched):.0%} of it, "
                    f"bending to its side at {side:.0%} of the points"
                )
                line += (
                    f"; asked for, most of it is out of these layers' reach: {why}" if why else ""
                )
            out.append(line)
        return out

    def to_dict(self) -> dict:
        return {
            "weights": {n: float(w) for n, w in zip(self.names[1:], self.weights[1:], strict=True)},
            "curvature_matched": {
                n: float(m) for n, m in zip(self.names[1:], self.matched[1:], strict=True)
            },
            "right_side": {
                n: float(r) for n, r in zip(self.names[1:], self.right_side[1:], strict=True)
            },
            "features_limited": [float(x) for x in self.limited],
            "metric_error": self.metric_error,
            "metric_error_p99": self.metric_error_p99,
            **({} if self.reach is None else self.reach.to_dict(self.names)),
            "why": {self.names[k]: self.why(k) for k in range(1, len(self.names))},
        }

    def why(self, k: int) -> str:
        """Why target k gets little of its curvature, or would if asked for it ("" when it
        gets, or would get, most of it): the sentence its line ends with."""
        if self.reach is None:
            return ""
        asked = self.weights[k] > 0
        if (self.matched[k] >= EXPLAINED) if asked else (self.reach.unreachable(k) < EXPLAINED):
            return ""
        return self.reach.why(k, self.names, self.limited)


def layered(
    design: Design,
    count: int,
    thickness: float,
    bounds: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    share: float = 1.0,
) -> tuple[Design, LayeringReport]:
    """``design`` made of ``count`` equal layers, ``thickness`` thick in all (design
    units), whose natural curvature at every target's stimulus is as near that target's
    second fundamental form as the material (and ``bounds``, (N, 2) eps ranges the
    features must keep) allows; ``weights`` (S,) weigh the targets (default 1 each; 0:
    ask nothing for that target, but still bend it to no other side); ``share`` in
    (0, 1] scales the layering's turn and slopes down (a natural curvature of that share
    of it: enough to choose a side, less to distort a shape).
    Returns the layered design and how well it did (module docstring)."""
    if not isinstance(count, int) or not 2 <= count <= MAX_LAYERS:
        raise FabkitError(f"--layers {count}: expected 2 to {MAX_LAYERS} layers")
    if not 0 < share <= 1:
        raise FabkitError(
            f"layers: the share of the curvature asked for must lie in (0, 1], got {share:g}"
        )
    if not (np.isfinite(thickness) and thickness > 0):
        raise FabkitError(f"layers: the sheet's thickness must be positive, got {thickness:g}")
    forms = design.second_forms
    if not np.isfinite(forms[1:]).any():
        raise FabkitError(
            "--layers: no target is embedded in 3D (metric-only surfaces), so there is no "
            "curvature to program"
        )
    weights = np.ones(len(design.stimuli)) if weights is None else np.asarray(weights, float)
    system = _System.build(design, forms, count, weights)
    reach = (count - 1) / (2 * count) * thickness  # the outer layers' height
    turn, slope, limited = system.solve(design.eps, reach, bounds)
    turn, slope = share * turn, share * slope
    valid = design.valid
    layering = Layering(
        count, float(thickness), np.where(valid, turn, np.nan), np.where(valid, slope, np.nan)
    )
    result = design.with_layering(layering)
    return result, system.report(design, result, turn, slope, limited)


def layering_report(
    design: Design,
    layered: Design,
    bounds: np.ndarray | None = None,
    weights: np.ndarray | None = None,
) -> LayeringReport:
    """The figures of ``layered``'s own layering (the first-order one, or one refined
    against the simulation) against ``design``'s targets, as :func:`layered` gives them;
    a feature counts as limited where a layer reaches ``bounds``."""
    layering = layered.layering
    if layering is None:
        raise FabkitError("layers: the design has no layers to report on")
    weights = np.ones(len(design.stimuli)) if weights is None else np.asarray(weights, float)
    system = _System.build(design, design.second_forms, layering.count, weights)
    turn, slope = np.nan_to_num(layering.turn), np.nan_to_num(layering.slope)
    limited = np.zeros(len(slope))
    if bounds is not None:
        reach = (layering.count - 1) / (2 * layering.count) * layering.thickness
        room = slope_room(design.eps, np.asarray(bounds, dtype=float), reach, slope)
        valid = np.isfinite(design.eps).all(axis=0)
        at_bound = (np.abs(slope) >= room - TINY) & (room < np.inf) & valid & (slope != 0)
        limited = at_bound.sum(axis=(1, 2)) / max(int(valid.sum()), 1)
    return system.report(design, layered, turn, slope, limited)


@dataclass(frozen=True)
class _System:
    """The normal equations of the least-squares layering at every grid point, in the
    targets' own lengths (module docstring). ``shear`` (S, nu, nv): the twist column of
    the off-diagonal component; ``along``, ``across`` (S, N, nu, nv): the feature columns
    of the diagonal components; ``target`` (S, 3, nu, nv) the scaled IIs (0 where
    unknown); ``weights`` (S,); ``factor`` c_K."""

    shear: np.ndarray
    along: np.ndarray
    across: np.ndarray
    target: np.ndarray
    known: np.ndarray
    weights: np.ndarray
    factor: float

    @classmethod
    def build(cls, design: Design, forms: np.ndarray, count: int, weights: np.ndarray):
        response = design.problem.material.response(np.nan_to_num(design.eps), design.stimuli)
        l1, l2 = response.lambda1, response.lambda2
        scale_u, scale_v = design.alpha * l1, design.beta * l2
        with np.errstate(all="ignore"):
            target = np.stack(
                [
                    forms[:, 0] / scale_u**2,
                    forms[:, 1] / (scale_u * scale_v),
                    forms[:, 2] / scale_v**2,
                ],
                axis=1,
            )
            shear = (l1**2 - l2**2) / (l1 * l2)
        known = np.isfinite(target).all(axis=1)
        known[0] = False  # the flat sheet asks for nothing, and gets nothing
        return cls(
            shear=np.nan_to_num(shear),
            along=2 * np.nan_to_num(response.l1_e),
            across=2 * np.nan_to_num(response.l2_e),
            target=np.nan_to_num(target),
            known=known,
            weights=weights,
            factor=(count * count - 1) / (2 * count * count),
        )

    def _weight(self) -> np.ndarray:
        """(S, nu, nv) weight of every target at every point (0 where its II is unknown)."""
        return self.weights[:, None, None] * self.known

    def solve(
        self, eps: np.ndarray, reach: float, bounds: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Turn (nu, nv), slopes (N, nu, nv) and the share of points where each feature's
        bounds scaled it down (N,)."""
        w, c = self._weight(), self.factor
        # off-diagonal: b̄_uv = -c shear t (counted twice in the Frobenius norm)
        normal = np.sum(w * (c * self.shear) ** 2, axis=0)
        right = np.sum(w * (-c * self.shear) * self.target[:, 1], axis=0)
        turn = np.where(normal > TINY, right / np.where(normal > TINY, normal, 1.0), 0.0)
        twist, *signs = self.signs()
        turn = np.where(turn * twist > 0, turn, 0.0)
        features = eps.shape[0]
        sides = np.stack(signs)
        free = sides != 0
        slope = np.zeros(eps.shape)
        limited = np.zeros(features)
        for _ in range(2 * features + 1):
            slope = self._slopes(free, slope)
            harmful = free & (slope * sides < 0)  # would bend a target to its wrong side
            if harmful.any():
                slope = np.where(harmful, 0.0, slope)
                free &= ~harmful
                continue
            if bounds is None:
                break
            room = slope_room(eps, np.asarray(bounds, dtype=float), reach, slope)
            over = free & (np.abs(slope) > room)
            if not over.any():
                break
            slope = np.where(over, np.sign(slope) * room, slope)
            free &= ~over
        valid = np.isfinite(eps).all(axis=0)
        if bounds is not None:
            room = slope_room(eps, np.asarray(bounds, dtype=float), reach, slope)
            limited = ((np.abs(slope) >= room - TINY) & (room < np.inf) & valid).sum(
                axis=(1, 2)
            ) / max(int(valid.sum()), 1)
        return turn, slope, limited

    def _slopes(self, free: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """Least-squares slopes of the ``free`` features, the others held at ``fixed``."""
        w, c = self._weight(), self.factor
        columns = [-c * self.along, -c * self.across]  # (S, N, nu, nv) each
        wanted = [self.target[:, 0], self.target[:, 2]]
        features = free.shape[0]
        normal = np.zeros((features, features, *free.shape[1:]))
        right = np.zeros(free.shape)
        for column, goal in zip(columns, wanted, strict=True):
            rest = goal - np.einsum("sn...,n...->s...", column, np.where(free, 0.0, fixed))
            normal += np.einsum("s...,sm...,sn...->mn...", w, column, column)
            right += np.einsum("s...,sm...,s...->m...", w, column, rest)
        mask = free[:, None] & free[None, :]
        eye = np.eye(features)[:, :, None, None]
        normal = np.where(mask, normal, eye) + TINY * eye
        right = np.where(free, right, 0.0)
        solved = np.linalg.solve(
            np.moveaxis(normal, (0, 1), (-2, -1)), np.moveaxis(right, 0, -1)[..., None]
        )[..., 0]
        return np.where(free, np.moveaxis(solved, -1, 0), fixed)

    def curvature(self, turn: np.ndarray, slope: np.ndarray) -> np.ndarray:
        """(S, 3, nu, nv) the natural curvature of the layers, scaled as ``target``."""
        c = self.factor
        uu = -c * np.einsum("sn...,n...->s...", self.along, slope)
        uv = -c * self.shear * turn
        vv = -c * np.einsum("sn...,n...->s...", self.across, slope)
        return np.stack([uu, uv, vv], axis=1)

    def levers(self) -> list[list[tuple[int, np.ndarray]]]:
        """Every lever (the twist, then each feature) as its effects: (the component of
        the curvature it acts on: 0 uu, 1 uv, 2 vv; its effect on that component of every
        target, (S, nu, nv)). A feature acting both along and across the director has
        two effects, with one sign (:meth:`solve`)."""
        features = self.along.shape[1]
        out = [[(1, -self.shear)]]
        for i in range(features):
            out.append([(0, -self.along[:, i]), (2, -self.across[:, i])])
        return out

    def signs(self) -> list[np.ndarray]:
        """Per lever (:meth:`levers`), (nu, nv) the sign it may take without bending any
        target to its wrong side (:func:`_allowed`)."""
        return [
            _allowed([(column, self.target[:, c]) for c, column in effects], self.known)
            for effects in self.levers()
        ]

    def reach(self, valid: np.ndarray) -> Reach:
        """Why each target gets what it gets (:class:`Reach`), over the ``valid`` points."""
        known = self.known & valid
        targets = len(self.weights)
        weight = np.stack(
            [(2.0 if c == 1 else 1.0) * self.target[:, c] ** 2 * known for c in range(3)], 1
        )  # (S, 3, nu, nv): |II|² by component
        reached = np.zeros(weight.shape, dtype=bool)
        free = np.zeros(weight.shape, dtype=bool)  # some lever may bend it its way
        against = np.zeros((targets, targets, *known.shape[1:]), dtype=bool)
        for effects, sign in zip(self.levers(), self.signs(), strict=True):
            votes = [(c, _votes(col, self.target[:, c], self.known)) for c, col in effects]
            for (c, column), (_, vote) in zip(effects, votes, strict=True):
                reaches = np.abs(column) > REACHES
                reached[:, c] |= reaches
                free[:, c] |= reaches & ((vote == 0) | (vote * sign > 0))
                for _, other in votes:
                    against |= (vote[:, None] * other[None, :] < 0) & reaches[:, None]
        held = reached & ~free
        total = np.maximum(weight.sum(axis=(1, 2, 3)), TINY)
        out_of_reach = np.sum(weight * ~reached, axis=(2, 3)) / total[:, None]
        held_back = np.sum(weight * held, axis=(2, 3)) / total[:, None]
        opposed = np.einsum("kcij,kmij->km", weight * held, against) / total[:, None]
        return Reach(out_of_reach, held_back, opposed)

    def report(
        self,
        design: Design,
        layered: Design,
        turn: np.ndarray,
        slope: np.ndarray,
        limited: np.ndarray,
    ) -> LayeringReport:
        bbar = self.curvature(turn, slope)
        names = tuple(t.name for t in design.problem.targets)
        matched = np.full(len(names), np.nan)
        side = np.full(len(names), np.nan)
        for k in range(1, len(names)):
            known = self.known[k] & design.valid
            if not known.any():
                continue
            goal, got = self.target[k][:, known], bbar[k][:, known]
            size = _norm(goal)
            matched[k] = 1.0 - _norm(goal - got) / size if size > TINY else 1.0
            inner = goal[0] * got[0] + 2 * goal[1] * got[1] + goal[2] * got[2]
            strong = np.sqrt(goal[0] ** 2 + 2 * goal[1] ** 2 + goal[2] ** 2) > 0.1 * np.sqrt(
                np.mean(goal**2) * 4 / 3
            )
            side[k] = float(np.mean(inner[strong] > 0)) if strong.any() else 1.0
        errors = _metric_errors(design, layered)
        worst = float(errors.max(initial=0.0))
        p99 = float(np.percentile(errors, 99)) if errors.size else 0.0
        reach = self.reach(design.valid)
        return LayeringReport(names, matched, side, limited, worst, self.weights, p99, reach)


def _allowed(effects: list[tuple[np.ndarray, np.ndarray]], known: np.ndarray) -> np.ndarray:
    """(nu, nv) the sign an unknown may take without bending any target to its wrong
    side: +1, -1, or 0 where targets want opposite signs (or none is reached). Each of
    ``effects`` is (its effect on one component of every target's curvature, that
    component of every target's II), both (S, nu, nv); every target whose II is
    ``known`` (S, nu, nv) votes (:func:`_votes`), whatever its weight."""
    plus = minus = np.zeros(known.shape[1:], dtype=bool)
    for column, target in effects:
        votes = _votes(column, target, known)
        plus = plus | (votes > 0).any(axis=0)
        minus = minus | (votes < 0).any(axis=0)
    return np.where(plus & ~minus, 1.0, np.where(minus & ~plus, -1.0, 0.0))


def _votes(column: np.ndarray, target: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(S, nu, nv) the sign every target wants an unknown to take for one component of
    its curvature (``column`` the unknown's effect on it, ``target`` the component of
    II, both (S, nu, nv)): 0 where the unknown does not reach it, where its II is not
    ``known``, or where the component is less than a tenth of its typical size."""
    typical = np.sqrt(np.mean(target**2, axis=(1, 2), keepdims=True)) + TINY
    votes = np.sign(column * target) * (np.abs(target) > 0.1 * typical)
    return votes * (known & (np.abs(column) > TINY))


def _norm(parts: np.ndarray) -> float:
    """Frobenius norm of (3, n) symmetric 2x2 components (uu, uv, vv) over n points."""
    return float(np.sqrt(np.sum(parts[0] ** 2 + 2 * parts[1] ** 2 + parts[2] ** 2)))


def slope_room(eps: np.ndarray, bounds: np.ndarray, reach: float, slope: np.ndarray) -> np.ndarray:
    """(N, nu, nv) the largest |slope| keeping every layer's features within ``bounds``."""
    if bounds.shape != (eps.shape[0], 2):
        raise FabkitError(f"layers: expected bounds for {eps.shape[0]} features (low, high)")
    low, high = bounds[:, 0, None, None], bounds[:, 1, None, None]
    with np.errstate(invalid="ignore"):
        room = np.where(
            slope >= 0, np.minimum(high - eps, eps - low), np.minimum(eps - low, high - eps)
        )
    return np.clip(np.nan_to_num(room, nan=0.0, posinf=np.inf), 0.0, None) / reach  # inf: unbounded


def _metric_errors(design: Design, layered: Design) -> np.ndarray:
    """At every valid grid point, the largest relative difference of the layers' mean
    metric (its components in (u, v), the director turn's effect included) from the
    design's, over every stimulus and component."""
    material = design.problem.material
    base = material.response(np.nan_to_num(design.eps), design.stimuli)
    layering = layered.layering
    count = layering.count
    heights = layering.heights[:, None, None]  # (K, 1, 1)
    # every layer's features at once, (N, K, nu, nv), as Design.layer gives them
    eps = np.nan_to_num(layered.eps[:, None] + heights * layering.slope[:, None])
    response = material.response(eps, design.stimuli)  # (S, K, nu, nv)
    l1, l2 = response.lambda1**2, response.lambda2**2
    turn = heights * np.nan_to_num(layering.turn)
    cos, sin = np.cos(turn), np.sin(turn)
    mean = np.zeros((3, *base.lambda1.shape))
    for k in range(count):
        mean[0] += (cos[k] ** 2 * l1[:, k] + sin[k] ** 2 * l2[:, k]) / count
        mean[1] += cos[k] * sin[k] * (l1[:, k] - l2[:, k]) / count
        mean[2] += (sin[k] ** 2 * l1[:, k] + cos[k] ** 2 * l2[:, k]) / count
    expected = (base.lambda1**2, 0.0, base.lambda2**2)
    scale = np.sqrt(base.lambda1**2 * base.lambda2**2)
    errors = [
        np.abs(component - goal) / scale for component, goal in zip(mean, expected, strict=True)
    ]
    return np.max(np.stack(errors), axis=(0, 1))[design.valid]
