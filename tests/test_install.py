"""The package installs outside the project's own ``.venv``: ``pip install -c environment.lock .``
into an empty virtual environment gives a working ``ibt`` command (slow: it installs torch and
the rest; 40 minutes, mostly pip, measured niced on 2 cores shared with a ``make figures`` run).

``pyproject.toml`` declares the runtime dependencies as compatible ranges and the lock pins them,
so the install resolves to exactly the tested versions. Offline: set ``IBT_WHEELHOUSE`` to a
folder of wheels (``pip download -d DIR -c environment.lock .`` fills one, the build backend
``setuptools`` included) and the install reads only that folder (``--no-index``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: what a source install needs: the build configuration, the files it names and the package
SOURCE = ("pyproject.toml", "README.md", "LICENSE", "ibt")


def _run(command: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "IBT_ROOT", "IBT_PROFILE")}
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


#: imported by ibt, installed by a declared package rather than declared itself
COMES_WITH = {"ipython": "ipykernel (notebooks)", "traitlets": "jupyterlab (notebooks)",
              "pygame-ce": "gymnasium's extras"}


def _key(name: str) -> str:
    return name.split("[")[0].lower().replace("_", "-")


def test_the_dependencies_cover_the_runtime_imports():
    # Expect: every third-party package ibt imports is declared (the notebook and book tooling
    # in the extras), and each declared range holds the locked version
    from importlib.metadata import packages_distributions

    from packaging.requirements import Requirement

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = [Requirement(r) for r in project["dependencies"]]
    for extra in project["optional-dependencies"].values():
        requirements += [Requirement(r) for r in extra]
    declared = {_key(r.name): r for r in requirements}
    locked = {_key(name): version for name, _, version in (
        line.partition("==") for line in (ROOT / "environment.lock").read_text().splitlines()
        if "==" in line and not line.startswith("#"))}
    for name, requirement in declared.items():
        assert name in locked, f"{name} is declared but not in environment.lock"
        assert requirement.specifier.contains(locked[name].strip(), prereleases=True), name
    imported = {words[1].split(".")[0] for path in (ROOT / "ibt").rglob("*.py")
                for words in map(str.split, path.read_text().splitlines())
                if len(words) >= 2 and words[0] in ("import", "from")}
    distributions = packages_distributions()
    missing = {_key(dist) for module in imported for dist in distributions.get(module, [])
               if _key(dist) in locked and _key(dist) not in declared
               and _key(dist) not in COMES_WITH}
    assert not missing, f"ibt imports {sorted(missing)}; declare them in pyproject.toml"


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_pip_install_with_the_lock_gives_a_working_ibt(tmp_path):
    # Expect: an empty venv, the source and the lock -> `ibt --help` and a CartPole pipeline at
    # the smoke budget work, from a folder that is not the repository
    source = tmp_path / "source"
    source.mkdir()
    for name in SOURCE:
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy2
        copy(ROOT / name, source / name)
    shutil.rmtree(source / "ibt" / "__pycache__", ignore_errors=True)
    venv = tmp_path / "venv"
    made = _run([sys.executable, "-m", "venv", str(venv)], tmp_path, 300)
    assert made.returncode == 0, made.stderr
    install = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet",
               "-c", str(ROOT / "environment.lock")]
    wheelhouse = os.environ.get("IBT_WHEELHOUSE")
    if wheelhouse:
        install += ["--no-index", "--find-links", wheelhouse]
    installed = _run([*install, str(source)], tmp_path, 3000)
    assert installed.returncode == 0, installed.stderr[-4000:]

    work = tmp_path / "work"
    work.mkdir()
    ibt = str(venv / "bin" / "ibt")
    helped = _run([ibt, "--help"], work, 120)
    assert helped.returncode == 0 and "pipeline" in helped.stdout, helped.stderr
    checkpoint = ROOT / "data" / "experts" / "CartPole-v1" / "ppo.zip"
    ran = _run([ibt, "pipeline", "CartPole-v1", "ppo", "--checkpoint", str(checkpoint),
                "-o", "my_bt", "--budget", "smoke", "--quiet"], work, 900)
    assert ran.returncode == 0, ran.stderr[-4000:]
    assert {"bt.json", "bt.xml", "report.md"} <= {p.name for p in (work / "my_bt").iterdir()}
