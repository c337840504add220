"""The BT in motion: animated GIFs of a Behavior Tree driving its task.

Each frame shows the environment (``render_mode="rgb_array"``) beside the drawing of that
step's tick: the ticked path highlighted (blue ✓ success, orange dashed ✗ failure, grey not
ticked), the deciding condition marked ◆ (the last condition ticked before the action, see
:func:`ibt.export.drawing.deciding_condition`), and a caption with the step, the action and the
value
that decided it. The BT is the committed ``data/trees/<task>/<algo>/imitation-bt.json`` of the
task's best expert (:func:`best_expert`); the episode is the first of the fixed final-evaluation
episodes, so a GIF comes out the same on every run. A BT too large to read in a frame is drawn
collapsed per action (:func:`ibt.export.pictures.fit_graphviz`).

``python -m ibt.views.animate`` (``make animations``) writes ``figures/anim/<task>.gif``. Each
GIF's comment names the BT file it was drawn from and that file's SHA-256
(:func:`gif_source`), so a test sees when a committed GIF no longer shows its committed BT.
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ibt.bt.executors import TraceStep, tick
from ibt.bt.json_io import load_json
from ibt.bt.model import BehaviorTree, Condition
from ibt.export.drawing import deciding_condition, to_graphviz
from ibt.export.pictures import measure_graph
from ibt.paths import DATA_DIR, FIGURES_DIR
from ibt.tasks.catalogue import TASKS
from ibt.tasks.task import Task, sdl_video_driver

WIDTH = 840  #: GIF width in px (about the README's text column)
BODY_HEIGHT = 360  #: height of the environment / BT row
CAPTION_HEIGHT = 64
FOOTER_HEIGHT = 24
BT_DPI = 72  #: the BT is rendered at this dpi and only ever scaled down
ENV_SHARE = 0.42  #: the environment's share of the width
MIN_SCALE = 0.75  #: the smallest scale at which a frame shows the whole BT
COLORS = 160  #: the GIF palette (one for every frame)
PALETTE_FRAMES = 8  #: frames the palette is drawn from
FOOTER = ("blue ✓ success   orange, dashed ✗ failure   ◆ deciding condition   "
          "grey: not ticked")


@dataclass(frozen=True)
class Step:
    """One tick of the episode: the frame, the state, the decision and its trace."""

    t: int
    frame: np.ndarray
    features: np.ndarray
    action: int
    trace: tuple[TraceStep, ...]
    total_return: float


def best_expert(task: Task, data_dir: Path = DATA_DIR) -> str:
    """The expert whose Imitation-BT to film: among experts with status ``ok`` (when the
    manifest says) whose committed BT is not a single action, the highest mean return, ties
    broken by the BT's random-normalised retention (``synthesis.csv``), then dqn, ppo, a2c."""
    experts = pd.read_csv(data_dir / "experts" / "manifest.csv")
    experts = experts[experts["task"] == task.name]
    if "status" in experts:
        experts = experts[experts["status"].fillna("ok") == "ok"]
    synthesis_path = data_dir / "results" / "synthesis.csv"
    retention: dict[str, float] = {}
    if synthesis_path.exists():
        synthesis = pd.read_csv(synthesis_path)
        rows = synthesis[(synthesis["task"] == task.name) & synthesis["seed_best"]
                         & (synthesis["method"] == "imitation-bt")]
        retention = dict(zip(rows["expert"], rows["retention_norm"], strict=True))
    order = {"dqn": 0, "ppo": 1, "a2c": 2}
    candidates = []
    for algo, mean_return in zip(experts["algo"], experts["mean_return"], strict=True):
        path = data_dir / "trees" / task.name / algo / "imitation-bt.json"
        if not path.exists() or load_json(path).node_count <= 2:
            continue
        candidates.append((-mean_return, -retention.get(algo, -np.inf), order.get(algo, 9),
                           algo))
    if not candidates:
        raise LookupError(f"no committed Imitation-BT with more than one action for "
                          f"{task.name} in {data_dir / 'trees'}")
    return min(candidates)[-1]


def episode(task: Task, bt: BehaviorTree, seed: int, max_steps: int, render: bool = True
            ) -> Iterator[Step]:
    """Run ``bt`` on ``task`` from ``reset(seed=seed)``, yielding every step (with its frame
    when ``render``; the states a BT really meets, for trace views). A BT with commands sends
    its chosen command's vector; the step records the command's index."""
    with sdl_video_driver(task.render_driver if render else None):
        env = task.make_env(render_mode="rgb_array") if render else task.make_env()
        try:
            obs, _ = env.reset(seed=seed)
            total = 0.0
            for t in range(max_steps):
                features = task.features(np.asarray(obs)[None])[0]
                action, trace = tick(bt, features)
                frame = np.asarray(env.render()) if render else np.zeros((0, 0, 3), np.uint8)
                yield Step(t, frame, features, action, tuple(trace), total)
                sent = (bt.commands.evaluate(np.array([action]), np.asarray(
                    features, dtype=np.float32).astype(np.float64)[None])[0].astype(np.float32)
                    if bt.commands is not None else action)
                obs, reward, terminated, truncated, _ = env.step(sent)
                total += float(reward)
                if terminated or truncated:
                    return
        finally:
            env.close()


class _Fonts:
    def __init__(self) -> None:
        from matplotlib import font_manager
        from PIL import ImageFont

        regular = font_manager.findfont("DejaVu Sans")
        bold = font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans",
                                                                 weight="bold"))
        self.title = ImageFont.truetype(bold, 17)
        self.text = ImageFont.truetype(regular, 15)
        self.small = ImageFont.truetype(regular, 13)


def _fit(image, width: int, height: int):
    """``image`` scaled down (never up) to fit ``width`` x ``height``."""
    from PIL import Image

    scale = min(1.0, width / image.width, height / image.height)
    if scale >= 1.0:
        return image
    size = (max(1, round(image.width * scale)), max(1, round(image.height * scale)))
    return image.resize(size, Image.Resampling.LANCZOS)


def _label_package_delivery(image, scale: float, fonts: _Fonts) -> None:
    from PIL import ImageDraw

    from ibt.envs.package_delivery import render_layout

    draw = ImageDraw.Draw(image)
    for name, (x, y) in render_layout().items():
        text = name.replace("zone_", "zone ").replace(" a", " A").replace(" b", " B")
        box = draw.textbbox((x * scale, y * scale), text, font=fonts.small, anchor="mm")
        draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill="white")
        draw.text((x * scale, y * scale), text, font=fonts.small, fill="black", anchor="mm")


class Film:
    """Frames of one task's BT in motion, composed with PIL."""

    def __init__(self, task: Task, bt: BehaviorTree, algo: str) -> None:
        self.task, self.bt, self.algo = task, bt, algo
        self.fonts = _Fonts()
        self.nodes = list(bt.nodes())
        # the whole tree if it fits its box at 3/4 size or more (12 pt -> 9 px); else
        # collapsed per action, over the number of rows that shows it largest
        box_w, box_h = WIDTH - int(WIDTH * ENV_SHARE) - 24, BODY_HEIGHT

        def scale(collapse: bool, rows: int) -> float:
            size = measure_graph(to_graphviz(bt, {}, legend=False, collapse=collapse,
                                             stagger=rows))
            return min(1.0, box_w / size.width_pt, box_h / size.height_pt) * 72 / BT_DPI

        n_children = len(getattr(bt.root, "children", ()))
        self.collapse, self.rows = False, 1
        if scale(False, 1) < MIN_SCALE:
            options = range(1, max(1, min(4, n_children)) + 1)
            self.collapse, self.rows = True, max(options, key=lambda r: (scale(True, r), -r))
        self._drawings: dict[tuple, object] = {}

    def drawing(self, trace: tuple[TraceStep, ...]):
        """The BT with this tick highlighted (rendered once per distinct tick)."""
        from PIL import Image

        highlight = {s.index: s.success for s in trace}
        deciding = deciding_condition(self.bt, trace)
        key = (tuple(sorted(highlight.items())), deciding)
        if key not in self._drawings:
            graph = to_graphviz(self.bt, highlight, deciding=deciding, legend=False,
                                collapse=self.collapse, stagger=self.rows,
                                title="one node per action" if self.collapse else None)
            graph.graph_attr["dpi"] = str(BT_DPI)
            png = graph.pipe(format="png")
            self._drawings[key] = Image.open(io.BytesIO(png)).convert("RGB")
        return self._drawings[key]

    def _read(self, node: Condition) -> str:
        """What a condition reads: a feature's name, or a relational condition's form."""
        if node.form is not None:
            return node.form.text(self.bt.feature_names)
        return self.bt.feature_names[node.feature]

    def caption(self, step: Step) -> tuple[str, str]:
        head = (f"{self.task.name}: the Imitation-BT of the {self.algo.upper()} expert, "
                f"step {step.t}, return so far {step.total_return:.1f}")
        deciding = deciding_condition(self.bt, list(step.trace))
        why = ""
        node = self.nodes[deciding] if deciding is not None else None
        if isinstance(node, Condition):
            ok = next(s.success for s in step.trace if s.index == deciding)
            value = float(node.value(np.asarray(step.features, dtype=np.float64)))
            labels = (dict(self.bt.value_labels).get(node.feature) if node.form is None
                      else None)
            if labels and value.is_integer() and 0 <= value < len(labels):
                shown = labels[int(value)]
            else:
                shown = f"{int(value)}" if value.is_integer() else f"{value:.4g}"
            why = (f"   ◆ {self.bt.label(node)}: {'true' if ok else 'false'} "
                   f"({self._read(node)} = {shown})")
        return head, f"action: {self.bt.action_names[step.action]}{why}"

    def frame(self, step: Step):
        """One GIF frame: caption, environment | BT, legend."""
        from PIL import Image, ImageDraw

        canvas = Image.new("RGB", (WIDTH, CAPTION_HEIGHT + BODY_HEIGHT + FOOTER_HEIGHT),
                           "white")
        draw = ImageDraw.Draw(canvas)
        head, line = self.caption(step)
        draw.text((10, 8), head, font=self.fonts.title, fill="black")
        draw.text((10, 36), line, font=self.fonts.text, fill="black")
        env = Image.fromarray(step.frame).convert("RGB")
        env_box = int(WIDTH * ENV_SHARE)
        env = _fit(env, env_box, BODY_HEIGHT)
        if self.task.name.startswith("PackageDelivery"):
            _label_package_delivery(env, env.width / step.frame.shape[1], self.fonts)
        top = CAPTION_HEIGHT
        canvas.paste(env, (6, top + (BODY_HEIGHT - env.height) // 2))
        bt_x = env.width + 18
        bt = _fit(self.drawing(step.trace), WIDTH - bt_x - 6, BODY_HEIGHT)
        canvas.paste(bt, (bt_x + (WIDTH - bt_x - 6 - bt.width) // 2, top))
        draw.text((10, top + BODY_HEIGHT + 3), FOOTER, font=self.fonts.small, fill="#333333")
        return canvas


SOURCE_TAG = "ibt-bt"  #: the GIF comment: "ibt-bt <path under the data dir> sha256=<hex>"


def file_sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def source_comment(bt_file: Path, data_dir: Path = DATA_DIR) -> bytes:
    """The GIF comment naming the BT file (relative to ``data_dir``) and its SHA-256."""
    relative = Path(bt_file).resolve().relative_to(Path(data_dir).resolve()).as_posix()
    return f"{SOURCE_TAG} {relative} sha256={file_sha256(bt_file)}".encode()


def gif_source(gif: Path) -> tuple[str, str] | None:
    """(BT file under the data dir, SHA-256) from a GIF's comment; None without one."""
    from PIL import Image

    with Image.open(gif) as image:
        comment = image.info.get("comment", b"")
    parts = comment.decode(errors="replace").split()
    if len(parts) != 3 or parts[0] != SOURCE_TAG or not parts[2].startswith("sha256="):
        return None
    return parts[1], parts[2].removeprefix("sha256=")


def filmed_tasks() -> list[Task]:
    """The registered tasks with a clip (``Task.clip``), in registry order."""
    return [t for t in TASKS.values() if t.clip is not None]


def film(task: Task, out_dir: Path = FIGURES_DIR / "anim", data_dir: Path = DATA_DIR,
         seed: int | None = None) -> dict[str, object]:
    """Write ``<out_dir>/<task>.gif`` as the task's clip says; returns what was written (path,
    frames, size, time)."""
    import imageio.v3 as iio
    from PIL import Image

    from ibt.evaluate.rollouts import final_seeds
    from ibt.files import atomic_target

    start = time.perf_counter()
    clip = task.clip
    if clip is None:
        raise ValueError(f"{task.name} has no clip in its catalogue entry (Task.clip)")
    algo = best_expert(task, data_dir)
    bt_file = data_dir / "trees" / task.name / algo / "imitation-bt.json"
    bt = load_json(bt_file)
    movie = Film(task, bt, algo)
    seed = final_seeds(1)[0] if seed is None else seed
    steps = list(episode(task, bt, seed, clip.max_steps))
    chosen = steps[::clip.every]
    if chosen[-1] is not steps[-1]:
        chosen.append(steps[-1])
    frames = [movie.frame(step) for step in chosen]
    # one palette for every frame: no flicker, and every frame compresses alike
    picks = np.linspace(0, len(frames) - 1, min(PALETTE_FRAMES, len(frames))).astype(int)
    sample = Image.new("RGB", (WIDTH, frames[0].height * len(picks)))
    for k, i in enumerate(picks):
        sample.paste(frames[i], (0, k * frames[0].height))
    palette = sample.quantize(colors=COLORS, method=Image.Quantize.MAXCOVERAGE)
    arrays = [np.asarray(f.quantize(palette=palette, dither=Image.Dither.NONE).convert("RGB"))
              for f in frames]
    durations = [clip.frame_ms] * len(arrays)
    durations[-1] = max(clip.frame_ms, 1500)  # hold the last frame
    target = Path(out_dir) / f"{task.name}.gif"
    with atomic_target(target) as tmp:
        iio.imwrite(tmp, np.stack(arrays), extension=".gif", plugin="pillow",
                    duration=durations, loop=0, comment=source_comment(bt_file, data_dir))
    return {"task": task.name, "expert": algo, "path": str(target), "steps": len(steps),
            "frames": len(arrays), "kb": round(target.stat().st_size / 1024),
            "collapsed": movie.collapse, "seconds": round(time.perf_counter() - start, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ibt.views.animate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("tasks", nargs="*", help="tasks to film (default: every task with a clip)")
    parser.add_argument("--out", type=Path, default=FIGURES_DIR / "anim",
                        help="folder for the GIFs (default: figures/anim)")
    args = parser.parse_args(argv)
    known = {t.name: t for t in filmed_tasks()}
    unknown = [t for t in args.tasks if t not in known]
    if unknown:
        print(f"error: no clip for {unknown[0]!r}; choose among {', '.join(known)}",
              file=sys.stderr)
        return 2
    start = time.perf_counter()
    for task in [known[t] for t in args.tasks] or list(known.values()):
        facts = film(task, args.out)
        print(f"{facts['path']}: {facts['expert']} expert, {facts['steps']} steps, "
              f"{facts['frames']} frames, {facts['kb']} KB, "
              f"{'collapsed' if facts['collapsed'] else 'full'} BT, {facts['seconds']} s")
    print(f"all GIFs in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
