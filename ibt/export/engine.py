"""Run exported BTs in BehaviorTree.CPP itself (through behaviortreepy) and compare with ``ibt``.

:class:`EngineTree` loads the portable XML of :mod:`ibt.export.btcpp` in the stock engine with only
the task's actions registered, fills the blackboard from a feature vector (``double(float(x))``
per key) and ticks once; the decision is the first action the engine ticked. On top of it:

* the states a BT is checked on are :func:`ibt.export.agreement.agreement_states`;
* :func:`engine_rollout`: episodes whose every decision is a BehaviorTree.CPP tick, and
  :func:`compare_rollouts`, the same seeds with the Python BT beside it;
* :func:`ticks_per_second`: the engine against ``ibt``'s executor, one state per tick.
"""

from __future__ import annotations

import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import behaviortreepy as btpy
import numpy as np

from ibt.bt.executors import as_features, decide_batch
from ibt.bt.model import NO_DECISION, BehaviorTree, Commands
from ibt.evaluate.policies import BTPolicy
from ibt.evaluate.rollouts import Rollout, rollout
from ibt.export.btcpp import (
    CONDITION_ID,
    action_ids,
    blackboard_keys,
    command_keys,
    from_btcpp_xml,
)
from ibt.tasks.catalogue import Task

GROOT_START_SECONDS = 0.2  # a Groot2Publisher destroyed right after it starts can hang


class EngineTree:
    """An XML tree loaded in BehaviorTree.CPP with only the actions of ``action_names``.

    Raises ``ValueError`` naming the problem when the XML is not one this task can run (a
    blackboard key or action ID of another task, the ``CheckFeature`` flavour, XML the engine
    rejects). ``bt`` is the same tree read by :func:`ibt.export.btcpp.from_btcpp_xml`.
    """

    def __init__(self, xml: str, feature_names: Sequence[str], action_names: Sequence[str],
                 source: str = "the XML", commands: Commands | None = None) -> None:
        try:
            self.bt = from_btcpp_xml(xml, feature_names, action_names, commands=commands)
        except ValueError as err:
            raise ValueError(f"{source}: {err}") from None
        if uses_check_feature(xml):
            raise ValueError(f"{source} uses the custom {CONDITION_ID} condition, which needs "
                             "its C++ node; export the portable flavour (the default of "
                             "`python -m ibt export BT.json --format btcpp-xml`)")
        self.keys = blackboard_keys(feature_names)
        self.action_ids = action_ids(action_names)
        self._fired = [NO_DECISION]
        self.actions_ticked = 0  # every action tick, the first of each tick and any later ones
        # commands (continuous actions): the engine's own Script nodes write them to the
        # blackboard, nothing is registered
        self.command_keys = command_keys(self.bt) if commands is not None else None
        factory = btpy.BehaviorTreeFactory()
        for index, ident in enumerate(self.action_ids if commands is None else ()):
            factory.register_simple_action(ident, self._action(index))
        try:
            self.tree = factory.create_tree_from_text(xml)
        except RuntimeError as err:
            raise ValueError(f"BehaviorTree.CPP cannot load {source}: "
                             f"{' '.join(str(err).split())}") from None
        self.blackboard = self.tree.root_blackboard()

    def _action(self, index: int) -> Callable[[Any], Any]:
        fired = self._fired

        def tick(_node: Any) -> Any:
            if fired[0] == NO_DECISION:
                fired[0] = index
            self.actions_ticked += 1
            return btpy.NodeStatus.SUCCESS

        return tick

    def tick(self, features: Sequence[float] | np.ndarray) -> int:
        """Fill the blackboard from one feature vector, tick once, return the action fired."""
        values = as_features(np.asarray(features).reshape(-1)).tolist()
        for key, value in zip(self.keys, values, strict=True):
            self.blackboard.set_double(key, value)
        self._fired[0] = NO_DECISION
        if self.command_keys is not None:
            self.blackboard.set_double(self.command_keys[0], NO_DECISION)
        self.tree.tick_once()
        if self.command_keys is not None:
            return int(self.blackboard.get_double(self.command_keys[0]))
        return self._fired[0]

    def command(self) -> np.ndarray:
        """The command values the last tick wrote to the blackboard (a BT with commands)."""
        assert self.command_keys is not None
        return np.array([self.blackboard.get_double(k) for k in self.command_keys[1:]],
                        dtype=np.float32)

    def act(self, features: np.ndarray) -> np.ndarray:
        """One tick per row; the command vectors the engine wrote ``(n, dims)``."""
        rows = np.atleast_2d(features)
        out = []
        for row in rows:
            if self.tick(row) == NO_DECISION:
                raise ValueError("no command was written on a tick")
            out.append(self.command())
        return np.asarray(out, dtype=np.float32)

    def decide(self, features: np.ndarray) -> np.ndarray:
        """One engine tick per row of ``features``; ``NO_DECISION`` where no action ran."""
        rows = np.atleast_2d(features)
        return np.fromiter((self.tick(row) for row in rows), dtype=np.int64, count=len(rows))

    def groot_publisher(self, port: int) -> Any:
        """Publish this tree to Groot2 on ``port`` while the returned object lives."""
        try:
            publisher = btpy.Groot2Publisher(self.tree, port)
        except RuntimeError as err:
            raise ValueError(f"cannot publish to Groot2 on port {port}: {err}") from None
        time.sleep(GROOT_START_SECONDS)
        return publisher


def uses_check_feature(xml: str) -> bool:
    """Whether a tree of the XML uses the ``CheckFeature`` flavour's custom condition."""
    return any(e.tag == CONDITION_ID or (e.tag == "Condition" and e.get("ID") == CONDITION_ID)
               for tree in ET.fromstring(xml).iter("BehaviorTree") for e in tree.iter())


def load_engine_tree(xml: str, task: Task, source: str = "the XML",
                     commands: Commands | None = None) -> EngineTree:
    """:class:`EngineTree` for ``task``'s features and actions (``commands``: a Box task's BT,
    whose action names are its commands' names: pass its ``action_names`` as a task view)."""
    return EngineTree(xml, task.feature_names, task.action_names, source, commands)


class EnginePolicy:
    """A policy on raw observations of ``task`` whose every decision is an engine tick."""

    def __init__(self, task: Task, engine: EngineTree) -> None:
        self.task = task
        self.engine = engine

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self.engine.command_keys is not None:  # a Box task: the command vectors
            return self.engine.act(self.task.features(obs))
        return self.engine.decide(self.task.features(obs))


# ------------------------------------------------------------------------------ rollouts
def engine_rollout(task: Task, engine: EngineTree, seeds: Sequence[int], **kwargs: Any) -> Rollout:
    """:func:`ibt.evaluate.rollouts.rollout` with every decision an engine tick."""
    return rollout(task, EnginePolicy(task, engine).act, seeds, **kwargs)


@dataclass(frozen=True)
class RolloutComparison:
    """The same seeds played by the engine and by the Python BT."""

    engine: Rollout
    python: Rollout
    ticks: int  # engine ticks, one per step
    disagreements: int  # steps where the Python BT would have chosen another action
    states: np.ndarray  # every feature vector the engine ticked on

    @property
    def same_returns(self) -> bool:
        return bool(np.array_equal(self.engine.returns, self.python.returns))


def compare_rollouts(task: Task, engine: EngineTree, seeds: Sequence[int],
                     on_step: Callable[[np.ndarray, np.ndarray], None] | None = None,
                     ) -> RolloutComparison:
    """Play ``seeds`` in the engine, then with ``engine.bt`` in Python; compare every step."""
    seen: list[np.ndarray] = []
    chosen: list[np.ndarray] = []

    def record(obs: np.ndarray, actions: np.ndarray) -> None:
        seen.append(task.features(obs))
        chosen.append(np.asarray(actions))
        if on_step is not None:
            on_step(obs, actions)

    played = engine_rollout(task, engine, seeds, on_step=record)
    states = np.concatenate(seen) if seen else np.empty((0, task.n_features), np.float32)
    actions = np.concatenate(chosen) if chosen else np.empty(0, np.int64)
    if engine.bt.commands is not None:  # a Box task: the command vectors, row by row
        from ibt.synth.commands import CommandBTPolicy, bt_actions

        ours = bt_actions(engine.bt, states).reshape(actions.shape)
        disagreements = int(np.sum(np.any(ours != actions, axis=-1))) if len(states) else 0
        python = rollout(task, CommandBTPolicy(task, engine.bt).act, seeds)
        return RolloutComparison(played, python, len(states), disagreements, states)
    disagreements = int(np.sum(engine.bt.decide(states) != actions))
    python = rollout(task, BTPolicy(task, engine.bt).act, seeds)
    return RolloutComparison(played, python, len(states), disagreements, states)


def _rate(fn: Callable[[np.ndarray], Any], states: np.ndarray, min_seconds: float) -> float:
    done, start = 0, time.perf_counter()
    while True:
        for row in states:
            fn(row)
        done += len(states)
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return done / elapsed


def ticks_per_second(engine: EngineTree, states: np.ndarray,
                     min_seconds: float = 0.25) -> dict[str, float]:
    """Ticks per second, one state per tick, of the engine (blackboard filled each tick) and of
    ``ibt``'s executor (:func:`ibt.bt.executors.decide_batch`, what
    :class:`ibt.evaluate.policies.BTPolicy` runs)."""
    states = np.asarray(states[:2000], dtype=np.float32)
    root = engine.bt.root
    return {"BehaviorTree.CPP": _rate(engine.tick, states, min_seconds),
            "ibt Python executor": _rate(lambda row: decide_batch(root, row[None]), states,
                                         min_seconds)}


# ------------------------------------------------------------------------------ the CLI
@dataclass(frozen=True)
class EngineRun:
    """What ``python -m ibt run-btcpp`` measured."""

    task: Task
    comparison: RolloutComparison
    rates: dict[str, float]
    bt: BehaviorTree | None = None  # the XML read back by ibt (what the Python side ran)

    @property
    def ok(self) -> bool:
        return self.comparison.same_returns and self.comparison.disagreements == 0

    def summary(self) -> str:
        c = self.comparison
        same = ("equal on every episode" if c.same_returns else
                f"DIFFERENT on {int(np.sum(c.engine.returns != c.python.returns))} episodes")
        rates = "; ".join(f"{name} {rate:,.0f}" for name, rate in self.rates.items())
        return (f"{self.task.name}: BehaviorTree.CPP return {c.engine.mean:.3f} +- "
                f"{c.engine.std:.3f} over {len(c.engine.returns)} episodes; the Python BT "
                f"{c.python.mean:.3f} +- {c.python.std:.3f} ({same}); {c.ticks} ticks, "
                f"{c.disagreements} decisions differ\n"
                f"ticks per second, one state per tick: {rates}")


def _other_task_hint(xml: str, task: Task) -> str:
    """`` It reads as a BT of X: pass --task X`` when exactly one other task reads ``xml``."""
    from ibt.tasks.catalogue import TASKS

    fits = []
    for other in TASKS.values():
        if other.name == task.name:
            continue
        try:
            from_btcpp_xml(xml, other.feature_names, other.action_names)
        except ValueError:
            continue
        fits.append(other.name)
    return f" It reads as a BT of {fits[0]}: pass --task {fits[0]}" if len(fits) == 1 else ""


def xml_commands(xml: str, task: Task, source: str = "the XML") -> Commands:
    """The command table a Box task's XML writes: every ``Script`` node's id and values
    (``command := 2; main_engine := 0.8; ...``, as :func:`ibt.export.btcpp.command_code`
    writes them); ids must run ``0 .. k-1`` and one id always write the same values."""
    from ibt.bt.model import Action, BehaviorTree
    from ibt.export.btcpp import blackboard_keys, command_keys, sum_terms

    dims = tuple(task.action_names)
    units = tuple(task.action_units or ("",) * len(dims))
    shell = BehaviorTree(Action(0), tuple(task.feature_names), ("command 0",), (),
                         Commands(dims, units, ((0.0,) * len(dims),)))
    keys = command_keys(shell)
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as err:
        raise ValueError(f"{source}: not well-formed XML ({err})") from None
    feature_of = {key: i for i, key in enumerate(blackboard_keys(task.feature_names))}
    table: dict[int, tuple[float, ...]] = {}
    linear: dict[int, tuple[tuple[tuple[int, float], ...], ...]] = {}
    for element in root.iter("Script"):
        code = element.get("code", "")
        assigned = {p[0].strip(): p[1].strip() for p in
                    (part.split(":=") for part in code.split(";")) if len(p) == 2}
        try:
            ident = int(assigned[keys[0]])
            sums = [sum_terms(assigned[k], code, feature_of) for k in keys[1:]]
            values = tuple(float(bias) for bias, _ in sums)  # type: ignore[arg-type]
            terms = tuple(t for _, t in sums)
        except (KeyError, ValueError, TypeError):
            raise ValueError(f"{source}: Script {code!r} does not write {task.name}'s command "
                             f"({'; '.join(f'{k} := ...' for k in keys)})") from None
        if not all(np.isfinite(values)):
            raise ValueError(f"{source}: Script {code!r} writes a value that is not a finite "
                             "number")
        if linear.setdefault(ident, terms) != terms:
            raise ValueError(f"{source}: command {ident} writes two different values")
        if table.setdefault(ident, values) != values:
            raise ValueError(f"{source}: command {ident} writes two different values")
    if not table:
        raise ValueError(f"{source} has no Script node that writes a command: it is a BT with "
                         f"discrete actions, but {task.name} has continuous actions (a Box), "
                         "whose BTs write commands; pass the task the XML was made for.")
    if sorted(table) != list(range(len(table))):
        raise ValueError(f"{source}: its Script nodes write command ids {sorted(table)}; "
                         f"expected 0 to {len(table) - 1}")
    commands = Commands(dims, units, tuple(table[i] for i in range(len(table))),
                        tuple(linear[i] for i in range(len(table))))
    if not commands.linear:
        task.check_action(commands.array())
    return commands


def read_xml_text(path: Path) -> str:
    """The XML file's text: UTF-8 (as ibt writes it), else ``ValueError`` naming the file."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path} is not UTF-8 text (byte 0x{data[err.start]:02x} at offset "
                         f"{err.start}); ibt writes BehaviorTree.CPP XML in UTF-8: export it "
                         "again") from None


def run_btcpp(path: str | Path, task: Task, episodes: int, groot_port: int | None = None,
              step_delay: float = 0.0) -> EngineRun:
    """Roll the XML at ``path`` out in BehaviorTree.CPP on the fixed evaluation episodes, with
    the Python BT on the same seeds beside it, and time both executors."""
    from ibt.evaluate.rollouts import final_seeds

    path = Path(path)
    if episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {episodes}")
    if groot_port is not None and not 1 <= groot_port <= 65535:
        raise ValueError(f"--groot-port must be a TCP port (1-65535), got {groot_port}")
    if step_delay < 0:
        raise ValueError(f"--step-delay must be >= 0 seconds, got {step_delay}")
    if not path.is_file():
        raise FileNotFoundError(f"no BehaviorTree.CPP XML at {path}; write one with `python -m "
                                f"ibt export BT.json --format btcpp-xml -o {path}`")
    text = read_xml_text(path)
    try:
        if task.continuous:  # the command table is the XML's own Script nodes
            commands = xml_commands(text, task, str(path))
            names = tuple(f"command {i}" for i in range(len(commands.values)))
            engine = EngineTree(text, task.feature_names, names, str(path), commands)
        else:
            engine = load_engine_tree(text, task, source=str(path))
    except ValueError as err:
        raise ValueError(f"{err}{_other_task_hint(text, task)}") from None
    publisher = engine.groot_publisher(groot_port) if groot_port is not None else None
    try:
        pause = (lambda _obs, _actions: time.sleep(step_delay)) if step_delay else None
        comparison = compare_rollouts(task, engine, final_seeds(episodes), on_step=pause)
    finally:
        del publisher  # (it has lived GROOT_START_SECONDS at least: see groot_publisher)
    return EngineRun(task, comparison, ticks_per_second(engine, comparison.states), engine.bt)
