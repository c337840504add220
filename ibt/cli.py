"""``python -m ibt``: the pipeline's steps without notebooks.

    python -m ibt train CartPole-v1 --algo ppo           # train + record committed experts
    python -m ibt distill CartPole-v1 ppo -o tree.joblib  # expert -> decision tree
    python -m ibt synthesize tree.joblib -o bt.json       # decision tree -> behavior tree
    python -m ibt evaluate bt.json --episodes 100         # returns of a BT, tree or expert
    python -m ibt export bt.json --format btcpp-xml -o bt.xml

``distill`` also takes any gymnasium env id with an SB3 checkpoint (``--checkpoint``), the
features then named x0, x1, ... (register a Task for readable names; see the README).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import joblib

from ibt.experts import ALGOS

EXPORT_FORMATS = ("json", "dot", "svg", "png", "btcpp-xml")
SYNTHESIS_METHODS = ("imitation-bt", "bt-espresso", "re-bt-espresso")


def _train(args: argparse.Namespace) -> int:
    from ibt.training import train_missing

    since = Path(args.refresh_before).stat().st_mtime if args.refresh_before else None
    root = Path(args.experts_dir) if args.experts_dir else None
    manifest = train_missing(args.tasks or None, args.algo or ALGOS, refresh=args.refresh,
                             seed=args.seed, timesteps=args.timesteps, refresh_before=since,
                             root=root)
    print(manifest.to_string(index=False))
    return 0


def _random(args: argparse.Namespace) -> int:
    from ibt.training import random_baselines

    path = Path(args.output) if args.output else None
    print(random_baselines(args.tasks or None, n_episodes=args.episodes, path=path)
          .to_string(index=False))
    return 0


def save_tree_file(path: str | Path, tree: Any, task_name: str, info: dict[str, Any]) -> Path:
    """A decision tree with what it needs to be read again: task, names, run facts."""
    from ibt.artifacts import atomic_target
    from ibt.tasks import resolve_task

    task = resolve_task(task_name)
    path = Path(path)
    with atomic_target(path) as tmp:
        joblib.dump({"tree": tree, "task": task.name, "feature_names": task.feature_names,
                     "action_names": task.action_names, **info}, tmp)
    return path


def load_tree_file(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no decision-tree file at {path}; make one with "
                                "`python -m ibt distill TASK ALGO -o FILE`")
    try:
        doc = joblib.load(path)
    except Exception as err:  # joblib raises many kinds on a damaged file
        raise ValueError(f"{path} is not a decision-tree file written by `python -m ibt distill`"
                         f" ({type(err).__name__})") from None
    if not isinstance(doc, dict) or "tree" not in doc:
        raise ValueError(f"{path} is not a decision-tree file written by `python -m ibt distill`")
    return doc


def _distill(args: argparse.Namespace) -> int:
    from ibt.distill import DistillConfig, distill
    from ibt.experts import load_expert
    from ibt.tasks import resolve_task

    task = resolve_task(args.task)
    expert = load_expert(task, args.algo, args.checkpoint)
    overrides = {"n_iterations": args.iterations, "selection_episodes": args.selection_episodes}
    if args.labels is not None:
        overrides["labels_per_iteration"] = args.labels
    if args.max_leaf_nodes is not None:
        overrides["max_leaf_nodes"] = args.max_leaf_nodes
    config = DistillConfig.for_task(task, method=args.method, **overrides)
    run = distill(task, expert, config, seed=args.seed, progress=not args.quiet)
    best = run.iterations[run.best_index]
    save_tree_file(args.output, run.best_tree, task.name,
                   {"algo": args.algo, "method": args.method, "seed": args.seed,
                    "iterations": run.iterations, "best_index": run.best_index})
    print(f"{task.name}/{args.algo}/{args.method}: best tree at iteration {run.best_index} "
          f"({best['nodes']} nodes, held-out return {best['selection_mean']:.2f}); "
          f"{run.expert_labels} expert labels; written to {args.output}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    from ibt.export import save_json
    from ibt.synthesis import imitation_bt
    from ibt.tasks import resolve_task

    doc = load_tree_file(args.tree)
    task = resolve_task(doc["task"])
    if args.method == "imitation-bt":
        result = imitation_bt(doc["tree"], task, default_strategy=args.default_strategy,
                              dont_cares=args.dont_cares)
    else:
        from ibt import baselines

        make = {"bt-espresso": baselines.bt_espresso, "re-bt-espresso": baselines.re_bt_espresso}
        result = make[args.method](doc["tree"], task)
    save_json(result.bt, args.output)
    print(f"{args.method}: {result.bt.node_count} nodes, verified equivalent to the tree; "
          f"written to {args.output}")
    return 0


def _load_policy(path: Path, task_name: str | None):
    from ibt.export import load_json
    from ibt.policies import BTPolicy, TreePolicy
    from ibt.tasks import resolve_task

    if path.suffix == ".json":
        bt = load_json(path)
        if task_name is None:
            raise ValueError("a BT file does not name its task; pass --task")
        task = resolve_task(task_name)
        if tuple(bt.feature_names) != task.feature_names:
            raise ValueError(f"{path} reads features {bt.feature_names}, but {task.name} has "
                             f"{task.feature_names}")
        return task, BTPolicy(task, bt)
    doc = load_tree_file(path)
    task = resolve_task(task_name or doc["task"])
    return task, TreePolicy(task, doc["tree"])


def _evaluate(args: argparse.Namespace) -> int:
    from ibt.evaluate import episode_metrics, final_seeds, rollout
    from ibt.experts import load_expert
    from ibt.tasks import resolve_task

    if args.policy in ALGOS:
        if args.task is None:
            raise ValueError("evaluating an expert needs --task")
        task = resolve_task(args.task)
        policy = load_expert(task, args.policy, args.checkpoint)
    else:
        task, policy = _load_policy(Path(args.policy), args.task)
    result = rollout(task, policy.act, final_seeds(args.episodes))
    extra = "".join(f", {k} {v:.3f}" for k, v in episode_metrics(task, result).items())
    print(f"{task.name}: mean return {result.mean:.3f} +- {result.std:.3f} over "
          f"{len(result.returns)} episodes{extra}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from ibt.export import load_json, save_drawing, save_json, to_graphviz

    bt = load_json(args.bt)
    out = Path(args.output)
    if args.format == "json":
        save_json(bt, out)
    elif args.format == "btcpp-xml":
        from ibt.artifacts import atomic_write_text
        from ibt.btcpp import to_btcpp_xml

        atomic_write_text(out, to_btcpp_xml(bt))
    elif args.format == "dot":
        from ibt.artifacts import atomic_write_text

        atomic_write_text(out, to_graphviz(bt).source)
    else:
        save_drawing(to_graphviz(bt), out.with_suffix(""), formats=(args.format,))
        out = out.with_suffix(f".{args.format}")
    print(f"written {out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m ibt", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    train = sub.add_parser("train", help="train, evaluate and record experts "
                           "(missing ones only unless --refresh)")
    train.add_argument("tasks", nargs="*", help="task names (default: all)")
    train.add_argument("--algo", action="append", choices=ALGOS, help="repeatable; default all")
    train.add_argument("--refresh", action="store_true", help="retrain existing experts")
    train.add_argument("--refresh-before", metavar="FILE",
                       help="retrain experts older than FILE (a resumable --refresh)")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--timesteps", type=int, default=None, help="override the table")
    train.add_argument("--experts-dir", metavar="DIR",
                       help="where checkpoints and manifest.csv go (default: data/experts)")
    train.set_defaults(func=_train)

    rnd = sub.add_parser("random-baselines", help="write data/experts/random.csv")
    rnd.add_argument("tasks", nargs="*")
    rnd.add_argument("--episodes", type=int, default=100)
    rnd.add_argument("-o", "--output", help="CSV to write (default: data/experts/random.csv)")
    rnd.set_defaults(func=_random)

    dist = sub.add_parser("distill", help="distil an expert into a decision tree")
    dist.add_argument("task", help="a registered task or any gymnasium env id")
    dist.add_argument("algo", choices=ALGOS)
    dist.add_argument("-o", "--output", required=True, help="decision-tree file (.joblib)")
    dist.add_argument("--checkpoint", help="SB3 checkpoint (default: the committed expert)")
    dist.add_argument("--method", default="imitation-bt",
                      choices=("bc", "dagger", "viper", "imitation-bt"))
    dist.add_argument("--seed", type=int, default=0)
    dist.add_argument("--iterations", type=int, default=50)
    dist.add_argument("--selection-episodes", type=int, default=20)
    dist.add_argument("--labels", type=int, default=None, help="expert labels per iteration")
    dist.add_argument("--max-leaf-nodes", type=int, default=None)
    dist.add_argument("--quiet", action="store_true", help="no progress bar")
    dist.set_defaults(func=_distill)

    syn = sub.add_parser("synthesize", help="turn a decision tree into a verified BT (JSON)")
    syn.add_argument("tree", help="decision-tree file from `distill`")
    syn.add_argument("-o", "--output", required=True, help="BT JSON file")
    syn.add_argument("--method", default="imitation-bt", choices=SYNTHESIS_METHODS)
    syn.add_argument("--default-strategy", default="max_complexity",
                     choices=("max_complexity", "most_frequent", "smallest_tree"))
    syn.add_argument("--dont-cares", action="store_true",
                     help="give Espresso the impossible threshold combinations as don't-cares")
    syn.set_defaults(func=_synthesize)

    ev = sub.add_parser("evaluate", help="returns of a BT (.json), a tree (.joblib) or an "
                        "expert (dqn/ppo/a2c) on the fixed evaluation episodes")
    ev.add_argument("policy", help="BT JSON, decision-tree file, or dqn|ppo|a2c")
    ev.add_argument("--task", help="task (required for BT files and experts)")
    ev.add_argument("--checkpoint", help="SB3 checkpoint for an expert")
    ev.add_argument("--episodes", type=int, default=100)
    ev.set_defaults(func=_evaluate)

    ex = sub.add_parser("export", help="write a BT as json, dot, svg, png or BehaviorTree.CPP "
                        "v4 XML")
    ex.add_argument("bt", help="BT JSON file")
    ex.add_argument("--format", required=True, choices=EXPORT_FORMATS)
    ex.add_argument("-o", "--output", required=True)
    ex.set_defaults(func=_export)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (KeyError, ValueError, FileNotFoundError, LookupError, RuntimeError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"error: {message}", file=sys.stderr)
        return 2
