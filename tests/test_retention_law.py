"""Retention, the headline's measure, as laws: random-normalised retention is 0 at the random
policy's return and 100 at the expert's, linear between, undefined (NaN) where the expert is
no better than random; its column form agrees with it row by row; its margin (two standard
errors) shrinks as one over the square root of the episodes and is undefined for none."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.evaluate.rollouts import retention_margin, retention_norm, retention_norm_column

returns = st.floats(-1e4, 1e4, allow_nan=False)
stds = st.floats(0.0, 1e3, allow_nan=False)


@given(mean=returns, expert=returns, random=returns)
def test_normalised_retention_is_0_at_random_and_100_at_the_expert(mean, expert, random):
    span = expert - random
    if span == 0:
        assert math.isnan(retention_norm(mean, expert, random))
        return
    assert retention_norm(random, expert, random) == 0.0
    assert retention_norm(expert, expert, random) == pytest.approx(100.0)
    assert retention_norm(mean, expert, random) == pytest.approx(
        100.0 * (mean - random) / span, rel=1e-9, abs=1e-9)


@given(rows=st.lists(st.tuples(returns, returns, returns), min_size=1, max_size=8))
def test_the_column_form_agrees_with_retention_row_by_row(rows):
    """Mutants: the column form's NaN for a zero span dropped or inverted."""
    mean, expert, random = (pd.Series(list(c)) for c in zip(*rows, strict=True))
    column = retention_norm_column(mean, expert, random)
    for got, (m, e, r) in zip(column.tolist(), rows, strict=True):
        want = retention_norm(m, e, r)
        assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want)


def test_the_column_form_is_nan_where_retention_is_undefined():
    column = retention_norm_column(pd.Series([1.0, 1.0, 3.0, 5.0]),
                                   pd.Series([5.0, np.inf, 3.0, 10.0]),
                                   pd.Series([5.0, 0.0, 1.0, 0.0]))
    assert np.isnan(column.iloc[:2]).all()
    assert column.iloc[2:].tolist() == [100.0, 50.0]


@given(policy_std=stds, expert_std=stds, n=st.integers(1, 10_000), expert=returns,
       random=returns)
def test_the_margin_is_two_standard_errors_on_the_retention_scale(policy_std, expert_std, n,
                                                                  expert, random):
    span = abs(expert - random)
    got = retention_margin(policy_std, expert_std, n, expert, random)
    if span == 0:
        assert math.isnan(got)
        return
    assert got == pytest.approx(
        200.0 * math.sqrt((policy_std ** 2 + expert_std ** 2) / n) / span)
    assert got >= 0.0
    assert retention_margin(policy_std, expert_std, 4 * n, expert, random) == pytest.approx(
        got / 2)


def test_the_margin_of_no_episodes_or_no_span_is_undefined():
    """Mutants: the guard ``n_episodes < 1`` as ``< 0`` (a division by zero) or ``<= 1`` (one
    episode refused), ``span == 0`` or the finiteness test dropped."""
    assert math.isnan(retention_margin(1.0, 1.0, 0, 10.0, 0.0))
    assert math.isnan(retention_margin(1.0, 1.0, -3, 10.0, 0.0))
    assert retention_margin(3.0, 4.0, 1, 10.0, 0.0) == pytest.approx(100.0)
    assert retention_margin(3.0, 4.0, 1, 0.0, 10.0) == pytest.approx(100.0)  # expert below
    assert math.isnan(retention_margin(3.0, 4.0, 1, 5.0, 5.0))
    assert math.isnan(retention_margin(3.0, 4.0, 1, math.inf, 0.0))
    assert math.isnan(retention_norm(3.0, math.inf, 0.0))
