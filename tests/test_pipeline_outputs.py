"""The pipeline's files beyond the recommended BT: ``episode.gif`` (the BT acting, skipped in
one line where the task renders no frames), ``faithful_bt.json``/``.xml`` (the BT of highest
action agreement with the agent) and the agreement numbers in the report; and ``distill``
taking a ``MODULE:FUNCTION`` agent as ``pipeline`` does."""

from __future__ import annotations

import io
import json
import re
import shutil
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from tqdm import tqdm

from ibt.cli import main
from ibt.pipeline.owned_folder import claim, write_set
from ibt.pipeline.recommend import (
    BOX_TOLERANCE,
    agreement_share,
    most_faithful,
    ticking,
)
from ibt.tasks.catalogue import get_task

pytestmark = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")
CARTPOLE = get_task("CartPole-v1")
RULE = """
def act(obs):
    return 1 if obs[2] + 0.1 * obs[3] > 0 else 0
"""
LINE_AGENT = """
def act(obs):
    return 0 if obs[0] > 0.1 else 2 if obs[0] < -0.1 else 1
"""
SMOKE = ["--budget", "smoke", "--quiet", "--leaves", "4", "--jobs", "1"]


def _agent(folder: Path, source: str = RULE) -> str:
    path = folder / "agent.py"
    path.write_text(textwrap.dedent(source))
    return f"{path}:act"


def _cells(report: str, first: str) -> list[str]:
    """The cells of the report's table rows whose first cell starts with ``first``."""
    return [[c.strip() for c in line.split("|")[1:-1]] for line in report.splitlines()
            if line.startswith(f"| {first}")]


def _check_faithful(out: Path, report: str) -> None:
    """faithful_bt.json/.xml are the report's most faithful BT, of the front's highest
    agreement; every agreement is a share in [0, 1]."""
    from ibt.bt.json_io import load_json
    from ibt.export.btcpp import to_btcpp_xml

    faithful = load_json(out / "faithful_bt.json")
    assert (out / "faithful_bt.xml").read_text() == to_btcpp_xml(faithful)
    assert f"Most faithful: the **{faithful.node_count}-node BT**" in report
    (share,) = [float(v) for v in re.findall(r"agreement \*\*([01]\.\d{3})\*\*", report)]
    front = [row for row in _cells(report, "") if len(row) == 9 and row[0].isdigit()]
    shares = [float(row[-1]) for row in front]
    assert front and all(0 <= v <= 1 for v in shares) and share == max(shares)
    (mark,) = [row for row in front if "most faithful" in row[1]]
    assert float(mark[-1]) == share and int(mark[3]) == faithful.node_count
    for name in ("recommended BT", "random"):  # beside the returns
        (row,) = _cells(report, name)
        assert 0 <= float(row[-1]) <= 1
    marker = json.loads((out / ".ibt-pipeline.json").read_text())
    assert {"faithful_bt.json", "faithful_bt.xml"} <= set(marker["files"])


# --- a callable agent of a user's task without frames -------------------------------------


def test_a_callable_agents_faithful_bt_and_agreement_and_no_gif_where_no_frames(tmp_path):
    """ToyLine-v0 renders nothing: the run writes every other file and says why in one line;
    a rerun where the GIF of an earlier run lies removes it (the set never mixes runs)."""
    out = tmp_path / "out"
    spec = _agent(tmp_path, LINE_AGENT)
    argv = ["pipeline", "ToyLine-v0", "callable", "--agent", spec, "--env-module",
            "tests.fixtures.toy_line", "-o", str(out), *SMOKE]
    assert main(argv) == 0
    report = (out / "report.md").read_text()
    _check_faithful(out, report)
    assert not (out / "episode.gif").exists()
    notes = [line for line in report.splitlines() if "no `episode.gif`" in line]
    assert len(notes) == 1 and "renders no `rgb_array` frames" in notes[0]
    assert "`episode.gif` (the recommended BT acting)" not in report


def test_an_old_gif_of_ours_is_removed_and_a_users_is_left(tmp_path):
    """An optional name a run does not make: the earlier set's file goes (the marker proves it
    ours); a file of the user's of that name (--force) stays."""
    names = ("a.txt", "episode.gif", "report.md")

    def writer(gif: bool):
        def write(tmp: Path) -> None:
            (tmp / "a.txt").write_text("a")
            (tmp / "report.md").write_text("r")
            if gif:
                (tmp / "episode.gif").write_bytes(b"GIF89a")
        return write

    out = tmp_path / "ours"
    write_set(claim(out, names), names, writer(True), "INCOMPLETE", optional=("episode.gif",))
    assert (out / "episode.gif").exists()
    written = write_set(claim(out, names), names, writer(False), "INCOMPLETE",
                        optional=("episode.gif",))
    assert not (out / "episode.gif").exists() and out / "episode.gif" not in written
    assert "episode.gif" not in json.loads((out / ".ibt-pipeline.json").read_text())["files"]
    users = tmp_path / "users"
    users.mkdir()
    (users / "episode.gif").write_bytes(b"mine")
    write_set(claim(users, names, force=True), names, writer(False), "INCOMPLETE",
              optional=("episode.gif",))
    assert (users / "episode.gif").read_bytes() == b"mine"
    with pytest.raises(RuntimeError, match=r"did not make a\.txt, report\.md$"):
        write_set(claim(out, names), names, lambda tmp: None, "INCOMPLETE",
                  optional=("episode.gif",))


# --- the GIF -----------------------------------------------------------------------------


def _gif_frames(path: Path) -> int:
    from PIL import Image

    with Image.open(path) as image:
        return int(image.n_frames)


def test_the_gif_shows_the_recommended_bt_in_few_frames(tmp_path):
    from ibt.bt.json_io import load_json
    from ibt.paths import DATA_DIR
    from ibt.pipeline.outputs import GIF_FRAMES
    from ibt.views.headline import pipeline_episode, write_gif

    bt = load_json(DATA_DIR / "trees" / "CartPole-v1" / "ppo" / "imitation-bt.json")
    rec = SimpleNamespace(task=CARTPOLE, chosen=SimpleNamespace(bt=bt), algo="callable",
                          budget=SimpleNamespace(smoke=True))
    frames, note = pipeline_episode(rec, tmp_path / "episode.gif")
    assert note is None and frames == _gif_frames(tmp_path / "episode.gif") > 1
    # a long episode is subsampled to the cap, its first and last steps kept
    row = SimpleNamespace(method="recommended BT", expert="ppo")
    capped = write_gif(CARTPOLE, bt, row, tmp_path / "capped.gif", 120, max_frames=7)
    assert capped == _gif_frames(tmp_path / "capped.gif") <= 7 and GIF_FRAMES == 300


# --- agreement ---------------------------------------------------------------------------


def test_agreement_is_a_share_and_box_actions_agree_within_the_tolerance():
    assert agreement_share(CARTPOLE, np.array([0, 1, 1, 0]), np.array([0, 1, 0, 0])) == 0.75
    pendulum = get_task("Pendulum-v1")  # torque in [-2, 2]: tolerance 5 % of 4
    agent = np.array([[0.0], [1.0], [2.5], [-2.0]])
    bt = np.array([[0.2 * 0.999], [1.3], [2.0], [-1.5]])
    assert BOX_TOLERANCE == 0.05
    assert agreement_share(pendulum, agent, bt) == 0.5  # 2.5 is clipped to 2: it agrees


def test_the_most_faithful_is_the_highest_agreement_then_the_smallest():
    def cand(nodes: int, retention: float):
        return SimpleNamespace(bt_nodes=nodes, retention=retention, rank=0)

    a, b, c = cand(9, 90.0), cand(5, 80.0), cand(12, 99.0)
    assert most_faithful([a, b, c], [0.9, 0.9, 0.8]) is b
    assert most_faithful([a, b, c], [0.7, 0.6, 0.8]) is c


def test_the_pipeline_bar_ticks_while_a_step_runs():
    stream = io.StringIO()
    bar = tqdm(file=stream, bar_format="[{elapsed}]", mininterval=0)
    with ticking(bar, every=0.02):
        time.sleep(0.2)
    assert stream.getvalue().count("[") >= 3
    quiet = tqdm(file=io.StringIO(), disable=True)
    with ticking(quiet, every=0.01):
        time.sleep(0.05)


# --- distill takes the pipeline's agents ----------------------------------------------------


def test_distill_takes_a_callable_agent_as_pipeline_does(tmp_path, capsys):
    from ibt.distill.tree_file import load_tree_file

    spec = _agent(tmp_path)
    out = tmp_path / "tree.json"
    assert main(["distill", "CartPole-v1", "callable", "--agent", spec, "-o", str(out),
                 "--iterations", "2", "--labels", "100", "--selection-episodes", "2",
                 "--quiet"]) == 0
    assert "CartPole-v1/callable/imitation-bt: best tree" in capsys.readouterr().out
    doc = load_tree_file(out)
    assert doc["algo"] == "callable" and doc["agent"] == spec
    # the same rules of the options as the pipeline's, in one line each
    for extra, says in ((["callable"], "algo callable takes --agent"),
                        (["ppo", "--agent", spec], "--agent is for algo callable")):
        assert main(["distill", "CartPole-v1", *extra, "-o", str(tmp_path / "t.json")]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_cartpole_callable_smoke_pipeline_writes_the_gif_and_the_faithful_bt(tmp_path):
    """The whole run on CartPole (about 20 s): the GIF is readable, of several frames, and the
    report names it; the faithful BT and the agreement numbers are there."""
    out = tmp_path / "out"
    assert main(["pipeline", "CartPole-v1", "callable", "--agent", _agent(tmp_path), "-o",
                 str(out), *SMOKE]) == 0
    report = (out / "report.md").read_text()
    assert _gif_frames(out / "episode.gif") > 1
    assert "![the recommended BT acting](episode.gif)" in report
    assert "`episode.gif` (the recommended BT acting)" in report
    _check_faithful(out, report)
