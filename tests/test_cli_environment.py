"""A Python outside the project's venv: help texts work, every command answers with one line
naming ``make setup`` and ``source .venv/bin/activate`` (exit 2, no traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run_without(modules: tuple[str, ...], argv: list[str]) -> subprocess.CompletedProcess:
    """``python -m ibt ARGV`` in a Python where ``modules`` cannot be imported."""
    code = (f"import sys, runpy\nfor m in {modules!r}:\n    sys.modules[m] = None\n"
            f"sys.argv = ['ibt', *{argv!r}]\nrunpy.run_module('ibt', run_name='__main__')")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, timeout=60)


@pytest.mark.parametrize("argv", [["evaluate", "bt.json", "--task", "CartPole-v1"],
                                  ["export", "bt.json", "--format", "dot", "-o", "bt.dot"],
                                  ["distill", "CartPole-v1", "sac", "-o", "t.json"]])
def test_outside_the_venv_a_command_is_one_line(argv):
    done = _run_without(("gymnasium", "pandas"), argv)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert "make setup" in lines[0] and "source .venv/bin/activate" in lines[0]
    assert not done.stdout


@pytest.mark.parametrize("argv", [["--help"], ["evaluate", "--help"]])
def test_outside_the_venv_help_still_works(argv):
    done = _run_without(("gymnasium", "pandas", "torch", "numpy"), argv)
    assert done.returncode == 0, done.stderr
    assert "usage: python -m ibt" in done.stdout


def test_a_library_missing_mid_command_is_one_line_too(monkeypatch, capsys):
    import ibt.cli

    def needs_more(argv):
        raise ModuleNotFoundError("No module named 'behaviortreepy'", name="behaviortreepy")

    monkeypatch.setattr(ibt.cli, "run", needs_more)
    assert ibt.cli.main(["run-btcpp", "bt.xml", "--task", "CartPole-v1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'behaviortreepy'" in err[0] and "make setup" in err[0]


def test_a_missing_module_of_ours_is_a_bug_not_the_environment(monkeypatch):
    import ibt.cli

    def broken(argv):
        raise ModuleNotFoundError("No module named 'ibt.nowhere'", name="ibt.nowhere")

    monkeypatch.setattr(ibt.cli, "run", broken)
    with pytest.raises(ModuleNotFoundError):
        ibt.cli.main(["evaluate", "bt.json"])


def test_evaluate_help_lists_every_expert_algorithm(capsys):
    from ibt.cli import main
    from ibt.tasks.settings import ALGOS

    assert main(["evaluate", "--help"]) == 0
    assert "|".join(ALGOS) in capsys.readouterr().out


def test_notebook_runner_names_a_missing_notebook(capsys, tmp_path):
    from ibt.notebooks import main

    assert main(["run", str(tmp_path / "nope.ipynb")]) == 2
    assert "no notebook at" in capsys.readouterr().err


def test_pipeline_front_ticks_are_plain_numbers(monkeypatch, tmp_path):
    # Expect: 10, 20, 30, 50 on the log axis, never 2x10^1
    from types import SimpleNamespace as NS

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ibt.pipeline.outputs import draw_front

    kept, close = [], plt.close
    monkeypatch.setattr(plt, "close", kept.append)  # draw_front's figure stays to be read
    for nodes in ([9, 21, 41, 63, 7, 15], [5, 7, 9]):
        cands = [NS(label="distilled" if k % 2 else "refined", bt_nodes=n, retention=90.0,
                    leaf_limit=4) for k, n in enumerate(nodes)]
        draw_front(NS(candidates=cands, keep=0.95, chosen=cands[-1], task=NS(name="T"),
                      algo="ppo"), tmp_path / "front.png")
        ax = kept[-1].axes[0]
        kept[-1].canvas.draw()
        low, high = ax.get_xlim()
        labels = [t.get_text() for t in ax.get_xticklabels() if low <= t.get_position()[0] <= high]
        assert len(labels) >= 3 and all(label.isdigit() for label in labels), labels
        assert not [t.get_text() for t in ax.xaxis.get_minorticklabels() if t.get_text()]
        close(kept[-1])
