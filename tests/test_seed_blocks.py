"""Held-out episodes stay held out: the seed blocks of final evaluation, selection (one block
per run seed, split further by ``offset``), distillation and refinement are disjoint, and a
selection block can be used to its last seed and no further."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.evaluate.rollouts import (
    FINAL_SEED_BASE,
    REFINE_SEED_BASE,
    REFINE_SELECTION_OFFSET,
    SELECTION_BLOCK,
    SELECTION_SEED_BASE,
    TRAIN_SEED_BASE,
    final_seeds,
    selection_seeds,
)

runs = st.integers(0, 99)
spans = st.tuples(st.integers(0, SELECTION_BLOCK - 1), st.integers(1, SELECTION_BLOCK)).map(
    lambda t: (t[0], min(t[1], SELECTION_BLOCK - t[0])))  # (offset, n) inside the block


@given(run=runs, span=spans)
def test_selection_seeds_are_the_run_s_block_from_its_offset(run, span):
    """Mutants: ``offset`` ignored, the block or the base miscomputed."""
    offset, n = span
    seeds = selection_seeds(n, run, offset)
    start = SELECTION_SEED_BASE + SELECTION_BLOCK * run + offset
    assert seeds == list(range(start, start + n))


@given(a=runs, b=runs, span_a=spans, span_b=spans)
def test_held_out_seed_blocks_are_disjoint(a, b, span_a, span_b):
    """Two uses share a seed only when they are the same run and their offset ranges
    overlap; no selection seed is a final, distillation or refinement one."""
    (off_a, n_a), (off_b, n_b) = span_a, span_b
    first, second = set(selection_seeds(n_a, a, off_a)), set(selection_seeds(n_b, b, off_b))
    overlap = a == b and off_a < off_b + n_b and off_b < off_a + n_a
    assert bool(first & second) == overlap
    assert not first & set(final_seeds(1_000))
    assert all(FINAL_SEED_BASE + 1_000_000 <= s < TRAIN_SEED_BASE for s in first)


def test_a_block_is_usable_to_its_last_seed_and_no_further():
    """Mutants: the bound ``offset + n <= SELECTION_BLOCK`` as ``<`` (the block's last seed
    refused) or loosened, and ``0 <= offset`` as ``<``."""
    last = selection_seeds(1, 3, SELECTION_BLOCK - 1)
    assert last == [SELECTION_SEED_BASE + 4 * SELECTION_BLOCK - 1]
    assert selection_seeds(SELECTION_BLOCK, 0) == list(
        range(SELECTION_SEED_BASE, SELECTION_SEED_BASE + SELECTION_BLOCK))
    assert selection_seeds(0, 0, SELECTION_BLOCK) == []
    for n, offset in ((1, SELECTION_BLOCK), (SELECTION_BLOCK + 1, 0), (2, SELECTION_BLOCK - 1),
                      (1, -1)):
        with pytest.raises(ValueError, match="leave the run's block of 10,000"):
            selection_seeds(n, 0, offset)


def test_refinement_s_choice_and_the_other_bases_are_apart():
    """The refinement's held-out choice lies inside each run's block, after offset 0's uses;
    final seeds count up from their base."""
    assert 0 < REFINE_SELECTION_OFFSET < SELECTION_BLOCK
    assert final_seeds(3) == [FINAL_SEED_BASE, FINAL_SEED_BASE + 1, FINAL_SEED_BASE + 2]
    assert final_seeds(0) == []
    assert (FINAL_SEED_BASE < SELECTION_SEED_BASE < TRAIN_SEED_BASE < REFINE_SEED_BASE)
    # 100 run seeds' selection blocks end before the distillation seeds begin
    assert SELECTION_SEED_BASE + 100 * SELECTION_BLOCK <= TRAIN_SEED_BASE
