"""Docs that cannot drift: every repository path, ``ibt`` module, ``python -m ibt`` command and
flag, and ``make`` target named in README.md, docs/ and paper/ exists.

:func:`problems` reads markdown files and returns one line per stale reference, naming the file,
the kind and the reference; the planted-doc tests prove it names each kind. Pages and flags
another piece of work is adding are listed in :data:`AWAITED` until they exist.
"""

from __future__ import annotations

import ast
import functools
import glob
import itertools
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "paper").rglob("*.md")])
TOP = ("ibt", "data", "figures", "notebooks", "docs", "paper", "tests")
ROOT_FILES = ("Makefile", "pyproject.toml", "environment.lock", "requirements.in", "README.md")
#: named by the README before they land (other branches of this work add them); a reference
#: listed here is accepted while it is missing, and checked like any other once it exists
AWAITED: dict[str, set[str]] = {}

_PATH = re.compile(r"(?<![\w/.:<-])((?:" + "|".join(TOP) + r")/[\w./<>{},*+-]*)")
_LINK = re.compile(r"\]\(([^)\s]+)\)")
_INLINE = re.compile(r"`([^`]+)`")
_MODULE = re.compile(r"(?<![\w./])ibt(?:\.[A-Za-z_]\w*)+")
# a sub-command followed by ":" is a message the CLI printed, not a command
_COMMAND = re.compile(r"python -m ibt[ \t]+([a-z][a-z-]*)(?![a-z-]|:)([^`\n#]*)")
_FENCE = re.compile(r"^```\w*\n(.*?)^```", re.M | re.S)


def _expand(path: str) -> list[str]:
    """``a.{b,c}`` -> ``a.b``, ``a.c``."""
    match = re.search(r"\{([^{}]*)\}", path)
    if not match:
        return [path]
    return [p for option in match.group(1).split(",")
            for p in _expand(path[:match.start()] + option + path[match.end():])]


def _exists(path: str, base: Path) -> bool:
    """Whether a path (placeholders ``<x>`` cut off, globs matched) names something."""
    for one in _expand(path.split("#")[0].rstrip(".,;:")):
        if "<" in one:
            one = one[:one.index("<")]
        target = base / one
        if any(c in one for c in "*?["):
            if not glob.glob(str(target)):
                return False
        elif not target.exists():
            return False
    return True


@functools.cache
def _cli() -> dict[str, set[str]]:
    """``python -m ibt`` sub-command -> its option strings."""
    from ibt.cli.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and isinstance(a.choices, dict))
    return {name: set(p._option_string_actions) for name, p in sub.choices.items()}


@functools.cache
def _make_targets(root: Path) -> set[str]:
    return set(re.findall(r"^([A-Za-z][\w-]*)\s*:", (root / "Makefile").read_text(), re.M))


@functools.cache
def _top_names(source: Path) -> dict[str, set[str]]:
    """A module's top-level names, each class with the names in its body."""
    tree = ast.parse(source.read_text())
    names: dict[str, set[str]] = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names[node.name] = set()
        elif isinstance(node, ast.ClassDef):
            inner = {n.name for n in node.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
            inner |= {t.id for n in node.body if isinstance(n, ast.AnnAssign)
                      for t in [n.target] if isinstance(t, ast.Name)}
            names[node.name] = inner
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update({t.id: set() for t in targets if isinstance(t, ast.Name)})
            if any(isinstance(t, ast.Name) and t.id == "_LAZY" for t in targets) and isinstance(
                    node.value, ast.Dict):  # ibt/__init__.py: names imported on first use
                names.update({k.value: set() for k in node.value.keys
                              if isinstance(k, ast.Constant)})
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update({(a.asname or a.name).split(".")[0]: set() for a in node.names})
    return names


def _module_ok(name: str, root: Path) -> bool:
    """``ibt.a.b`` is a module or package of the repository, ``ibt.a.b.NAME`` (or
    ``.Class.attr``) a name defined at its top level."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        stem = root.joinpath(*parts[:i])
        source = (stem.with_suffix(".py") if stem.with_suffix(".py").is_file()
                  else stem / "__init__.py" if (stem / "__init__.py").is_file() else None)
        if source is None:
            continue
        rest = parts[i:]
        if not rest:
            return True
        names = _top_names(source)
        if rest[0] not in names:
            return False
        return len(rest) == 1 or not names[rest[0]] or rest[1] in names[rest[0]]
    return False


def problems(docs: list[Path], root: Path = ROOT) -> list[str]:
    """One line per stale reference in ``docs``: ``<doc>: <kind> <reference>``."""
    out: list[str] = []

    def stale(doc: Path, kind: str, ref: str) -> None:
        if ref not in AWAITED.get(kind, set()):
            line = f"{doc.name}: {kind} {ref}"
            if line not in out:
                out.append(line)

    cli = _cli()
    flags = set(itertools.chain.from_iterable(cli.values()))
    for doc in docs:
        text = doc.read_text()
        prose = _INLINE.sub("", _FENCE.sub("", text))
        for link in _LINK.findall(prose):
            if not re.match(r"[a-z]+:|#", link):
                local = link.split("#")[0]
                if not _exists(local, doc.parent):
                    stale(doc, "path", (doc.parent / local).resolve().relative_to(
                        root.resolve()).as_posix() if (doc.parent / local).resolve().is_relative_to(
                        root.resolve()) else local)
        for path in _PATH.findall(re.sub(r"\]\([^)]*\)|https?://\S+", "", text)):
            if not _exists(path, root):
                stale(doc, "path", path.rstrip(".,;:"))
        for code in _INLINE.findall(text):
            code = code.strip()
            if code in ROOT_FILES and not (root / code).exists():
                stale(doc, "path", code)
            if code.startswith("--") and code.split()[0] not in flags:
                stale(doc, "flag", code.split()[0])
            if code.startswith("make "):
                target = code.split()[1]
                if target not in _make_targets(root):
                    stale(doc, "make target", target)
        for block in _FENCE.findall(text):
            for line in block.splitlines():
                if line.startswith("make ") and line.split()[1] not in _make_targets(root):
                    stale(doc, "make target", line.split()[1])
        for module in _MODULE.findall(text):
            if not _module_ok(module, root):
                stale(doc, "module", module)
        for command, rest in _COMMAND.findall(text):
            if command not in cli:
                stale(doc, "command", f"python -m ibt {command}")
                continue
            for flag in re.findall(r"(?<!\S)(--[a-z][\w-]*)", rest):
                if flag not in cli[command]:
                    stale(doc, "flag", flag)
    return out


def test_the_docs_name_only_what_exists():
    assert DOCS, "no docs found"
    assert problems(DOCS) == []


def test_a_planted_stale_doc_is_named_line_by_line(tmp_path):
    # Expect: each stale kind is named: a path in backticks, a broken link, a flag of a real
    # sub-command, a sub-command, a bare flag, a make target, a module and a module's name
    doc = tmp_path / "stale.md"
    doc.write_text(
        "See `figures/no_such_figure.png` and [the guide](no_such_guide.md).\n"
        "Run `python -m ibt evaluate bt.json --task CartPole-v1 --no-such-flag 3`, then\n"
        "`python -m ibt no-such-command`; pass `--no-such-option`, run `make no-such-target`.\n"
        "```bash\nmake another-missing-target\n```\n"
        "The code: `ibt.no_such_package.x` and `ibt.cache.store.NO_SUCH_NAME`.\n")
    found = problems([doc])
    for expected in ["path figures/no_such_figure.png", "path no_such_guide.md",
                     "flag --no-such-flag", "command python -m ibt no-such-command",
                     "flag --no-such-option", "make target no-such-target",
                     "make target another-missing-target", "module ibt.no_such_package.x",
                     "module ibt.cache.store.NO_SUCH_NAME"]:
        assert f"stale.md: {expected}" in found, (expected, found)
    assert len(found) == 9, found


def test_a_planted_doc_naming_only_real_things_passes(tmp_path):
    # Expect: no false alarms on real paths, placeholders, globs, braces, flags, targets, names
    doc = tmp_path / "fine.md"
    doc.write_text(
        "`data/trees/<task>/<algo>/<method>.json`, `data/results/*.csv`,\n"
        "`figures/quickstart_bt.{svg,png}`, `Makefile`, `ibt.cache.store.CODE_VERSIONS`,\n"
        "`ibt.bt.model.BehaviorTree`, `python -m ibt evaluate bt.json --task X --episodes 5`,\n"
        "`--keep 0.95`, `make figures`, and `ibt.synth.decision_list`.\n")
    assert problems([doc]) == []


def test_the_awaited_references_are_only_those_not_yet_here():
    # Expect: an awaited page that exists is checked like any other (the list only shrinks)
    assert all(not (ROOT / p).exists() or _exists(p, ROOT) for p in AWAITED.get("path", ()))
