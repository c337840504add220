"""Two-level logic minimisation of ATL rule sets with Espresso (pyeda).

Every distinct threshold test ``x[f] <= t`` of a tree becomes one boolean variable; a term is a
cube over those variables. Espresso minimises each action's cover on its own. Two optional
refinements, both exact on every real state:

* **float merging** (RE:BT-Espresso's containment reduction, as the paper uses it): inside a term
  ``x <= a and x <= b`` becomes ``x <= min(a, b)`` (see :func:`ibt.synth.rules.merge_thresholds`);
* **implication don't-cares** (beyond the paper): for thresholds ``t1 < t2`` on one feature,
  ``x <= t1`` true with ``x <= t2`` false cannot happen; telling Espresso so lets it merge cubes
  across implied literals.
* **extra don't-care terms** (beyond the paper, for :mod:`ibt.synth.decision_list`): states an
  earlier rule of a decision list already decided, or states outside a subtree's region.

This is the only module that imports pyeda. Espresso on covers read off decision trees runs in
milliseconds; large covers run in a child process with a time limit and fall back to the
unminimised cover with a warning.
"""

from __future__ import annotations

import multiprocessing as mp
import warnings
from collections.abc import Iterable

from ibt.synth.rules import Literal, Term, merge_thresholds

# Espresso cube encoding of pyeda: input 1 = variable false, 2 = true, 3 = absent;
# output 1 = ON, 2 = don't-care.
_FALSE, _TRUE, _ABSENT = 1, 2, 3
_ON, _DC = 1, 2
IN_PROCESS_LIMIT = 4_000  # cubes x variables below which Espresso runs in this process


class Variables:
    """The boolean variables of a rule set: one per distinct ``(feature, threshold)`` test."""

    def __init__(self, terms: Iterable[Term]) -> None:
        keys = sorted({(lit.feature, lit.threshold) for term in terms for lit in term})
        self.keys: list[tuple[int, float]] = keys
        self.index = {key: i for i, key in enumerate(keys)}

    def __len__(self) -> int:
        return len(self.keys)

    def cube(self, term: Term) -> tuple[int, ...]:
        values = [_ABSENT] * len(self.keys)
        for lit in term:
            i = self.index[(lit.feature, lit.threshold)]
            value = _TRUE if lit.le else _FALSE
            if values[i] not in (_ABSENT, value):
                raise ValueError(f"contradictory term {term}")
            values[i] = value
        return tuple(values)

    def term(self, cube: tuple[int, ...]) -> Term:
        lits = [Literal(f, t, le=(v == _TRUE))
                for (f, t), v in zip(self.keys, cube, strict=True) if v != _ABSENT]
        return tuple(lits)

    def implication_dont_cares(self) -> list[tuple[int, ...]]:
        """Cubes that no real state satisfies: ``x <= t1`` and not ``x <= t2`` with t1 < t2."""
        cubes = []
        by_feature: dict[int, list[int]] = {}
        for i, (feature, _) in enumerate(self.keys):
            by_feature.setdefault(feature, []).append(i)
        for indices in by_feature.values():  # keys are sorted by threshold within a feature
            for a, i in enumerate(indices):
                for j in indices[a + 1:]:
                    values = [_ABSENT] * len(self.keys)
                    values[i], values[j] = _TRUE, _FALSE
                    cubes.append(tuple(values))
        return cubes


def _run_espresso(ninputs: int, on: list[tuple[int, ...]], dc: list[tuple[int, ...]]
                  ) -> list[tuple[int, ...]]:
    from pyeda.boolalg import espresso as esp
    from pyeda.boolalg.minimization import CONFIG

    esp.set_config(**CONFIG)
    cover = {(c, (_ON,)) for c in on} | {(c, (_DC,)) for c in dc}
    intype = esp.FTYPE | esp.DTYPE if dc else esp.FTYPE
    result = esp.espresso(ninputs, 1, cover, intype=intype)
    return sorted(inputs for inputs, _ in result)


def _espresso_child(conn, ninputs, on, dc) -> None:
    conn.send(_run_espresso(ninputs, on, dc))
    conn.close()


def espresso_cubes(ninputs: int, on: list[tuple[int, ...]], dc: list[tuple[int, ...]],
                   timeout: float = 30.0, in_process_limit: int = IN_PROCESS_LIMIT
                   ) -> list[tuple[int, ...]] | None:
    """Minimise an ON cover with optional don't-cares; ``None`` if Espresso ran out of time.

    Covers of up to ``in_process_limit`` cubes x variables run in this process (no time
    limit: forking costs more than they take); larger ones in a child with ``timeout``.
    """
    if not on:
        return []
    if ninputs == 0:
        return [()]
    if (len(on) + len(dc)) * ninputs <= in_process_limit:
        return _run_espresso(ninputs, on, dc)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_espresso_child, args=(child, ninputs, on, dc), daemon=True)
    proc.start()
    child.close()
    if parent.poll(timeout):
        cubes = parent.recv()
        proc.join()
        return cubes
    proc.kill()
    proc.join()
    return None


def minimise(terms: list[Term], variables: Variables, *, dont_cares: bool = False,
             merge: bool = True, timeout: float = 30.0,
             extra_dont_cares: Iterable[Term] = (),
             in_process_limit: int = IN_PROCESS_LIMIT) -> list[Term]:
    """Espresso-minimised DNF equivalent to ``terms`` on every real state.

    ``variables`` must cover every literal of ``terms`` and of ``extra_dont_cares`` (build it
    from the whole ATL so all actions share one variable order). ``extra_dont_cares`` are
    terms whose states the caller never asks about (in a decision list: the states an earlier
    rule already caught, or states outside the region being synthesised); the result may
    cover them or not. The result is then equivalent to ``terms`` only outside them. Terms come
    back with merged thresholds (when ``merge``) and sorted by literal count, then
    lexicographically, so the result is deterministic.
    """
    if not terms:
        return []
    on = [variables.cube(t) for t in terms]
    dc = variables.implication_dont_cares() if dont_cares else []
    dc += [variables.cube(t) for t in extra_dont_cares]
    cubes = espresso_cubes(len(variables), on, dc, timeout=timeout,
                           in_process_limit=in_process_limit)
    if cubes is None:
        warnings.warn(f"Espresso exceeded {timeout:.0f} s on {len(on)} cubes over "
                      f"{len(variables)} variables; keeping the unminimised cover", stacklevel=2)
        cubes = on
    out = [variables.term(c) for c in cubes]
    if merge:
        out = [merge_thresholds(t) for t in out]
    out = list(dict.fromkeys(out))  # drop duplicates, keep order
    return sorted(out, key=lambda t: (len(t), t))
