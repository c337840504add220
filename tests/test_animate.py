"""The BT in motion: GIFs render, follow the BT's decisions, and highway frames are not black."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from ibt.bt.json_io import load_json
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import Clip
from ibt.views.animate import best_expert, episode, film, filmed_tasks, main

pytestmark = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")


def test_the_clips_cover_the_five_tasks_of_the_issue():
    assert {"CartPole-v1", "MountainCar-v0", "FrozenLake-v1", "LunarLander-v3",
            "PackageDelivery-v0"} <= {task.name for task in filmed_tasks()}


def test_best_expert_skips_constant_action_bts():
    # Expect: highway's A2C expert has the highest return but a one-action BT (2 nodes)
    task = get_task("highway-fast-v0")
    algo = best_expert(task)
    assert load_json(DATA_DIR / "trees" / task.name / algo / "imitation-bt.json").node_count > 2
    assert best_expert(get_task("MountainCar-v0")) == "dqn"  # -99.8, the best of the three


def test_an_episode_acts_as_the_bt_decides():
    task = get_task("FrozenLake-v1")
    bt = load_json(DATA_DIR / "trees" / task.name / "dqn" / "imitation-bt.json")
    steps = list(episode(task, bt, seed=0, max_steps=20))
    # Expect: the non-slippery lake is walked along the BT's greedy path to the goal
    assert [int(s.features[0]) for s in steps] == [0, 4, 8, 9, 10, 14]
    assert all(s.action == int(bt.decide(s.features[None])[0]) for s in steps)
    assert steps[0].frame.ndim == 3


def test_film_writes_a_gif_of_every_drawn_step(tmp_path):
    from PIL import Image

    facts = film(replace(get_task("FrozenLake-v1"), clip=Clip(20, 1, 200)), tmp_path)
    with Image.open(facts["path"]) as gif:
        assert gif.n_frames == facts["frames"] == facts["steps"] == 6
        assert gif.size[0] == 840
    assert facts["kb"] < 2048


def test_highway_frames_are_rendered_not_black():
    frame = get_task("highway-fast-v0").render_frame(seed=0, steps=0)
    assert frame.std() > 5 and len(np.unique(frame.reshape(-1, 3), axis=0)) > 3


def test_an_unknown_clip_is_a_clear_error(capsys):
    assert main(["Pong-v5"]) == 2
    assert "no clip for 'Pong-v5'" in capsys.readouterr().err


def test_film_names_its_bt_file_and_digest_in_the_gif(tmp_path):
    from ibt.views.animate import file_sha256, gif_source

    task = replace(get_task("FrozenLake-v1"), clip=Clip(20, 1, 200))
    facts = film(task, tmp_path)
    path, digest = gif_source(facts["path"])
    assert path == f"trees/FrozenLake-v1/{facts['expert']}/imitation-bt.json"
    assert digest == file_sha256(DATA_DIR / path)


@pytest.mark.parametrize("task", [t.name for t in filmed_tasks()])
def test_every_committed_gif_was_drawn_from_its_committed_bt(task):
    # Expect: the GIF's comment names the BT it shows; a BT changed since (`make figures` wrote a
    # new data/trees/...) fails here until `make animations` draws the GIF again
    from ibt.paths import FIGURES_DIR
    from ibt.views.animate import file_sha256, gif_source

    gif = FIGURES_DIR / "anim" / f"{task}.gif"
    assert gif.exists(), f"{gif} is missing: run `make animations`"
    source = gif_source(gif)
    assert source is not None, f"{gif} does not name its BT: run `make animations`"
    path, digest = source
    assert path == f"trees/{task}/{best_expert(get_task(task))}/imitation-bt.json"
    assert digest == file_sha256(DATA_DIR / path), (
        f"{gif} shows an older {path}: run `make animations`")
