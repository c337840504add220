"""``python -m ibt run-btcpp`` and ``export --flavour``: BehaviorTree.CPP ticking a BT from the
command line, and one-line errors (exit 2) for XML it cannot run."""

from __future__ import annotations

import re
import socket

import pytest

from ibt.cli import main
from ibt.export import engine
from ibt.paths import DATA_DIR

MOUNTAINCAR = DATA_DIR / "trees/MountainCar-v0/dqn/imitation-bt.json"


@pytest.fixture(scope="module")
def xml_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("btcpp")
    portable, check = folder / "bt.xml", folder / "check.xml"
    assert main(["export", str(MOUNTAINCAR), "--format", "btcpp-xml", "-o", str(portable)]) == 0
    assert main(["export", str(MOUNTAINCAR), "--format", "btcpp-xml", "-o", str(check),
                 "--flavour", "check-feature"]) == 0
    return folder, portable, check


def test_export_writes_the_portable_flavour_by_default(xml_files):
    _, portable, check = xml_files
    assert "<ScriptCondition" in portable.read_text()
    assert "CheckFeature" not in portable.read_text()
    assert 'ID="CheckFeature"' in check.read_text()
    assert "<ScriptCondition" not in check.read_text()


def test_run_btcpp_prints_equal_returns_and_ticks_per_second(xml_files, capsys):
    _, portable, _ = xml_files
    assert main(["run-btcpp", str(portable), "--task", "MountainCar-v0", "--episodes", "3"]) == 0
    out = capsys.readouterr().out
    returns = re.search(r"BehaviorTree.CPP return (\S+) \+- (\S+) over 3 episodes; the Python BT "
                        r"(\S+) \+- (\S+) \(equal on every episode\); (\d+) ticks, 0 decisions "
                        "differ", out)
    assert returns, out
    assert returns[1] == returns[3] and returns[2] == returns[4]
    assert int(returns[5]) > 0
    rates = re.search(r"ticks per second, one state per tick: BehaviorTree.CPP ([\d,]+); "
                      r"ibt Python executor ([\d,]+)", out)
    assert rates and all(int(r.replace(",", "")) > 0 for r in rates.groups()), out


def _fails(argv, capsys, *patterns):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    for pattern in patterns:
        assert re.search(pattern, err), err


def test_xml_of_another_task_is_named(xml_files, capsys):
    _, portable, _ = xml_files
    _fails(["run-btcpp", str(portable), "--task", "CartPole-v1"], capsys,
           "key 'position'", "another task", "pass --task MountainCar-v0")


def test_unknown_action_id_is_named(xml_files, capsys):
    folder, portable, _ = xml_files
    bad = folder / "jump.xml"
    bad.write_text(portable.read_text().replace('<Action ID="right" />', '<Action ID="jump" />'))
    _fails(["run-btcpp", str(bad), "--task", "MountainCar-v0"], capsys,
           "unknown action ID 'jump'", "actions are left, no_push, right")


def test_check_feature_flavour_and_missing_files_are_refused(xml_files, capsys):
    folder, _, check = xml_files
    _fails(["run-btcpp", str(check), "--task", "MountainCar-v0"], capsys,
           "CheckFeature", "portable flavour")
    _fails(["run-btcpp", str(folder / "none.xml"), "--task", "MountainCar-v0"], capsys,
           "no BehaviorTree.CPP XML at", "export")
    (folder / "broken.xml").write_text("<root")
    _fails(["run-btcpp", str(folder / "broken.xml"), "--task", "MountainCar-v0"], capsys,
           "well-formed")


def test_bad_numbers_are_refused(xml_files, capsys):
    _, portable, _ = xml_files
    for argv in (["--episodes", "0"], ["--groot-port", "70000"], ["--step-delay", "-1"],
                 ["--step-delay", "nan"], ["--step-delay", "inf"]):
        code = main(["run-btcpp", str(portable), "--task", "MountainCar-v0", *argv])
        assert code == 2, argv
        assert capsys.readouterr().err.count("\n") == 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_groot_port_publishes_while_running(xml_files, capsys, monkeypatch):
    _, portable, _ = xml_files
    port = _free_port()
    connected = []
    original = engine.compare_rollouts

    def probe(_obs, _actions):  # during the first step, someone connects to the publisher
        if not connected:
            with socket.socket() as s:
                connected.append(s.connect_ex(("127.0.0.1", port)) == 0)

    monkeypatch.setattr(engine, "compare_rollouts",
                        lambda task, engine, seeds, on_step=None:
                        original(task, engine, seeds, on_step=probe))
    assert main(["run-btcpp", str(portable), "--task", "MountainCar-v0", "--episodes", "1",
                 "--groot-port", str(port)]) == 0
    assert connected == [True]
    monkeypatch.undo()
    # a port held by something else: one line, exit 2
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        _fails(["run-btcpp", str(portable), "--task", "MountainCar-v0", "--episodes", "1",
                "--groot-port", str(busy.getsockname()[1])], capsys,
               "cannot publish to Groot2 on port")
