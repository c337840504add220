"""Train, evaluate and record the committed experts and the random baselines.

``train_missing`` trains every (task, algo) expert that has no checkpoint yet (or all, with
``refresh``), evaluates it over 100 fixed-seed episodes with deterministic actions, and updates
``data/experts/manifest.csv`` row by row (atomically), so an interrupted run loses at most the
expert in progress. ``random_baselines`` writes ``data/experts/random.csv``.
"""

from __future__ import annotations

import fcntl
import importlib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from ibt.evaluate.policies import RandomPolicy
from ibt.evaluate.rollouts import episode_metrics, final_seeds, rollout
from ibt.experts.expert import ALGOS, expert_path, load_expert, train_expert
from ibt.files import atomic_write_csv, file_digest
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import TASKS
from ibt.tasks.task import Task

MANIFEST_COLUMNS = ["task", "algo", "timesteps", "seed", "mean_return", "std_return",
                    "n_episodes", "success_rate", "collision_rate", "battery_failure_rate",
                    "wall_seconds", "n_envs", "normalize", "net_arch", "hyperparams_source",
                    "bar", "meets_bar", "note", "status", "status_evidence", "sha256"]

#: An expert's status (``status`` column of the manifest): ``ok`` experts count in every claim;
#: ``excluded`` ones missed their quality bar; ``constant-action`` ones take one action on every
#: step of the final episodes (a one-leaf tree copies them exactly, which proves nothing). The
#: last two stay in the tables, marked, and are left out of every claim and every count.
STATUSES = ("ok", "excluded", "constant-action")

def meets_bar(task: Task, algo: str, row: dict[str, Any], scripted: float | None = None
              ) -> bool:
    """Whether an expert's evaluation row passes its task's quality bar (``Task.bar``)."""
    return task.bar(algo, row, scripted)


def evaluate_expert(task: Task, algo: str, path: Path | None = None, n_episodes: int = 100
                    ) -> dict[str, Any]:
    expert = load_expert(task, algo, path)
    result = rollout(task, expert.act, final_seeds(n_episodes))
    row = {"mean_return": round(result.mean, 3), "std_return": round(result.std, 3),
           "n_episodes": n_episodes}
    row.update({k: round(v, 3) for k, v in episode_metrics(task, result).items()})
    return row


def scripted_return(task: Task, n_episodes: int = 100) -> float:
    """Mean return of the task's scripted policy (``Task.scripted_policy``, its bar's
    reference)."""
    if task.scripted_policy is None:
        raise LookupError(f"{task.name} has no scripted policy; its bar cannot need one")
    module, _, name = task.scripted_policy.partition(":")
    policy = getattr(importlib.import_module(module), name)
    return rollout(task, policy, final_seeds(n_episodes)).mean


def _read_manifest(path: Path) -> pd.DataFrame:
    if path.exists():
        return pd.read_csv(path)
    return pd.DataFrame(columns=MANIFEST_COLUMNS)


def record(row: dict[str, Any], manifest: Path) -> None:
    """Insert or replace the (task, algo) row of the manifest, atomically.

    A lock file serialises concurrent writers (several training queues may run at once).
    """
    manifest.parent.mkdir(parents=True, exist_ok=True)
    with open(manifest.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        _record_locked(row, manifest)


def _record_locked(row: dict[str, Any], manifest: Path) -> None:
    frame = _read_manifest(manifest)
    frame = frame[~((frame["task"] == row["task"]) & (frame["algo"] == row["algo"]))]
    frame = pd.concat([frame, pd.DataFrame([row])], ignore_index=True)
    order = {name: i for i, name in enumerate(TASKS)}
    frame = frame.sort_values(["task", "algo"], key=lambda c: c.map(order) if c.name == "task"
                              else c.map({a: i for i, a in enumerate(ALGOS)}))
    atomic_write_csv(manifest, frame.reindex(columns=MANIFEST_COLUMNS))


def catalogue_pairs(tasks: Iterable[Task] | None, algos: Iterable[str] | None
                    ) -> list[tuple[Task, str]]:
    """The (task, algo) experts asked for: every algorithm given, or (``algos`` None) each
    task's own catalogue algorithms (discrete tasks: DQN, PPO, A2C; Box tasks: theirs)."""
    chosen = list(tasks) if tasks else list(TASKS.values())
    if algos is not None:
        return [(t, a) for t in chosen for a in algos]
    return [(t, a) for t in chosen for a in ALGOS if a in dict(t.experts)]


def train_missing(tasks: Iterable[Task] | None = None, algos: Iterable[str] | None = None, *,
                  refresh: bool = False, root: Path | None = None, seed: int = 0,
                  timesteps: int | None = None, progress: bool = True,
                  refresh_before: float | None = None) -> pd.DataFrame:
    """Train (when missing or ``refresh``) and record each expert; returns the manifest.

    ``refresh_before`` (a POSIX time) retrains only checkpoints older than it: a from-scratch
    run that was interrupted resumes where it stopped.
    """
    root = root or DATA_DIR / "experts"
    manifest = root / "manifest.csv"
    pairs = catalogue_pairs(tasks, algos)
    scripted: dict[str, float] = {}
    for task, algo in tqdm(pairs, desc="experts", disable=not progress):
        path = expert_path(task, algo, root)
        existing = _read_manifest(manifest)
        have_row = ((existing["task"] == task.name) & (existing["algo"] == algo)).any()
        stale = refresh or (refresh_before is not None and path.exists()
                            and path.stat().st_mtime < refresh_before)
        if path.exists() and have_row and not stale:
            continue
        facts = train_expert(task, algo, path, seed=seed, timesteps=timesteps,
                             progress=progress)
        row = {**facts, **evaluate_expert(task, algo, path)}
        if task.scripted_policy is not None and task.name not in scripted:
            scripted[task.name] = scripted_return(task)
        row["bar"] = task.bar.describe()
        row["meets_bar"] = meets_bar(task, algo, row, scripted.get(task.name))
        row["note"] = "" if row["meets_bar"] else "below the bar"
        row.update(expert_status(task, algo, row["meets_bar"], path))
        row["sha256"] = file_digest(path)
        record(row, manifest)
    return _read_manifest(manifest)


def action_counts(task: Task, algo: str, path: Path | None = None, n_episodes: int = 100
                  ) -> tuple[dict[int, int], int]:
    """How often the expert takes each action over the final episodes, and the step count
    (on a Box task: each distinct action vector, numbered in order of first use)."""
    import numpy as np

    expert = load_expert(task, algo, path)
    if task.continuous:
        seen: dict[bytes, int] = {}
        uses: list[int] = []

        def count_vectors(_obs: Any, actions: Any) -> None:
            for row in np.asarray(actions, dtype=np.float32):
                k = seen.setdefault(row.tobytes(), len(seen))
                uses.extend([0] * (k + 1 - len(uses)))
                uses[k] += 1

        rollout(task, expert.act, final_seeds(n_episodes), on_step=count_vectors)
        return dict(enumerate(uses)), int(sum(uses))
    counts = np.zeros(expert.n_actions, dtype=np.int64)

    def count(_obs: Any, actions: Any) -> None:
        np.add.at(counts, np.asarray(actions, dtype=np.int64), 1)

    rollout(task, expert.act, final_seeds(n_episodes), on_step=count)
    return {a: int(n) for a, n in enumerate(counts) if n}, int(counts.sum())


def expert_status(task: Task, algo: str, bar_met: bool, path: Path | None = None,
                  n_episodes: int = 100) -> dict[str, str]:
    """``status`` and ``status_evidence`` of one expert (see :data:`STATUSES`).

    Below its bar it is ``excluded``; else one action on every step of the ``n_episodes``
    final episodes makes it ``constant-action``; else ``ok``. The evidence names the action
    counts it was measured on.
    """
    spec = task
    counts, steps = action_counts(task, algo, path, n_episodes)
    if task.continuous:  # action vectors: how many distinct ones, not each one's count
        measured = (f"{len(counts)} distinct action vectors over the {n_episodes} final "
                    f"episodes ({steps} steps)")
        if not bar_met:
            return {"status": "excluded", "status_evidence": f"below its bar; {measured}"}
        if len(counts) == 1:
            return {"status": "constant-action",
                    "status_evidence": f"one action vector on all {steps} steps of the "
                                       f"{n_episodes} final episodes"}
        return {"status": "ok", "status_evidence": measured}
    shares = ", ".join(f"{spec.action_names[a]} {n}" for a, n in
                       sorted(counts.items(), key=lambda kv: -kv[1]))
    measured = f"actions over the {n_episodes} final episodes ({steps} steps): {shares}"
    if not bar_met:
        return {"status": "excluded", "status_evidence": f"below its bar; {measured}"}
    if len(counts) == 1:
        action = spec.action_names[next(iter(counts))]
        return {"status": "constant-action",
                "status_evidence": f"always '{action}' on all {steps} steps of the "
                                   f"{n_episodes} final episodes"}
    return {"status": "ok", "status_evidence": measured}


def record_statuses(root: Path | None = None, tasks: Iterable[Task] | None = None,
                    progress: bool = True) -> pd.DataFrame:
    """Measure and write the status of every expert of the manifest (or of ``tasks``)."""
    root = root or DATA_DIR / "experts"
    manifest = root / "manifest.csv"
    frame = _read_manifest(manifest)
    # the manifest names its tasks: they are looked up among the tasks given (all registered)
    by_name = {t.name: t for t in (tasks if tasks is not None else TASKS.values())}
    rows = [r for r in frame.to_dict("records") if r["task"] in by_name]
    for row in tqdm(rows, desc="expert status", disable=not progress):
        task = by_name[row["task"]]
        path = expert_path(task, row["algo"], root)
        row.update(expert_status(task, row["algo"], bool(row["meets_bar"]), path))
        record(row, manifest)
    return _read_manifest(manifest)


def expert_statuses(root: Path | None = None) -> dict[tuple[str, str], str]:
    """``(task, algo) -> status`` from the manifest; where none is recorded, ``excluded`` if
    the expert missed its bar, else ``ok``."""
    frame = _read_manifest((root or DATA_DIR / "experts") / "manifest.csv")
    status = frame["status"] if "status" in frame else pd.Series(None, index=frame.index)
    bar = frame["meets_bar"] if "meets_bar" in frame else pd.Series(True, index=frame.index)
    return {(t, a): (s if isinstance(s, str) and s else
                     "excluded" if str(m) == "False" else "ok")
            for t, a, s, m in zip(frame["task"], frame["algo"], status, bar, strict=True)}


def random_baselines(tasks: Iterable[Task] | None = None, n_episodes: int = 100,
                     path: Path | None = None) -> pd.DataFrame:
    """Mean return of the uniform random policy per task (normalises retention)."""
    rows = []
    for task in tasks or list(TASKS.values()):
        act = (BoxRandomPolicy(task, seed=0).act if task.continuous
               else RandomPolicy(task.n_actions, seed=0).act)
        result = rollout(task, act, final_seeds(n_episodes))
        rows.append({"task": task.name, "mean_return": round(result.mean, 3),
                     "std_return": round(result.std, 3), "n_episodes": n_episodes})
    frame = pd.DataFrame(rows)
    target = path or DATA_DIR / "experts" / "random.csv"
    if target.exists():
        old = pd.read_csv(target)
        frame = pd.concat([old[~old["task"].isin(frame["task"])], frame], ignore_index=True)
    atomic_write_csv(target, frame)
    return frame


class BoxRandomPolicy:
    """Uniformly random action vectors inside a Box task's bounds, from a seeded generator."""

    def __init__(self, task: Task, seed: int = 0) -> None:
        import numpy as np

        self.low, self.high = np.asarray(task.action_low), np.asarray(task.action_high)
        self.rng = np.random.default_rng(seed)

    def act(self, obs: Any) -> Any:
        import numpy as np

        return self.rng.uniform(self.low, self.high, size=(len(obs), len(self.low))
                                ).astype(np.float32)


def expert_manifest(task: str | None = None, algo: str | None = None,
                    root: Path | None = None) -> pd.DataFrame:
    """Rows of the committed experts' manifest (all, or one task name and/or algo)."""
    frame = _read_manifest((root or DATA_DIR / "experts") / "manifest.csv")
    if task is not None:
        frame = frame[frame["task"] == task]
    if algo is not None:
        frame = frame[frame["algo"] == algo]
    return frame


def expert_table(root: Path | None = None) -> pd.DataFrame:
    """The experts beside the random policy and their quality bars (one row per expert)."""
    root = root or DATA_DIR / "experts"
    manifest = _read_manifest(root / "manifest.csv")
    random_file = root / "random.csv"
    if random_file.exists():
        rnd = pd.read_csv(random_file)[["task", "mean_return"]]
        manifest = manifest.merge(rnd.rename(columns={"mean_return": "random_return"}),
                                  on="task", how="left")
    keep = ["task", "algo", "timesteps", "net_arch", "mean_return", "std_return",
            "success_rate", "collision_rate", "battery_failure_rate", "random_return", "bar",
            "meets_bar", "status", "status_evidence", "note", "wall_seconds"]
    table = manifest.reindex(columns=[c for c in keep if c in manifest.columns])
    return table.dropna(axis=1, how="all").reset_index(drop=True)


def expert_return(task: str, algo: str, root: Path | None = None) -> float:
    """The committed expert's mean return (from the manifest)."""
    manifest = _read_manifest((root or DATA_DIR / "experts") / "manifest.csv")
    rows = manifest[(manifest["task"] == task) & (manifest["algo"] == algo)]
    if rows.empty:
        raise LookupError(f"no manifest row for the {algo} expert of {task}; train it with "
                          f"`python -m ibt train {task} {algo}`")
    return float(rows["mean_return"].iloc[0])
