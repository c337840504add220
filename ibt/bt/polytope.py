"""States inside polytopes: the regions of relational trees and BTs.

A region is a conjunction of *tests* ``(what, threshold, le)``: ``what`` is a feature index
(``x[f] <= t`` / ``x[f] > t`` on the widened float32 value) or a
:class:`~ibt.bt.linear.LinearForm` (its double value by the floating-point rule of
:mod:`ibt.bt.linear`). Its states form a polytope in observed space, so one state inside is a
linear program: the point deepest inside (a Chebyshev centre in box-scaled coordinates, found
with scipy's ``linprog``), rounded to float32 and kept only if it passes every test exactly as
the executors compute them. Used by the verifier (:mod:`ibt.synth.relational`), the coverage
proof (:mod:`ibt.bt.coverage`) and the engine's agreement states.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ibt.bt.linear import Form, LinearForm

Test = tuple[int | Form, float, bool]  # (feature or form, threshold, True for "<=")
MAX_STEPS = 256  # float32 steps a crossing search walks from its first guess


def _coefficients(what: int | Form, n_features: int) -> np.ndarray:
    a = np.zeros(n_features)
    if not isinstance(what, int | np.integer):
        for feature, weight in what.terms:
            a[feature] += weight
    else:
        a[what] = 1.0
    return a


def satisfies(row: np.ndarray, tests: Sequence[Test]) -> bool:
    """Does the state (float32 values) pass every test, computed as the executors do?"""
    x = np.asarray(row, dtype=np.float32).astype(np.float64)
    if not np.isfinite(x).all():
        return False
    for what, threshold, le in tests:
        value = x[what] if isinstance(what, int | np.integer) else what.value(x)
        if bool(value <= threshold) != le:
            return False
    return True


def find_state(n_features: int, tests: Sequence[Test], low: Sequence[float] | None = None,
               high: Sequence[float] | None = None) -> np.ndarray | None:
    """A float32 state passing every test, as deep inside the region as a linear program finds
    (inside the box ``low``/``high`` when one is given, else a box around the thresholds);
    ``None`` when the region is empty, lower-dimensional or too thin for a float32 point."""
    lo, hi = _box(n_features, tests, low, high)
    for grow in (1.0, 1e3):  # the box first; a region outside it holds real states too
        state = _deepest(n_features, tests, *_grown(lo, hi, grow))
        if state is not None:
            return state
        if low is None:
            break
    return None


def _box(n_features: int, tests: Sequence[Test], low: Sequence[float] | None,
         high: Sequence[float] | None) -> tuple[np.ndarray, np.ndarray]:
    if low is not None and high is not None:
        lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        if np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all():
            return lo, hi
    scale = max([1.0, *(2.0 * abs(t) + 1.0 for _, t, _ in tests if math.isfinite(t))])
    return np.full(n_features, -scale), np.full(n_features, scale)


def _grown(lo: np.ndarray, hi: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * factor
    return centre - half, centre + half


def _deepest(n_features: int, tests: Sequence[Test], lo: np.ndarray, hi: np.ndarray
             ) -> np.ndarray | None:
    from scipy.optimize import linprog

    centre, half = (lo + hi) / 2, (hi - lo) / 2  # x = centre + half * u, u in [-1, 1]
    rows, bounds = [], []
    for what, threshold, le in tests:
        if not math.isfinite(threshold):
            continue
        a = _coefficients(what, n_features) * half
        b = threshold - float(_coefficients(what, n_features) @ centre)
        if not le:
            a, b = -a, -b
        norm = float(np.linalg.norm(a))
        if norm == 0.0:
            continue
        rows.append([*(a / norm), 1.0])  # a.u + s |a| <= b, normalised
        bounds.append(b / norm)
    for f in range(n_features):  # stay strictly inside the box: |u_f| + s <= 1
        for sign in (1.0, -1.0):
            row = [0.0] * (n_features + 1)
            row[f], row[-1] = sign, 1.0
            rows.append(row)
            bounds.append(1.0)
    cost = [0.0] * n_features + [-1.0]  # maximise the margin s
    result = linprog(cost, A_ub=np.asarray(rows), b_ub=np.asarray(bounds),
                     bounds=[(-1.0, 1.0)] * n_features + [(None, 1.0)], method="highs")
    if result.status != 0 or result.x[-1] <= 0:
        return None
    state = (centre + half * result.x[:-1]).astype(np.float32)
    return state if satisfies(state, tests) else None


def region_state(n_features: int, region: dict[int, tuple[float, float]],
                 forms: Sequence[Form]) -> np.ndarray:
    """A state in a box over observed features and derived values (the coverage proof's
    regions: key ``n_features + k`` is ``forms[k]``; ``lo < value <= hi``), or, when the linear
    program finds none, the middle of its observed bounds (a best guess for the message)."""
    tests: list[Test] = []
    for key, (lo, hi) in region.items():
        what: int | Form = key if key < n_features else forms[key - n_features]
        if math.isfinite(lo):
            tests.append((what, lo, False))
        if math.isfinite(hi):
            tests.append((what, hi, True))
    state = find_state(n_features, tests)
    if state is not None:
        return state
    guess = np.zeros(n_features, dtype=np.float32)
    for key, (lo, hi) in region.items():
        if key < n_features:
            guess[key] = hi if math.isfinite(hi) else (lo + 1.0 if math.isfinite(lo) else 0.0)
    return guess


def crossing_rows(what: int | Form, threshold: float, row: np.ndarray) -> list[np.ndarray]:
    """States on both sides of one test, next to ``row``: the last float32 state passing
    ``<= threshold`` and the first past it, moving one feature (for a form, each of its two
    features in turn). Empty where no finite crossing is found near the first guess."""
    base = np.asarray(row, dtype=np.float32)
    if isinstance(what, int | np.integer):
        at = np.float32(threshold)
        if float(at) > threshold:
            at = np.nextafter(at, np.float32(-np.inf))
        out = []
        for value in (at, np.nextafter(at, np.float32(np.inf))):
            edge = base.copy()
            edge[what] = value
            out.append(edge)
        return out
    out = []
    for moved, weight in what.terms:  # each feature of the form in turn, the others fixed
        others = sum(w * float(base[f]) for f, w in what.terms if f != moved)
        with np.errstate(over="ignore", invalid="ignore"):
            guess = np.float32((threshold - others) / weight)
        if not np.isfinite(guess):
            continue
        pair = _crossing(what, threshold, base, moved, guess, weight > 0)
        out.extend(pair)
    return out


def _crossing(form: Form, threshold: float, base: np.ndarray, moved: int,
              guess: np.float32, rising: bool) -> list[np.ndarray]:
    """Walk ``x[moved]`` from ``guess`` over float32 values to where ``form <= threshold``
    flips (the form is monotone in one feature, rounding included)."""
    def value(v: np.float32) -> float:
        edge = base.copy()
        edge[moved] = v
        return float(form.value(edge.astype(np.float64)))

    up, down = np.float32(np.inf), np.float32(-np.inf)
    # "inside" side: the direction in which the form decreases
    towards_in, towards_out = (down, up) if rising else (up, down)
    v = guess
    for _ in range(MAX_STEPS):  # step into the "<=" side
        if not np.isfinite(v):
            return []
        if value(v) <= threshold:
            break
        v = np.nextafter(v, towards_in)
    else:
        return []
    for _ in range(MAX_STEPS):  # then to the last value on it
        nxt = np.nextafter(v, towards_out)
        if not np.isfinite(nxt):
            return []
        if value(nxt) > threshold:
            inside, outside = base.copy(), base.copy()
            inside[moved], outside[moved] = v, nxt
            return [inside, outside]
        v = nxt
    return []


# ------------------------------------------------------------------ a BT's own regions
def condition_test(node: Any, le: bool = True) -> Test:
    """A BT condition as a test (``le=False``: where it fails)."""
    what: int | LinearForm = node.feature if node.form is None else node.form
    return (what, node.threshold, (node.op == "<=") == le)


class _Split(Exception):
    def __init__(self, node: Any) -> None:
        self.node = node


def _status(node: Any, tests: tuple[Test, ...], n_features: int,
            memo: dict[tuple[Test, ...], bool]) -> tuple[bool, int]:
    """Success and decision of ``node`` on the region, or :class:`_Split` at the first
    condition the region does not decide (decided: the other side holds no float32 state)."""
    from ibt.bt.model import NO_DECISION, Action, Condition, Inverter
    from ibt.bt.model import Sequence as SequenceNode

    if isinstance(node, Condition):
        sides = []
        for le in (True, False):
            key = (*tests, condition_test(node, le))
            if key not in memo:
                memo[key] = find_state(n_features, key) is not None
            sides.append(memo[key])
        if sides[0] and sides[1]:
            raise _Split(node)
        return sides[0], NO_DECISION  # holds on the region (an empty region: fails)
    if isinstance(node, Action):
        return True, node.action
    if isinstance(node, Inverter):
        ok, decision = _status(node.child, tests, n_features, memo)
        return not ok, decision
    want = isinstance(node, SequenceNode)
    decision = NO_DECISION
    for child in node.children:
        ok, chosen = _status(child, tests, n_features, memo)
        if decision == NO_DECISION:
            decision = chosen
        if ok != want:
            return not want, decision
    return want, decision


def bt_regions(bt: Any, max_regions: int = 10_000) -> list[tuple[tuple[Test, ...], int]]:
    """The polytopes on which a BT (relational conditions allowed) decides one action, each as
    its tests and the action: the region is split at the first condition it does not decide
    (both sides hold a float32 state a linear program finds), like the leaves of a tree."""
    n = bt.n_features
    memo: dict[tuple[Test, ...], bool] = {}
    stack: list[tuple[Test, ...]] = [()]
    regions: list[tuple[tuple[Test, ...], int]] = []
    while stack and len(regions) < max_regions:
        tests = stack.pop()
        try:
            _, action = _status(bt.root, tests, n, memo)
        except _Split as split:
            stack.append((*tests, condition_test(split.node, False)))
            stack.append((*tests, condition_test(split.node, True)))
            continue
        regions.append((tests, action))
    return regions


def agreement_rows(bt: Any, low: Sequence[float], high: Sequence[float], random: np.ndarray,
                   seed: int = 0) -> np.ndarray:
    """States to check an executor against a relational BT on: one inside every region of
    :func:`bt_regions` (inside the box where it can), both sides of each of its tests next to
    it, both sides of every condition next to a random state, and the random states."""
    from ibt.bt.model import Condition

    rng = np.random.default_rng(seed)
    rows: list[np.ndarray] = []
    for tests, _ in bt_regions(bt):
        state = find_state(bt.n_features, tests, low, high)
        if state is None:
            continue
        rows.append(state)
        for what, threshold, _le in tests:
            rows.extend(crossing_rows(what, threshold, state))
    for node in bt.nodes():
        if isinstance(node, Condition) and len(random):
            what, threshold, _ = condition_test(node)
            rows.extend(crossing_rows(what, threshold, random[rng.integers(len(random))]))
    return np.concatenate([np.asarray(rows, dtype=np.float32).reshape(-1, bt.n_features),
                           np.asarray(random, dtype=np.float32)])
