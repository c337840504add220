"""``make verify``: every number of the README's headline and of the paper's verdicts, checked.

The claims table (``paper/claims.csv``, written by :func:`write_claims` from the committed
results, never by hand) has one row per number: its ``id``, what it is, the ``value`` as
committed, its ``tolerance`` and the ``interval`` rule that gives it, the committed
``artifact`` it comes from and the ``command`` that reproduces it. Two sources:

* **headline**: each BT of ``data/results/headline.csv`` (its ``bt.json`` under
  ``figures/headline/``). Its node count is exact (counted from the file:
  :attr:`ibt.bt.model.BehaviorTree.node_count`). Its return statistics are replayed on the
  stated episodes (the fixed final seeds, as ``python -m ibt evaluate`` does): the same seeds on
  the same software give the same episodes, but a machine with other floating-point rounding may
  change single episodes, so a statistic may move within twice its standard error over ``N``
  episodes: the mean by ``2 s / sqrt(N)``, the standard deviation by ``2 s / sqrt(2 (N - 1))``,
  the share of landings at >= 200 by ``2 sqrt(p (1 - p) / N)``, the retention by the mean's
  tolerance in retention points. The headline's other columns (the tree's leaves, the
  published policy's numbers, the paper's method as run here) come from other tables and the
  literature, not from the BT, and have no row.
* **verdict**: each claim of :mod:`ibt.report.claims`, recomputed from the committed CSVs under
  ``data/results/``: its verdict and every number of its evidence (``measured``), in order,
  exactly as printed (deterministic: the same CSVs give the same text).

:func:`main` (``python -m ibt.check_claims``) recomputes every row and prints ``OK`` or the
difference and the row; it exits 1 on a difference beyond a row's tolerance, 2 on bad input.
``--smoke`` checks a few rows: the smallest headline BT's node count, and its mean and
retention on its first few episodes within ``3`` standard errors of those few episodes (a
deterministic replay: the same episodes every time), and the first claim's rows.
``notebooks/12_headline.ipynb`` rewrites the table after the headline it reads.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from ibt.files import atomic_write_text
from ibt.paths import DATA_DIR, ROOT

CLAIMS_FILE = ROOT / "paper" / "claims.csv"
HEADLINE = Path("data/results/headline.csv")
COLUMNS = ("id", "source", "what", "value", "tolerance", "interval", "artifact", "command")
EXACT = "exact: deterministic from the committed file"
Z = 2.0  #: a replayed statistic may move by this many standard errors
SMOKE_EPISODES = 10  #: episodes of the smoke replay
SMOKE_Z = 3.0  #: the smoke replay's few episodes: their mean within this many standard errors
SOLVED = 200.0  #: LunarLander's "solved" landing, the headline's ``share_200``
_NUMBER = re.compile(r"(?<![\w.])-?\d+(?:,\d{3})*(?:\.\d+)?(?=x?(?!\w))")
REPORT_COMMAND = "python -m ibt.check_claims --only {id}"


@dataclass(frozen=True)
class Row:
    """One number of the claims table (see the module's docstring)."""

    id: str
    source: str
    what: str
    value: str
    tolerance: float
    interval: str
    artifact: str
    command: str


def numbers(text: str) -> list[str]:
    """The numbers of a claim's evidence in order, as printed (``1.7x`` gives ``1.7``; the
    digits of names such as ``LunarLander-v3`` are not numbers)."""
    return _NUMBER.findall(text)


def _context(text: str, index: int) -> str:
    """The few words before the ``index``-th number: what the number is."""
    match = list(_NUMBER.finditer(text))[index]
    before = text[max(0, match.start() - 48):match.start()].split(";")[-1].strip()
    return f"... {before} [{match.group()}]"


# --- the table from the committed results -----------------------------------------------------

def _headline_bts(data_dir: Path) -> pd.DataFrame:
    table = pd.read_csv(data_dir / "results" / "headline.csv")
    whats = table.groupby("json_file", sort=False)["what"].agg("; ".join)
    first = table.drop_duplicates("json_file").set_index("json_file")
    return first.assign(what=whats).reset_index()


def _half_width(std: float, n: int) -> float:
    return Z * std / math.sqrt(n)


def headline_rows(data_dir: Path = DATA_DIR) -> list[Row]:
    """The rows of the headline's BTs (node count, mean, std, share >= 200, retention)."""
    rows = []
    for bt in _headline_bts(data_dir).itertuples(index=False):
        n = int(bt.episodes)
        command = f"python -m ibt evaluate {bt.json_file} --task {bt.task} --episodes {n}"
        base = f"headline.{bt.name}"
        label = f"{bt.task} ({bt.expert}), {bt.what}"
        se_rule = f"{Z:g} standard errors over {n} episodes"
        mean_tol = _half_width(bt.std_return, n)
        span = bt.expert_return - bt.random_return
        rows += [
            Row(f"{base}.nodes", "headline", f"{label}: BT nodes", str(int(bt.bt_nodes)), 0.0,
                "exact: counted from the file", bt.json_file, command),
            Row(f"{base}.mean_return", "headline", f"{label}: mean return",
                repr(float(bt.mean_return)), mean_tol, f"{se_rule}: {Z:g} s / sqrt(N)",
                bt.json_file, command),
            Row(f"{base}.std_return", "headline", f"{label}: standard deviation of the return",
                repr(float(bt.std_return)), Z * bt.std_return / math.sqrt(2 * (n - 1)),
                f"{se_rule}: {Z:g} s / sqrt(2 (N - 1))", bt.json_file, command),
            Row(f"{base}.retention_norm", "headline", f"{label}: retention (%)",
                repr(float(bt.retention_norm)), 100.0 * mean_tol / abs(span),
                f"the mean's tolerance in retention points (expert {bt.expert_return:.1f}, "
                f"random {bt.random_return:.1f})", bt.json_file, command),
        ]
        if pd.notna(bt.share_200):
            p = float(bt.share_200)
            rows.append(Row(f"{base}.share_200", "headline", f"{label}: share of episodes >= 200",
                            repr(p), Z * math.sqrt(p * (1 - p) / n),
                            f"{se_rule}: {Z:g} sqrt(p (1 - p) / N)", bt.json_file, command))
    return rows


def _claim_key(fn: Callable[..., Any]) -> str:
    return fn.__name__.removeprefix("claim_")


def _recording_results(data_dir: Path) -> Any:
    """:class:`ibt.report.stats.Results` that records the files a claim reads."""
    from ibt.report.stats import Results

    class Recording(Results):
        def __init__(self, data_dir: Path) -> None:
            super().__init__(data_dir)
            self.read: list[str] = []

        def table(self, name: str) -> pd.DataFrame | None:
            self.read.append(f"data/results/{name}.csv")
            return super().table(name)

        def experts(self) -> pd.DataFrame | None:
            self.read.append("data/experts/manifest.csv")
            return super().experts()

    return Recording(data_dir)


def verdict_rows(data_dir: Path = DATA_DIR, keys: set[str] | None = None) -> list[Row]:
    """The rows of the paper's verdicts (of the claims named ``keys``, default all): each
    claim's verdict and its evidence's numbers; the artifact is every committed table the claim
    read (recorded as it reads them)."""
    from ibt.report import claims

    rows = []
    for fn in claims.CLAIMS:
        if keys is not None and _claim_key(fn) not in keys:
            continue
        results = _recording_results(data_dir)
        claim = fn(results)
        key = _claim_key(fn)
        command = REPORT_COMMAND.format(id=f"verdict.{key}")
        artifact = "; ".join(dict.fromkeys(results.read))
        rows.append(Row(f"verdict.{key}", "verdict", f"{claim.claim}: verdict", claim.verdict,
                        0.0, EXACT, artifact, command))
        for i, number in enumerate(numbers(claim.measured)):
            rows.append(Row(f"verdict.{key}.{i}", "verdict",
                            f"{claim.claim}: {_context(claim.measured, i)}", number, 0.0, EXACT,
                            artifact, command))
    return rows


def claims_table(data_dir: Path = DATA_DIR) -> pd.DataFrame:
    """The claims table: the headline's rows, then the verdicts'."""
    rows = headline_rows(data_dir) + verdict_rows(data_dir)
    return pd.DataFrame([r.__dict__ for r in rows], columns=list(COLUMNS))


def write_claims(path: Path = CLAIMS_FILE, data_dir: Path = DATA_DIR) -> pd.DataFrame:
    """Write the claims table to ``path`` (atomically) and return it."""
    table = claims_table(data_dir)
    atomic_write_text(path, table.to_csv(index=False))
    return table


def read_claims(path: Path) -> list[Row]:
    """The rows of a claims table; ``ValueError`` names what is wrong with the file."""
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, pd.errors.ParserError, UnicodeDecodeError) as err:
        raise ValueError(f"{path} is not a readable claims table ({type(err).__name__}); "
                         f"write it with `python -m ibt.check_claims --write`") from None
    absent = [c for c in COLUMNS if c not in table.columns]
    if absent:
        raise ValueError(f"{path} lacks the column(s) {', '.join(absent)}; write it with "
                         f"`python -m ibt.check_claims --write`")
    rows = []
    for record in table[list(COLUMNS)].to_dict("records"):
        try:
            tolerance = float(record["tolerance"])
        except ValueError:
            raise ValueError(f"{path}: row {record['id']!r} has the tolerance "
                             f"{record['tolerance']!r:.40}, not a number") from None
        rows.append(Row(**{**record, "tolerance": tolerance}))
    return rows


# --- recomputing --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    """One row recomputed: ``now`` beside the table's value; ``ok`` within its tolerance."""

    row: Row
    now: str
    ok: bool
    tolerance: float


def _replay(json_file: str, task_name: str, episodes: int) -> dict[str, float]:
    """What ``python -m ibt evaluate`` measures of a BT file on ``episodes`` final episodes
    (none: its node count only)."""
    import numpy as np

    from ibt.bt.model import BehaviorTree
    from ibt.evaluate.policies import BTPolicy
    from ibt.evaluate.rollouts import final_seeds, rollout
    from ibt.tasks.catalogue import get_task

    task = get_task(task_name)
    bt = BehaviorTree.from_json((ROOT / json_file).read_bytes())
    if episodes == 0:
        return {"nodes": bt.node_count}
    if bt.commands is not None:  # continuous actions: the BT sends commands
        from ibt.synth.commands import CommandBTPolicy

        act = CommandBTPolicy(task, bt).act
    else:
        act = BTPolicy(task, bt).act
    result = rollout(task, act, final_seeds(episodes))
    returns = np.asarray(result.returns, dtype=float)
    return {"nodes": bt.node_count, "mean_return": float(returns.mean()),
            "std_return": float(result.std), "share_200": float(np.mean(returns >= SOLVED))}


def _check_headline(rows: list[Row], data_dir: Path, episodes: int | None) -> Iterator[Check]:
    """Replay each BT once and check its rows; ``episodes`` (smoke) replays that many only."""
    bts = _headline_bts(data_dir).set_index("name")
    by_bt: dict[str, list[Row]] = {}
    for row in rows:
        by_bt.setdefault(row.id.split(".")[1], []).append(row)
    for name, bt_rows in by_bt.items():
        if name not in bts.index:
            for row in bt_rows:
                yield Check(row, "absent from data/results/headline.csv", False, row.tolerance)
            continue
        bt = bts.loc[name]
        n = int(bt.episodes) if episodes is None else episodes
        counted_only = all(row.id.endswith(".nodes") for row in bt_rows)
        stats = _replay(bt.json_file, bt.task, 0 if counted_only else n)
        if not counted_only:
            stats["retention_norm"] = float(100.0 * (stats["mean_return"] - bt.random_return)
                                            / (bt.expert_return - bt.random_return))
        for row in bt_rows:
            stat = row.id.rsplit(".", 1)[1]
            now = stats[stat]
            tolerance = row.tolerance
            if episodes is not None and stat != "nodes":
                # few episodes: the mean and retention within SMOKE_Z standard errors of them
                if stat not in ("mean_return", "retention_norm"):
                    continue
                tolerance = row.tolerance * SMOKE_Z / Z * math.sqrt(int(bt.episodes) / n)
            yield Check(row, repr(now), abs(now - float(row.value)) <= tolerance + 1e-9,
                        tolerance)


def _check_verdicts(rows: list[Row], data_dir: Path) -> Iterator[Check]:
    if not rows:
        return
    now = {r.id: r.value for r in verdict_rows(data_dir, {row.id.split(".")[1] for row in rows})}
    for row in rows:
        value = now.get(row.id)
        if value is None:
            yield Check(row, "no such number now (regenerate: python -m ibt.check_claims --write)",
                        False, row.tolerance)
        else:
            yield Check(row, value, value == row.value, row.tolerance)


def smoke_rows(rows: list[Row]) -> list[Row]:
    """A few rows: the cheapest headline BT (fewest nodes) and the first claim's rows."""
    headline = [r for r in rows if r.source == "headline"]
    verdicts = [r for r in rows if r.source == "verdict"]
    smallest = min(headline, key=lambda r: int(r.value) if r.id.endswith(".nodes") else 10**9)
    bt = smallest.id.split(".")[1]
    first = verdicts[0].id if verdicts else ""
    return ([r for r in headline if r.id.split(".")[1] == bt]
            + [r for r in verdicts if r.id == first or r.id.startswith(first + ".")])


def check_rows(rows: list[Row], data_dir: Path = DATA_DIR, *, smoke: bool = False) -> list[Check]:
    """Recompute ``rows``: headline BTs replayed, verdicts from the committed CSVs."""
    unknown = [r.id for r in rows if r.source not in ("headline", "verdict")]
    if unknown:
        raise ValueError(f"rows of an unknown source: {', '.join(unknown[:5])}; the sources are "
                         "headline and verdict")
    episodes = SMOKE_EPISODES if smoke else None
    checks = list(_check_headline([r for r in rows if r.source == "headline"], data_dir,
                                  episodes))
    checks += _check_verdicts([r for r in rows if r.source == "verdict"], data_dir)
    return checks


def _line(check: Check) -> str:
    row = check.row
    if check.ok:
        now = "" if check.now == row.value else f" (now {check.now})"
        return f"OK    {row.id} = {row.value}{now}"
    try:
        diff = f" (difference {float(check.now) - float(row.value):+.6g}, " \
               f"tolerance {check.tolerance:.6g})"
    except ValueError:
        diff = ""
    return (f"DIFF  {row.id}: the table says {row.value}, now {check.now}{diff}\n"
            f"      row: {row.what} | {row.interval} | {row.artifact} | {row.command}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ibt.check_claims",
        description="Check every number of the headline and the verdicts against the claims "
                    "table: OK, or the difference and the row (exit 1).")
    parser.add_argument("--claims", type=Path, default=CLAIMS_FILE,
                        help="the claims table (default: paper/claims.csv)")
    parser.add_argument("--smoke", action="store_true",
                        help=f"a few rows, {SMOKE_EPISODES} episodes per replay (seconds)")
    parser.add_argument("--only", action="append", default=[], metavar="ID",
                        help="check only this row, or every row whose id starts with ID.; "
                             "repeatable")
    parser.add_argument("--write", action="store_true",
                        help="write the claims table from the committed results instead")
    args = parser.parse_args(argv)
    if args.write:
        table = write_claims(args.claims)
        print(f"wrote {len(table)} rows to {args.claims}")
        return 0
    try:
        rows = read_claims(args.claims)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.smoke:
        rows = smoke_rows(rows)
    if args.only:
        rows = [r for r in rows if any(r.id == o or r.id.startswith(o + ".") for o in args.only)]
        if not rows:
            print(f"error: no row of {args.claims} has the id {', '.join(args.only)}; the ids "
                  "are its first column", file=sys.stderr)
            return 2
    try:
        checks = check_rows(rows, smoke=args.smoke)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for check in checks:
        print(_line(check))
    bad = [c for c in checks if not c.ok]
    print(f"{len(checks) - len(bad)} of {len(checks)} rows OK"
          + (f"; {len(bad)} differ: {', '.join(c.row.id for c in bad)}" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
