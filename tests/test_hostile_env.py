"""A user's environment or agent that misbehaves, through the real command line.

Each case of :data:`CASES` runs ``python -m ibt`` in a subprocess on one environment of
``tests.fixtures.hostile_envs`` (or a user's module registering a task that does not fit its
environment) and asserts: the exit code; on failure exactly one line on stderr, naming the
environment; no traceback anywhere; the user's files untouched (only the pipeline's cache, and
the marker naming it, may be added). The cases run two at a time (one fixture for the
session), so the file stays within about 40 s on two cores. ``python -m
tests.test_hostile_env`` runs them and writes the table of ``docs/hostile-env.md`` (case,
command, expected, observed).
"""

from __future__ import annotations

import os
import pickle
import re
import shutil
import subprocess
import sys
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "hostile-env.md"
ENV = "--env-module tests.fixtures.hostile_envs"
SMOKE = "--budget smoke --quiet"
EXITS = "tests.fixtures.hostile_exits"
EARLIER = "bt.json"  # an earlier result in the output folder: a failed run leaves it as it was
NOTES = "notes.txt"  # the user's own file there: every run leaves it as it was


@dataclass(frozen=True)
class Case:
    """One hostile run: ``command`` is ``python -m ibt`` + this text, where AGENT, TREE, BT and
    OUT stand for the user's checkpoint, tree file, BT file and output folder."""

    name: str
    command: str
    exit_code: int
    expected: str  # a regular expression the stderr line (or stdout on success) must match
    culprit: str  # named on that line


def _bad_task(features: str, actions: str, low: str, high: str) -> str:
    """A user's module registering a task of ``Hostile-Fine-v0`` that does not fit it."""
    return ("import tests.fixtures.hostile_envs\n"
            "from ibt.tasks.catalogue import Task, register_task\n"
            f"register_task(Task(name='Hostile-Fine-v0', gym_id='Hostile-Fine-v0', "
            f"feature_names={features}, action_names={actions}, low={low}, high={high}))\n")


BAD_TASKS = {
    "bad_features": _bad_task("('a', 'b', 'c')", "('l', 'r')", "(-1, -1, -1)",
                              "(1, 1, 1)"),
    "bad_actions": _bad_task("('a', 'b')", "('l', 'r', 's')", "(-1, -1)", "(1, 1)"),
    "bad_infinite_box": _bad_task("('a', 'b')", "('l', 'r')", "(-1, -float('inf'))",
                                  "(1, 1)"),
    "bad_wide_box": _bad_task("('a', 'b')", "('l', 'r')", "(-1e308, -1)", "(1e308, 1)"),
}

STEP_FAULT = r"the environment {} failed in step\(\) \(step \d+ of the episode with seed \d+\): "
CASES = [
    Case("flat reward (agent = random)",
         f"pipeline Hostile-FlatReward-v0 ppo --checkpoint AGENT -o OUT {SMOKE} {ENV}", 2,
         r"does no better than the random policy", "Hostile-FlatReward-v0"),
    Case("NaN reward, pipeline",
         f"pipeline Hostile-NaNReward-v0 ppo --checkpoint AGENT -o OUT {SMOKE} {ENV}", 2,
         STEP_FAULT.format("Hostile-NaNReward-v0") + "it returned the reward nan",
         "Hostile-NaNReward-v0"),
    Case("NaN reward, refine",
         f"refine TREE -o OUT/bt.json --episodes 40 --quiet {ENV}", 2,
         STEP_FAULT.format("Hostile-NaNReward-v0") + "it returned the reward nan",
         "Hostile-NaNReward-v0"),
    Case("rewards overflow to inf",
         f"evaluate BT --task Hostile-InfReward-v0 --episodes 2 {ENV}", 2,
         STEP_FAULT.format("Hostile-InfReward-v0") + "the rewards summed to inf",
         "Hostile-InfReward-v0"),
    Case("inf in an observation",
         f"distill Hostile-InfObservation-v0 ppo --checkpoint AGENT -o OUT/bt.json "
         f"--iterations 1 --labels 50 --selection-episodes 1 --quiet {ENV}", 2,
         STEP_FAULT.format("Hostile-InfObservation-v0") + r"it returned a non-finite "
         r"observation \(x1=inf\)", "Hostile-InfObservation-v0"),
    Case("observation of the wrong shape",
         f"distill Hostile-WrongShape-v0 ppo --checkpoint AGENT -o OUT/bt.json "
         f"--iterations 1 --labels 50 --selection-episodes 1 --quiet {ENV}", 2,
         r"failed in reset\(\) .*shape \(3,\), but its observation_space has shape \(2,\)",
         "Hostile-WrongShape-v0"),
    Case("step raises RuntimeError",
         f"evaluate BT --task Hostile-RaisingStep-v0 --episodes 2 {ENV}", 2,
         STEP_FAULT.format("Hostile-RaisingStep-v0") + "it raised RuntimeError: joint 2 "
         "exceeded its torque limit", "Hostile-RaisingStep-v0"),
    Case("reset raises ValueError",
         f"evaluate BT --task Hostile-RaisingReset-v0 --episodes 2 {ENV}", 2,
         r"failed in reset\(\) .*it raised ValueError: the simulator's licence server",
         "Hostile-RaisingReset-v0"),
    Case("endless episodes, default cut",
         f"evaluate BT --task Hostile-Endless-v0 --episodes 2 {ENV}", 0,
         r"^notice: Hostile-Endless-v0 sets no max_episode_steps, so its episodes are cut at "
         r"1,000 steps; choose another cut with --max-episode-steps N", "Hostile-Endless-v0"),
    Case("endless episodes, pipeline with --max-episode-steps",
         f"pipeline Hostile-Endless-v0 ppo --checkpoint AGENT -o OUT --leaves 4 "
         f"--max-episode-steps 25 {SMOKE} {ENV}", 0,
         r"^Hostile-Endless-v0/ppo: recommended a \d+-node BT", "Hostile-Endless-v0"),
    Case("Discrete(2, start=1) actions",
         f"pipeline Hostile-StartsAtOne-v0 callable --agent {EXITS}:steady -o OUT {SMOKE} "
         f"--env-module {EXITS}", 2,
         r"the environment Hostile-StartsAtOne-v0 numbers its actions from 1 \(Discrete\(2, "
         r"start=1\)\)", "Hostile-StartsAtOne-v0"),
    Case("an agent that calls sys.exit(0)",
         f"pipeline Hostile-Fine-v0 callable --agent {EXITS}:quitter -o OUT {SMOKE} {ENV} "
         f"--env-module {EXITS}", 2,
         r"agent 'tests\.fixtures\.hostile_exits:quitter': the agent on observation 0 raised "
         r"SystemExit: 0", "tests.fixtures.hostile_exits:quitter"),
    Case("an environment whose step calls sys.exit(0)",
         f"pipeline Hostile-ExitingStep-v0 callable --agent {EXITS}:steady -o OUT {SMOKE} "
         f"--env-module {EXITS}", 2,
         r"the environment of Hostile-ExitingStep-v0 \(or code it runs\) called sys\.exit\(0\)",
         "Hostile-ExitingStep-v0"),
    *[Case(f"task does not fit: {what}",
           f"evaluate BT --task Hostile-Fine-v0 --env-module {module}", 2,
           rf"the environment module '{module}' registers a task that does not fit: .*{pattern}",
           "Hostile-Fine-v0")
      for module, what, pattern in (
          ("bad_features", "3 feature names, 2 numbers observed",
           r"names 3 features .* observes 2 number"),
          ("bad_actions", "3 action names, 2 actions", r"names 3 actions .* has 2"),
          ("bad_infinite_box", "a feature box to -inf", r"feature 'b' has the box \[-inf"),
          ("bad_wide_box", "a box too wide to sample", r"too wide to draw numbers from"))],
]


@dataclass
class Observed:
    exit_code: int
    stdout: str
    stderr: str
    changed: list[str]  # the user's files that were changed, removed or added (not the cache)

    @property
    def line(self) -> str:
        """The line a user reads: stderr's, else stdout's last."""
        text = self.stderr.strip() or self.stdout.strip()
        return text.splitlines()[-1] if text else ""


def make_materials(folder: Path) -> Path:
    """The user's files every case starts from: a checkpoint that plays the task well, a tree
    file of the NaN-reward environment, a BT, and the modules registering ill-fitting tasks."""
    from ibt.cli import main
    from tests.fixtures.hostile_envs import save_agent

    folder.mkdir(parents=True, exist_ok=True)
    save_agent(str(folder / "agent.zip"))
    tree = folder / "fine_tree.json"
    assert main(["distill", "Hostile-Fine-v0", "ppo", "--checkpoint", str(folder / "agent.zip"),
                 "-o", str(tree), "--iterations", "1", "--labels", "50",
                 "--selection-episodes", "1", "--quiet", *ENV.split()]) == 0
    assert main(["synthesize", str(tree), "-o", str(folder / "user_bt.json"),
                 *ENV.split()]) == 0
    # the same tree, as if distilled on the NaN-reward environment (same spaces and names)
    text = tree.read_text().replace("Hostile-Fine-v0", "Hostile-NaNReward-v0")
    (folder / "tree.json").write_text(text)
    tree.unlink()
    for module, source in BAD_TASKS.items():
        (folder / f"{module}.py").write_text(source)
    return folder


def _snapshot(folder: Path) -> dict[str, bytes]:
    """The user's files: not the pipeline's cache, nor the marker that names it (kept after a
    failed run so that the corrected rerun resumes from the cache)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and "cache" not in p.relative_to(folder).parts
            and "__pycache__" not in p.parts and p.name != ".ibt-pipeline.json"}


def argv_of(case: Case, folder: Path) -> list[str]:
    """The case's command line in ``folder`` (a copy of the materials)."""
    names = {"AGENT": folder / "agent.zip", "TREE": folder / "tree.json",
             "BT": folder / "user_bt.json", "OUT": folder / "out"}
    words = []
    for word in case.command.split():
        for key, path in names.items():
            word = word.replace(key, str(path)) if word.startswith(key) else word
        words.append(word)
    return words


def observe(case: Case, materials: Path, folder: Path) -> Observed:
    """Run ``case`` in a fresh copy of the materials; what it printed and changed."""
    shutil.copytree(materials, folder)
    (folder / "out").mkdir()
    if case.command.startswith("pipeline"):  # it writes only into a folder it owns: the
        (folder / NOTES).write_text("the user's own notes\n")  # user's files sit beside it
    else:
        (folder / "out" / EARLIER).write_text("an earlier result\n")
        (folder / "out" / NOTES).write_text("the user's own notes\n")
    before = _snapshot(folder)
    environ = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(folder)]),
               "SDL_VIDEODRIVER": "dummy", "PYTHONHASHSEED": "0"}
    ran = subprocess.run([sys.executable, "-m", "ibt", *argv_of(case, folder)],
                         capture_output=True, text=True, env=environ, cwd=folder, timeout=300)
    after = _snapshot(folder)
    if case.exit_code == 0:  # a finished run writes its files; the user's own ones stay
        changed = [p for p in before if before[p] != after.get(p)
                   and (not p.startswith("out/") or p.endswith(NOTES))]
    else:
        changed = sorted(p for p in set(before) | set(after) if before.get(p) != after.get(p))
    def plain(text: str) -> str:  # the case's folders as the doc names them
        return text.replace(str(folder / "out"), "OUT").replace(str(folder), ".")

    return Observed(ran.returncode, plain(ran.stdout), plain(ran.stderr), changed)


def observe_all(cases: list[Case], root: Path, workers: int = 2) -> dict[str, Future]:
    """Every case, ``workers`` at a time (each one a subprocess)."""
    materials = make_materials(root / "materials")
    pool = ThreadPoolExecutor(workers)
    futures = {c.name: pool.submit(observe, c, materials, root / f"case{i}")
               for i, c in enumerate(cases)}
    pool.shutdown(wait=False)
    return futures


@pytest.fixture(scope="session")
def observed(tmp_path_factory):
    return observe_all(CASES, tmp_path_factory.mktemp("hostile"))


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_a_hostile_environment_fails_safely(case: Case, observed):
    seen: Observed = observed[case.name].result()
    assert "Traceback" not in seen.stdout + seen.stderr, seen.stderr
    assert seen.exit_code == case.exit_code, seen.stderr
    stderr = seen.stderr.strip().splitlines()
    if case.exit_code != 0:
        assert len(stderr) == 1, seen.stderr
    assert len(stderr) <= 1, seen.stderr
    assert case.culprit in seen.line and re.search(case.expected, seen.line), seen.line
    assert not seen.changed, f"the user's files changed: {seen.changed}"


def test_the_doc_lists_every_case():
    doc = DOC.read_text()
    for case in CASES:
        assert f"| {case.name} | `python -m ibt {case.command}` | exit {case.exit_code}" in doc


# --------------------------------------------------------------- the library beneath the CLI
def test_retention_is_undefined_not_an_error_where_the_agent_is_random():
    from ibt.evaluate.rollouts import retention_margin, retention_norm

    assert np.isnan(retention_norm(3.0, 5.0, 5.0))
    assert retention_norm(4.0, 5.0, 3.0) == pytest.approx(50.0)
    assert np.isnan(retention_margin(1.0, 1.0, 10, 5.0, 5.0))
    # two standard errors of the difference, on the retention's scale
    assert retention_margin(3.0, 4.0, 25, 10.0, 0.0) == pytest.approx(20.0)


def test_the_report_flags_retention_above_the_agent_beyond_noise():
    from ibt.pipeline.outputs import beyond_the_agent

    def returns(mean: float, std: float) -> SimpleNamespace:
        return SimpleNamespace(mean=mean, std=std)

    def candidate(retention: float) -> SimpleNamespace:
        return SimpleNamespace(retention=retention, std_return=1.0, label="refined",
                               leaf_limit=8)

    rec = SimpleNamespace(episodes=100, agent=returns(10.0, 1.0), random=returns(0.0, 1.0),
                          bt=returns(12.0, 1.0), retention=120.0, agent_choice=10.0,
                          random_choice=0.0, candidates=[candidate(101.0), candidate(130.0)])
    text = " ".join(beyond_the_agent(rec))
    assert "120.0 %" in text and "130.0 %" in text and "101.0" not in text  # within noise
    rec.retention, rec.bt, rec.candidates = 100.5, returns(10.05, 1.0), [candidate(99.0)]
    assert beyond_the_agent(rec) == []
    rec.retention = float("nan")
    assert "Retention undefined" in beyond_the_agent(rec)[0]


def test_the_episode_cap_keys_the_cache_and_cuts_an_endless_environment(tmp_path):
    import tests.fixtures.hostile_envs  # noqa: F401
    from ibt.evaluate.rollouts import EnvError, rollout
    from ibt.tasks.catalogue import resolve_task, with_episode_cap
    from ibt.tasks.settings import DEFAULT_MAX_EPISODE_STEPS

    endless = resolve_task("Hostile-Endless-v0")
    capped, notice = with_episode_cap(endless)
    assert capped.episode_cap == DEFAULT_MAX_EPISODE_STEPS and "--max-episode-steps" in notice
    chosen, none = with_episode_cap(endless, 7)
    assert none is None and len({endless.key, capped.key, chosen.key}) == 3
    fine = resolve_task("Hostile-Fine-v0")
    assert with_episode_cap(fine) == (fine, None) and fine.key == fine.name
    assert list(rollout(chosen, lambda obs: np.zeros(len(obs), int), [0, 1]).lengths) == [7, 7]
    with pytest.warns(UserWarning, match="sets no max_episode_steps"):  # no task cap: cut anyway
        lengths = rollout(endless, lambda obs: np.zeros(len(obs), int), [0]).lengths
    assert list(lengths) == [DEFAULT_MAX_EPISODE_STEPS]
    error = EnvError("the environment X failed in step()")  # crosses process boundaries
    assert str(pickle.loads(pickle.dumps(error))) == str(error)


def write_doc(root: Path) -> None:
    """Run every case and write the table of ``docs/hostile-env.md`` (observed as measured)."""
    futures = observe_all(CASES, root)
    rows = []
    for case in CASES:
        seen = futures[case.name].result()
        line = seen.line.replace("|", "\\|")
        ok = (seen.exit_code == case.exit_code and "Traceback" not in seen.stderr
              and not seen.changed)
        rows.append(f"| {case.name} | `python -m ibt {case.command}` | exit {case.exit_code}, "
                    f"`{case.expected.replace('|', chr(92) + '|')}` | exit {seen.exit_code}"
                    f"{'' if ok else ' (MISMATCH)'}: {line} |")
    text = DOC.read_text()
    head, _, rest = text.partition("<!-- cases:begin -->")
    _, _, tail = rest.partition("<!-- cases:end -->")
    table = ["| case | command | expected | observed |", "|---|---|---|---|", *rows]
    DOC.write_text(head + "<!-- cases:begin -->\n" + "\n".join(table) + "\n<!-- cases:end -->"
                   + tail)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        write_doc(Path(scratch))
