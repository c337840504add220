"""The headline BTs as files a reader opens (:mod:`ibt.runs.headline` chooses them).

Each picked BT is written under ``figures/headline/<run>/`` as ``bt.json``, ``bt.xml``
(BehaviorTree.CPP), ``bt.png`` and ``bt.svg`` (the drawing) and ``episode.gif`` (the BT driving
the first final episode); the table is ``data/results/headline.csv``. Under the ``smoke``
profile one small task is written, to the profile's scratch folders, read from the committed
cache under the paper budgets (:func:`lookup_config`): nothing is computed.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd

from ibt.bt.model import BehaviorTree
from ibt.evaluate.rollouts import final_seeds
from ibt.paths import DATA_DIR
from ibt.profiles import Config
from ibt.runs.headline import KEEP, bt_of, headline_table
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import Clip
from ibt.tasks.task import Task
from ibt.views.animate import COLORS, PALETTE_FRAMES, Film, Step, episode

DEFAULT_CLIP = Clip(200, 4, 110)  #: a task without a clip of its own (the continuous ones)
SMOKE_TASKS = ("MountainCar-v0",)


class _HeadlineFilm(Film):
    """The animation's frames, captioned with the headline BT's method and size."""

    def __init__(self, task: Task, bt: BehaviorTree, row: Any) -> None:
        super().__init__(task, bt, row.expert)
        self.label = f"{row.method} ({str(row.expert).upper()}, {bt.node_count} nodes)"

    def caption(self, step: Step) -> tuple[str, str]:
        _, line = super().caption(step)
        return (f"{self.task.name}, {self.label}: step {step.t}, return "
                f"{step.total_return:.1f}", line)


def write_gif(task: Task, bt: BehaviorTree, row: Any, target: Path, max_steps: int | None = None,
              max_frames: int | None = None) -> int:
    """One final episode of ``bt`` as a GIF (the first final seed), every clip's ``every``-th
    step, or fewer so that at most ``max_frames`` frames are drawn; returns the frames."""
    import imageio.v3 as iio
    from PIL import Image

    from ibt.files import atomic_target

    clip = task.clip or DEFAULT_CLIP
    steps = list(episode(task, bt, final_seeds(1)[0], max_steps or clip.max_steps))
    every = clip.every
    if max_frames is not None:  # the first and last step always; every-th between them
        every = max(every, -(-(len(steps) - 1) // max(1, max_frames - 1)))
    chosen = steps[::every] + ([] if (len(steps) - 1) % every == 0 else steps[-1:])
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


def pipeline_episode(rec: Any, target: Path) -> tuple[int, str | None]:
    """``episode.gif`` of a pipeline run (:class:`ibt.pipeline.recommend.Recommendation`): its
    recommended BT driving the first final episode, drawn as the headline BTs are (the task's
    clip length and step; at most ``GIF_FRAMES`` frames, ``SMOKE_GIF_STEPS`` steps under the
    smoke budget, of :mod:`ibt.pipeline.outputs`). Returns the frames written and None, or 0
    and a one-line note of why not: a task that renders no ``rgb_array`` frames gets no GIF,
    and the run goes on."""
    import warnings

    from ibt.pipeline.outputs import GIF_FRAMES, SMOKE_GIF_STEPS
    from ibt.tasks.task import sdl_video_driver

    task = rec.task
    try:
        with warnings.catch_warnings(), sdl_video_driver(task.render_driver):
            warnings.simplefilter("ignore")  # gymnasium warns of a render mode it lacks
            env = task.make_env()  # its metadata says which frames it renders
            try:
                modes = list(getattr(env.unwrapped, "metadata", {}).get("render_modes") or ())
            finally:
                env.close()
            if "rgb_array" not in modes:
                return 0, (f"no `episode.gif`: {task.name} renders no `rgb_array` frames (its "
                           f"metadata's render_modes: {', '.join(map(str, modes)) or 'none'})")
            row = SimpleNamespace(method="recommended BT", expert=rec.algo)
            frames = write_gif(task, rec.chosen.bt, row, target,
                               SMOKE_GIF_STEPS if rec.budget.smoke else None, GIF_FRAMES)
    except Exception as err:  # the user's renderer: a GIF is not worth failing the run
        target.unlink(missing_ok=True)
        why = " ".join(f"{type(err).__name__}: {err}".split())[:200]
        return 0, f"no `episode.gif`: rendering {task.name} failed ({why})"
    return frames, None


def lookup_config(cfg: Config) -> Config:
    """Where the headline's BTs are read: ``cfg`` itself, except under ``smoke``, whose budgets
    key other cache entries: there the ``paper`` profile's budgets on the committed cache (the
    entries notebooks 07 and 10 wrote), so a smoke run reads them and computes nothing."""
    if cfg.profile != "smoke":
        return cfg
    from ibt.profiles import paper_settings

    paper = {k: v for k, v in paper_settings().items() if k not in ("data_dir", "figures_dir",
                                                                    "paper_dir")}
    return replace(cfg, profile="paper", **{**paper, "progress": False, "refresh": False})


HEADLINE_FILES = ("bt.json", "bt.xml", "bt.png", "bt.svg", "episode.gif")  #: a folder's files


def retire(root: Path, before: list[str], now: list[str]) -> list[str]:
    """Remove the folders under ``root`` that the last headline listed (``before``: the names
    in its CSV, which this module wrote) and this one does not (``now``): only the files this
    module writes there, and the folder where that empties it (a user's file in it stays).
    Returns the names retired."""
    gone = []
    for name in sorted(set(before) - set(now)):
        folder = root / name
        if "/" in name or name in ("", ".", "..") or not folder.is_dir() or folder.is_symlink():
            continue
        for file in HEADLINE_FILES:
            if (folder / file).is_file() and not (folder / file).is_symlink():
                (folder / file).unlink()
        if not any(folder.iterdir()):
            folder.rmdir()
        gone.append(name)
    return gone


def write_headline(cfg: Config, results: Path = DATA_DIR / "results") -> pd.DataFrame:
    """Pick the headline BTs, write each one's files and ``data/results/headline.csv``; the
    folders of BTs that the last headline listed and this one does not are retired
    (:func:`retire`)."""
    from ibt.export.btcpp import to_btcpp_xml
    from ibt.export.pictures import draw_bt
    from ibt.files import atomic_write_text
    from ibt.runs.grid import write_results

    smoke = cfg.profile == "smoke"
    table = headline_table(results, list(SMOKE_TASKS) if smoke else None)
    if smoke:  # one task, read from the committed cache; files to the scratch folders
        table = table.iloc[:1]
    root, lookup = cfg.figures_dir / "headline", lookup_config(cfg)
    last = cfg.data_dir / "results" / "headline.csv"
    before = pd.read_csv(last)["name"].astype(str).tolist() if last.is_file() else []
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
            title = (f"{row.task}, {row.method} ({str(row.expert).upper()}):\n"
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
    retire(root, before, sorted(written))
    return out


def _shown(path: Path, cfg: Config) -> str:
    """A path as the CSV shows it: relative to the repository under ``paper``."""
    root = DATA_DIR.parent
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name


__all__ = ["lookup_config", "pipeline_episode", "retire", "write_gif", "write_headline"]
