"""The house rules as tests: a lazy package root and an import contract that catches breaches."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("torch", "gymnasium", "sklearn", "pandas", "stable_baselines3")


def _loaded_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys\n"
                          "print('MODULES:', *sorted(m.split('.')[0] for m in sys.modules))"],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    line = out.stdout.rsplit("MODULES:", 1)[1]
    return set(line.split())


@pytest.mark.parametrize("code", ["import ibt", "import ibt.tasks.settings",
                                  "import ibt.cli; ibt.cli.build_parser()"])
def test_light_imports_load_no_compute_stack(code):
    # Expect: none of the heavy libraries is loaded by the package root, the statistics or the
    # CLI's parser
    assert not _loaded_after(code) & set(HEAVY)


def test_cli_help_loads_no_compute_stack():
    code = ("import sys, runpy\nsys.argv = ['ibt', '--help']\ntry:\n"
            "    runpy.run_module('ibt', run_name='__main__')\nexcept SystemExit:\n    pass")
    assert not _loaded_after(code) & set(HEAVY)


def test_lazy_names_resolve():
    import ibt

    assert callable(ibt.config) and callable(ibt.get_task) and ibt.BehaviorTree.__name__
    with pytest.raises(AttributeError):
        ibt.no_such_name  # noqa: B018


def _lint_imports(tree: Path) -> subprocess.CompletedProcess:
    linter = Path(sys.executable).parent / "lint-imports"
    return subprocess.run([str(linter), "--no-cache", "--config", str(tree / "pyproject.toml")],
                          capture_output=True, text=True, cwd=tree,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tree)})


@pytest.fixture(scope="module")
def package_copy(tmp_path_factory):
    tree = tmp_path_factory.mktemp("house")
    shutil.copytree(ROOT / "ibt", tree / "ibt", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


@pytest.mark.parametrize(("module", "line", "broken"), [
    ("report/markdown.py", "from ibt.runs import grid", "Report side"),
    ("report/stats.py", "from ibt.distill import loop", "Report side"),
    ("report/claims.py", "from ibt.experts import expert", "Report side"),
    ("bt/model.py", "from ibt.synth import rules", "Layers"),
    ("tasks/catalogue.py", "from ibt.experts import expert", "Layers"),
    ("synth/rules.py", "from ibt.refine import tree_arrays", "Layers"),
])
def test_contract_catches_an_upward_or_forbidden_import(package_copy, module, line, broken):
    # Expect: the unmodified copy keeps every contract; one added import breaks the named one
    assert _lint_imports(package_copy).returncode == 0
    path = package_copy / "ibt" / module
    original = path.read_text()
    try:
        path.write_text(original + f"\n{line}  # noqa\n")
        result = _lint_imports(package_copy)
        assert result.returncode != 0
        assert any(broken in ln and "BROKEN" in ln for ln in result.stdout.splitlines()), \
            result.stdout
    finally:
        path.write_text(original)
