"""A run's plan: the ladder's steps in the order it took them, and where it stopped, as plain
JSON; and their replay, with no clock.

Which steps the anytime ladder (:mod:`ibt.engine.ladder`) takes depends on the clock, so on the
machine's speed and load: how far distillation goes before the search, how many restarts a
search runs, whether time is left to polish again, which steps are left out because they would
not fit. Every step's result is cached by content (its budgets are episodes, not seconds), so
the same steps in the same order give the same candidates and the same recommended BT anywhere.
A plan records them: each step's name (what the ladder asks for), kind, stage, learner, leaf
limit and seeds (a search's restarts, a polish's seeds, else the run's seed), each stop (its
reason and the step it came at), and what the plan was made for (the task, the agent's digest,
the settings that change results, the package's version). Replayed (:class:`Replay`), the
ladder runs every planned step and nothing else, with no deadline: a search runs the restarts
recorded, a polish the seeds recorded, on any number of cores. A plan file is data: read as
strict, bounded JSON and checked field by field (:func:`read_plan`), never run.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

FORMAT = "ibt-plan"
FORMAT_VERSION = 1
MAX_PLAN_BYTES = 4 << 20  #: a plan file larger than this is refused (a run's is a few kB)
MAX_ENTRIES = 10_000
MAX_SEEDS = 10_000
#: the ladder's stop reason where a replayed plan stops (a recorded stop, or its last step done)
END = "plan"
#: the settings a plan is made with, as the pipeline's options name them (``max_nodes``:
#: ``--max-nodes``); a replay must be given the same
SETTINGS = ("keep", "budget", "leaves", "seed", "restarts", "episodes", "max_nodes")
KINDS = ("distil", "refine", "search", "polish")


class PlanError(ValueError):
    """A plan that cannot be replayed here, in one line naming the problem and the fix."""


@dataclass(frozen=True)
class PlannedStep:
    """One step the ladder took."""

    name: str  # what the ladder asks for: "search relational at 8 leaves"
    kind: str  # distil, refine, search or polish
    stage: str  # the candidate's stage: distilled, refined, searched, polished
    learner: str
    leaves: int
    seeds: tuple[int, ...]  # a search's restarts, a polish's seeds, else the run's seed

    def as_data(self) -> dict[str, Any]:
        return {"step": self.name, "kind": self.kind, "stage": self.stage,
                "learner": self.learner, "leaves": self.leaves, "seeds": list(self.seeds)}


@dataclass(frozen=True)
class PlannedStop:
    """Where the ladder stopped: ``reason`` (``time``, ``interrupted``, ...) at the step
    ``at`` (one not started, or cut while under way; empty: between steps)."""

    reason: str
    at: str

    def as_data(self) -> dict[str, Any]:
        return {"stop": self.reason, "at": self.at}


Entry = PlannedStep | PlannedStop


class Replay:
    """A plan's entries handed to the ladder in order (``source``: how errors name the plan)."""

    def __init__(self, entries: list[Entry] | tuple[Entry, ...], source: str = "the plan"
                 ) -> None:
        self.entries, self.source, self.done = tuple(entries), source, 0

    def peek(self, name: str) -> PlannedStep | None:
        """The next entry where it is the step ``name``, else None."""
        entry = self.entries[self.done] if self.done < len(self.entries) else None
        return entry if isinstance(entry, PlannedStep) and entry.name == name else None

    def take(self, name: str) -> Entry | None:
        """The next entry, the ladder asking for the step ``name`` (None: the plan is done);
        :class:`PlanError` where the plan holds another step there."""
        if self.done == len(self.entries):
            return None
        entry = self.entries[self.done]
        planned = entry.name if isinstance(entry, PlannedStep) else entry.at
        if planned != name and planned:
            raise PlanError(f"{self.source}: entry {self.done + 1} is {describe(entry)} but this "
                            f"run's ladder asks for \"{name}\": the plan was made by other code "
                            "or settings; make a new one with a run under --time")
        self.done += 1
        return entry

    def check_finished(self) -> None:
        """:class:`PlanError` where the ladder ended before the plan's last entry."""
        if self.done < len(self.entries):
            raise PlanError(f"{self.source}: the ladder ended with {len(self.entries) - self.done}"
                            f" of its entries left (next: {describe(self.entries[self.done])}): "
                            "the plan was made by other code or settings; make a new one with "
                            "a run under --time")


def describe(entry: Entry) -> str:
    if isinstance(entry, PlannedStep):
        return f"the step \"{entry.name}\""
    return f"a stop ({entry.reason})" + (f" at \"{entry.at}\"" if entry.at else "")


def document(made_for: dict[str, Any], entries: list[Entry]) -> dict[str, Any]:
    """The plan as plain data: what it was made for (:func:`made_for`), how it ended (the
    last stop's reason, or ``finished``) and its entries."""
    from ibt import __version__

    last = entries[-1] if entries else None
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "ibt_version": __version__,
            **made_for, "ended": last.reason if isinstance(last, PlannedStop) else "finished",
            "entries": [e.as_data() for e in entries]}


def dumps(doc: dict[str, Any]) -> str:
    """The plan as JSON text, one line an entry."""
    head = json.dumps({k: v for k, v in doc.items() if k != "entries"}, indent=1,
                      allow_nan=False)
    rows = ",\n  ".join(json.dumps(e, allow_nan=False) for e in doc["entries"])
    return head[:-2] + (f',\n "entries": [\n  {rows}\n ]\n}}\n' if rows else
                        ',\n "entries": []\n}\n')


def made_for(task: str, algo: str, agent_sha256: str, settings: dict[str, Any]
             ) -> dict[str, Any]:
    """What a plan is replayed for: the task, the agent and :data:`SETTINGS`."""
    return {"task": task, "algo": algo, "agent_sha256": agent_sha256,
            "settings": {name: settings[name] for name in SETTINGS}}


def check_made_for(plan: dict[str, Any], run: dict[str, Any], source: str) -> None:
    """:class:`PlanError` naming the first way the plan (:func:`made_for`) was made for another
    run than ``run``: the task, the agent, or an option of :data:`SETTINGS`."""
    if (plan["task"], plan["algo"]) != (run["task"], run["algo"]):
        raise PlanError(f"{source} is a plan for {plan['task']:.100}/{plan['algo']:.20}, not "
                        f"{run['task']}/{run['algo']}: pass the plan a run of this task and agent "
                        "wrote, or make one with a run under --time")
    if plan["agent_sha256"] != run["agent_sha256"]:
        raise PlanError(f"{source} was made for another agent (SHA-256 "
                        f"{plan['agent_sha256'][:12]}, this one's {run['agent_sha256'][:12]}): "
                        "replay it with the agent that made it, or make a new plan with a run "
                        "under --time")
    for name in SETTINGS:
        made, given = plan["settings"][name], run["settings"][name]
        if made != given:
            option = "--" + name.replace("_", "-")
            fix = (f"drop {option}" if made is None else f"pass {option} {_said(made)}")
            raise PlanError(f"{source} was made with {option} {_said(made)}, this run has "
                            f"{_said(given)}: {fix} (a replay takes the settings of the run "
                            "that made the plan) or drop --plan")


def _said(value: Any) -> str:
    if value is None:
        return "(none)"
    if isinstance(value, list):
        return ",".join(map(str, value))[:100]
    return str(value)[:100]


def summary(entries: list[Entry]) -> str:
    """The entries in a few words: the steps of each kind, a search's restarts, the stops."""
    steps = [e for e in entries if isinstance(e, PlannedStep)]
    parts = []
    for kind in KINDS:
        mine = [s for s in steps if s.kind == kind]
        if kind == "search":
            parts += [f"a search at {s.leaves} leaves ({len(s.seeds)} restarts)" for s in mine]
        elif mine:
            parts.append(f"{len(mine)} {kind} step{'s' if len(mine) > 1 else ''}")
    stops = [f"stopped ({e.reason})" + (f" at \"{e.at}\"" if e.at else "")
             for e in entries if isinstance(e, PlannedStop)]
    return "; ".join([", ".join(parts) or "no step", *(stops or ["the ladder finished"])])


# ------------------------------------------------------------------------------ reading
def read_plan(data: bytes, source: str) -> tuple[dict[str, Any], list[Entry]]:
    """A plan file's bytes (``source``: its path, for messages) as what it was made for and
    its entries; :class:`PlanError` for anything but a plan this version wrote."""
    from ibt import __version__
    from ibt.distill.tree_file import parse_json

    fix = "pass the plan.json a pipeline run wrote into its output folder"
    if len(data) > MAX_PLAN_BYTES:
        raise PlanError(f"{source} holds more than {MAX_PLAN_BYTES >> 20} MiB: no plan is that "
                        f"large; {fix}")
    try:
        doc = parse_json(data, source, "plan")
    except ValueError as err:
        raise PlanError(f"{err}; {fix}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise PlanError(f"{source} is not a pipeline plan (no \"format\": \"{FORMAT}\"); {fix}")
    if doc.get("format_version") != FORMAT_VERSION or doc.get("ibt_version") != __version__:
        raise PlanError(f"{source} was made by ibt {str(doc.get('ibt_version'))[:20]} (plan "
                        f"format {str(doc.get('format_version'))[:10]}), this is ibt "
                        f"{__version__} (format {FORMAT_VERSION}): a plan replays on the version "
                        "that made it; make a new one with a run under --time")
    want = {"format", "format_version", "ibt_version", "task", "algo", "agent_sha256",
            "settings", "ended", "entries"}
    if set(doc) != want:
        raise PlanError(f"{source}: expected the fields {', '.join(sorted(want))}, got "
                        f"{', '.join(sorted(map(str, doc)))[:200]}; {fix}")
    settings = doc["settings"]
    if not (isinstance(doc["task"], str) and isinstance(doc["algo"], str)
            and isinstance(doc["agent_sha256"], str) and isinstance(settings, dict)
            and set(settings) == set(SETTINGS) and _count(settings["seed"], 0)):
        raise PlanError(f"{source}: its task, algo, agent_sha256 or settings ({', '.join(SETTINGS)}"
                        f") are missing or malformed; {fix}")
    entries = doc["entries"]
    if not isinstance(entries, list) or len(entries) > MAX_ENTRIES:
        raise PlanError(f"{source}: \"entries\" must be a list of at most {MAX_ENTRIES:,} steps "
                        f"and stops; {fix}")
    return ({k: doc[k] for k in ("task", "algo", "agent_sha256", "settings")},
            [_entry(e, i, source, fix, settings.get("seed")) for i, e in enumerate(entries, 1)])


def _entry(data: Any, number: int, source: str, fix: str, seed: Any) -> Entry:
    """One entry, checked: its fields, their types, a search's seeds from the run's seed on."""
    bad = f"{source}: entry {number}"

    def text(value: Any) -> bool:
        return isinstance(value, str) and len(value) <= 200

    if isinstance(data, dict) and set(data) == {"stop", "at"}:
        if not (text(data["stop"]) and data["stop"] and text(data["at"])):
            raise PlanError(f"{bad} is a stop whose \"stop\" and \"at\" must be short texts; {fix}")
        return PlannedStop(data["stop"], data["at"])
    fields = {"step", "kind", "stage", "learner", "leaves", "seeds"}
    if not isinstance(data, dict) or set(data) != fields:
        raise PlanError(f"{bad} must be a step (fields {', '.join(sorted(fields))}) or a stop "
                        f"(stop, at); {fix}")
    seeds = data["seeds"]
    if not (text(data["step"]) and data["kind"] in KINDS and text(data["stage"])
            and text(data["learner"]) and _count(data["leaves"]) and isinstance(seeds, list)
            and 0 < len(seeds) <= MAX_SEEDS and all(_count(s, 0) for s in seeds)
            and data["step"].split()[0] == data["kind"]):
        raise PlanError(f"{bad} (a step) has a malformed field (kind one of {', '.join(KINDS)}, "
                        "the step's name starting with it, leaves a positive integer, seeds a "
                        f"list of integers >= 0); {fix}")
    if data["kind"] == "search" and seeds != list(range(seed, seed + len(seeds))):
        raise PlanError(f"{bad}: a search's seeds are its restarts, the run's seed {seed} on; "
                        f"got {seeds[:5]}; {fix}")
    return PlannedStep(data["step"], data["kind"], data["stage"], data["learner"],
                       data["leaves"], tuple(seeds))


def _count(value: Any, least: int = 1) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and least <= value <= 10**9
