"""The command line: each subcommand end to end on tiny budgets, and clear errors."""

from __future__ import annotations

import json

import pytest

from ibt.cli import main
from ibt.experts import expert_path

TINY = ["--iterations", "2", "--labels", "200", "--selection-episodes", "2", "--quiet"]


@pytest.fixture(scope="module")
def tree_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "tree.joblib"
    assert main(["distill", "CartPole-v1", "ppo", "-o", str(out), *TINY]) == 0
    return out


def test_distill_synthesize_evaluate_export(tree_file, tmp_path, capsys):
    bt_file = tmp_path / "bt.json"
    assert main(["synthesize", str(tree_file), "-o", str(bt_file)]) == 0
    doc = json.loads(bt_file.read_text())
    assert doc["root"]["type"] == "selector"
    assert main(["synthesize", str(tree_file), "-o", str(tmp_path / "re.json"),
                 "--method", "re-bt-espresso"]) == 0
    assert main(["evaluate", str(bt_file), "--task", "CartPole-v1", "--episodes", "3"]) == 0
    bt_line = capsys.readouterr().out.strip().splitlines()[-1]
    assert main(["evaluate", str(tree_file), "--episodes", "3"]) == 0
    tree_line = capsys.readouterr().out.strip().splitlines()[-1]
    assert bt_line == tree_line  # the BT plays exactly as its tree
    for fmt, suffix in [("json", "json"), ("dot", "dot"), ("btcpp-xml", "xml"), ("svg", "svg")]:
        out = tmp_path / f"out.{suffix}"
        assert main(["export", str(bt_file), "--format", fmt, "-o", str(out)]) == 0
        assert out.exists() and out.stat().st_size > 0
    assert "BTCPP_format" in (tmp_path / "out.xml").read_text()


def test_distill_accepts_a_plain_gymnasium_id_with_a_checkpoint(tmp_path, capsys):
    # CartPole-v0 is not a registered task: features become x0..x3
    out = tmp_path / "v0.joblib"
    code = main(["distill", "CartPole-v0", "ppo", "-o", str(out), "--checkpoint",
                 str(expert_path("CartPole-v1", "ppo")), *TINY])
    assert code == 0, capsys.readouterr().err
    assert main(["synthesize", str(out), "-o", str(tmp_path / "v0.json")]) == 0
    assert json.loads((tmp_path / "v0.json").read_text())["feature_names"][0] == "x0"


@pytest.mark.parametrize(("argv", "message"), [
    (["distill", "CartPol-v1", "ppo", "-o", "x"], "Did you mean CartPole-v1"),
    (["distill", "NoSuchEnv-v9", "ppo", "-o", "x"], "unknown task"),
    (["distill", "CartPole-v1", "ppo", "-o", "x", "--checkpoint", "/nonexistent.zip"],
     "no expert checkpoint"),
    (["distill", "MountainCar-v0", "ppo", "-o", "x", "--checkpoint", "CARTPOLE"],
     "another task"),
    (["synthesize", "/nonexistent.joblib", "-o", "x"], "no decision-tree file"),
    (["evaluate", "ppo", "--episodes", "1"], "needs --task"),
    (["export", "/nonexistent.json", "--format", "json", "-o", "x"], "no behavior tree"),
])
def test_bad_input_exits_2_with_a_message(argv, message, capsys):
    argv = [str(expert_path("CartPole-v1", "ppo")) if a == "CARTPOLE" else a for a in argv]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_help_lists_every_subcommand(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    for command in ("train", "distill", "synthesize", "evaluate", "export"):
        assert command in text


def test_train_and_random_baselines_write_where_told(tmp_path, capsys):
    import pandas as pd

    experts = tmp_path / "experts"
    assert main(["train", "FrozenLake-v1", "--algo", "ppo", "--timesteps", "256",
                 "--experts-dir", str(experts)]) == 0
    assert (experts / "FrozenLake-v1" / "ppo.zip").exists()
    row = pd.read_csv(experts / "manifest.csv").iloc[0]
    assert (row.task, row.algo, row.n_episodes) == ("FrozenLake-v1", "ppo", 100)
    assert row.meets_bar in (True, False) and row.sha256
    out = tmp_path / "random.csv"
    assert main(["random-baselines", "CartPole-v1", "--episodes", "5", "-o", str(out)]) == 0
    assert pd.read_csv(out).set_index("task").loc["CartPole-v1", "n_episodes"] == 5
    with pytest.raises(SystemExit):
        main(["train", "CartPole-v1", "--algo", "sac"])
    assert "invalid choice" in capsys.readouterr().err
