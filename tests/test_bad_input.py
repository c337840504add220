"""Bad input at every boundary of the command line: exit code 2, one line, nothing written.

Each row of :data:`CASES` is a command that must fail before doing any work: a bad BT file
(NaN threshold, fractional index, no reachable action ...), a bad or mismatched tree file, a
number out of range, an output path that cannot be written, an environment module that cannot
be imported, a checkpoint of another kind, a pickle that would run code, a device or a pipe
instead of a file, a BT nested too deeply, every option and path of ``pipeline``, an output that
is the command's own input, a weight or command outside the number rule, BehaviorTree.CPP XML
with attributes or nodes ibt does not write. The test runs it, expects exit code 2, exactly one
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
    _hostile_inputs(folder, doc)
    return folder


#: BehaviorTree.CPP attributes ibt does not model, each put on the first <Sequence>
XML_ATTRIBUTES = ("_skipIf", "_successIf", "_failureIf", "_while", "_pre", "_post",
                  "_onSuccess", "_onFailure", "_onHalted")


def _hostile_inputs(folder: Path, doc: dict) -> None:
    """Links, numbers at the edge of the number rule, XML edited past what ibt writes."""
    from ibt.export.btcpp import to_btcpp_xml

    (folder / "loop_a").symlink_to(folder / "loop_b")
    (folder / "loop_b").symlink_to(folder / "loop_a")
    (folder / "dangling").symlink_to(folder / "nowhere")
    (folder / "bt_link.json").symlink_to(folder / "bt.json")
    relational = _mutate(doc, lambda d: _first_condition(d).update(
        {"form": {"features": [0, 1], "weights": [1e-320, -1.0]}}))
    del _first_condition(relational)["feature"]  # a relational condition names no feature
    (folder / "weight_subnormal.json").write_text(json.dumps(relational))
    text = json.dumps(_mutate(doc, _set("threshold", 12345.0)))
    (folder / "threshold_huge_int.json").write_text(text.replace("12345.0", "1" + "0" * 400))
    pendulum = json.loads((Path(__file__).resolve().parents[1] / "data" / "trees" / "Pendulum-v1"
                           / "sac" / "imitation-bt-plus.json").read_text())
    pendulum["commands"]["values"][0][0] = 1e300
    (folder / "command_huge.json").write_text(json.dumps(pendulum))
    from ibt.bt.model import BehaviorTree

    xml = to_btcpp_xml(BehaviorTree.from_dict(doc))
    (folder / "bt.xml").write_text(xml)
    for name in XML_ATTRIBUTES:
        (folder / f"{name}.xml").write_text(xml.replace("<Sequence>", f'<Sequence {name}="x">', 1))
    (folder / "SubTree.xml").write_text(xml.replace("<Sequence>", '<SubTree ID="T"/><Sequence>', 1))
    (folder / "Parallel.xml").write_text(xml.replace("Sequence>", "Parallel>"))
    (folder / "include.xml").write_text(xml.replace("<TreeNodesModel>",
                                                    '<include path="x.xml"/><TreeNodesModel>'))
    (folder / "not_utf8.xml").write_bytes(xml.encode().replace(b"<root", b"<root \xff", 1))


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
    # --- pipeline: every option, path and input checked before any work
    *[(f"pipeline-{name}", ["pipeline", "CartPole-v1", "ppo", "-o", "{o}/p", *extra], words)
      for name, extra, words in [
          ("keep-0", ["--keep", "0"], "--keep: must be in (0, 1]"),
          ("keep-nan", ["--keep", "nan"], "--keep: must be in (0, 1]"),
          ("keep-text", ["--keep", "most"], "--keep: expected a share such as 0.95"),
          ("budget-word", ["--budget", "lots"], "--budget: expected smoke"),
          ("budget-0x", ["--budget", "0x"], "--budget: expected smoke"),
          ("budget-2000x", ["--budget", "2000x"], "--budget: expected smoke"),
          ("budget-episodes-huge", ["--budget", "99999999999"],
           "--budget: refinement episodes per leaf limit must be at most 10,000,000"),
          ("budget-very-long", ["--budget", "9" * 5000], "--budget: expected smoke"),
          ("leaves-1", ["--leaves", "1,4"], "--leaves: leaf limits must be at least 2"),
          ("leaves-huge", ["--leaves", "4,100000000000000000000"],
           "--leaves: leaf limits must be at most 100,000"),
          ("leaves-5000-digits", ["--leaves", "9" * 5000], "--leaves: expected leaf limits"),
          ("leaves-too-many", ["--leaves", ",".join(map(str, range(2, 40)))],
           "--leaves: at most 12 leaf limits"),
          ("leaves-text", ["--leaves", "four"], "--leaves: expected leaf limits"),
          ("leaves-empty", ["--leaves", ","], "--leaves: leaf limits must be at least 2"),
          ("episodes-0", ["--episodes", "0"], "--episodes: must be at least 1"),
          ("episodes-huge", ["--episodes", "100000000000"], "must be at most 1,000,000"),
          ("episodes-float", ["--episodes", "1e3"], "--episodes: expected an integer"),
          ("seed-negative", ["--seed", "-1"], "--seed: must be at least 0"),
          ("seed-beyond-32-bits", ["--seed", "4294967296"], "must be at most 4,294,967,295"),
          ("checkpoint-missing", ["--checkpoint", "{d}/nothing.zip"], "no SB3 checkpoint at"),
          ("checkpoint-is-a-folder", ["--checkpoint", "{d}/a_folder"], "is a folder"),
          ("checkpoint-device", ["--checkpoint", "/dev/zero"], "not a regular file"),
          ("checkpoint-not-a-zip", ["--checkpoint", "{d}/not_a_zip.zip"], "not a zip archive"),
          ("checkpoint-of-another-algorithm", ["--checkpoint", CARTPOLE_DQN],
           "is a DQN checkpoint, not a PPO one"),
          ("cache-dir-is-a-file", ["--cache-dir", "{d}/a_file.txt"],
           "a_file.txt is a file, not a folder"),
          ("cache-dir-under-a-file", ["--cache-dir", "{d}/a_file.txt/cache"],
           "is a file, not a folder"),
          ("cache-dir-link-loop", ["--cache-dir", "{d}/loop_a"], "a loop of symbolic links"),
          ("cache-dir-is-the-output", ["--cache-dir", "{o}/p"], "is the output folder itself"),
      ]],
    ("pipeline-output-is-a-file", ["pipeline", "CartPole-v1", "ppo", "-o", "{d}/a_file.txt"],
     "is a file, not a folder"),
    ("pipeline-output-under-a-file", ["pipeline", "CartPole-v1", "ppo", "-o",
                                      "{d}/a_file.txt/out"], "is a file, not a folder"),
    ("pipeline-output-link-loop", ["pipeline", "CartPole-v1", "ppo", "-o", "{d}/loop_a"],
     "a loop of symbolic links"),
    ("pipeline-output-dangling-link", ["pipeline", "CartPole-v1", "ppo", "-o", "{d}/dangling"],
     "which does not exist"),
    ("pipeline-output-unwritable", ["pipeline", "CartPole-v1", "ppo", "-o", "/sys/ibt-test"],
     "cannot write in /sys"),
    ("pipeline-output-holds-other-files", ["pipeline", "CartPole-v1", "ppo", "-o", "{d}"],
     "holds files ibt pipeline did not write"),
    ("pipeline-task-misspelt", ["pipeline", "CartPol-v1", "ppo", "-o", "{o}/p"],
     "Did you mean CartPole-v1"),
    ("pipeline-env-module-missing", ["pipeline", "CartPole-v1", "ppo", "-o", "{o}/p",
                                     "--env-module", "no_such_package.envs"],
     "cannot import the environment module 'no_such_package.envs'"),
    ("pipeline-unknown-algorithm", ["pipeline", "CartPole-v1", "ddpg", "-o", "{o}/p"],
     "invalid choice: 'ddpg'"),
    ("pipeline-checkpoint-of-another-task", ["pipeline", "MountainCar-v0", "ppo", "-o",
                                             "{o}/p", "--checkpoint", CARTPOLE_PPO],
     "another task"),
    # --- no command writes over its own input
    ("synthesize-over-its-input", ["synthesize", "{d}/tree.json", "-o", "{d}/tree.json"],
     "never writes over its own input"),
    ("refine-over-its-input", ["refine", "{d}/tree.json", "-o", "{d}/tree.json"],
     "never writes over its own input"),
    ("export-over-its-input", ["export", "{d}/bt.json", "--format", "json", "-o",
                               "{d}/bt.json"], "never writes over its own input"),
    ("export-through-a-link-to-its-input", ["export", "{d}/bt.json", "--format", "json", "-o",
                                            "{d}/bt_link.json"], "is a symbolic link"),
    # --- one number rule for weights and commands
    ("weight-subnormal-evaluate", ["evaluate", "{d}/weight_subnormal.json", "--task",
                                   "CartPole-v1"], "not subnormal"),
    ("weight-subnormal-export", ["export", "{d}/weight_subnormal.json", "--format",
                                 "btcpp-xml", "-o", "{o}/x.xml"], "not subnormal"),
    ("threshold-huge-integer", ["evaluate", "{d}/threshold_huge_int.json", "--task",
                                "CartPole-v1"], "threshold must be finite"),
    ("command-beyond-float32", ["evaluate", "{d}/command_huge.json", "--task", "Pendulum-v1"],
     "not a finite number that fits in float32"),
    ("command-beyond-float32-export", ["export", "{d}/command_huge.json", "--format",
                                       "btcpp-xml", "-o", "{o}/x.xml"],
     "not a finite number that fits in float32"),
    ("discrete-bt-on-a-box-task", ["evaluate", "{d}/bt.json", "--task", "Pendulum-v1"],
     "has discrete actions (push_left, push_right), but Pendulum-v1 has continuous actions"),
    # --- BehaviorTree.CPP XML that differs from what ibt writes
    *[(f"xml-{name}", ["run-btcpp", f"{{d}}/{name}.xml", "--task", "CartPole-v1"], words)
      for name, words in [
          ("_skipIf", "attribute _skipIf, which ibt does not model (this file differs"),
          ("_successIf", "attribute _successIf"), ("_failureIf", "attribute _failureIf"),
          ("_while", "attribute _while"), ("_pre", "attribute _pre"),
          ("_post", "attribute _post"), ("_onSuccess", "attribute _onSuccess"),
          ("_onFailure", "attribute _onFailure"), ("_onHalted", "attribute _onHalted"),
          ("SubTree", "node <SubTree>, which ibt does not model"),
          ("Parallel", "node <Parallel>, which ibt does not model"),
          ("include", "<root> holds <include>, which ibt does not model"),
          ("not_utf8", "not_utf8.xml is not UTF-8 text"),
      ]],
    ("xml-discrete-on-a-box-task", ["run-btcpp", "{d}/bt.xml", "--task", "Pendulum-v1"],
     "it is a BT with discrete actions, but Pendulum-v1 has continuous actions"),
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
