"""``python -m ibt``: the pipeline's steps without notebooks."""

from __future__ import annotations

import argparse
import sys

from ibt.experts import ALGOS


def _train(args: argparse.Namespace) -> int:
    from ibt.training import train_missing

    manifest = train_missing(args.tasks or None, args.algo or ALGOS, refresh=args.refresh,
                             seed=args.seed, timesteps=args.timesteps)
    print(manifest.to_string(index=False))
    return 0


def _random(args: argparse.Namespace) -> int:
    from ibt.training import random_baselines

    print(random_baselines(args.tasks or None).to_string(index=False))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m ibt", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    train = sub.add_parser("train", help="train, evaluate and record experts "
                           "(missing ones only unless --refresh)")
    train.add_argument("tasks", nargs="*", help="task names (default: all)")
    train.add_argument("--algo", action="append", choices=ALGOS, help="repeatable; default all")
    train.add_argument("--refresh", action="store_true", help="retrain existing experts")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--timesteps", type=int, default=None, help="override the table")
    train.set_defaults(func=_train)
    rnd = sub.add_parser("random-baselines", help="write data/experts/random.csv")
    rnd.add_argument("tasks", nargs="*")
    rnd.set_defaults(func=_random)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (KeyError, ValueError, FileNotFoundError, LookupError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"error: {message}", file=sys.stderr)
        return 2
