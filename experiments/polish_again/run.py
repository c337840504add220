"""Does polishing the 8-leaf search's chosen tree again (another CMA-ES + prune, other seeds,
the same or twice the episodes) raise its return?

Usage: ``python experiments/polish_again/run.py CACHE`` where CACHE is the cache of a finished
``ibt pipeline LunarLander-v3 ppo --time 30m`` run (its distillations and its search at 8
leaves are read from there; the polishes are added to it). Writes ``results.json`` here."""
import json
import sys
from dataclasses import replace
from pathlib import Path

from ibt.engine import budgets, distil, measure, search, synthesis
from ibt.engine.agent import sb3_agent
from ibt.engine.keys import leaves_of, tree_key
from ibt.engine.parallel import parallel_map
from ibt.evaluate.rollouts import selection_seeds
from ibt.experts.expert import expert_path
from ibt.pipeline.recommend import Budget, pipeline_config
from ibt.tasks.catalogue import resolve_task

cache = Path(sys.argv[1])
task = resolve_task("LunarLander-v3")
agent = sb3_agent(task, "ppo", expert_path(task, "ppo"), check=False)
cfg = pipeline_config(Budget(), cache, None, False)
learners = ("axis", "relational")
sources = []
for learner in learners:  # the ladder's order: each learner at the rung, then the largest
    for leaves in (8, 32):
        t = distil.distil(cfg, agent, leaves, 0, learner)
        if all(tree_key(t) != tree_key(u) for u in sources):
            sources.append(t)
tree, info = search.search(cfg, agent, sources, 8, 0, restarts=3, relational=True, n_jobs=2)
print("search info", info, flush=True)
config = budgets.search_config(cfg, task, 8, 1.0)
polish = budgets.polish_config(cfg, config)
restart_choice = selection_seeds(search.choice_episodes(config), 0,
                                 offset=search.RESTART_CHOICE_OFFSET)
choice, confirm = measure.held_out(1000, 0), measure.held_out(1000, 1)
variants = [("again", s, polish) for s in (10, 11)] + [
    ("again-x2", s, replace(polish, episodes=2 * polish.episodes)) for s in (20, 21)]
jobs = [(cfg, agent, s, search.SEARCHED_REL, tree, p) for _, s, p in variants]
trees = [tree, *parallel_map(search.polish_one, jobs, n_jobs=2)]
names = ["chosen", *(f"{n} seed {s}" for n, s, _ in variants)]
rows = []
for name, t in zip(names, trees, strict=True):
    bts = synthesis.synthesise(cfg, agent, t, 0)
    nodes = min(bt.node_count for bt in bts.values())
    rc = measure.measure(cfg, agent, t, bts, restart_choice).mean
    c100 = measure.measure(cfg, agent, t, bts, choice[:100]).mean
    c1000 = measure.measure(cfg, agent, t, bts, choice).mean
    f1000 = measure.measure(cfg, agent, t, bts, confirm).mean
    row = {"tree": name, "leaves": leaves_of(t), "bt_nodes": nodes,
           "restart_choice_1000": round(rc, 2), "choice_100": round(c100, 2),
           "choice_1000": round(c1000, 2), "confirm_1000": round(f1000, 2)}
    rows.append(row)
    print(json.dumps(row), flush=True)
Path(__file__).with_name("results.json").write_text(json.dumps(rows, indent=1))
