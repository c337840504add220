"""Bad input at every boundary of the command line: exit code 2, one line, nothing written.

Each row of :data:`CASES` is a command that must fail before doing any work: a bad BT file
(NaN threshold, fractional index, no reachable action ...), a bad or mismatched tree file, a
number out of range, an output path that cannot be written, an environment module that cannot
be imported, a checkpoint of another kind, a pickle that would run code, a device or a pipe
instead of a file, a BT nested too deeply. The test runs it, expects exit code 2, exactly one
line on stderr containing the expected words, nothing on stdout, and no file left behind (so no
pickle payload and no module named in a file ran: each would write a marker there).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
from pathlib import Path

import joblib
import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.json_io import save_json
from ibt.cli import main
from ibt.distill.tree_file import save_tree_file
from ibt.experts.expert import expert_path
from ibt.synth.imitation import imitation_bt
from ibt.tasks.catalogue import get_task
from tests.privileges import run_unprivileged

CARTPOLE_DQN = str(expert_path(get_task("CartPole-v1"), "dqn"))
CARTPOLE_PPO = str(expert_path(get_task("CartPole-v1"), "ppo"))
CLIFF_PPO = str(expert_path(get_task("CliffWalking-v1"), "ppo"))
MOUNTAINCAR_PPO = expert_path(get_task("MountainCar-v0"), "ppo")


class Payload:
    """A pickle that makes a folder ``PWNED`` when loaded (it must never be)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def __reduce__(self):
        return os.mkdir, (str(self.folder / "PWNED"),)


def _mutate(doc: dict, change) -> dict:
    doc = json.loads(json.dumps(doc))
    change(doc)
    return doc


def _first_condition(doc: dict) -> dict:
    node = doc["root"]
    while node["type"] != "condition":
        node = node["children"][0]
    return node


def _set(key: str, value):
    return lambda doc: _first_condition(doc).__setitem__(key, value)


GAP_ROOT = {"type": "selector", "children": [
    {"type": "sequence", "children": [
        {"type": "condition", "feature": 2, "op": "<=", "threshold": 0.0},
        {"type": "action", "action": 0}]},
    {"type": "sequence", "children": [
        {"type": "condition", "feature": 2, "op": ">", "threshold": 0.1},
        {"type": "action", "action": 1}]}]}

#: bad BT documents: name -> how to spoil a valid CartPole BT
BAD_BTS = {
    "nan_threshold": _set("threshold", math.nan),
    "infinite_threshold": _set("threshold", math.inf),
    "string_threshold": _set("threshold", "0.5"),
    "fractional_feature": _set("feature", 0.7),
    "boolean_feature": _set("feature", True),
    "feature_out_of_range": _set("feature", 9),
    "misspelt_key": lambda doc: _first_condition(doc).__setitem__(
        "treshold", _first_condition(doc).pop("threshold")),
    "negative_action": lambda doc: doc["root"]["children"].__setitem__(
        -1, {"type": "action", "action": -1}),
    "action_out_of_range": lambda doc: doc["root"]["children"].__setitem__(
        -1, {"type": "action", "action": 5}),
    "no_default_and_a_gap": lambda doc: doc.__setitem__("root", GAP_ROOT),
    "no_action_at_all": lambda doc: doc.__setitem__("root", {"type": "sequence", "children": [
        {"type": "condition", "feature": 0, "op": "<=", "threshold": 0.0}]}),
    "empty_selector": lambda doc: doc.__setitem__("root", {"type": "selector",
                                                           "children": []}),
    "inverter_with_two_children": lambda doc: doc.__setitem__("root", {
        "type": "inverter", "children": [{"type": "action", "action": 0}] * 2}),
    "unknown_node_type": lambda doc: doc.__setitem__("root", {"type": "parallel",
                                                              "children": []}),
    "no_root": lambda doc: doc.pop("root"),
    "repeated_feature_name": lambda doc: doc["feature_names"].__setitem__(1, "cart_position"),
    "other_format": lambda doc: doc.__setitem__("format", "ibt-behavior-tree/9"),
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """Valid and spoiled input files in one folder (module scope: made once)."""
    folder = tmp_path_factory.mktemp("inputs")
    task = get_task("CartPole-v1")
    rng = np.random.default_rng(0)
    x = task.sample_features(2000, rng)
    y = (x[:, 2] + 0.5 * x[:, 3] > 0).astype(int)
    tree = DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, y)
    save_tree_file(folder / "tree.json", tree, task, {"algo": "ppo"})
    doc = imitation_bt(tree, task).bt.to_dict()
    save_json(imitation_bt(tree, task).bt, folder / "bt.json")
    for name, change in BAD_BTS.items():
        (folder / f"{name}.json").write_text(json.dumps(_mutate(doc, change)))
    (folder / "not_json.json").write_text("{feature_names: [")
    (folder / "garbage_tree.json").write_bytes(b"this is not a tree file")
    (folder / "dict_tree.json").write_text(json.dumps({"weights": [1, 2]}))
    tree_doc = json.loads((folder / "tree.json").read_text())
    (folder / "inconsistent.json").write_text(json.dumps(
        {**tree_doc, "feature_names": tree_doc["feature_names"][:3]}))
    (folder / "module_task.json").write_text(json.dumps(
        {**tree_doc, "task": "evil_env_module:CartPole-v1"}))
    (folder / "evil_env_module.py").write_text(
        f"import os\nos.mkdir({str(folder / 'PWNED')!r})\n")
    (folder / "duplicate_keys.json").write_text(
        (folder / "bt.json").read_text().replace('"format":', '"format": "x", "format":', 1))
    for name, levels in [("deep", 150), ("very_deep", 500)]:  # text: json.dumps would recurse
        root = '{"type": "inverter", "children": [' * levels + '{"type": "action", "action": 0}'
        root += "]}" * levels
        head = json.dumps({**doc, "root": None})
        (folder / f"{name}.json").write_text(head.replace('"root": null', f'"root": {root}'))
    cyclic = DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, y)
    state = cyclic.tree_.__getstate__()
    state["nodes"]["left_child"][1] = 0  # node 1's left child is the root: a cycle
    cyclic.tree_.__setstate__(state)
    save_tree_file(folder / "cyclic.json", cyclic, task, {})
    joblib.dump({"format": "ibt-tree/1", "tree": Payload(folder), "task": "CartPole-v1"},
                folder / "evil.joblib")
    shutil.copy(folder / "evil.joblib", folder / "evil_renamed.json")
    os.truncate(_sparse(folder / "huge.json"), 65 << 20)  # sparse: no disk used
    os.mkfifo(folder / "pipe.json")
    shutil.copy(MOUNTAINCAR_PPO, folder / "mc_no_sidecar.zip")
    for name, sidecar in [("mc_short", '{"mean": [0, 0, 0], "var": [1, 1, 1], "epsilon": 1e-8, '
                                       '"clip": 10}'), ("mc_broken", "{mean")]:
        shutil.copy(MOUNTAINCAR_PPO, folder / f"{name}.zip")
        (folder / f"{name}.obs_norm.json").write_text(sidecar)
    (folder / "exiting_env_module.py").write_text("import sys\nsys.exit(3)\n")
    (folder / "not_a_zip.zip").write_text("not a checkpoint")
    (folder / "a_folder").mkdir()
    (folder / "a_file.txt").write_text("a file, not a folder")
    (folder / "broken_env_module.py").write_text("raise RuntimeError('the module is broken')\n")
    return folder


def _sparse(path: Path) -> Path:
    path.touch()
    return path


#: (id, argv, words the one-line message must contain); {d}: the input folder, {o}: an empty
#: output folder per case
CASES: list[tuple[str, list[str], str]] = [
    # --- BT JSON files
    *[(f"bt-{name}", ["evaluate", f"{{d}}/{name}.json", "--task", "CartPole-v1"], words)
      for name, words in [
          ("nan_threshold", "threshold must be finite"),
          ("infinite_threshold", "threshold must be finite"),
          ("string_threshold", "threshold must be a number"),
          ("fractional_feature", "feature must be an integer index, got 0.7"),
          ("boolean_feature", "feature must be an integer index"),
          ("feature_out_of_range", "condition on feature 9"),
          ("misspelt_key", "lacks 'threshold'"),
          ("negative_action", "non-negative index"),
          ("action_out_of_range", "action 5, but the tree names 2 actions"),
          ("no_default_and_a_gap", "no action is reached on some states (e.g. cart_position"),
          ("no_action_at_all", "no action is reached"),
          ("empty_selector", "needs at least one child"),
          ("inverter_with_two_children", "exactly one child"),
          ("unknown_node_type", "unknown node type 'parallel'"),
          ("no_root", "lacks the key 'root'"),
          ("repeated_feature_name", "names 'cart_position' twice"),
          ("other_format", "ibt-behavior-tree/9"),
          ("not_json", "not strict JSON"),
      ]],
    ("bt-of-another-task", ["evaluate", "{d}/bt.json", "--task", "MountainCar-v0"],
     "but MountainCar-v0 has position, velocity"),
    ("bt-without-task", ["evaluate", "{d}/bt.json"], "does not name its task"),
    ("bt-missing", ["export", "{d}/nothing.json", "--format", "json", "-o", "{o}/x.json"],
     "no behavior tree at"),
    ("bt-export-nan", ["export", "{d}/nan_threshold.json", "--format", "btcpp-xml", "-o",
                       "{o}/x.xml"], "threshold must be finite"),
    ("bt-duplicate-keys", ["evaluate", "{d}/duplicate_keys.json", "--task", "CartPole-v1"],
     "duplicate key 'format'"),
    ("bt-150-deep", ["export", "{d}/deep.json", "--format", "json", "-o", "{o}/x.json"],
     "more than 100 levels deep"),
    ("bt-500-deep", ["evaluate", "{d}/very_deep.json", "--task", "CartPole-v1"],
     "very_deep.json is nested too deeply"),
    ("bt-device", ["export", "/dev/zero", "--format", "json", "-o", "{o}/x.json"],
     "/dev/zero is not a regular file"),
    ("bt-pipe", ["evaluate", "{d}/pipe.json", "--task", "CartPole-v1"],
     "pipe.json is not a regular file"),
    ("bt-too-large", ["export", "{d}/huge.json", "--format", "json", "-o", "{o}/x.json"],
     "more than a behavior tree may be"),
    # --- decision-tree files
    ("tree-of-another-task", ["evaluate", "{d}/tree.json", "--task", "MountainCar-v0"],
     "was distilled on CartPole-v1, not MountainCar-v0"),
    ("tree-garbage", ["synthesize", "{d}/garbage_tree.json", "-o", "{o}/bt.json"],
     "is not a valid decision-tree file: not strict JSON"),
    ("tree-dict", ["synthesize", "{d}/dict_tree.json", "-o", "{o}/bt.json"],
     "not a decision-tree file"),
    ("tree-inconsistent", ["synthesize", "{d}/inconsistent.json", "-o", "{o}/bt.json"],
     "reads 4 features"),
    ("tree-missing", ["synthesize", "{d}/nothing.json", "-o", "{o}/bt.json"],
     "no decision-tree file at"),
    ("tree-is-a-folder", ["synthesize", "{d}/a_folder", "-o", "{o}/bt.json"], "is a folder"),
    ("tree-with-a-cycle", ["synthesize", "{d}/cyclic.json", "-o", "{o}/bt.json"],
     "do not form a decision tree"),
    ("tree-device", ["synthesize", "/dev/zero", "-o", "{o}/bt.json"], "not a regular file"),
    ("tree-names-a-module", ["synthesize", "{d}/module_task.json", "-o", "{o}/bt.json"],
     "a tree file imports nothing"),
    ("tree-pickle-synthesize", ["synthesize", "{d}/evil.joblib", "-o", "{o}/bt.json"],
     "python -m ibt convert-tree"),
    ("tree-pickle-evaluate", ["evaluate", "{d}/evil.joblib"], "--trust-pickle"),
    ("tree-pickle-refine", ["refine", "{d}/evil.joblib", "-o", "{o}/t.json"],
     "would run code when read"),
    ("tree-pickle-named-json", ["synthesize", "{d}/evil_renamed.json", "-o", "{o}/bt.json"],
     "binary: a pickle or an archive"),
    ("convert-untrusted", ["convert-tree", "{d}/evil.joblib", "-o", "{o}/t.json"],
     "--trust-pickle"),
    ("convert-a-json-tree", ["convert-tree", "{d}/tree.json", "-o", "{o}/t.json",
                             "--trust-pickle"], "JSON tree files need no conversion"),
    ("policy-unknown", ["evaluate", "{d}/policy.txt", "--task", "CartPole-v1"],
     "expected a BT (.json), a decision-tree file (.json) or an expert"),
    # --- numbers
    ("selection-episodes-0", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                              "--selection-episodes", "0"], "must be at least 1"),
    ("iterations-negative", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                             "--iterations", "-3"], "must be at least 1"),
    ("labels-not-a-number", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                             "--labels", "many"],
     "expected an integer (expert labels), got 'many'"),
    ("one-leaf", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                  "--max-leaf-nodes", "1"], "must be at least 2"),
    ("seed-negative", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json", "--seed", "-1"],
     "must be at least 0"),
    ("evaluate-episodes-0", ["evaluate", "{d}/bt.json", "--task", "CartPole-v1",
                             "--episodes", "0"], "must be at least 1"),
    ("random-episodes-0", ["random-baselines", "CartPole-v1", "--episodes", "0", "-o",
                           "{o}/r.csv"], "must be at least 1"),
    ("timesteps-0", ["train", "CartPole-v1", "--algo", "ppo", "--timesteps", "0",
                     "--experts-dir", "{o}/experts"], "must be at least 1"),
    ("max-leaf-nodes-huge", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                             "--max-leaf-nodes", "100000000000000000000"],
     "--max-leaf-nodes: must be at most 100,000"),
    ("episodes-float", ["evaluate", "{d}/bt.json", "--task", "CartPole-v1", "--episodes",
                        "1e20"], "--episodes: expected an integer (episodes), got '1e20'"),
    ("episodes-huge", ["evaluate", "{d}/bt.json", "--task", "CartPole-v1", "--episodes",
                       "100000000000"], "must be at most 1,000,000"),
    ("seed-beyond-32-bits", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json", "--seed",
                             "4294967296"], "--seed: must be at most 4,294,967,295"),
    ("labels-huge", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json", "--labels",
                     "10000000000"], "--labels: must be at most"),
    ("refine-episodes-huge", ["refine", "{d}/tree.json", "-o", "{o}/t.json", "--episodes",
                              "10000000000"], "must be at most 10,000,000"),
    ("groot-port-huge", ["run-btcpp", "{d}/bt.xml", "--task", "CartPole-v1", "--groot-port",
                         "70000"], "must be at most 65,535"),
    ("step-delay-huge", ["run-btcpp", "{d}/bt.xml", "--task", "CartPole-v1", "--step-delay",
                         "1e9"], "from 0 to 60"),
    # --- output paths, checked before any work
    ("output-is-a-folder", ["synthesize", "{d}/tree.json", "-o", "{d}/a_folder"],
     "is a folder"),
    ("output-under-a-file", ["synthesize", "{d}/tree.json", "-o", "{d}/a_file.txt/bt.json"],
     "is a file, not a folder"),
    ("distill-output-suffix", ["distill", "CartPole-v1", "ppo", "-o", "{o}/tree.joblib"],
     "expected a .json file, e.g. -o"),
    ("export-output-suffix", ["export", "{d}/bt.json", "--format", "png", "-o", "{o}/bt.svg"],
     "expected a .png file"),
    ("random-output-suffix", ["random-baselines", "CartPole-v1", "-o", "{o}/random.txt"],
     "expected a .csv file"),
    ("experts-dir-is-a-file", ["train", "CartPole-v1", "--algo", "ppo", "--experts-dir",
                               "{d}/a_file.txt"], "is a file, not a folder"),
    ("output-unwritable", ["distill", "CartPole-v1", "ppo", "-o", "/sys/ibt-test/t.json"],
     "cannot write in /sys"),
    # --- tasks and environment modules
    ("task-misspelt", ["distill", "CartPol-v1", "ppo", "-o", "{o}/t.json"],
     "Did you mean CartPole-v1"),
    ("env-module-missing", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                            "--env-module", "no_such_package.envs"],
     "cannot import the environment module 'no_such_package.envs'"),
    ("env-module-broken", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                           "--env-module", "broken_env_module"], "the module is broken"),
    ("env-module-exits", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                          "--env-module", "exiting_env_module"], "called sys.exit(3)"),
    ("module-colon-id-missing", ["distill", "no_such_package:Env-v0", "ppo", "-o",
                                 "{o}/t.json"], "no module named 'no_such_package'"),
    ("continuous-actions", ["distill", "Pendulum-v1", "ppo", "-o", "{o}/t.json",
                            "--checkpoint", CARTPOLE_PPO], "acts in a Box of 1 dimension"),
    ("no-hyperparameters", ["train", "CartPole-v0", "--algo", "ppo", "--experts-dir",
                            "{o}/experts"], "no hyperparameters for (CartPole-v0, ppo)"),
    ("refresh-before-missing", ["train", "CartPole-v1", "--algo", "ppo", "--experts-dir",
                                "{o}/experts", "--refresh-before", "{o}/stamp"],
     "no such file"),
    # --- experts
    ("checkpoint-missing", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                            "--checkpoint", "{d}/nothing.zip"], "no expert checkpoint at"),
    ("checkpoint-of-another-algorithm", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                                         "--checkpoint", CARTPOLE_DQN],
     "is a DQN checkpoint, not a PPO one; pass dqn"),
    ("checkpoint-is-a-folder", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                                "--checkpoint", "{d}/a_folder"], "is a folder, not a"),
    ("checkpoint-not-a-zip", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                              "--checkpoint", "{d}/not_a_zip.zip"], "not a zip archive"),
    ("checkpoint-of-another-task", ["distill", "MountainCar-v0", "ppo", "-o", "{o}/t.json",
                                    "--checkpoint", CARTPOLE_PPO], "another task"),
    ("checkpoint-same-shape-other-task", ["distill", "FrozenLake-v1", "ppo", "-o",
                                          "{o}/t.json", "--checkpoint", CLIFF_PPO],
     "observes Discrete(48), but FrozenLake-v1 has Discrete(16)"),
    ("checkpoint-without-sidecar", ["evaluate", "ppo", "--task", "MountainCar-v0",
                                    "--checkpoint", "{d}/mc_no_sidecar.zip"],
     "mc_no_sidecar.obs_norm.json is missing"),
    ("checkpoint-short-sidecar", ["evaluate", "ppo", "--task", "MountainCar-v0",
                                  "--checkpoint", "{d}/mc_short.zip"],
     "mc_short.obs_norm.json normalises 3 means"),
    ("checkpoint-broken-sidecar", ["evaluate", "ppo", "--task", "MountainCar-v0",
                                   "--checkpoint", "{d}/mc_broken.zip"],
     "mc_broken.obs_norm.json is not a readable normalisation sidecar"),
    ("checkpoint-device", ["distill", "CartPole-v1", "ppo", "-o", "{o}/t.json",
                           "--checkpoint", "/dev/zero"], "/dev/zero is not a regular file"),
    ("xml-device", ["run-btcpp", "/dev/zero", "--task", "CartPole-v1"], "not a regular file"),
    ("expert-without-task", ["evaluate", "ppo", "--episodes", "1"], "needs --task"),
    ("checkpoint-for-a-bt", ["evaluate", "{d}/bt.json", "--task", "CartPole-v1",
                             "--checkpoint", CARTPOLE_PPO], "--checkpoint is for experts"),
    # --- the parser itself
    ("missing-output", ["synthesize", "{d}/tree.json"], "required: -o/--output"),
    ("unknown-algorithm", ["train", "CartPole-v1", "--algo", "ddpg"], "invalid choice: 'ddpg'"),
    ("algorithm-not-in-catalogue", ["train", "CartPole-v1", "--algo", "sac"],
     "no hyperparameters for (CartPole-v1, sac)"),
    ("no-command", [], "required: command"),
]


def _listing(*folders: Path) -> set[Path]:
    return {p for folder in folders for p in folder.rglob("*")}


@pytest.mark.parametrize(("argv", "words"), [(argv, words) for _, argv, words in CASES],
                         ids=[case for case, _, _ in CASES])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(argv, words, files, tmp_path,
                                                             monkeypatch, capsys):
    if any(a.startswith("/sys/") for a in argv) and not Path("/sys").is_dir():
        pytest.skip("no /sys here")
    monkeypatch.syspath_prepend(str(files))
    out = tmp_path / "out"
    out.mkdir()
    argv = [a.replace("{d}", str(files)).replace("{o}", str(out)) for a in argv]
    before = _listing(files, out)
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert words in lines[0]
    assert captured.out == ""
    assert _listing(files, out) == before  # nothing written, no temporary file left


def test_the_table_is_large():
    assert len(CASES) >= 30
    assert len({case for case, _, _ in CASES}) == len(CASES)


def test_a_read_only_folder_is_found_before_any_work(files, tmp_path):
    """Run as a user who meets permission bits (root without its override: CI runs as root)."""
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        done = run_unprivileged([sys.executable, "-m", "ibt", "synthesize",
                                 str(files / "tree.json"), "-o", str(folder / "bt.json")])
        assert done.returncode == 2, done.stderr
        assert len(done.stderr.splitlines()) == 1 and "cannot write in" in done.stderr
        assert done.stdout == "" and list(folder.iterdir()) == []
    finally:
        folder.chmod(0o700)
