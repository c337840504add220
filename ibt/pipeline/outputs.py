"""The files of ``python -m ibt pipeline`` (:func:`write_outputs`): the recommended BT
(``bt.json``, ``bt.xml``, ``bt.png``, ``bt.svg``), the BT that agrees most with the agent
(``faithful_bt.json``, ``faithful_bt.xml``), ``front.png``, ``episode.gif`` (the recommended
BT acting, where the task renders frames), ``plan.json`` (the steps the run took,
:mod:`ibt.engine.plan`) and ``report.md``, written as one set into a folder the pipeline owns
(:mod:`ibt.pipeline.owned_folder`)."""

from __future__ import annotations

import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ibt.pipeline.owned_folder import OwnedFolder, claim, write_set
from ibt.pipeline.recommend import Recommendation

#: the set a run writes; report.md last (it says what the others are)
OUTPUTS = ("bt.json", "bt.xml", "bt.png", "bt.svg", "faithful_bt.json", "faithful_bt.xml",
           "front.png", "episode.gif", "plan.json", "report.md")
#: files a run may leave out (said in the report); an earlier run's copy is then removed
OPTIONAL = ("episode.gif",)
GIF_FRAMES = 300  #: episode.gif: at most this many frames (a longer episode is subsampled)
SMOKE_GIF_STEPS = 20  #: episode.gif under ``--budget smoke``: the episode's first steps only


# ---------------------------------------------------------------------------- the BT as rules
def _guard(bt: Any, node: Any) -> str | None:
    """A condition-only subtree as a boolean expression (None: it acts)."""
    from ibt.bt.model import Condition, Fallback, Inverter, Sequence

    if isinstance(node, Condition):
        return bt.label(node, precision=6)
    if isinstance(node, Inverter):
        inner = _guard(bt, node.child)
        return None if inner is None else f"not ({inner})"
    if isinstance(node, Sequence | Fallback):
        parts = [_guard(bt, c) for c in node.children]
        if any(p is None for p in parts):
            return None
        joiner = " and " if isinstance(node, Sequence) else " or "
        return parts[0] if len(parts) == 1 else "(" + joiner.join(parts) + ")"  # type: ignore
    return None


def _rules(bt: Any, node: Any, guards: tuple[str, ...]) -> list[tuple[tuple[str, ...], str]] | None:
    """First-match rules (guards, action) of an acting subtree; None for shapes without them."""
    from ibt.bt.model import Action, Fallback, Sequence

    if isinstance(node, Action):
        return [(guards, bt.action_names[node.action])]
    if isinstance(node, Fallback):
        out: list[tuple[tuple[str, ...], str]] = []
        for child in node.children:
            rules = _rules(bt, child, guards)
            if rules is None:
                return None
            out += rules
        return out
    if isinstance(node, Sequence) and node.children:
        *conditions, last = node.children
        texts = [_guard(bt, c) for c in conditions]
        if any(t is None for t in texts):
            return None
        return _rules(bt, last, guards + tuple(texts))  # type: ignore[arg-type]
    return None


def rules_text(bt: Any) -> str:
    """The BT as an ordered list of rules (the first that holds decides), or as an indented
    outline when its shape has no such reading."""
    rules = _rules(bt, bt.root, ())
    if rules is not None:
        lines = []
        for i, (guards, action) in enumerate(rules, 1):
            when = " and ".join(guards) if guards else "otherwise"
            lines.append(f"{i}. {'if ' + when + ': ' if guards else 'otherwise: '}{action}")
        return "\n".join(lines)

    def outline(node: Any, depth: int) -> list[str]:
        lines = ["  " * depth + bt.label(node, precision=6)]
        for child in getattr(node, "children", ()):
            lines += outline(child, depth + 1)
        return lines

    return "\n".join(outline(bt.root, 0))


# ---------------------------------------------------------------------------------- front
def draw_front(rec: Recommendation, path: Path) -> None:
    """Retention against BT nodes, every candidate, the target and the recommendation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ibt.files import atomic_target

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    markers = dict((("distilled", "o"), ("refined", "s"), ("searched", "*"), ("polished", "X"),
                    ("distilled, relational", "^"), ("refined, relational", "D"),
                    ("searched, relational", "P"), ("polished, relational", "p")))
    labels = list(dict.fromkeys([*markers, *(c.label for c in rec.candidates)]))
    spare = iter("v<>hH8d1234")  # every other learner's stages (oblique, controller, a user's)
    for stage in labels:
        marker = markers.get(stage) or next(spare, "o")
        points = [c for c in rec.candidates if c.label == stage]
        if not points:
            continue
        ax.scatter([c.bt_nodes for c in points], [c.retention for c in points], marker=marker,
                   label=f"{stage} (leaf limits {', '.join(str(c.leaf_limit) for c in points)})",
                   alpha=0.8)
    ax.axhline(100 * rec.keep, color="grey", linestyle="--", linewidth=1,
               label=f"target: {100 * rec.keep:.0f} % of the agent")
    ax.scatter([rec.chosen.bt_nodes], [rec.chosen.retention], s=220, facecolors="none",
               edgecolors="crimson", linewidths=2, label="recommended")
    ax.set_xscale("log")
    # plain ticks (10, 20, 30, 60), not 10^1, 2x10^1: round numbers inside the axis' range
    from matplotlib.ticker import FixedLocator, NullFormatter, StrMethodFormatter

    low, high = ax.get_xlim()
    ticks = [m * 10**e for e in range(0, 6) for m in (1, 2, 3, 5) if low <= m * 10**e <= high]
    if len(ticks) < 3:  # a narrow range: whole numbers spread over it
        ticks = sorted({*ticks, *(round(low * (high / low) ** (k / 4)) for k in (1, 2, 3))})
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(StrMethodFormatter("{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("BT nodes (smallest verified BT of each tree)")
    ax.set_ylabel("retention, % (0 random, 100 agent)")
    ax.set_title(f"{rec.task.name}, {rec.algo} agent: choice episodes", fontsize=10)
    ax.legend(fontsize=8, loc="best")  # the corner that hides the fewest candidates
    fig.tight_layout()
    with atomic_target(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


# --------------------------------------------------------------------------------- report
def _interval(returns: list[float]) -> str:
    from ibt.report.stats import bootstrap_ci, interval_label

    low, high = bootstrap_ci(returns)
    return f"[{low:.2f}, {high:.2f}] ({interval_label('ci', len(returns), 'episode')})"


def rerun(rec: Recommendation, out: Path, *, plan: bool = False) -> str:
    """The run's command again: under the clock (its ``--time``, a replay's ``--plan``
    dropped), or with ``plan`` replaying the plan it wrote (its ``--time`` dropped)."""
    task = rec.task.name
    if rec.argv:
        argv = _without(rec.argv, "--plan")
        argv = _without(argv, "--time") if plan else argv
    else:
        argv = ["pipeline", task, rec.algo, "--checkpoint", str(rec.checkpoint), "-o", str(out),
                "--keep", str(rec.keep), "--budget", rec.budget.text, "--seed", str(rec.seed)]
    return "python -m ibt " + shlex.join([*argv, *(["--plan", str(out / "plan.json")]
                                                    if plan else [])])


def _without(argv: list[str], option: str) -> list[str]:
    """``argv`` without ``option`` and its value (``--time 5m``, ``--time=5m``, or an
    abbreviation argparse takes, ``--ti 5m``)."""
    kept: list[str] = []
    skip = False
    for arg in argv:
        name = arg.split("=", 1)[0]
        if skip:
            skip = False
        elif arg.startswith("--") and len(name) > 2 and option.startswith(name):
            skip = "=" not in arg
        else:
            kept.append(arg)
    return kept


def commands(rec: Recommendation, out: Path) -> list[str]:
    """Commands that reproduce the run (its plan replayed, then the ladder anytime) and check
    its BT."""
    task, q = rec.task.name, shlex.quote
    env = list(dict.fromkeys([*rec.env_modules, *filter(None, [rec.task.setup_module])]))
    module = "".join(f" --env-module {q(m)}" for m in env)
    bt = q(str(out / "bt.json"))
    return [rerun(rec, out, plan=True) + "  # the same steps, whatever the time",
            rerun(rec, out) + "  # rerun anytime: the steps the time allows",
            f"python -m ibt evaluate {bt} --task {task}{module} --episodes {rec.episodes}"
            "  # the choice episodes",
            f"python -m ibt run-btcpp {q(str(out / 'bt.xml'))} --task {task}{module}"]


def plan_document(rec: Recommendation) -> dict[str, Any]:
    """``plan.json``: the steps the run took and where it stopped (:mod:`ibt.engine.plan`)."""
    from ibt.engine.plan import document, made_for

    settings = {"keep": rec.keep, "budget": rec.budget.text, "leaves": list(rec.leaf_limits),
                "seed": rec.seed, "restarts": rec.restarts, "episodes": rec.episodes,
                "max_nodes": rec.max_nodes}
    return document(made_for(rec.task.name, rec.algo, rec.checkpoint_sha256, settings),
                    rec.ladder.plan)


def reproduce_text(rec: Recommendation, out: Path) -> list[str]:
    """The report's ``## Reproduce`` section: what the run was given, its plan, the commands."""
    from ibt.engine.plan import summary

    replayed = (f"This run replayed the plan `{rec.replayed}` (`--plan`: no time budget). "
                if rec.replayed else "")
    return [
        "## Reproduce", "",
        f"{'Agent' if rec.algo == 'callable' else 'Checkpoint'} `{rec.checkpoint}` "
        f"(SHA-256 prefix {rec.checkpoint_sha256}), seed "
        f"{rec.seed}, budget {rec.budget.text}, leaf limits "
        f"{', '.join(map(str, rec.leaf_limits))}.", "",
        f"{replayed}The steps a run takes under `--time` depend on the clock (the machine's "
        f"speed and load); `plan.json` records those this run took, in order, and where it "
        f"stopped: {summary(rec.ladder.plan)}. Replayed with `--plan` (the first command), "
        "every step of the plan runs and nothing else, whatever the time or the number of "
        "`--jobs`: the same files on any machine (each step is cached, so here it repeats "
        "nothing). The second command climbs the ladder again under the clock, as far as the "
        "time allows.", "",
        *fenced("\n".join(commands(rec, out)), "bash"), ""]


def next_step(rec: Recommendation) -> str:
    """What to try when the target was missed."""
    best = rec.chosen
    if rec.agent.mean - rec.random.mean <= 1e-9:
        return ("the agent does no better than the random policy on these episodes: train it "
                "further before distilling it")
    if best.leaf_limit == max(rec.leaf_limits):
        bigger = ",".join(str(v) for v in (*rec.leaf_limits, 2 * max(rec.leaf_limits),
                                           4 * max(rec.leaf_limits)))
        return (f"the best tree is at the largest leaf limit ({best.leaf_limit}): allow larger "
                f"trees with `--leaves {bigger}`, and raise the budget (`--budget 4x`)")
    return ("raise the budget (`--budget 4x`: more expert labels and refinement episodes); if "
            "that does not help, the agent may need features a small axis-aligned tree cannot "
            "read (add them to your environment's observation)")


def ladder_text(rec: Recommendation) -> list[str]:
    """How the ladder went: a stop's mark, the steps done and left, and each search's choice
    among its restarts."""
    ladder = rec.ladder
    budget = f" of {rec.time_limit:.0f}" if rec.time_limit is not None else ""  # a replay's
    lines = ["## How the search went", ""]
    if ladder.stopped:
        how = (f"{rec.time_stop}, so it stopped" if ladder.stopped == "time" else
               {"interrupted": "Ctrl-C stopped it", "terminated": "SIGTERM stopped it"}.get(
                   ladder.stopped, ladder.stopped))
        lines += [f"**Stopped early**: {how} after "
                  f"{rec.elapsed:.0f}{budget} s; this report covers the {len(ladder.steps)} "
                  "steps done (the recommendation is the best BT among them, confirmed as "
                  f"below). Left undone: {', '.join(ladder.skipped) or 'nothing'}. Where a "
                  "run stops depends on the machine's speed; a rerun with a longer `--time` "
                  "resumes from the cache and, once the ladder finishes, gives the same "
                  "files.", ""]
    else:
        how_far = ("replayed its plan, every step in order (no time budget)"
                   if getattr(rec, "replayed", None) else "finished within its time budget")
        lines += [f"The ladder {how_far}: trees distilled at each leaf "
                  "limit, smallest first (axis-aligned, then relational), up to the first limit "
                  "whose best BT kept the target; the structure search by return below it (at "
                  "every limit when none kept the target) in the order of a binary search for "
                  "the smallest limit whose searched BT keeps it; then, where no smaller limit "
                  "kept it, the trees that kept it refined by return. A Box task's trees are "
                  "distilled then refined at each limit instead.", ""]
    lines += [f"Steps done: {', '.join(ladder.steps)}.", ""]
    if any(step.startswith("polish again") for step in ladder.steps):
        lines += ["With time left over, the searched BT nearest the target among those smaller "
                  "than every BT that kept it was polished again, one seed a core at twice the "
                  "search's polish episodes, and kept where that beat it on the search's own "
                  "choice episodes (the notes give the means).", ""]
    for c in rec.candidates:
        if c.search is not None:
            means = ", ".join(f"seed {s}: {m:.2f}" for s, m in zip(c.search.seeds,
                                                                  c.search.choice_means,
                                                                  strict=True))
            polished = ", ".join(f"seed {s}: {m:.2f}" for s, m in zip(
                c.search.polished, c.search.polished_means, strict=True))
            lines += [f"Search at leaf limit {c.leaf_limit} ({c.label}): {len(c.search.seeds)} "
                      f"restarts chosen among on {c.search.choice_episodes} held-out episodes "
                      f"of their own ({means}); the best {len(c.search.polished)} polished "
                      f"scored ({polished}) there; seed {c.search.seeds[c.search.chosen]} won.",
                      ""]
    lines += [f"Note: {note}." for note in ladder.notes]
    if rec.max_nodes is not None:
        lines += [f"Only BTs of at most {rec.max_nodes} nodes could be recommended "
                  "(`--max-nodes`)."]
    return [*lines, ""] if lines[-1] else lines


def beyond_the_agent(rec: Recommendation) -> list[str]:
    """Report lines flagging every retention above 100 % by more than its noise (two standard
    errors), on the confirmation episodes and on the choice episodes, and a retention that is
    undefined (the agent's mean return is the random policy's): such numbers must not be read
    as a plain share of the agent."""
    import math

    from ibt.evaluate.rollouts import retention_margin

    n, agent_std = rec.episodes, rec.agent.std
    if math.isnan(rec.retention):
        return [f"**Retention undefined**: on the confirmation episodes the agent's mean return "
                f"({rec.agent.mean:.2f}) is the random policy's ({rec.random.mean:.2f}), so a "
                "share of their difference means nothing: the agent does no better than the "
                "random policy; train it further before distilling it.", ""]
    flagged = []
    margin = retention_margin(rec.bt.std, agent_std, n, rec.agent.mean, rec.random.mean)
    if rec.retention > 100 + margin:
        flagged.append(f"the recommended BT on the confirmation episodes, {rec.retention:.1f} % "
                       f"(noise +- {margin:.1f})")
    for c in rec.candidates:
        margin = retention_margin(c.std_return, agent_std, n, rec.agent_choice,
                                  rec.random_choice)
        if c.retention > 100 + margin:
            flagged.append(f"the {c.label} tree at leaf limit {c.leaf_limit} on the choice "
                           f"episodes, {c.retention:.1f} % (noise +- {margin:.1f})")
    if not flagged:
        return []
    return [f"**Above the agent beyond noise** (two standard errors of the difference): "
            f"{'; '.join(flagged)}. These BTs return more than the agent on these episodes: the "
            "agent is not optimal there (a small tree can undo its mistakes) or its returns are "
            "noisy; read such a retention as 'at least as good as the agent', and check it on "
            "more `--episodes`.", ""]


# ---------------------------------------------------------------------------- episode.gif
#: draws ``episode.gif`` of a recommendation at a path: the frames written and None, or 0 and a
#: one-line note of why not (the views layer's :func:`ibt.views.headline.pipeline_episode`)
EpisodeDrawer = Callable[[Recommendation, Path], tuple[int, str | None]]


def gif_text(rec: Recommendation, frames: int, note: str | None) -> list[str]:
    """The report's lines on ``episode.gif`` (``frames`` of them), or on why there is none."""
    if note is not None:
        return [f"Note: {note}.", ""]
    from ibt.evaluate.rollouts import final_seeds

    smoke = f" (its first {SMOKE_GIF_STEPS} steps under the smoke budget)" if (
        rec.budget.smoke) else ""
    return ["![the recommended BT acting](episode.gif)", "",
            f"`episode.gif`: the recommended BT acting on the first choice episode (seed "
            f"{final_seeds(1)[0]}){smoke}, in {frames} frames (at most {GIF_FRAMES}: a longer "
            "episode is subsampled), each beside the tick that decided its action.", ""]


# --------------------------------------------------------------------------------- agreement
def _share(value: float | None) -> str:
    return "not measured" if value is None else f"{value:.3f}"


def agreement_text(rec: Recommendation) -> list[str]:
    """The report's section on the BTs' agreement with the agent and the most faithful BT."""
    a = rec.agreement
    if a is None:
        return []
    how = ("the BT's action is the agent's" if a.tolerance is None else
           f"every dimension of the BT's command is within {100 * a.tolerance:.0f} % of its "
           "range of the agent's action (both clipped to the action box)")
    f, c = rec.faithful, rec.chosen
    same = (" It is the recommended BT." if f.bt.to_json() == c.bt.to_json() else
            f" The recommended BT agrees on {_share(rec.agreement_of(c))}: a BT may keep the "
            "agent's return while acting otherwise where it matters little.")
    return [
        "## Agreement with the agent", "",
        f"Agreement is the share of the {a.states:,} states the agent visited on the first "
        f"{a.episodes} confirmation episodes where {how}; the uniform random policy agrees on "
        f"{_share(a.random)} of them. The candidates' agreements are in the front's table.", "",
        f"Most faithful: the **{f.bt_nodes}-node BT** ({f.bt_method}) of the {f.label} tree "
        f"at leaf limit {f.leaf_limit}, agreement **{_share(rec.agreement_of(f))}**, mean "
        f"return {f.mean_return:.2f} ({f.retention:.1f} % of the agent) on the choice "
        f"episodes, in `faithful_bt.json` and `faithful_bt.xml`; it is chosen among every "
        f"verified BT of the front (highest agreement, then fewest nodes).{same}", ""]


def report_text(rec: Recommendation, out: Path, gif: tuple[int, str | None]) -> str:
    """``report.md``; ``gif``: the frames of ``episode.gif``, or 0 and why it was not written
    (an :data:`EpisodeDrawer`)."""
    frames, gif_note = gif
    c, keep = rec.chosen, 100 * rec.keep
    if rec.met:
        verdict = (f"**Target met**: the recommended BT keeps {rec.retention:.1f} % of the agent "
                   f"(target {keep:.0f} %).")
    elif rec.met_on_choice:
        verdict = (f"**Target missed**: the smallest BT that kept {keep:.0f} % of the agent on "
                   f"the choice episodes ({c.retention:.1f} %) keeps {rec.retention:.1f} % on the "
                   f"confirmation episodes. Next: {next_step(rec)}.")
    else:
        verdict = (f"**Target missed**: no BT kept {keep:.0f} % of the agent on the choice "
                   f"episodes; the best one ({c.retention:.1f} % there) keeps "
                   f"{rec.retention:.1f} % on the confirmation episodes. Next: "
                   f"{next_step(rec)}.")
    rows = ["| leaf limit | stage | leaves | BT nodes | relational tests | smallest BT by | "
            "mean return | retention % | agreement |", "|---|---|---|---|---|---|---|---|---|"]
    faithful = rec.faithful if rec.agreement is not None else None
    for cand in rec.candidates:
        marks = [m for m, which in (("recommended", c), ("most faithful", faithful))
                 if cand is which]
        mark = f" **({', '.join(marks)})**" if marks else ""
        rows.append(f"| {cand.leaf_limit} | {cand.label}{mark} | {cand.leaves} | "
                    f"{cand.bt_nodes} | {cand.relational_tests} | {cand.bt_method} | "
                    f"{cand.mean_return:.2f} | {cand.retention:.1f} | "
                    f"{_share(rec.agreement_of(cand))} |")
    returns = ["| policy | mean return | interval of the mean | agreement with the agent |",
               "|---|---|---|---|"]
    agreeing = {"agent": "1 (itself)", "recommended BT": _share(rec.agreement_of(c)),
                "random": _share(rec.agreement.random if rec.agreement else None)}
    for name, r in (("agent", rec.agent), ("recommended BT", rec.bt), ("random", rec.random)):
        returns.append(f"| {name} | {r.mean:.2f} | {_interval(r.returns)} | {agreeing[name]} |")
    sizes = ", ".join(f"{m} {bt.node_count}" for m, bt in c.bts.items())
    cache = (rec.cache_dir.relative_to(out) if rec.cache_dir and rec.cache_dir.is_relative_to(out)
             else rec.cache_dir)
    lines = [
        f"# A behavior tree for {rec.task.name}'s {rec.algo} agent", "",
        *([stopped_note(rec), ""] if rec.stopped else []),
        verdict, "",
        f"Recommended: a **{c.bt_nodes}-node BT** ({c.bt_method}) of the {c.label} tree at "
        f"leaf limit {c.leaf_limit} ({c.leaves} leaves); every synthesiser's BT of that tree, "
        f"each verified to decide exactly as it does: {sizes} nodes.", "",
        "## Returns on the confirmation episodes", "",
        f"{rec.episodes} held-out episodes (seeds {rec.bt.first_seed} to "
        f"{rec.bt.first_seed + rec.episodes - 1}), never used to distil, refine or choose. "
        f"Retention is random-normalised: 0 % is the uniform random policy, 100 % the agent, "
        f"both measured here on the same episodes.", "",
        *returns, "",
        f"Retention: **{rec.retention:.1f} %** (target {keep:.0f} %).", "",
        *beyond_the_agent(rec),
        "## The front (choice episodes)", "",
        f"Every candidate on {rec.episodes} other held-out episodes (seeds "
        f"{rec.bt.first_seed - rec.episodes} to {rec.bt.first_seed - 1}; agent "
        f"{rec.agent_choice:.2f}, random {rec.random_choice:.2f}); the recommendation is the "
        f"smallest BT at or above the target there, or the best one when none is. "
        "Distilled trees come from Imitation-BT's interactive loop at each leaf limit; refined "
        "ones from refinement by return (thresholds, leaf actions, pruning) on other episodes; "
        "searched ones from the structure search by return (splits, features, thresholds and "
        "leaves evolved under the leaf limit from the trees distilled at that limit and at "
        "the largest limit distilled, relational ones included, helped by the agent's "
        "labels), then polished; *polished* ones, made with time left over, from the "
        "searched BT nearest the target among those smaller than every BT that kept it, "
        "polished again (kept where that beat it on the search's own choice episodes). "
        "*Relational* trees come from the same loop with a learner whose splits may test "
        "`w1 * x_i + w2 * x_j` where that beats every single-feature split by a margin; one "
        "is recommended only where its BT is smaller than every single-feature one that keeps "
        "the target. *Oblique* trees (discrete actions) test up to four features at once, "
        "`w1 * x1 + ... + w4 * x4 > t`; *controller* trees (continuous actions) also send "
        "commands linear in up to four features; both lay out one rule per leaf, are refined "
        "by return (thresholds, weights, biases), and their BT is checked to send exactly "
        "their tree's decisions.",
        "", *rows, "", "![front](front.png)", "", *agreement_text(rec), *ladder_text(rec),
        "## The BT as rules (the first rule that holds decides)", "",
        *fenced(rules_text(c.bt)), "", "![the BT](bt.png)", "", *gif_text(rec, frames, gif_note),
        "## Files", "",
        "`bt.json` (this package's BT format), `bt.xml` (BehaviorTree.CPP v4, portable "
        "flavour), `bt.png`/`bt.svg` (drawing), `faithful_bt.json`/`faithful_bt.xml` (the "
        "BT that agrees most with the agent), `front.png`, "
        f"{'`episode.gif` (the recommended BT acting), ' if gif_note is None else ''}"
        f"`plan.json` (the steps this run took), this report; `{cache}` holds every step, so a "
        "rerun with a larger budget repeats only what changed.", "",
        *reproduce_text(rec, out)]
    return "\n".join(lines)


def fenced(text: str, info: str = "") -> list[str]:
    """``text`` as a Markdown code block whose fence is longer than any run of backticks in it
    (a name holding three backticks cannot end the block early)."""
    import re

    longest = max((len(run) for run in re.findall(r"`+", text)), default=0)
    fence = "`" * max(3, longest + 1)
    return [fence + info, text, fence]


def stopped_note(rec: Recommendation) -> str:
    """The line under the report's title when the run stopped before its last step."""
    stopped = rec.stopped or ""
    why = {"time": rec.time_stop, "interrupted": "Ctrl-C",
           "terminated": "SIGTERM"}.get(stopped, stopped)
    return (f"> **Stopped early** ({why}): this is the best recommendation found before the "
            "run stopped (see *How the search went*); rerun the same command, with a longer "
            "`--time` where the budget ran out, to continue: every finished step is cached.")


def incomplete_text(rec: Recommendation, out: Path) -> str:
    """``report.md`` for the milliseconds its set is renamed into place: what to do if a crash
    leaves it there."""
    return (f"# Incomplete: {out} was being rewritten\n\n`python -m ibt pipeline` stopped while "
            "it renamed its new files into place, so this folder may mix files of two runs. "
            "Rerun it (every finished step is cached):\n\n"
            + "\n".join(fenced(rerun(rec, out), "bash")) + "\n")


def write_outputs(rec: Recommendation, out: str | Path | OwnedFolder,
                  draw_episode: EpisodeDrawer | None = None) -> list[Path]:
    """Write :data:`OUTPUTS` (those of :data:`OPTIONAL` where made) into ``out`` as one set
    (:func:`ibt.pipeline.owned_folder.write_set`: an interrupted write leaves the old set, the
    new one, or a ``report.md`` saying the set is incomplete); a run stopped early says so
    under the report's title. ``draw_episode`` draws ``episode.gif`` (the command line passes
    :func:`ibt.views.headline.pipeline_episode`: drawings are the views layer's); without it
    the report says there is none.

    ``out`` is a folder checked by :func:`ibt.pipeline.owned_folder.claim` (the CLI claims it
    before any work), or a path, claimed here (:class:`FolderError` if it holds files the
    pipeline did not write)."""
    from ibt.bt.json_io import save_json
    from ibt.engine.plan import dumps
    from ibt.export.btcpp import to_btcpp_xml
    from ibt.export.pictures import draw_bt
    from ibt.files import atomic_write_text

    folder = out if isinstance(out, OwnedFolder) else claim(
        out, OUTPUTS, cache=rec.cache_dir)
    path = folder.path

    def write(tmp: Path) -> None:
        bt, faithful = rec.chosen.bt, rec.faithful.bt
        save_json(bt, tmp / "bt.json")
        atomic_write_text(tmp / "bt.xml", to_btcpp_xml(bt))
        save_json(faithful, tmp / "faithful_bt.json")
        atomic_write_text(tmp / "faithful_bt.xml", to_btcpp_xml(faithful))
        draw_bt(bt, tmp / "bt", title=f"{rec.task.name}: {bt.node_count}-node BT")
        draw_front(rec, tmp / "front.png")
        gif = (draw_episode(rec, tmp / "episode.gif") if draw_episode is not None
               else (0, "no `episode.gif`: this run drew none"))
        atomic_write_text(tmp / "plan.json", dumps(plan_document(rec)))
        atomic_write_text(tmp / "report.md", report_text(rec, path, gif))

    return write_set(folder, OUTPUTS, write, incomplete_text(rec, path), optional=OPTIONAL)
