"""The headline BTs, as files a reader opens: chosen from the committed results, never rerun.

For every task with a published small policy to compare with (:data:`ibt.runs.front.ANCHORS`,
:data:`ibt.runs.continuous.ANCHORS`) or a continuous target (:data:`ibt.runs.continuous.TARGETS`),
two BTs are picked from the committed result tables (``data/results/``):

* the **smallest BT that keeps >= 95 %** of its agent (random-normalised retention; ties: the
  higher mean return); where no run reaches 95 %, the run that keeps the most, said so;
* the **best BT at the best published tree's size**: the highest mean return among the BTs
  whose tree has at most as many leaves as the task's best published tree.

Each task's runs are read on its 1,000-episode evaluations (the anchors' protocol) where the
project has them, on its 100 final episodes otherwise; the ``episodes`` column says which. The
BT itself is read back from the cache (``data/cache``: the run that made the row, then its
smallest verified BT), and written under ``figures/headline/<name>/`` as ``bt.json``, ``bt.xml``
(BehaviorTree.CPP), ``bt.png`` and ``bt.svg`` (the drawing) and ``episode.gif`` (the BT driving
the first final episode); the table is ``data/results/headline.csv``. Under the ``smoke`` profile
one small task is written, to the profile's scratch folders, from the committed cache.

This module sits in :mod:`ibt.views` (it films the BTs); it reads :mod:`ibt.runs` cache entries
and never computes one: every row it picks was computed by notebooks 07 and 10.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ibt.bt.executors import tick
from ibt.bt.model import BehaviorTree
from ibt.evaluate.rollouts import final_seeds, retention_norm
from ibt.paths import DATA_DIR
from ibt.profiles import Config
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import Clip
from ibt.tasks.task import Task, sdl_video_driver
from ibt.views.animate import COLORS, PALETTE_FRAMES, Film, Step

KEEP = 95.0  #: % random-normalised retention the smallest BT must keep
SMALLEST, AT_PUBLISHED = "smallest >= 95 %", "best at the published size"
CLOSEST = "closest to 95 % (none reaches it)"
DEFAULT_CLIP = Clip(200, 4, 110)  #: a task without a clip of its own (the continuous ones)
SMOKE_TASKS = ("MountainCar-v0",)


def anchors() -> pd.DataFrame:
    """Every published small policy (source, task, leaves, mean_return), both tables."""
    from ibt.runs import continuous, front

    rows = [{"source": a.source, "task": a.task, "leaves": a.leaves, "nodes": a.nodes,
             "mean_return": a.mean_return} for a in front.ANCHORS if a.leaves is not None]
    rows += [{"source": s, "task": t, "leaves": n, "nodes": 2 * n - 1, "mean_return": r}
             for s, t, n, r in continuous.ANCHORS]
    return pd.DataFrame(rows)


def headline_tasks() -> list[str]:
    """Tasks with a published anchor or a continuous target, in a stable order."""
    from ibt.runs import continuous

    names = [*anchors()["task"], *(t for t, _, _ in continuous.TARGETS)]
    return list(dict.fromkeys(names))


def candidates(results: Path) -> pd.DataFrame:
    """One row per committed run with a BT: its size, its evaluation and how to find it."""
    front = pd.read_csv(results / "front.csv")
    front = front.assign(episodes=100, share_200=np.nan, leaf_limit=front.max_leaf_nodes,
                         source="front.csv")
    agents = front.drop_duplicates(["task", "expert"])[["task", "expert", "expert_return",
                                                        "random_return"]]
    protocol = pd.read_csv(results / "front_protocol.csv").merge(agents, on=["task", "expert"])
    protocol = protocol.assign(method="imitation-bt+s", leaf_limit=protocol.max_leaf_nodes,
                               share_200=protocol.share_at_threshold,
                               source="front_protocol.csv")
    searched = pd.read_csv(results / "relational_search.csv").merge(agents,
                                                                    on=["task", "expert"])
    searched = searched.assign(episodes=searched.protocol_episodes,
                               mean_return=searched.protocol_mean_return,
                               std_return=searched.protocol_std_return,
                               share_200=searched.share_at_threshold,
                               leaf_limit=searched.max_leaf_nodes,
                               source="relational_search.csv")
    box = []
    for name in ("continuous.csv", "continuous_protocol.csv"):
        if (results / name).exists():
            part = pd.read_csv(results / name)
            box.append(part.assign(expert=part.algo, tree_leaves=part.leaves, source=name,
                                   method=part.method.where(~part.refined,
                                                            part.method + ", refined")))
    table = pd.concat([front, protocol, searched, *box], ignore_index=True)
    table["retention_norm"] = retention_norm(table.mean_return, table.expert_return,
                                             table.random_return)
    # the share of episodes >= 200 is LunarLander's "solved" landing; elsewhere it means nothing
    table.loc[~table.task.str.startswith("LunarLander"), "share_200"] = np.nan
    return table


def select(table: pd.DataFrame, tasks: list[str], published: pd.DataFrame) -> pd.DataFrame:
    """The two headline rows of each task (see the module's docstring)."""
    rows = []
    for task in tasks:
        runs = table[table.task == task]
        if runs.empty:
            continue
        runs = runs[runs.episodes == runs.episodes.max()]  # 1,000 episodes where there are
        keeping = runs[runs.retention_norm >= KEEP]
        if keeping.empty:
            rows.append(runs.sort_values("retention_norm").iloc[-1:].assign(what=CLOSEST))
        else:
            rows.append(keeping.sort_values(["bt_nodes", "mean_return"],
                                            ascending=[True, False]).iloc[:1]
                        .assign(what=SMALLEST))
        anchor = published[published.task == task].sort_values("mean_return")
        if anchor.empty:
            continue
        best = anchor.iloc[-1]
        fits = runs[runs.tree_leaves <= best.leaves]
        if not fits.empty:
            rows.append(fits.sort_values(["mean_return", "bt_nodes"], ascending=[False, True])
                        .iloc[:1].assign(what=AT_PUBLISHED))
    picked = pd.concat(rows, ignore_index=True) if rows else table.iloc[:0].assign(what="")
    return picked.merge(_best_anchor(published), on="task", how="left")


def _best_anchor(published: pd.DataFrame) -> pd.DataFrame:
    best = published.sort_values("mean_return").groupby("task").tail(1)
    return best.rename(columns={"source": "anchor", "leaves": "anchor_leaves",
                                "nodes": "anchor_tree_nodes", "mean_return": "anchor_return"})


def paper_method(results: Path) -> pd.DataFrame:
    """The paper's method as reproduced here: Imitation-BT's mean BT nodes and retention per
    task and expert (``synthesis.csv``, 100 final episodes, mean over seeds)."""
    syn = pd.read_csv(results / "synthesis.csv")
    syn = syn[syn.method == "imitation-bt"]
    return (syn.groupby(["task", "expert"], as_index=False)
            .agg(paper_method_nodes=("nodes", "mean"),
                 paper_method_retention=("retention_norm", "mean")))


def headline_table(results: Path = DATA_DIR / "results", tasks: list[str] | None = None
                   ) -> pd.DataFrame:
    """The headline rows (no files): selection, anchors on each agent's scale, the paper."""
    from ibt.report.claims import PAPER_RULE_NODES

    published = anchors()
    picked = select(candidates(results), tasks or headline_tasks(), published)
    picked["anchor_retention"] = retention_norm(picked.anchor_return, picked.expert_return,
                                                picked.random_return)
    picked = picked.merge(paper_method(results), on=["task", "expert"], how="left")
    # the paper's own number, where it gives one: its MountainCar BT's node count
    picked["paper_bt_nodes"] = np.where(picked.task == "MountainCar-v0", PAPER_RULE_NODES,
                                        np.nan)
    picked["name"] = [_name(r) for r in picked.itertuples()]
    return picked


def _name(row: Any) -> str:
    """The run's folder name: one per BT, whichever headline rows it fills."""
    method = str(row.method).replace("+", "-plus-")
    episodes = "" if row.episodes == 100 else f"-e{int(row.episodes)}"
    name = f"{row.task}-{row.expert}-{method}-s{int(row.seed)}-L{int(row.leaf_limit)}{episodes}"
    return re.sub(r"-+", "-", re.sub(r"[^A-Za-z0-9_.-]+", "-", name))


def bt_of(cfg: Config, row: Any) -> BehaviorTree:
    """The BT of a picked row, read back from the cache entries its run wrote."""
    from ibt.runs import continuous, front, search
    from ibt.runs.relational_search import relational_search_run

    task = get_task(row.task)
    seed, limit = int(row.seed), int(row.leaf_limit)
    if str(row.source).startswith("continuous"):
        method, _, refined = str(row.method).partition(", ")
        return continuous.point_bt(cfg, continuous.BoxPoint(row.task, row.expert, method, seed,
                                                            limit, bool(refined)))
    if row.source == "relational_search.csv":
        plus = [int(n) for n in re.findall(r"Imitation-BT\+ at (\d+) leaves", row.seeded_with)]
        chosen = None if pd.isna(row.selection_episodes) else int(row.selection_episodes)
        tree = relational_search_run(
            cfg, task, row.expert, seed, limit, plus, int(row.search_budget),
            row.candidate_weights == "scaled to spreads", row.leaf_rule, chosen).tree
    elif row.method == front.STRUCTURE:
        tree = search.structure_run(cfg, task, row.expert, seed, limit).tree
    elif row.method == front.PLUS:
        tree = front.plus_run(cfg, task, row.expert, seed, limit).tree
    else:
        leaves = None if limit == task.budget.max_leaf_nodes else limit
        tree = front.source_run(cfg, task, row.expert, row.method, seed, leaves).best_tree
    return BehaviorTree.from_dict(front.bt_sizes(cfg, task, tree)["bt"])


def episode(task: Task, bt: BehaviorTree, seed: int, max_steps: int) -> Iterator[Step]:
    """:func:`ibt.views.animate.episode` for discrete and command BTs alike (a command BT's
    action is its command's vector)."""
    with sdl_video_driver(task.render_driver):
        env = task.make_env(render_mode="rgb_array")
        try:
            obs, _ = env.reset(seed=seed)
            total = 0.0
            for t in range(max_steps):
                features = task.features(np.asarray(obs)[None])[0]
                action, trace = tick(bt, features)
                yield Step(t, np.asarray(env.render()), features, action, tuple(trace), total)
                sent = (np.asarray(bt.commands.values[action], dtype=np.float32)
                        if bt.commands is not None else action)
                obs, reward, terminated, truncated, _ = env.step(sent)
                total += float(reward)
                if terminated or truncated:
                    return
        finally:
            env.close()


class _HeadlineFilm(Film):
    """The animation's frames, captioned with the headline BT's method and size."""

    def __init__(self, task: Task, bt: BehaviorTree, row: Any) -> None:
        super().__init__(task, bt, row.expert)
        self.label = f"{row.method} ({str(row.expert).upper()}, {bt.node_count} nodes)"

    def caption(self, step: Step) -> tuple[str, str]:
        _, line = super().caption(step)
        return (f"{self.task.name}, {self.label}: step {step.t}, return "
                f"{step.total_return:.1f}", line)


def write_gif(task: Task, bt: BehaviorTree, row: Any, target: Path, max_steps: int | None = None
              ) -> int:
    """One final episode of ``bt`` as a GIF (the first final seed); returns the frames."""
    import imageio.v3 as iio
    from PIL import Image

    from ibt.files import atomic_target

    clip = task.clip or DEFAULT_CLIP
    steps = list(episode(task, bt, final_seeds(1)[0], max_steps or clip.max_steps))
    chosen = steps[::clip.every] + ([] if (len(steps) - 1) % clip.every == 0 else steps[-1:])
    film = _HeadlineFilm(task, bt, row)
    images = [film.frame(s) for s in chosen]
    # one palette for every frame, drawn from a few of them (as ibt.views.animate does)
    picks = np.linspace(0, len(images) - 1, min(PALETTE_FRAMES, len(images))).astype(int)
    sample = Image.new("RGB", (images[0].width, images[0].height * len(picks)))
    for k, i in enumerate(picks):
        sample.paste(images[i], (0, k * images[0].height))
    palette = sample.quantize(colors=COLORS, method=Image.Quantize.MAXCOVERAGE)
    frames = [np.asarray(f.quantize(palette=palette, dither=Image.Dither.NONE).convert("RGB"))
              for f in images]
    durations = [clip.frame_ms] * len(frames)
    durations[-1] = max(clip.frame_ms, 1500)
    with atomic_target(target) as tmp:
        iio.imwrite(tmp, np.stack(frames), extension=".gif", plugin="pillow",
                    duration=durations, loop=0)
    return len(frames)


def lookup_config(cfg: Config) -> Config:
    """Where the headline's BTs are read: ``cfg`` itself, except under ``smoke``, whose budgets
    key other cache entries: there the ``paper`` profile's budgets on the committed cache (the
    entries notebooks 07 and 10 wrote), so a smoke run reads them and computes nothing."""
    if cfg.profile != "smoke":
        return cfg
    from ibt.profiles import _paper

    paper = {k: v for k, v in _paper().items() if k not in ("data_dir", "figures_dir",
                                                            "paper_dir")}
    return replace(cfg, profile="paper", **{**paper, "progress": False, "refresh": False})


def write_headline(cfg: Config, results: Path = DATA_DIR / "results") -> pd.DataFrame:
    """Pick the headline BTs, write each one's files and ``data/results/headline.csv``."""
    from ibt.export.btcpp import to_btcpp_xml
    from ibt.export.pictures import draw_bt
    from ibt.files import atomic_write_text
    from ibt.runs.grid import write_results

    smoke = cfg.profile == "smoke"
    table = headline_table(results, list(SMOKE_TASKS) if smoke else None)
    if smoke:  # one task, read from the committed cache; files to the scratch folders
        table = table.iloc[:1]
    root, lookup = cfg.figures_dir / "headline", lookup_config(cfg)
    paths, written = [], set()
    for row in table.itertuples():
        folder = root / row.name
        if row.name not in written:  # one BT may fill both of its task's rows
            written.add(row.name)
            folder.mkdir(parents=True, exist_ok=True)
            bt, task = bt_of(lookup, row), get_task(row.task)
            if bt.node_count != row.bt_nodes:
                raise RuntimeError(f"{row.name}: the cached BT has {bt.node_count} nodes, its "
                                   f"row in {row.source} {row.bt_nodes}; rerun its notebook")
            atomic_write_text(folder / "bt.json", bt.to_json())
            atomic_write_text(folder / "bt.xml", to_btcpp_xml(bt))
            title = (f"{row.task}, {row.method} ({str(row.expert).upper()}): "
                     f"{bt.node_count} nodes")
            draw_bt(bt, folder / "bt", title=title)
            write_gif(task, bt, row, folder / "episode.gif", 20 if smoke else None)
        paths.append({f"{k}_file": _shown(folder / f"bt.{k}", cfg)
                      for k in ("json", "xml", "png", "svg")}
                     | {"gif_file": _shown(folder / "episode.gif", cfg)})
    out = pd.concat([table.reset_index(drop=True), pd.DataFrame(paths)], axis=1)
    columns = ["task", "expert", "what", "method", "seed", "leaf_limit", "tree_leaves",
               "bt_nodes", "mean_return", "std_return", "episodes", "share_200",
               "expert_return", "random_return", "retention_norm", "anchor", "anchor_leaves",
               "anchor_tree_nodes", "anchor_return", "anchor_retention", "paper_method_nodes",
               "paper_method_retention", "paper_bt_nodes", "source", "name", "json_file",
               "xml_file", "png_file", "svg_file", "gif_file"]
    out = out.reindex(columns=columns)
    write_results(cfg, out, "headline", keep=KEEP)
    return out


def _shown(path: Path, cfg: Config) -> str:
    """A path as the CSV shows it: relative to the repository under ``paper``."""
    root = DATA_DIR.parent
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name


__all__ = ["AT_PUBLISHED", "CLOSEST", "KEEP", "SMALLEST", "anchors", "bt_of", "candidates",
           "headline_table", "headline_tasks", "select", "write_headline"]
