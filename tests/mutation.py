"""Mutation testing of the core with Cosmic Ray (``make mutants``): one small change to a module
at a time, then the tests that concern that module; a change no test notices is a survivor.

Each core module runs against the test files named for it in :data:`TESTS_OF` (the one place
that maps modules to tests); a module not named there runs against the test files that import
it, so the mapping follows a module that is split or renamed. Mutants are sampled with a fixed
seed (``--sample``, ``--seed``): the same sample on the same source. Sessions are Cosmic Ray
work databases under ``build/mutation/`` and resume: a rerun tests the pending mutants and
re-tests the survivors (the tests may have grown; not the known equivalents), and keeps the
killed ones unless the module changed; the unmutated run, which must pass, is skipped when
neither the module nor its tests changed since it last passed. A survivor listed in
:data:`EQUIVALENT` (a change that alters no behaviour) counts as equivalent, with its reason.
The summary, ``data/results/mutation_summary.csv``, and the generated part of
``docs/mutation.md`` are rewritten from the sessions after each module.

Usage: ``python -m tests.mutation [MODULE ...] [--sample N] [--seed S]`` (MODULE: a path such
as ``ibt/bt/executors.py``; none: every core module).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import csv
import fnmatch
import hashlib
import io
import json
import os
import random
import shlex
import signal
import sys
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCOPE = ("ibt/bt/*.py", "ibt/synth/*.py", "ibt/evaluate/*.py", "ibt/engine/*.py",
         "ibt/pipeline/owned_folder.py")
SESSIONS = ROOT / "build" / "mutation"
SUMMARY = ROOT / "data" / "results" / "mutation_summary.csv"
DOC = ROOT / "docs" / "mutation.md"
BEGIN, END = "<!-- mutation summary: begin -->", "<!-- mutation summary: end -->"
PYTEST_ARGS = '-x -q -m "not slow" -p no:cacheprovider'
DEFAULT_SAMPLE, DEFAULT_SEED = 30, 0
IN_ANNOTATION = "in a type annotation"
NOT_PYTHON = "the mutated module does not compile"

#: module (a glob relative to the repository root; the first match wins) -> the test files (or
#: single tests, ``file::name``) that concern it, quick ones first: a mutant's run stops at its
#: first failure. A module matched by no key runs against the test files that import it.
TESTS_OF: dict[str, tuple[str, ...]] = {
    "ibt/bt/executors.py": ("tests/test_executors_law.py", "tests/test_mutants.py",
                            "tests/test_bt.py", "tests/test_nonfinite.py"),
    "ibt/bt/model.py": ("tests/test_bt_model_law.py", "tests/test_executors_law.py",
                        "tests/test_bt.py", "tests/test_linear_law.py",
                        "tests/test_controller_bt_law.py",
                        "tests/test_nonfinite.py", "tests/test_mutants.py"),
    # the proof's parts first, then BTs it proves or refuses, then its relational gaps
    "ibt/bt/coverage.py": (
        "tests/test_coverage_law.py", "tests/test_bt.py",
        "tests/test_relational_bt.py::test_guards_that_cover_every_state_on_one_form_are_proved",
        "tests/test_relational_bt.py::test_a_gap_between_relational_guards_is_found_with_a_state",
        "tests/test_relational_bt.py::test_guards_that_cover_only_geometrically_are_refused_"
        "not_trusted"),
    # its own laws (forms, feature maps, exact thresholds); its importers learn relational
    # trees, run the engine or distil controllers (minutes a mutant)
    "ibt/bt/linear.py": ("tests/test_linear_law.py",),
    # its own laws on hand-made regions and BTs; its importers run the verifier and the
    # engine on learnt relational trees (minutes a mutant)
    "ibt/bt/polytope.py": ("tests/test_polytope_law.py",),
    # its own laws (split tests, commands, layout, checks, rules text) on hand-made trees
    "ibt/synth/controller.py": ("tests/test_controller_bt_law.py",),
    # its own laws; the files importing it (the CLI, the grid, Box tasks) take minutes a mutant
    "ibt/synth/registry.py": ("tests/test_synth_registry.py",),
    # the reader's own laws; its importers (the CLI, the views, the engines) take minutes
    "ibt/bt/json_io.py": ("tests/test_json_io.py",),
    # merging leaves into commands on hand-made trees; its importers distil an expert's tree
    "ibt/synth/commands.py": ("tests/test_commands.py",),
    # the route and its verifier on small relational trees (seconds); the importers run the
    # CLI, the grid, the engines or every synthesiser on relational trees
    "ibt/synth/relational.py": ("tests/test_synth_relational.py",),
    # the exact region arithmetic against brute force, then the synthesis's own tests
    "ibt/synth/decision_list_exact.py": (
        "tests/test_decision_list_exact.py",
        "tests/test_decision_list.py::test_decides_like_is_exact_where_sampling_is_not",
        "tests/test_decision_list.py::test_simplify_and_factoring_keep_every_decision"),
    # the winner and what it reports on small trees, then the size table; the other tests of
    # tests/test_decision_list.py read committed trees or run the CLI (minutes a mutant)
    "ibt/synth/decision_list.py": (
        "tests/test_decision_list_winner.py",
        "tests/test_decision_list.py::test_size_table_reads_the_synthesis_rows",
        "tests/test_decision_list.py::test_single_leaf_and_relabelled_trees"),
    # factoring against brute force and hand-worked factorings
    "ibt/synth/decision_list_factoring.py": (
        "tests/test_decision_list_factoring.py",
        "tests/test_decision_list.py::test_simplify_and_factoring_keep_every_decision"),
    "ibt/synth/imitation.py": ("tests/test_verification_law.py", "tests/test_mutants.py",
                               "tests/test_synthesis.py"),
    "ibt/synth/rules.py": ("tests/test_rules_logic.py", "tests/test_verification_law.py",
                           "tests/test_mutants.py", "tests/test_synthesis.py"),
    "ibt/bt/document.py": ("tests/test_bt_document.py", "tests/test_bt_model_law.py",
                           "tests/test_relational_bt.py"),
    # the workers' progress lines: in-process laws, then two loky workers (seconds)
    "ibt/engine/worker_progress.py": ("tests/test_worker_progress.py",),
    # the digests' laws on hand-made trees; the importers run the ladder (minutes)
    "ibt/engine/keys.py": ("tests/test_keys.py",),
    # the cluster and the cores stood in for in-process, then one run on two loky workers
    "ibt/engine/parallel.py": ("tests/test_parallel.py",),
    # settings only; the importers run searches and learners
    "ibt/engine/budgets.py": ("tests/test_budgets_law.py", "tests/test_budgets.py"),
    # the plan as data; tests/test_plan.py replays plans on trained agents (minutes)
    "ibt/engine/plan.py": ("tests/test_plan_file.py",),
    # the arithmetic first; then the ladder's use of it (which trains agents: minutes)
    "ibt/engine/deadline.py": ("tests/test_deadline_law.py", "tests/test_deadline.py"),
    # in-process tests only: the CLI runs of test_hostile_files.py take minutes a mutant
    "ibt/pipeline/owned_folder.py": (
        "tests/test_owned_folder.py",
        "tests/test_hostile_files.py::test_every_point_of_the_write_phase_leaves_a_whole_set",
        "tests/test_hostile_files.py::test_the_force_note_names_an_edited_file_as_edited",
        "tests/test_hostile_files.py::test_a_file_edited_during_the_run_is_not_replaced",
        "tests/test_deletes_only_its_own.py::test_the_pipeline_removes_only_temporary_folders_"
        "it_recorded",
        "tests/test_pipeline_outputs.py::test_an_old_gif_of_ours_is_removed_and_a_users_is_"
        "left"),
    "ibt/evaluate/rollouts.py": ("tests/test_seed_blocks.py", "tests/test_retention_law.py",
                                 "tests/test_rollout_accounting.py", "tests/test_env_faults.py",
                                 "tests/test_mutants.py",
                                 # its quick test (the others run the CLI on hostile envs
                                 # or an endless one)
                                 "tests/test_hostile_env.py::test_retention_is_undefined_not_"
                                 "an_error_where_the_agent_is_random"),
}

#: Survivors that change no behaviour: (module, the line as written, the line as mutated,
#: why no test can tell them apart). Lines are compared without blanks.
EQUIVALENT: tuple[tuple[str, str, str, str], ...] = (
    ("ibt/bt/executors.py",
     'where = f"feature {bad[-1]}" + (f" of row {bad[0]}" if bad.size > 1 else "")',
     'where = f"feature {bad[-1]}" + (f" of row {bad[0]}" if bad.size != 1 else "")',
     "`bad` is one row of `np.argwhere` on an array of at least one dimension, so its size "
     "is never below 1: `> 1` and `!= 1` agree"),
    ("ibt/bt/executors.py", "ok = not visit(children[0], depth + 1)",
     "ok = not visit(children[-1], depth + 1)",
     "an Inverter has exactly one child, so `children[0]` and `children[-1]` name it"),
    ("ibt/synth/imitation.py", "return _condition(term[0])", "return _condition(term[-1])",
     "the branch is taken for a term of exactly one literal, which `term[0]` and `term[-1]` "
     "both name"),
    ("ibt/synth/imitation.py", "return next(rs.k for rs in sets if rs.action == action)",
     "return next(rs.k for rs in sets if rs.action is action)",
     "actions are small Python integers, one object each in CPython, so `is` and `==` agree"),
    ("ibt/evaluate/rollouts.py", 'call = "reset" if slot_length[s] == 0 else "step"',
     'call = "reset" if slot_length[s] <= 0 else "step"',
     "an episode's length counts its steps from 0 and is never negative"),
    ("ibt/evaluate/rollouts.py", "bad = np.flatnonzero(~np.isfinite(array.reshape(-1)))",
     "bad = np.flatnonzero(~np.isfinite(array.reshape(-2)))",
     "NumPy (the pinned 2.x) reads any negative size as the one inferred dimension"),
    ("ibt/evaluate/rollouts.py", "slot_episode = [-1] * n_slots", "slot_episode = [1] * n_slots",
     "every slot is started, which sets its episode (or -1), before anything reads it"),
    ("ibt/bt/executors.py",
     'if x.ndim != 2 or x.shape[1] != io["n_features"]:',
     'if x.ndim is not 2 or x.shape[1] != io["n_features"]:',
     "CPython keeps one object per small integer, so `ndim is not 2` and `ndim != 2` agree"),
    ("ibt/bt/executors.py",
     'if x.ndim != 2 or x.shape[1] != io["n_features"]:',
     'if x.ndim != 2 or x.shape[1] is not io["n_features"]:',
     "CPython keeps one object per small integer (a feature count is one), so `is not` and "
     "`!=` agree"),
    ("ibt/pipeline/owned_folder.py",
     "if threading.current_thread() is not threading.main_thread():",
     "if threading.current_thread() != threading.main_thread():",
     "`threading.Thread` defines no equality, so `!=` compares identities as `is not` does"),
    ("ibt/bt/document.py", "return Inverter(children[0])",
     "return Inverter(children[-1])",
     "the line follows the check that an inverter has exactly one child, which `children[0]` "
     "and `children[-1]` both name"),
    ("ibt/synth/rules.py", "if left == right:  # leaf", "if left >= right:  # leaf",
     "scikit-learn adds a node's two children together, the left one first, so an inner "
     "node's left child is numbered below its right one; at a leaf both are -1"),
    ("ibt/synth/rules.py", "action = int(classes[int(np.argmax(t.value[node][0]))])",
     "action = int(classes[int(np.argmax(t.value[node][-1]))])",
     "a tree of one output (every tree ibt distils; a multi-output tree's classes cannot be "
     "read as actions at all) has one row of class weights per node, which `[0]` and `[-1]` "
     "both name"),
    ("ibt/bt/json_io.py", "data = fh.read(MAX_BT_BYTES + 1)",
     "data = fh.read(MAX_BT_BYTES | 1)",
     "`MAX_BT_BYTES` is `64 << 20`, an even number, so `| 1` and `+ 1` give the same size"),
    ("ibt/synth/commands.py",
     "for node in range(t.node_count - 1, -1, -1):  # children come after their parent",
     "for node in range(t.node_count - 2, -1, -1):  # children come after their parent",
     "scikit-learn numbers a node's children after it, so a fitted tree's last node is a "
     "leaf, where the loop's body does nothing: leaving it out changes no value"),
    ("ibt/synth/commands.py", "if left != -1:", "if left > -1:",
     "a node's left child is a node number (at least 1) or -1 at a leaf (scikit-learn's "
     "TREE_LEAF), so `!= -1` and `> -1` agree"),
    ("ibt/engine/parallel.py", "if not isinstance(outcome[0], BaseException):",
     "if not isinstance(outcome[-1], BaseException):",
     "the connecting thread appends exactly one thing (the client or its error), and the line "
     "is reached only where it has: `outcome[0]` and `outcome[-1]` name it"),
    ("ibt/engine/parallel.py",
     "return items / n_jobs if running == items > n_jobs else float(math.ceil(items / running))",
     "return items / n_jobs if running >= items > n_jobs else float(math.ceil(items / running))",
     "`processes` gives `items` or `n_jobs`, and where `items > n_jobs` neither is above "
     "`items`, so `running >= items` holds exactly where `running == items` does"),
    ("ibt/engine/plan.py", "if self.done < len(self.entries):",
     "if self.done != len(self.entries):",
     "`done` counts the entries taken, and `take` returns None at the last one instead of "
     "going past it, so `done` never exceeds their number: `<` and `!=` agree"),
    ("ibt/engine/budgets.py",
     'if search_episodes is not None and cfg.profile != "smoke":',
     'if search_episodes is not None and cfg.profile < "smoke":',
     "a profile is `paper` or `smoke` (`ibt.config` refuses any other), and `paper` sorts "
     "before `smoke`: `< \"smoke\"` and `!= \"smoke\"` agree on both"),
    ("ibt/bt/coverage.py", "cut = lo if rlo < lo < rhi else hi if rlo < hi < rhi else None",
     "cut = lo if rlo < lo < rhi else hi if rlo <= hi < rhi else None",
     "the box is live, so it meets the region: on each of its features `hi > rlo`, and "
     "`rlo <= hi` and `rlo < hi` agree"),
    ("ibt/bt/coverage.py",
     "np.nextafter(np.float32(lo), np.float32(np.inf)) if math.isfinite(lo) else 0.0)",
     "np.nextafter(np.float32(lo), np.float32(np.inf)) if math.isfinite(lo) else 1.0)",
     "a region names a feature only once it was split there, at a cut strictly inside its "
     "bounds, so one of its two bounds is finite and the last branch is never taken"),
    ("ibt/bt/coverage.py",
     "def _truth(node: Node, negate: bool = False, columns: Columns | None = None",
     "def _truth(node: Node, negate: bool = True, columns: Columns | None = None",
     "every call of `_truth` passes `negate` (its three calls, all in the module), so the "
     "default is never used"),
    ("ibt/bt/coverage.py", "guarded = acts or fails or any(k.guarded for k in kids)",
     "guarded = acts and fails or any(k.guarded for k in kids)",
     "a Sequence that surely acts or surely fails has a child that does, and every node that "
     "surely acts or fails is guarded (an Action is; an Inverter, a Sequence and a Fallback "
     "are by their own rules), so `any(k.guarded)` already holds there"),
    ("ibt/synth/controller.py",
     "out.extend(part.children if type(part) is Sequence else (part,))",
     "out.extend(part.children if type(part) == Sequence else (part,))",
     "`type(part)` is a class, and classes compare by identity (no metaclass of a node "
     "defines `==`), so `==` and `is` agree"),
    ("ibt/synth/controller.py", 'lines.append(f"{head} {bt.label(body[0])}")',
     'lines.append(f"{head} {bt.label(body[-1])}")',
     "the line is reached only where `len(body) == 1`, where `body[0]` and `body[-1]` name "
     "the same node"),
    ("ibt/bt/polytope.py",
     'bounds=[(-1.0, 1.0)] * n_features + [(None, 1.0)], method="highs")',
     'bounds=[(-1.0, 2.0)] * n_features + [(None, 1.0)], method="highs")',
     "a state needs the margin `s > 0`, and the box's rows `|u_f| + s <= 1` then keep every "
     "`u_f` below 1 already: the bound 1 or 2 never binds where `s > 0`, so the deepest "
     "margin and the points that reach it are the same (among several, which one is returned "
     "is the solver's choice either way)"),
    *(("ibt/synth/relational.py",
       "states = np.concatenate([np.asarray(rows, dtype=np.float32).reshape(-1, "
       "task.n_features),",
       f"states = np.concatenate([np.asarray(rows, dtype=np.float32).reshape({size}, "
       "task.n_features),",
       "NumPy (the pinned 2.x) reads any negative size as the one inferred dimension, an "
       "empty list of rows included") for size in ("~1", "-2")),
    ("ibt/synth/decision_list_exact.py",
     "keep = lit.threshold == hi if lit.le else lit.threshold == lo",
     "keep = lit.threshold <= hi if lit.le else lit.threshold == lo",
     "`hi` is the least threshold of the feature's `<=` literals, this one's among them, so "
     "its threshold is at least `hi`: `<= hi` holds exactly where `== hi` does"),
    ("ibt/synth/decision_list_exact.py",
     "keep = lit.threshold == hi if lit.le else lit.threshold == lo",
     "keep = lit.threshold == hi if lit.le else lit.threshold is lo",
     "`lo` is the threshold object of the feature's first `>` literal with the greatest "
     "threshold (`max` returns the first of equal arguments), which `is` keeps; a later `>` "
     "literal of the feature with an equal threshold equals that literal and is dropped "
     "as a repeat either way"),
    *(("ibt/synth/decision_list.py",
       'frame["tree_splits"] = (frame["tree_nodes"] - 1) // 2',
       f'frame["tree_splits"] = (frame["tree_nodes"] {op}) // 2',
       "a binary tree's node count is odd (`2 * splits + 1`), so floor division by 2 gives "
       "the same splits from `nodes` as from `nodes - 1`") for op in ("- 0", "** 1")),
    *(("ibt/engine/worker_progress.py",
       'self.bars.append(tqdm(total=0, bar_format="{desc}", leave=False,',
       f'self.bars.append(tqdm(total={total}, bar_format="{{desc}}", leave=False,',
       "a line's bar shows `{desc}` alone and never advances: its total feeds only the "
       "fraction, rate and time left that this format leaves out, so the drawn text is the "
       "same (checked with tqdm 4.70 for totals 0, 1 and -1)") for total in (1, -1)),
    ("ibt/bt/model.py",
     "if len(terms) > MAX_TERMS or len(set(features)) != len(features):",
     "if len(terms) > MAX_TERMS or len(set(features)) is not len(features):",
     "the comparison is reached only where `len(terms) <= MAX_TERMS` (4), so both lengths are "
     "at most 4, inside CPython's cache of small integers (-5 to 256, one object each): "
     "`is not` and `!=` agree (unlike `checked_names`' lengths, which a test takes past 256)"),
)

#: Why the keyword-only ``*`` of a signature mutated into ``/`` changes nothing.
KEYWORD_ONLY = ("the bare `*` of a signature as `/`: the parameters after it could then be "
                "passed by position too, but every caller names them, so no call changes")


@dataclass(frozen=True)
class Row:
    """One line of the summary."""

    module: str
    tests: str
    mutants: int
    in_annotations: int
    sampled: int
    killed: int
    survived: int
    equivalent: int
    not_python: int
    incompetent: int

    @property
    def score(self) -> str:
        judged = self.killed + self.survived
        return f"{100.0 * self.killed / judged:.1f}" if judged else ""


def core_modules() -> list[str]:
    """Every module in the scope, as repository-relative paths."""
    found = {p.relative_to(ROOT).as_posix() for pattern in SCOPE for p in ROOT.glob(pattern)}
    return sorted(m for m in found if not m.endswith("__init__.py"))


def _dotted(module: str) -> str:
    return module.removesuffix(".py").replace("/", ".")


def importers(module: str) -> tuple[str, ...]:
    """The test files that import ``module`` (``import a.b.c``, ``from a.b.c import x`` or
    ``from a.b import c``), found in their syntax trees."""
    name = _dotted(module)
    parent, _, leaf = name.rpartition(".")
    found = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name == name for a in node.names):
                break
            if isinstance(node, ast.ImportFrom) and (
                    node.module == name
                    or (node.module == parent and any(a.name == leaf for a in node.names))):
                break
        else:
            continue
        found.append(path.relative_to(ROOT).as_posix())
    return tuple(found)


def tests_of(module: str) -> tuple[str, ...]:
    """The test files that concern ``module``: :data:`TESTS_OF`, else its importers."""
    for pattern, tests in TESTS_OF.items():
        if fnmatch.fnmatchcase(module, pattern):
            return tuple(t for t in tests if (ROOT / t.partition("::")[0]).exists())
    return importers(module)


def test_command(tests: tuple[str, ...]) -> str:
    return f"{shlex.quote(sys.executable)} -m pytest {PYTEST_ARGS} {' '.join(tests)}"


def _equivalence(module: str, diff: str) -> str | None:
    def bare(line: str) -> str:  # Cosmic Ray may respace a line it mutates
        return "".join(line.split())

    removed = [bare(ln[1:]) for ln in diff.splitlines()
               if ln.startswith("-") and not ln.startswith("---")]
    added = [bare(ln[1:]) for ln in diff.splitlines()
             if ln.startswith("+") and not ln.startswith("+++")]
    if (len(removed) == len(added) == 1 and removed[0].startswith("def")
            and removed[0].replace("*,", "/,") == added[0]):
        return KEYWORD_ONLY
    for mod, before, after, reason in EQUIVALENT:
        if mod == module and bare(before) in removed and bare(after) in added:
            return reason
    return None


@contextlib.contextmanager
def _terminate_cleanly() -> Iterator[None]:
    """SIGTERM and SIGHUP raise, so that Cosmic Ray puts a mutated module back."""
    def stop(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)
    old = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _session_paths(module: str) -> tuple[Path, Path, Path]:
    stem = module.removesuffix(".py").replace("/", ".")
    return (SESSIONS / f"{stem}.sqlite", SESSIONS / f"{stem}.json",
            SESSIONS / f"{stem}.backup")


def _restore_backup(module: str) -> None:
    """Put back a module left mutated by a run that was killed outright."""
    _, _, backup = _session_paths(module)
    if backup.exists():
        (ROOT / module).write_bytes(backup.read_bytes())
        backup.unlink()
        print(f"{module}: restored from {backup} (a previous run was killed mid-mutant)")


def run_module(module: str, sample: int, seed: int) -> None:
    """Measure ``module``: init (or resume) its session, test the sampled mutants."""
    from cosmic_ray.commands import init
    from cosmic_ray.mutating import mutate_and_test
    from cosmic_ray.testing import run_tests
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome, WorkResult

    SESSIONS.mkdir(parents=True, exist_ok=True)
    db_path, meta_path, backup = _session_paths(module)
    _restore_backup(module)
    source = ROOT / module
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    tests = tests_of(module)
    if not tests:
        print(f"{module}: no test file concerns it; skipped")
        return
    meta = {"source": digest, "sample": sample, "seed": seed}
    old_meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    fresh = {k: old_meta.get(k) for k in meta} != meta or not db_path.exists()
    command = test_command(tests)
    tests_digest = hashlib.sha256(b"".join(
        (ROOT / t.partition("::")[0]).read_bytes() for t in tests) + command.encode()).hexdigest()
    if old_meta.get("source") == digest and old_meta.get("tests_digest") == tests_digest:
        baseline = float(old_meta["baseline_s"])  # passed on this very code and these tests
    else:
        start = time.monotonic()
        outcome, output = run_tests(command, 1800)
        baseline = time.monotonic() - start
        if outcome != TestOutcome.SURVIVED:
            sys.exit(f"{module}: its tests fail on the unmutated code; fix them first:\n"
                     f"{command}\n{output[-2000:]}")
    # a mutant that loops forever is killed by it; generous, as a run under `nice` on a loaded
    # machine can take minutes where its baseline took seconds (a false kill otherwise)
    timeout = max(300.0, 5 * baseline)
    if fresh:
        db_path.unlink(missing_ok=True)
    with use_db(str(db_path), WorkDB.Mode.create) as db:
        if fresh:
            init([source.relative_to(ROOT)], db, {})
            spans = annotation_spans(source)
            everything = sorted(db.work_items, key=lambda w: (
                w.mutations[0].operator_name, w.mutations[0].occurrence))
            notes = [w for w in everything if _in_annotation(
                spans, w.mutations[0].start_pos, w.mutations[0].end_pos)]
            db.set_multiple_results([w.job_id for w in notes], WorkResult(
                worker_outcome=WorkerOutcome.SKIPPED, output=IN_ANNOTATION))
            noted = {w.job_id for w in notes}
            items = [w for w in everything if w.job_id not in noted]
            random.Random(f"{module}:{seed}").shuffle(items)
            code = source.read_text(encoding="utf-8")
            chosen: set[str] = set()
            for item in items:  # the first ``sample`` mutants, in a seeded order, that compile
                if len(chosen) == sample:
                    break
                if _compiles(code, item.mutations[0]):
                    chosen.add(item.job_id)
                else:
                    db.set_result(item.job_id, WorkResult(
                        worker_outcome=WorkerOutcome.SKIPPED, output=NOT_PYTHON))
            judged = chosen | {job for job, r in db.results if r.output == NOT_PYTHON}
            db.set_multiple_results([w.job_id for w in items if w.job_id not in judged],
                                    WorkResult(worker_outcome=WorkerOutcome.SKIPPED))
        done = {job: result for job, result in db.results}
        ordered = sorted(db.work_items, key=lambda w: (
            w.mutations[0].operator_name, w.mutations[0].occurrence))
        todo = [w for w in ordered if w.job_id not in done
                or (done[w.job_id].worker_outcome == WorkerOutcome.NORMAL
                    and done[w.job_id].test_outcome == TestOutcome.SURVIVED
                    and not _equivalence(module, done[w.job_id].diff or ""))]
        meta_path.write_text(json.dumps({**meta, "tests": list(tests),
                                         "tests_digest": tests_digest, "baseline_s": baseline}))
        print(f"{module}: {len(todo)} mutants to test against {len(tests)} test files "
              f"(baseline {baseline:.0f} s, timeout {timeout:.0f} s)", flush=True)
        for n, item in enumerate(todo, 1):
            backup.write_bytes(source.read_bytes())
            t0 = time.monotonic()
            try:
                with _terminate_cleanly():
                    result = mutate_and_test(item.mutations, command, timeout)
            finally:  # Cosmic Ray has put the module back (a SIGKILL leaves the backup)
                backup.unlink()
            db.set_result(item.job_id, result)
            spec = item.mutations[0]
            print(f"  [{n}/{len(todo)}] {spec.operator_name}#{spec.occurrence} line "
                  f"{spec.start_pos[0]}: {result.test_outcome} "
                  f"({time.monotonic() - t0:.0f} s)", flush=True)


def summarise(module: str) -> tuple[Row, list[tuple[str, str]], list[tuple[str, str]]] | None:
    """The row of ``module`` from its session, its survivors' and its equivalents' diffs."""
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome

    db_path, meta_path, _ = _session_paths(module)
    if not db_path.exists() or not meta_path.exists():
        return None
    tests = json.loads(meta_path.read_text())["tests"]
    counts = dict.fromkeys(("killed", "survived", "equivalent", "not_python", "incompetent"), 0)
    code = (ROOT / module).read_text(encoding="utf-8")
    survivors, equivalents = [], []
    with use_db(str(db_path), WorkDB.Mode.open) as db:
        total = db.num_work_items
        results = dict(db.results)
        sampled = sum(1 for r in results.values() if r.worker_outcome != WorkerOutcome.SKIPPED)
        in_annotations = sum(1 for r in results.values() if r.output == IN_ANNOTATION)
        specs = {w.job_id: w.mutations[0] for w in db.work_items}
        for job, result in results.items():
            if result.worker_outcome in (WorkerOutcome.SKIPPED, WorkerOutcome.NO_TEST):
                continue
            if result.worker_outcome != WorkerOutcome.NORMAL:
                counts["incompetent"] += 1
            elif not _compiles(code, specs[job]):
                counts["not_python"] += 1
            elif result.test_outcome == TestOutcome.SURVIVED:
                diff = result.diff or ""
                reason = _equivalence(module, diff)
                if reason:
                    counts["equivalent"] += 1
                    equivalents.append((diff, reason))
                else:
                    counts["survived"] += 1
                    survivors.append((diff, ""))
            else:
                counts["killed"] += 1
    return (Row(module, " ".join(Path(t).name for t in tests), total, in_annotations,
                sampled, **counts),
            survivors, equivalents)


def annotation_spans(path: Path) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Where ``path`` writes type annotations: a mutant there alters no behaviour when the
    module defers annotations (``from __future__ import annotations``), so it is not sampled."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    deferred = any(isinstance(n, ast.ImportFrom) and n.module == "__future__"
                   and any(a.name == "annotations" for a in n.names) for n in tree.body)
    if not deferred:
        return []
    notes: list[ast.expr] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.arg) and node.annotation is not None:
            notes.append(node.annotation)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.returns:
            notes.append(node.returns)
        elif isinstance(node, ast.AnnAssign):
            notes.append(node.annotation)
    return [((n.lineno, n.col_offset), (n.end_lineno or n.lineno, n.end_col_offset or 0))
            for n in notes]


def _compiles(code: str, spec: object) -> bool:
    """Whether the mutant ``spec`` of ``code`` is valid Python (Cosmic Ray also rewrites the
    bare ``*`` of keyword-only parameters, which no test needs to notice)."""
    from cosmic_ray.mutating import mutate_code
    from cosmic_ray.plugins import get_operator

    operator = get_operator(spec.operator_name)(**spec.operator_args)  # type: ignore[attr-defined]
    mutated = mutate_code(code, operator, spec.occurrence)  # type: ignore[attr-defined]
    if mutated is None:
        return False
    try:
        with warnings.catch_warnings():  # e.g. "is not" with a literal: valid, if odd
            warnings.simplefilter("ignore", SyntaxWarning)
            compile(mutated, "<mutant>", "exec")
    except SyntaxError:
        return False
    return True


def _in_annotation(spans: list[tuple[tuple[int, int], tuple[int, int]]],
                   start: tuple[int, int], end: tuple[int, int]) -> bool:
    return any(a <= tuple(start) and tuple(end) <= b for a, b in spans)


def _changed_lines(diff: str) -> str:
    lines = [ln for ln in diff.splitlines() if ln[:1] in "-+" and ln[:3] not in ("---", "+++")]
    return " / ".join(f"`{ln[0]} {ln[1:].strip()}`" for ln in lines)


def _listed_lines() -> dict[str, dict[str, list[str]]]:
    """The survivor and equivalent lines of docs/mutation.md's generated part, by section and
    module: a module without a session here keeps its lines, as it keeps its row."""
    doc = DOC.read_text(encoding="utf-8") if DOC.exists() else ""
    block = doc.partition(BEGIN)[2].partition(END)[0]
    found: dict[str, dict[str, list[str]]] = {"survivors": {}, "equivalents": {}}
    section = None
    for line in block.splitlines():
        if line.startswith("Survivors"):
            section = "survivors"
        elif line.startswith("Equivalent"):
            section = "equivalents"
        elif section and line.startswith("- `"):
            found[section].setdefault(line[3:].partition("`")[0], []).append(line)
    return found


def write_summary() -> None:
    """Rewrite the CSV and the generated part of docs/mutation.md from every session (a module
    without a session keeps its committed row)."""
    from ibt.files import atomic_write_text

    fields = ("module", "tests", "mutants", "in_annotations", "sampled", "killed", "survived",
              "equivalent", "not_python", "incompetent", "score_pct")
    old: dict[str, dict[str, str]] = {}
    if SUMMARY.exists():
        with SUMMARY.open(newline="") as f:
            old = {r["module"]: r for r in csv.DictReader(f)}
    listed = _listed_lines()
    rows, survivors, equivalents = [], [], []
    for module in core_modules():
        got = summarise(module)
        if got is None:
            rows.append(old.get(module, {"module": module, "tests": "not measured"}))
            survivors += listed["survivors"].get(module, [])
            equivalents += listed["equivalents"].get(module, [])
            continue
        row, surv, equiv = got
        rows.append({**{f: getattr(row, f) for f in fields[:-1]}, "score_pct": row.score})
        survivors += [f"- `{module}`: {_changed_lines(d)}" for d, _ in surv]
        equivalents += [f"- `{module}`: {_changed_lines(d)}: {r}" for d, r in equiv]
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    writer.writerows({f: r.get(f, "") for f in fields} for r in rows)
    atomic_write_text(SUMMARY, out.getvalue())
    table = ["| module | mutants | in annotations | sampled | killed | survived | equivalent "
             "| score |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r.get("sampled"):
            table.append(f"| `{r['module']}` | {r['mutants']} | {r['in_annotations']} "
                         f"| {r['sampled']} | {r['killed']} | {r['survived']} "
                         f"| {r['equivalent']} | {r['score_pct']} % |")
    unmeasured = [f"`{r['module']}`" for r in rows if not r.get("sampled")]
    text = ["", *table, ""]
    if unmeasured:
        text += [f"Not measured yet: {', '.join(unmeasured)}.", ""]
    text += ["Survivors (each a change no mapped test notices):", ""]
    text += survivors or ["- none"]
    text += ["", "Equivalent mutants (excluded from the score):", ""]
    text += equivalents or ["- none"]
    doc = DOC.read_text(encoding="utf-8")
    head, _, rest = doc.partition(BEGIN)
    _, _, tail = rest.partition(END)
    atomic_write_text(DOC, head + BEGIN + "\n".join(text) + "\n" + END + tail)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.mutation", description=__doc__)
    parser.add_argument("modules", nargs="*", help="core modules (default: all)")
    parser.add_argument("--sample", type=int, default=DEFAULT_SAMPLE,
                        help="mutants sampled per module (a fixed-seed sample)")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--summary-only", action="store_true",
                        help="rewrite the summary from the sessions, testing nothing")
    args = parser.parse_args(argv)
    scope = core_modules()
    unknown = [m for m in args.modules if m not in scope]
    if unknown:
        print(f"not a core module: {', '.join(unknown)}; pick from: {' '.join(scope)}",
              file=sys.stderr)
        return 2
    if args.sample < 1:
        print("--sample must be at least 1", file=sys.stderr)
        return 2
    os.chdir(ROOT)  # Cosmic Ray mutates and tests relative to the working directory
    start = time.monotonic()
    if not args.summary_only:
        for module in args.modules or scope:
            run_module(module, args.sample, args.seed)
            write_summary()
    write_summary()
    print(f"mutation testing: {time.monotonic() - start:.0f} s; summary in "
          f"{SUMMARY.relative_to(ROOT)} and {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
