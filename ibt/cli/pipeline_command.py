"""The command line's ``pipeline`` command (from an agent to a recommended BT, anytime) and
the argparse types of its options (``--keep``, ``--budget``, ``--leaves``). The compute stack
is imported when it runs."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibt.cli.checks import (
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    MAX_LEAVES,
    MAX_REFINE_EPISODES,
    UsageError,
    callable_spec,
    check_cache_folder,
    check_input,
    check_not_input,
    check_output_folder,
    one_line_warnings,
    read_input,
    same_path,
    task_for,
)

if TYPE_CHECKING:
    from ibt.tasks.task import Task


def pipeline_command(args: argparse.Namespace) -> int:
    """The ``pipeline`` command: from an agent to a recommended BT and its report."""
    from ibt.engine.agent import callable_agent, sb3_agent
    from ibt.pipeline.outputs import OUTPUTS
    from ibt.pipeline.owned_folder import FolderError, claim, release, take

    # every path is checked before any work: the folder, the cache, the checkpoint
    out = check_output_folder(args.output, "-o")
    cache = check_cache_folder(args.cache_dir or out / "cache", "--cache-dir")
    if same_path(cache, out):
        raise UsageError(f"--cache-dir {cache} is the output folder itself; drop --cache-dir "
                         f"(the cache then goes to {out / 'cache'}) or name another folder")
    task = task_for(args, args.task)
    spec = callable_spec(args)
    if spec is not None:
        agent = callable_agent(task, spec)
    else:
        checkpoint = args.checkpoint
        if checkpoint is None:
            from ibt.experts.expert import expert_path

            checkpoint = expert_path(task, args.algo)
        check_input(checkpoint, "SB3 checkpoint", "pass your agent's zip with --checkpoint")
        check_not_input([out / name for name in OUTPUTS], checkpoint)
        agent = sb3_agent(task, args.algo, checkpoint)  # its kind and spaces, loaded once
    replay = plan_replay(args, task, agent.digest, cache)
    try:
        folder = claim(out, OUTPUTS, force=args.force, cache=cache)
    except FolderError as err:
        raise UsageError(str(err)) from None
    note = folder.note()
    if note:
        print(note)
    from ibt.pipeline.outputs import write_outputs
    from ibt.pipeline.recommend import recommend

    first = take(folder)  # marked as the pipeline's before the long work: a rerun may write
    try:
        with one_line_warnings():  # e.g. one line for a cache that cannot be written
            rec = recommend(agent, keep=args.keep, budget=args.budget,
                            leaf_limits=args.leaves, seed=args.seed, episodes=args.episodes,
                            cache_dir=cache, progress=not args.quiet, argv=args.argv,
                            env_modules=args.env_module, time_limit=args.time,
                            max_nodes=args.max_nodes, restarts=args.restarts,
                            n_jobs=args.jobs or os.cpu_count() or 1, replay=replay)
    except SystemExit as stop:  # the agent's or the environment's code called sys.exit
        if first:
            release(folder)
        raise UsageError(f"the environment of {task.name} (or code it runs) called "
                         f"sys.exit({stop.code!r}) during the run; an environment must not "
                         "exit the process: fix it (no output file was written)") from None
    except BaseException:
        if first:
            release(folder)
        raise
    from ibt.views.headline import pipeline_episode

    try:
        write_outputs(rec, folder, pipeline_episode)
    except FolderError as err:
        raise UsageError(str(err)) from None
    verdict = "meets" if rec.met else "MISSES"
    stopped = {"time": f"; the --time budget ended the search after {rec.elapsed:.0f} s "
                       f"({rec.time_stop})",
               "interrupted": "; stopped by Ctrl-C", "terminated": "; stopped by SIGTERM"
               }.get(rec.stopped or "", "")
    print(f"{task.name}/{args.algo}: recommended a {rec.chosen.bt_nodes}-node BT keeping "
          f"{rec.retention:.1f} % of the agent (random-normalised, {rec.episodes} held-out "
          f"episodes); {verdict} the {100 * args.keep:.0f} % target{stopped}; see "
          f"{out / 'report.md'}")
    if rec.stopped in ("interrupted", "terminated"):
        return EXIT_INTERRUPTED if rec.stopped == "interrupted" else EXIT_TERMINATED
    return 0


def plan_replay(args: argparse.Namespace, task: Task, digest: str, cache: Path) -> Any:
    """``--plan``: the plan read (as data), checked against this run (the task, the agent, the
    settings), as a :class:`ibt.engine.plan.Replay`; None without ``--plan``. Bad input is a
    one-line ``UsageError``."""
    if args.plan is None:
        return None
    from ibt.engine.plan import (
        MAX_PLAN_BYTES,
        PlanError,
        Replay,
        check_made_for,
        made_for,
        read_plan,
    )
    from ibt.pipeline.recommend import pipeline_config

    data = read_input(args.plan, "plan", "pass the plan.json a pipeline run wrote into its "
                      "output folder (or drop --plan to run under --time)", MAX_PLAN_BYTES + 1)
    episodes = pipeline_config(args.budget, cache, args.episodes, False).final_episodes
    settings = {"keep": args.keep, "budget": args.budget.text, "leaves": list(args.leaves),
                "seed": args.seed, "restarts": args.restarts, "episodes": episodes,
                "max_nodes": args.max_nodes}
    try:
        planned, entries = read_plan(data, str(args.plan))
        check_made_for(planned, made_for(task.name, args.algo, digest, settings), str(args.plan))
    except PlanError as err:
        raise UsageError(str(err)) from None
    return Replay(entries, str(args.plan))


def keep_arg(text: str) -> float:
    """An argparse type: a share in (0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share such as 0.95, got {text!r}") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1] (a share of the agent), got {text}")
    return value


def budget_arg(text: str) -> Any:
    """An argparse type: ``smoke``, a scale (``2x``, at most 1000x) or refinement episodes per
    leaf limit, at most refine's ``--episodes`` maximum."""
    from ibt.pipeline.recommend import parse_budget

    try:
        budget = parse_budget(text if len(text) <= 40 else "?")
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).split(": ", 1)[-1]) from None
    if (budget.refine_episodes or 0) > MAX_REFINE_EPISODES:
        raise argparse.ArgumentTypeError(f"refinement episodes per leaf limit must be at most "
                                         f"{MAX_REFINE_EPISODES:,}, got {text:.40}")
    return budget


MAX_LEAF_LIMITS = 12  #: --leaves: at most this many limits (each is a distillation)


def leaf_limits_arg(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated leaf limits, each from 2 to distill's
    ``--max-leaf-nodes`` maximum, at most :data:`MAX_LEAF_LIMITS` of them."""
    parts = [v for v in text.split(",") if v.strip()]
    if len(parts) > MAX_LEAF_LIMITS:
        raise argparse.ArgumentTypeError(f"at most {MAX_LEAF_LIMITS} leaf limits, got "
                                         f"{len(parts)}")
    try:
        if any(len(v) > 30 for v in parts):
            raise ValueError("too long")
        values = tuple(sorted({int(v) for v in parts}))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected leaf limits such as 4,8,16,32, got "
                                         f"{text!r:.60}") from None
    if not values or values[0] < 2:
        raise argparse.ArgumentTypeError(f"leaf limits must be at least 2, got {text!r:.60}")
    if values[-1] > MAX_LEAVES:
        raise argparse.ArgumentTypeError(f"leaf limits must be at most {MAX_LEAVES:,} (as "
                                         f"distill's --max-leaf-nodes), got {values[-1]:,}")
    return values
