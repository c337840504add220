"""The pipeline's benchmark (not a test): wall time, recommended BT and confirmed retention.

    python -m tests.bench_pipeline                     # every case (LunarLander: an hour)
    python -m tests.bench_pipeline thermostat cartpole # some cases
    IBT_BENCH_JOBS=1 python -m tests.bench_pipeline lunarlander-dqn  # one process (--jobs 1)

Each case runs ``python -m ibt pipeline`` in a subprocess with a fresh cache (what a new user
meets), timed as a whole, with its peak resident memory (``peak_rss_mb``; empty in the rows
measured before it was recorded); its row goes into ``data/results/pipeline_bench.csv``
(rows of other cases are kept). Agents of the users' own tasks are trained first (seeded; not
timed). Then, for the cases marked ``full``, the whole ladder is climbed on the same cache
(every rung and step, whatever kept the target; distillation and refinement, not the structure
search, to keep it within minutes) to measure how often a larger leaf limit would have given a
smaller BT that keeps the target, which the ladder's stop rule gives up.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "build" / "bench"
CSV = ROOT / "data" / "results" / "pipeline_bench.csv"
LINE = re.compile(r"recommended a (\d+)-node BT keeping (-?[\d.]+|nan) % of the agent .*?; "
                  r"(meets|MISSES) the")


@dataclass(frozen=True)
class Case:
    name: str
    task: str
    algo: str
    checkpoint: str | None = None  # None: the committed expert
    env_module: str | None = None
    time: str = "10m"
    full: bool = True  # also climb the whole ladder (the stop rule's check)
    leaves: str | None = None  # --leaves (default: the pipeline's)
    confirm: int = 0  # also evaluate the recommended BT on this many further fresh episodes
    max_nodes: int | None = None  # --max-nodes
    seed: int = 0  # --seed: another draw of the same command (distillation and search seeds)


CASES = (
    Case("thermostat", "Thermostat-v0", "ppo", "build/bench/agents/thermostat_ppo.zip",
         "tests.fixtures.thermostat"),
    Case("go-to-target", "GoToTarget-v0", "ppo", "tests/fixtures/go_to_target_ppo.zip",
         "tests.fixtures.go_to_target"),
    Case("thruster-sac", "Thruster-v0", "sac", "build/bench/agents/thruster_sac.zip",
         "bench_thruster"),
    Case("cartpole-dqn", "CartPole-v1", "dqn", full=False),  # full ladders: long episodes
    Case("mountaincar-dqn", "MountainCar-v0", "dqn", full=False),
    Case("pendulum-sac", "Pendulum-v1", "sac", full=False),
    Case("lunarlander-ppo", "LunarLander-v3", "ppo", time="30m", full=False, confirm=1000),
    Case("lunarlander-dqn", "LunarLander-v3", "dqn", time="30m", full=False, confirm=1000),
    # a budget that ends soon after the distillations: a first search sure to be cut is not
    # started, one that starts is cut at its grace; the run ends near its 15 minutes
    Case("lunarlander-ppo-15m", "LunarLander-v3", "ppo", time="15m", full=False, confirm=1000),
    Case("lunarlander-ppo-max25", "LunarLander-v3", "ppo", time="30m", full=False,
         confirm=1000, max_nodes=25),
    # the best published LunarLander tree's size (22 leaves)
    Case("lunarlander-ppo-22", "LunarLander-v3", "ppo", time="60m", full=False, leaves="22",
         confirm=1000),
    Case("lunarlander-dqn-22", "LunarLander-v3", "dqn", time="60m", full=False, leaves="22",
         confirm=1000),
)
# seeds 1 and 2 of the LunarLander one-command results: three draws of each command
CASES += tuple(replace(case, name=f"{case.name}-seed{seed}", seed=seed) for case in CASES
               if case.task == "LunarLander-v3" for seed in (1, 2))


def train_user_agents() -> None:
    """The users' agents the cases need (once; seeded, so the same files every time)."""
    agents = OUT / "agents"
    agents.mkdir(parents=True, exist_ok=True)
    from tests.test_env_module_box import ENV_SOURCE

    (OUT / "bench_thruster.py").write_text(ENV_SOURCE)
    if not (agents / "thermostat_ppo.zip").exists():
        import tests.fixtures.thermostat  # noqa: F401
        from ibt.experts.expert import train_expert
        from ibt.tasks.catalogue import resolve_task
        from ibt.tasks.settings import hp

        task = replace(resolve_task("Thermostat-v0"), experts=(
            ("ppo", hp(30_000, 4, n_steps=256, batch_size=64, gamma=0.95)),))
        train_expert(task, "ppo", agents / "thermostat_ppo.zip", progress=False)
    if not (agents / "thruster_sac.zip").exists():
        import gymnasium as gym
        from stable_baselines3 import SAC
        from stable_baselines3.common.logger import Logger

        sys.path.insert(0, str(OUT))
        import bench_thruster  # noqa: F401

        model = SAC("MlpPolicy", gym.make("Thruster-v0"), seed=0, device="cpu",
                    learning_starts=200, policy_kwargs={"net_arch": [32, 32]})
        model.set_logger(Logger(None, []))  # no empty /tmp/SB3-<date> folder
        model.learn(6_000)
        model.save(agents / "thruster_sac.zip")


def run(case: Case) -> dict[str, object]:
    """One timed pipeline run with a fresh cache, then (``full``) the whole ladder."""
    out = OUT / case.name
    shutil.rmtree(out, ignore_errors=True)
    argv = [sys.executable, "-m", "ibt", "pipeline", case.task, case.algo, "-o", str(out),
            "--time", case.time, "--quiet"]
    if case.checkpoint:
        argv += ["--checkpoint", str(ROOT / case.checkpoint)]
    if case.env_module:
        argv += ["--env-module", case.env_module]
    if case.leaves:
        argv += ["--leaves", case.leaves]
    if case.max_nodes:
        argv += ["--max-nodes", str(case.max_nodes)]
    if case.seed:
        argv += ["--seed", str(case.seed)]
    jobs = os.environ.get("IBT_BENCH_JOBS")  # fewer processes, e.g. two benchmarks at once
    if jobs:
        argv += ["--jobs", jobs]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(OUT)])}
    load = os.getloadavg()[0]
    start = time.perf_counter()
    done, peak_mb = _measured(argv, env)
    wall = time.perf_counter() - start
    said = done.stdout + done.stderr
    match = LINE.search(said)
    row: dict[str, object] = {
        "case": case.name, "task": case.task, "algo": case.algo,
        "time_limit": case.time, "leaves": case.leaves or "default",
        "max_nodes": case.max_nodes, "seed": case.seed, "wall_s": round(wall, 1),
        "exit": done.returncode,
        "bt_nodes": int(match.group(1)) if match else None,
        "retention_confirmed": float(match.group(2)) if match else None,
        "met": (match.group(3) == "meets") if match else None,
        "stopped_by_time": "--time budget ended" in said, "cpus": os.cpu_count(),
        "jobs": int(jobs) if jobs else os.cpu_count(),
        "load_before": round(load, 2), "peak_rss_mb": peak_mb, "commit": _commit()}
    if not match:
        row["error"] = said.strip().splitlines()[-1] if said.strip() else "no output"
    if case.full and match:
        row.update(full_ladder(case, out / "cache", int(match.group(1))))
    if match:
        row.update(search_speed(out / "cache"))
        row.update(search_choices(out / "report.md"))
        row["learner"] = recommended_learner(out / "report.md")
    if case.confirm and match:
        row.update(confirm(case, out / "bt.json", case.confirm))
    return row


def _commit() -> str:
    """The commit the run measured (``+changes`` when the work tree differed from it), so a
    row says which code made it."""
    head = subprocess.run(["git", "rev-parse", "--short=8", "HEAD"], cwd=ROOT,
                          capture_output=True, text=True).stdout.strip()
    changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                              "ibt"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return head + ("+changes" if changed else "")


def _measured(argv: list[str], env: dict[str, str]
              ) -> tuple[subprocess.CompletedProcess[str], float]:
    """Run ``argv``; what it printed and its peak resident memory in MB (the largest of the
    process and the worker processes it waited for, as ``wait4`` reports it)."""
    import tempfile

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        done = subprocess.CompletedProcess(argv, proc.returncode, out.read(), err.read())
    return done, round(usage.ru_maxrss / 1024, 1)  # Linux reports kilobytes


def search_speed(cache: Path) -> dict[str, object]:
    """The run's structure searches' stepping rate against random stepping measured in the
    same process (each restart's record holds both): the lowest and the mean ratio, over every
    restart run (a search that reached its target drops the restarts of its round after the
    one that did from its choice, not from this count)."""
    from ibt.cache.store import read_entry

    ratios = []
    for entry in sorted(cache.glob("evolve*/*/")):
        record = read_entry(entry, "evolution")
        if record.random_steps_per_second > 0:
            ratios.append(record.steps_per_second / record.random_steps_per_second)
    if not ratios:
        return {}
    return {"search_restarts_run": len(ratios), "search_speed_vs_random_min": round(min(ratios), 2),
            "search_speed_vs_random_mean": round(sum(ratios) / len(ratios), 2)}


SEARCH = re.compile(r"Search at leaf limit (\d+) [^:]*: \d+ restarts chosen among on \d+ "
                    r"held-out episodes of their own \(([^)]*)\); the best \d+ polished "
                    r"scored \(([^)]*)\) there; seed (\d+) won")


RECOMMENDED = re.compile(r"Recommended: a \*\*\d+-node BT\*\* \([^)]*\) of the ([a-z, ]+?) tree")


def recommended_learner(report: Path) -> str | None:
    """The learner whose tree the recommended BT came from, as the report labels it
    (``refined, oblique``: oblique; a label without one: the plain learner of its actions)."""
    found = RECOMMENDED.search(" ".join(report.read_text().split())) if report.exists() else None
    if found is None:
        return None
    _, _, learner = found.group(1).partition(", ")
    return learner or "axis or box"


def search_choices(report: Path) -> dict[str, object]:
    """Each search's restarts' means on its choice episodes, the polished ones' (``seed:
    mean``) and the seed that won, read from the run's report (``leaves: mean;mean;...``,
    searches apart by ``|``)."""
    found = SEARCH.findall(" ".join(report.read_text().split())) if report.exists() else []
    if not found:
        return {}
    return {"search_choice_means": " | ".join(
                f"{leaves}: " + ";".join(m.split(": ")[1] for m in means.split(", "))
                for leaves, means, *_ in found),
            "search_polished_means": " | ".join(
                f"{leaves}: " + ";".join(m.replace("seed ", "") for m in polished.split(", "))
                for leaves, _, polished, _ in found),
            "search_winners": ";".join(seed for *_, seed in found)}


def confirm(case: Case, bt_file: Path, n: int) -> dict[str, object]:
    """The recommended BT's mean return on ``n`` fresh episodes (seeds after the pipeline's
    choice and confirmation blocks), and on the final-evaluation protocol's first ``n`` seeds,
    the episodes of the committed studies and of the published trees run here (of which the
    pipeline's 100 choice episodes are the first 100)."""
    from ibt.bt.json_io import load_json
    from ibt.evaluate.policies import BTPolicy
    from ibt.evaluate.rollouts import FINAL_SEED_BASE, final_seeds, rollout
    from ibt.tasks.catalogue import resolve_task

    task = resolve_task(case.task)
    bt = load_json(bt_file)
    fresh = rollout(task, BTPolicy(task, bt).act, [FINAL_SEED_BASE + n + i for i in range(n)])
    protocol = rollout(task, BTPolicy(task, bt).act, final_seeds(n))
    return {"confirm_episodes": n, "confirm_mean": round(fresh.mean, 1),
            "confirm_std": round(fresh.std, 1),
            "confirm_share_200": round(float((fresh.returns >= 200).mean()), 3),
            "protocol_mean": round(protocol.mean, 1)}


def full_ladder(case: Case, cache: Path, chosen_nodes: int) -> dict[str, object]:
    """Every rung and step on the run's cache: the smallest BT that keeps the target at any
    leaf limit, against the one the stop rule recommended."""
    from ibt.engine.agent import sb3_agent
    from ibt.pipeline.recommend import recommend
    from ibt.tasks.catalogue import import_env_module, resolve_task

    if case.env_module:
        sys.path.insert(0, str(OUT))
        import_env_module(case.env_module)
    task = resolve_task(case.task)
    from ibt.experts.expert import expert_path

    checkpoint = ROOT / case.checkpoint if case.checkpoint else expert_path(task, case.algo)
    start = time.perf_counter()
    modules = (case.env_module,) if case.env_module else ()
    rec = recommend(sb3_agent(task, case.algo, checkpoint), cache_dir=cache, progress=False,
                    env_modules=modules,
                    full=True, search=False, time_limit=None, n_jobs=os.cpu_count() or 1)
    keeping = [c.bt_nodes for c in rec.candidates if c.retention >= 100 * rec.keep]
    return {"full_wall_s": round(time.perf_counter() - start, 1),
            "full_candidates": len(rec.candidates),
            "full_smallest_keeping": min(keeping) if keeping else None,
            "smaller_bt_at_larger_limit": bool(keeping) and min(keeping) < chosen_nodes}


def main(names: list[str]) -> None:
    chosen = [c for c in CASES if not names or c.name in names]
    unknown = set(names) - {c.name for c in CASES}
    if unknown:
        raise SystemExit(f"unknown cases {sorted(unknown)}; known: {[c.name for c in CASES]}")
    train_user_agents()
    for case in chosen:  # each row is written as soon as it is measured
        row = run(case)
        print(row, flush=True)
        write_row(row)


def write_row(row: dict[str, object]) -> None:
    """``row`` into the CSV in place of an earlier row of its case, in :data:`CASES` order."""
    import fcntl

    from ibt.files import atomic_write_text

    with open(OUT / "csv.lock", "w") as lock:  # two benchmarks may end together
        fcntl.flock(lock, fcntl.LOCK_EX)
        frame = pd.DataFrame([row])
        if CSV.exists():
            old = pd.read_csv(CSV, dtype={"search_winners": str})  # seeds, ``;``-joined
            frame = pd.concat([old[old["case"] != row["case"]], frame], ignore_index=True)
        order = {c.name: i for i, c in enumerate(CASES)}
        frame = frame.sort_values("case", key=lambda s: s.map(order)).reset_index(drop=True)
        atomic_write_text(CSV, frame.to_csv(index=False))


if __name__ == "__main__":
    main(sys.argv[1:])
