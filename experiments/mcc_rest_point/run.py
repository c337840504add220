"""Why do the controllers study's MountainCarContinuous BTs fall short of 98.5, and would more
refinement episodes fix it?

Usage (from the repository root; the study's cache must be there, as committed)::

    python experiments/mcc_rest_point/run.py diagnose
    python experiments/mcc_rest_point/run.py variant LEAVES SEED '{"cma_episodes": 128, ...}'

``diagnose`` reads the study's six cached refinements (1 and 2 leaves, seeds 0-2) and measures
every candidate of each (the distilled tree, each CMA-ES stage's result, the rounded one) on the
first 1,000 final episodes (the study's), the chosen BT's rule on 4,000 final episodes, and two
families of hand-set rules over the same episodes: one linear rule ``force := b + k * velocity``
over its gain ``k``, and two rules split at rest whose first one pushes hard where the car stands
still. It writes ``diagnose.json`` here (about 4 minutes of one core).

``standstill`` measures one linear rule with and without a second rule for the standing start
(``if -1e-6 < velocity <= 1e-6: force := kick``, which fires at reset and at the left wall, where
the velocity is exactly 0) on 4,000 final episodes, and writes ``standstill.json`` here.

``variant`` refines the cached distilled tree of one run under the study's budget with the
given fields of :class:`ibt.tasks.settings.RefineConfig` replaced (nothing is cached), and
appends each candidate's returns on the 1,000 and 4,000 final episodes to ``variants.json``.
"""

from __future__ import annotations

import itertools
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

import ibt
import ibt.engine.learners  # the learner registry before the controller learners
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.refine.controller import ControllerPopulation, refine_controller, tree_from_doc
from ibt.runs import controllers
from ibt.tasks.catalogue import get_task

HERE = Path(__file__).resolve().parent
TASK = get_task("MountainCarContinuous-v0")
FAILED = 50.0  #: an episode under this return never reached the goal (successes score 90+)


def measured(returns: np.ndarray) -> dict[str, Any]:
    """Mean, failures and mean of the successes of one policy's returns."""
    failed = returns < FAILED
    return {"episodes": len(returns), "mean": round(float(returns.mean()), 3),
            "failures": int(failed.sum()),
            "mean_of_successes": round(float(returns[~failed].mean()), 3)}


def batch(act: Any, members: int, episodes: int) -> np.ndarray:
    """``members`` policies side by side on the first ``episodes`` final episodes: act(obs,
    member) -> actions; returns ``(members, episodes)``."""
    seeds = [s for _ in range(members) for s in final_seeds(episodes)]
    returns = rollout(TASK, lambda obs, e: act(obs, e // episodes), seeds, n_envs=256,
                      indexed=True).returns
    return returns.reshape(members, episodes)


def trees_returns(trees: list[Any], episodes: int) -> np.ndarray:
    """Controller trees of one shape on the first ``episodes`` final episodes."""
    population = ControllerPopulation.of(trees, TASK)
    return batch(lambda obs, m: population.decide(TASK.features(obs), m), len(trees), episodes)


def starts(returns: np.ndarray) -> list[float]:
    """The start positions of the failed episodes among the first final episodes."""
    import gymnasium as gym

    env = gym.make(TASK.name)
    seeds = final_seeds(len(returns))
    return sorted(round(float(env.reset(seed=seeds[i])[0][0]), 4)
                  for i in np.flatnonzero(returns < FAILED))


def diagnose() -> dict[str, Any]:
    """The study's runs and the two families of hand-set rules (see the module docstring)."""
    cfg = ibt.config("paper")
    runs = []
    for leaves in (1, 2):
        for seed in (0, 1, 2):
            record = controllers.refined(TASK, "sac", leaves, seed, cfg)
            trees = [tree_from_doc(d) for d in record["candidates"]]
            first = trees_returns(trees, 1000)
            chosen = trees_returns([trees[record["best_index"]]], 4000)[0]
            runs.append({
                "leaves": leaves, "seed": seed, "best_index": record["best_index"],
                "stages": [s["stage"] for s in record["stages"]],
                "selection_means": [round(m, 3) for m in record["selection_means"]],
                "candidates_final_1000": [measured(r) for r in first],
                "chosen_final_4000": measured(chosen),
                "chosen_failed_starts_1000": starts(chosen[:1000])})
    gains = [(b, k) for b in (-0.06, 0.025) for k in (9, 11, 13, 16, 20, 25)]
    g = np.array(gains)
    linear = batch(lambda obs, m: np.clip(g[m, 0] + g[m, 1] * obs[:, 1], -1, 1)
                   .astype(np.float32)[:, None], len(gains), 2000)
    rest = list(itertools.product((0.0005,), (-0.45, -0.6, -0.8), (5, 10), (-0.03, 0.05),
                                  (9, 11)))
    p = np.array(rest)

    def two_rules(obs: np.ndarray, m: np.ndarray) -> np.ndarray:
        v, q = obs[:, 1], p[m]
        force = np.where(v <= q[:, 0], q[:, 1] + q[:, 2] * v, q[:, 3] + q[:, 4] * v)
        return np.clip(force, -1, 1).astype(np.float32)[:, None]

    split = batch(two_rules, len(rest), 1000)
    return {"runs": runs,
            "linear_rule": [{"b": b, "k": k, **measured(r)}
                            for (b, k), r in zip(gains, linear, strict=True)],
            "two_rules_split_at_rest": [
                {"t": t, "b1": b1, "k1": k1, "b2": b2, "k2": k2, **measured(r)}
                for (t, b1, k1, b2, k2), r in zip(rest, split, strict=True)]}


#: (b, c, k, kick) of ``force := b + c * position + k * velocity`` and the standing start's force
#: (None: no such rule). The first two are the committed 1-leaf BT's rule (seed 0) alone and with
#: a kick; the rest come from CMA-ES on a NumPy copy of the task's dynamics over 3,000 random
#: start positions (not the final episodes, so these are held out): a best sample to three
#: decimals, two roundings of it by hand, the same rule without the kick, and a later
#: generation's best sample rounded (the copy first kept the state in float64; the task keeps it
#: in float32, and only the float32 copy agrees with the task on failures).
STANDSTILL_RULES = ((-0.05, -0.1, 9.0, None), (-0.05, -0.1, 9.0, -0.5),
                    (-0.027, -0.064, 5.736, -0.728), (-0.03, -0.06, 5.7, -0.7),
                    (-0.04, -0.09, 6.2, -0.5), (-0.04, -0.09, 6.2, None),
                    (-0.02, -0.04, 6.1, -0.8))


def standstill() -> list[dict[str, Any]]:
    """Each rule of :data:`STANDSTILL_RULES` on the first 4,000 final episodes."""
    rules = np.array([(b, c, k, np.nan if kick is None else kick)
                      for b, c, k, kick in STANDSTILL_RULES])

    def act(obs: np.ndarray, m: np.ndarray) -> np.ndarray:
        x, v, r = obs[:, 0], obs[:, 1], rules[m]
        force = r[:, 0] + r[:, 1] * x + r[:, 2] * v
        still = (v > -1e-6) & (v <= 1e-6) & ~np.isnan(r[:, 3])
        force = np.where(still, r[:, 3], force)
        return np.clip(force, -1, 1).astype(np.float32)[:, None]

    returns = batch(act, len(rules), 4000)
    return [{"b": b, "c": c, "k": k, "kick": kick, **measured(r)}
            for (b, c, k, kick), r in zip(STANDSTILL_RULES, returns, strict=True)]


def variant(leaves: int, seed: int, overrides: dict[str, Any]) -> dict[str, Any]:
    """One run refined under the study's budget with ``overrides`` (not cached)."""
    cfg = ibt.config("paper")
    budget = controllers.budget_of(TASK, cfg)
    config = replace(budget.refine, **overrides)
    tree = controllers.distilled(TASK, "sac", leaves, seed, cfg)
    cpu = time.process_time()
    record = refine_controller(tree, TASK, config, seed, tolerance=budget.tolerance,
                               progress=False)
    cpu = time.process_time() - cpu
    returns = trees_returns(record.candidates, 4000)
    return {"leaves": leaves, "seed": seed, "overrides": overrides,
            "cpu_seconds": round(cpu), "episodes": record.episodes,
            "stages": record.stages, "best_index": record.best_index,
            "selection_means": [round(m, 3) for m in record.selection_means],
            "candidates_final_1000": [measured(r[:1000]) for r in returns],
            "candidates_final_4000": [measured(r) for r in returns]}


def main(argv: list[str]) -> None:
    if argv[:1] == ["diagnose"]:
        (HERE / "diagnose.json").write_text(json.dumps(diagnose(), indent=1) + "\n")
    elif argv[:1] == ["standstill"]:
        (HERE / "standstill.json").write_text(json.dumps(standstill(), indent=1) + "\n")
    elif argv[:1] == ["variant"] and len(argv) == 4:
        path = HERE / "variants.json"
        done = json.loads(path.read_text()) if path.is_file() else []
        done.append(variant(int(argv[1]), int(argv[2]), json.loads(argv[3])))
        path.write_text(json.dumps(done, indent=1) + "\n")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
