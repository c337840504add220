"""Cache upkeep: what no lookup can reach, pruning it, verification, and migrations.

The command line of the cache's upkeep (:mod:`ibt.cache.upkeep`, whose docstring says what each
status of an entry means) and of its migrations (:mod:`ibt.cache.migrations`).

``python -m ibt.cache.admin stale`` lists what is not current (and the temporary files),
``--reads FOLDER`` also the current entries that the lookups logged there (``IBT_CACHE_READS``)
never touched, which is what ``make figures`` counts at its end (``--count``: one line, and none
when there is nothing to count: the committed cache holds only what ``make figures`` reads, so
a line there means runs were superseded, by a retrained expert or a changed budget or setting,
and their entries can be pruned). ``prune`` removes what ``stale``
lists (``--dry-run`` to see it first), except ``legacy`` and ``unmigrated`` entries (migrate
those) and ``incomplete`` entries that still hold a payload: those only with ``--incomplete``
(the payload may be all that is left of hours of computing; a later lookup overwrites it
anyway). ``verify`` reads every entry as a lookup would and lists those that do not verify
(exit 1 if any). ``summary`` counts entries per kind and status.

Every command first checks that ``--cache-dir`` is an ibt cache
(:func:`ibt.cache.upkeep.check_cache_root`: its marker, or a cache's layout): a folder of
other files, or a pipeline's output folder, is refused with exit 2, nothing touched.

Migrations: ``migrate`` is the one-off re-keying of 2026-11, ``migrate-plain --trust-pickles``
the plain-data conversion of 2026-12 (:mod:`ibt.cache.migrations` says what each does).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from ibt.cache.migrations import migrate, migrate_plain, pickled_entries
from ibt.cache.upkeep import (
    Entry,
    NotACache,
    check_cache_root,
    entries,
    not_current,
    prune,
    read_log,
    verify,
)


def _listing(found: Sequence[Entry]) -> str:
    if not found:
        return "none"
    counts = Counter(e.status for e in found)
    head = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    return head + "\n" + "\n".join(f"  {e.status:10s} {e.name}  {e.reason}" for e in found)


def main(argv: Sequence[str] | None = None) -> int:
    from ibt.paths import DATA_DIR

    parser = argparse.ArgumentParser(prog="python -m ibt.cache.admin",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("stale", "prune", "verify", "summary", "migrate",
                                            "migrate-plain"))
    parser.add_argument("--cache-dir", type=Path,
                        default=Path(os.environ.get("IBT_CACHE_DIR") or DATA_DIR / "cache"))
    parser.add_argument("--reads", type=Path, help="a folder of IBT_CACHE_READS logs: also "
                        "list (or prune) the current entries no lookup read")
    parser.add_argument("--dry-run", action="store_true", help="say what would change")
    parser.add_argument("--count", action="store_true", help="stale: one summary line with the "
                        "command that lists them, instead of the list")
    parser.add_argument("--incomplete", action="store_true", help="prune: also remove "
                        "incomplete entries that still hold a payload")
    parser.add_argument("--trust-pickles", action="store_true", help="migrate-plain: unpickle "
                        "the payload.joblib files (a pickle runs code when loaded)")
    args = parser.parse_args(argv)
    if not args.cache_dir.is_dir():
        print(f"error: no cache at {args.cache_dir}; pass --cache-dir", file=sys.stderr)
        return 2
    try:
        check_cache_root(args.cache_dir)
    except NotACache as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.reads is not None and not args.reads.is_dir():
        print(f"error: no reads log at {args.reads}; run with IBT_CACHE_READS={args.reads} "
              "first (make figures does)", file=sys.stderr)
        return 2
    reads = read_log(args.reads) if args.reads is not None else None
    if args.command == "summary":
        counts = Counter((e.kind, e.status) for e in entries(args.cache_dir))
        for (kind, status), n in sorted(counts.items()):
            print(f"{kind:12s} {status:10s} {n}")
    elif args.command == "stale":
        found = not_current(args.cache_dir, reads)
        what = f"cache entries in {args.cache_dir} that no lookup " + (
            "read" if reads is not None else "can reach")
        if args.count and found:  # `make figures`: one line, not a list that reads like an error
            again = [a for a in (argv if argv is not None else sys.argv[1:]) if a != "--count"]
            why = (" (results of runs nothing asks for any more: a retrained expert, a changed "
                   "budget or setting; harmless)" if reads is not None else " (harmless)")
            print(f"{what}: {_listing(found).splitlines()[0]}{why}; list them with "
                  f"`python -m ibt.cache.admin {' '.join(again)}`, remove them with "
                  "`prune`")
        elif args.count:  # nothing to say: every entry is current (and was read)
            pass
        else:
            print(f"{what}: {_listing(found)}")
    elif args.command == "prune":
        gone = prune(args.cache_dir, reads, dry_run=args.dry_run, incomplete=args.incomplete)
        print(f"{'would remove' if args.dry_run else 'removed'}: {_listing(gone)}")
    elif args.command == "verify":
        bad = verify(args.cache_dir)
        print(f"cache entries in {args.cache_dir} that do not verify: {_listing(bad)}")
        return 1 if bad else 0
    elif args.command == "migrate-plain":
        pickles = pickled_entries(args.cache_dir)
        if pickles and not args.trust_pickles:
            print(f"error: refusing to unpickle {len(pickles)} payload.joblib file(s) under "
                  f"{args.cache_dir}: loading a pickle runs whatever code it names; if they are "
                  "this repository's own (e.g. the committed data/cache), re-run with "
                  "--trust-pickles, else delete those entries and let the next run recompute "
                  "them", file=sys.stderr)
            return 2
        report = migrate_plain(args.cache_dir, dry_run=args.dry_run, progress=True)
        print(("dry run: " if args.dry_run else "") + report.summary())
        return 1 if report.refused else 0
    else:
        print(migrate(args.cache_dir, dry_run=args.dry_run).summary())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
