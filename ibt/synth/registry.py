"""The registry of BT synthesisers: one line per method; the CLI, the grid and the front read it.

A synthesiser turns a fitted decision tree and its :class:`~ibt.tasks.task.Task` into a
:class:`~ibt.synth.imitation.Synthesis` whose BT decides exactly as the tree (every caller
verifies it). Its function is named as ``"module:attribute"`` and imported on first use, so
the registry is cheap to import and a worker process resolves the same entry by name.

Adding a synthesiser is one module plus one :func:`register_synthesiser` call (or one line in
:data:`SYNTHESISERS` for the built-in ones): ``python -m ibt synthesize --method NAME``, the
paper grid (:func:`ibt.runs.grid.synthesize_grid`) and the size-retention front
(``on_front=True``) then offer it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Synthesiser:
    """One BT synthesis method and how the pipeline uses it."""

    name: str
    function: str  # "module:attribute", called as function(tree, task, **options)
    # whose trees the grid gives it: a distillation method, or "baseline" (the grid's offline
    # demonstrations, BC by default, as in the baselines' papers)
    source: str = "imitation-bt"
    on_front: bool = False  # one of the BTs each front point is made of
    version: str | None = None  # "module:attribute" of a version number keyed into its cache
    description: str = ""

    def resolve(self, spec: str) -> Any:
        module, _, attribute = spec.partition(":")
        return getattr(importlib.import_module(module), attribute)

    def __call__(self, tree: Any, task: Any, **options: Any) -> Any:
        """The synthesis of ``tree``; a relational tree is synthesised on its
        augmented space and verified in observed space (:func:`ibt.synth.relational.synthesise`),
        so a user's synthesiser takes relational trees too."""
        function = self.resolve(self.function)
        if getattr(tree, "feature_map_", None) is not None:
            from ibt.synth import relational

            return relational.synthesise(function, tree, task, **options)
        return function(tree, task, **options)

    def version_number(self) -> Any:
        return None if self.version is None else self.resolve(self.version)


SYNTHESISERS: dict[str, Synthesiser] = {}


def register_synthesiser(synthesiser: Synthesiser) -> Synthesiser:
    """Add (or replace) a synthesiser; returns it."""
    SYNTHESISERS[synthesiser.name] = synthesiser
    return synthesiser


def get_synthesiser(name: str) -> Synthesiser:
    """The registered synthesiser ``name``; ``ValueError`` lists the known ones."""
    try:
        return SYNTHESISERS[name]
    except KeyError:
        raise ValueError(f"unknown BT method {name!r}; choose from "
                         f"{', '.join(SYNTHESISERS)}") from None


def front_synthesisers() -> tuple[str, ...]:
    """The synthesisers every point of the front is made of (in registry order)."""
    return tuple(name for name, s in SYNTHESISERS.items() if s.on_front)


for _entry in (
    Synthesiser("imitation-bt", "ibt.synth.imitation:imitation_bt", on_front=True,
                description="the paper's construction: one guarded Sequence per action"),
    Synthesiser("bt-espresso", "ibt.synth.baselines:bt_espresso", source="baseline",
                description="BT-Espresso (baseline)"),
    Synthesiser("re-bt-espresso", "ibt.synth.baselines:re_bt_espresso", source="baseline",
                description="RE:BT-Espresso (baseline)"),
    Synthesiser("decision-list", "ibt.synth.decision_list:decision_list_bt", on_front=True,
                version="ibt.synth.decision_list:VERSION",
                description="beyond the paper: the Selector as a decision list"),
):
    register_synthesiser(_entry)
