"""A guard on the cache's code versions: a cached computation's source cannot change unseen.

Every cache key carries its kind's code version (:data:`ibt.cache.store.CODE_VERSIONS`), so a
changed computation misses instead of returning a stale result, but only if a person remembers to
bump the number. This module takes that memory off the person: :data:`KIND_SOURCES` names, per
kind, the modules whose code decides its results; ``data/cache/code_hashes.json`` records, per
kind, the code version and a SHA-256 of those modules' source at the time it was set; and
``tests/test_code_guard.py`` fails unless the record is current: a kind whose source changed
must have its version bumped or the change recorded, and either is then written down.

When the test fails, decide: if the change can change a result, bump the kind's number in
``CODE_VERSIONS`` (its entries then recompute); if it cannot (a docstring, a rename, a refactor
that keeps every number), say so by rewriting the record::

    python -m ibt.cache.guard --write

Either way the decision is explicit and reviewed in the diff of ``code_hashes.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from ibt.cache.store import CODE_VERSIONS
from ibt.files import atomic_write_text
from ibt.paths import DATA_DIR

PACKAGE = Path(__file__).resolve().parent.parent
RECORD = DATA_DIR / "cache" / "code_hashes.json"

_ROLLOUT = ("evaluate/rollouts.py", "evaluate/policies.py", "tasks/task.py", "tasks/builtin.py",
            "tasks/settings.py", "envs/package_delivery.py", "envs/__init__.py")
_TREES = ("refine/tree_arrays.py", "distill/loop.py")
#: the engine's modules every stage shares: identities, the agent, the budgets
_ENGINE = ("engine/keys.py", "engine/agent.py", "engine/budgets.py")
_DISTIL = ("engine/distil.py", "engine/learners.py", *_ENGINE)
_REFINE = ("engine/refine.py", "engine/learners.py", *_ENGINE)
_SEARCH = ("engine/search.py", "engine/refine.py", "engine/measure.py", *_ENGINE)
_MEASURE = ("engine/measure.py", "engine/synthesis.py", *_ENGINE)
_AGENTS = ("experts/expert.py", "experts/checkpoint.py", "experts/callable_agent.py")
_SYNTH = ("synth/rules.py", "synth/logic.py", "synth/imitation.py", "synth/decision_list.py",
          "synth/decision_list_search.py", "synth/decision_list_exact.py",
          "synth/decision_list_factoring.py", "synth/baselines.py", "synth/registry.py",
          "bt/model.py", "bt/document.py", "bt/executors.py", "bt/coverage.py")

#: the modules of the built-in learners cached under the shared kinds (a pattern: a new one is
#: guarded from its first line, see :mod:`ibt.engine.learners`)
LEARNER_MODULES = "engine/learner_*.py"

#: The modules (relative to the package) whose code decides each cache kind's results; a name
#: with ``*`` stands for the modules it matches, in sorted order.
KIND_SOURCES: dict[str, tuple[str, ...]] = {
    "distill": ("distill/loop.py", "distill/schedules.py", *_AGENTS, "runs/steps.py",
                *_DISTIL, *_ROLLOUT),
    "expert-eval": (*_AGENTS, *_MEASURE, *_ROLLOUT),
    "tree-eval": (*_MEASURE, *_TREES, *_ROLLOUT),
    "bt-eval": (*_MEASURE, "bt/model.py", "bt/document.py", "bt/executors.py", *_ROLLOUT),
    "synthesis": ("runs/grid.py", "engine/synthesis.py", *_ENGINE, *_TREES, *_SYNTH),
    "refine": ("refine/by_return.py", "runs/front.py", *_REFINE, *_TREES, *_ROLLOUT),
    "front-bt": ("runs/front.py", *_TREES, *_SYNTH),
    "executors": ("runs/grid.py", "evaluate/speed.py", *_TREES, *_SYNTH),
    "evolve": ("refine/structure.py", "refine/structure_mutations.py", "refine/forest.py",
               "runs/search.py", *_AGENTS, *_SEARCH, *_TREES, *_ROLLOUT),
    "protocol": (*_MEASURE, "bt/model.py", "bt/document.py", "bt/executors.py",
                 *_ROLLOUT),
    "speed": ("runs/grid.py", "evaluate/speed.py", *_TREES, *_SYNTH),
    "box-distill": ("distill/continuous.py", "runs/continuous.py", *_AGENTS, *_DISTIL,
                    *_ROLLOUT),
    "box-commands": ("synth/commands.py", "distill/continuous.py", "runs/continuous.py",
                     *_AGENTS, "experts/training.py", "engine/commands.py", *_MEASURE,
                     *_ROLLOUT),
    "box-refine": ("refine/commands.py", "refine/by_return.py", "runs/continuous.py",
                   "runs/front.py", *_REFINE, *_TREES, *_ROLLOUT),
    "box-eval": (*_MEASURE, "synth/commands.py", "refine/commands.py", *_TREES, *_SYNTH,
                 *_ROLLOUT),
    "distill-rel": ("distill/relational.py", "bt/linear.py", "distill/loop.py",
                    "distill/schedules.py", *_AGENTS, "runs/relational.py",
                    "runs/steps.py", *_DISTIL, *_ROLLOUT),
    "refine-rel": ("refine/relational.py", "refine/by_return.py", "distill/relational.py",
                   "bt/linear.py", "runs/relational.py", "runs/front.py",
                   "runs/relational_search.py", "refine/relational_structure.py",
                   "refine/structure.py", "refine/structure_mutations.py", "refine/forest.py",
                   *_REFINE, *_TREES, *_ROLLOUT),
    "evolve-rel": ("refine/relational_structure.py", "refine/relational.py",
                   "refine/structure.py", "refine/structure_mutations.py", "refine/forest.py",
                   "distill/relational.py", "bt/linear.py", "runs/relational_search.py",
                   "runs/search.py", *_AGENTS, *_SEARCH, *_TREES, *_ROLLOUT),
    "returns": (*_MEASURE, *_AGENTS, "experts/training.py", *_TREES, *_SYNTH,
                "synth/commands.py", *_ROLLOUT),
    "evolve-select": ("refine/relational_structure.py", "refine/relational.py",
                      "refine/structure.py", "refine/structure_mutations.py",
                      "refine/forest.py", "distill/relational.py", "bt/linear.py",
                      "runs/relational_search.py", *_TREES, *_ROLLOUT),
    "controller-distil": ("engine/controller_learners.py", "distill/controller.py",
                          "distill/oblique.py", "distill/loop.py", "distill/schedules.py",
                          "runs/controllers.py", "bt/linear.py", *_AGENTS, *_ROLLOUT),
    "controller-refine": ("engine/controller_learners.py", "refine/controller.py",
                          "refine/by_return.py", "distill/controller.py", "distill/oblique.py",
                          "runs/controllers.py", *_ROLLOUT),
    "learner-distil": (LEARNER_MODULES, *_AGENTS, *_DISTIL, *_ROLLOUT),
    "learner-refine": (LEARNER_MODULES, "engine/learners.py", *_ENGINE, *_ROLLOUT),
}


def source_digest(kind: str) -> str:
    """SHA-256 of the sources of a kind's modules (in their listed order, names included)."""
    return _digest(KIND_SOURCES[kind])


def _digest(sources: Sequence[str]) -> str:
    h = hashlib.sha256()
    for name in _expanded(sources):
        h.update(name.encode() + b"\0" + (PACKAGE / name).read_bytes() + b"\0")
    return h.hexdigest()


def _expanded(sources: Sequence[str]) -> list[str]:
    """The module names, each pattern replaced by the modules it matches (sorted)."""
    out: list[str] = []
    for name in sources:
        out += (sorted(p.relative_to(PACKAGE).as_posix() for p in PACKAGE.glob(name))
                if "*" in name else [name])
    return out


def current() -> dict[str, dict[str, object]]:
    """Per kind: its code version now and the digest of its sources now."""
    return {kind: {"version": CODE_VERSIONS[kind], "sources": source_digest(kind)}
            for kind in sorted(CODE_VERSIONS)}


def differences(record: dict[str, dict[str, object]]) -> list[str]:
    """What differs between the record and the code now, one line per kind, each naming the
    decision to take (empty: the record is current)."""
    lines = []
    for kind, facts in current().items():
        old = record.get(kind)
        if old is None:
            lines.append(f"{kind}: not recorded; record it with --write")
        elif facts["version"] != old["version"]:
            lines.append(f"{kind}: version {old['version']} -> {facts['version']}; record the "
                         "bump with --write")
        elif facts["sources"] != old["sources"]:
            lines.append(f"{kind}: its sources changed but CODE_VERSIONS[{kind!r}] did not; "
                         "bump it if the change can change a result, else record it with "
                         "--write")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ibt.cache.guard",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true",
                        help=f"record the current versions and sources in {RECORD}")
    args = parser.parse_args(argv)
    if args.write:
        atomic_write_text(RECORD, json.dumps(current(), indent=1, sort_keys=True) + "\n")
        print(f"recorded {len(CODE_VERSIONS)} kinds in {RECORD}")
        return 0
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    lines = differences(record)
    print("\n".join(lines) if lines else f"{RECORD.name} is current")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
