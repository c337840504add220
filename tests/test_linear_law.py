"""Linear forms on their own (ibt.bt.linear): a form's value is its formula summed left to right
in double, its weights are normal doubles, its texts and JSON read as written, a feature map
appends one derived column per form, and ``exact_threshold`` turns a float32 tree's threshold
into the double that decides every double alike, and a linear command (``Commands.terms``) holds
one list of terms per command and dimension whose weights keep it finite. Quick: no learner, no
environment."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from ibt.bt.linear import (
    DEFAULT_WEIGHTS,
    MAX_TERMS,
    FeatureMap,
    LinearForm,
    ObliqueForm,
    checked_weight,
    exact_threshold,
    form_from_json,
    linear_form,
    script_sum,
    terms_text,
)
from ibt.bt.model import Commands

F32_MAX = float(np.finfo(np.float32).max)
weights = st.floats(-1e3, 1e3, allow_nan=False).filter(lambda w: abs(w) > 1e-3)
values32 = st.floats(-1e3, 1e3, allow_nan=False, width=32)


# ------------------------------------------------------------------------------ weights
@pytest.mark.parametrize("value", [1, -3, 0.5, np.int64(2), np.float32(0.25), sys.float_info.min,
                                   -sys.float_info.max, 2 ** 53])
def test_a_normal_double_is_a_weight_read_as_a_float(value):
    got = checked_weight(value, "w1")
    assert type(got) is float and got == float(value)


@pytest.mark.parametrize("value", [0, 0.0, -0.0, True, False, "1", None, math.inf, -math.inf,
                                   math.nan, np.float64(np.nextafter(sys.float_info.min, 0)),
                                   5e-324, 10 ** 400, 2 ** 53 + 1, 2 ** 53 + 3,
                                   np.int64(2 ** 63 - 1)])
def test_zero_subnormal_non_finite_and_inexact_weights_are_refused(value):
    """An integer a double does not hold is refused whether it rounds down (``2 ** 53 + 1``)
    or up (``2 ** 53 + 3``, ``2 ** 63 - 1``)."""
    with pytest.raises(ValueError, match="weight w2"):
        checked_weight(value, "w2")


# -------------------------------------------------------------------- the two-term form
@settings(max_examples=60, deadline=None)
@given(weights, weights, st.lists(values32, min_size=3, max_size=3), st.permutations([0, 1, 2]))
def test_a_linear_form_is_its_formula_in_double_on_rows_and_single_states(w1, w2, row, order):
    """Law: ``value`` is ``w1 * x[i] + w2 * x[j]`` in double, on a batch as on one state."""
    i, j = order[0], order[1]
    form = LinearForm(i, j, w1, w2)
    x = np.asarray(row, dtype=np.float64)
    assert form.value(x) == w1 * x[i] + w2 * x[j]
    batch = np.stack([x, -x])
    assert form.value(batch).tolist() == [w1 * x[i] + w2 * x[j], w1 * -x[i] + w2 * -x[j]]
    assert form.terms == ((i, w1), (j, w2)) and form.features == (i, j)
    assert LinearForm.from_json(form.to_json()) == form
    assert form_from_json(form.to_json()) == form


def test_a_linear_form_takes_numpy_indices_and_refuses_bad_ones():
    form = LinearForm(np.int64(2), np.int32(0), np.float32(0.5), 2)
    assert (form.i, form.j, form.w1, form.w2) == (2, 0, 0.5, 2.0)
    assert type(form.i) is int and type(form.j) is int and type(form.w2) is float
    assert LinearForm(0, 1) == LinearForm(0, 1, 1.0, -1.0)  # the default: a difference
    for i, j in ((0, 0), (-1, 0), (0, -1), (True, 1), (0, 1.0), ("0", 1)):
        with pytest.raises(ValueError, match=r"feature|two different"):
            LinearForm(i, j)
    with pytest.raises(ValueError, match="weight w1"):
        LinearForm(0, 1, 0.0, 1.0)
    with pytest.raises(ValueError, match="weight w2"):
        LinearForm(0, 1, 1.0, 0.0)


@pytest.mark.parametrize("w1, w2, text, script", [
    (1.0, -1.0, "x - vx", "1.0 * x + -1.0 * vx"),
    (0.5, 1.0, "0.5 * x + vx", "0.5 * x + 1.0 * vx"),
    (-2.0, 1.0, "-2 * x + vx", "-2.0 * x + 1.0 * vx"),
    (-1.0, 2.0, "-x + 2 * vx", "-1.0 * x + 2.0 * vx"),
    (2.0, -0.5, "2 * x - 0.5 * vx", "2.0 * x + -0.5 * vx"),
    (0.1, -1.0, "0.1 * x - vx", "0.1 * x + -1.0 * vx"),
])
def test_a_form_reads_as_a_reader_writes_it_and_scripts_its_exact_weights(w1, w2, text, script):
    form = LinearForm(0, 2, w1, w2)
    assert form.text(["x", "y", "vx"]) == text
    assert form.script(["x", "y", "vx"]) == script


@pytest.mark.parametrize("doc", [None, [], {"features": [0, 1]},
                                 {"features": [0, 1], "weights": [1, 1], "x": 0},
                                 {"features": (0, 1), "weights": [1, 1]},
                                 {"features": [0, 1], "weights": (1, 1)},
                                 {"features": [0, 1, 2], "weights": [1, 1, 1]},
                                 {"features": [0, 1], "weights": [1]}])
def test_a_bad_two_term_document_is_refused(doc):
    with pytest.raises(ValueError, match="linear form"):
        LinearForm.from_json(doc)


# ------------------------------------------------------------------------ oblique forms
def test_a_form_of_two_terms_is_the_relational_form_and_others_are_oblique():
    assert linear_form([(0, 1.0), (2, -1.0)]) == LinearForm(0, 2, 1.0, -1.0)
    oblique = linear_form([(0, 0.5), (2, 1.0), (3, -1.0)])
    assert isinstance(oblique, ObliqueForm) and oblique.features == (0, 2, 3)
    assert oblique.i == 0 and oblique.terms == ((0, 0.5), (2, 1.0), (3, -1.0))
    # Expect: JSON round trips, the reader's text, and refusals naming the problem
    assert form_from_json(oblique.to_json()) == oblique
    assert oblique.to_json() == {"features": [0, 2, 3], "weights": [0.5, 1.0, -1.0]}
    assert oblique.text(["x", "y", "vx", "angle"]) == "0.5 * x + vx - angle"
    assert oblique.script(["x", "y", "vx", "angle"]) == "(0.5 * x + 1.0 * vx) + -1.0 * angle"
    assert oblique.sort_key() == ((0, 2, 3), (0.5, 1.0, -1.0))
    one = linear_form([(np.int64(3), 2)])
    assert isinstance(one, ObliqueForm) and one.terms == ((3, 2.0),) and one.i == 3
    assert type(one.features[0]) is int
    assert one.script(["a", "b", "c", "d"]) == "2.0 * d"


@pytest.mark.parametrize("features, weights_, words", [
    ((), (), "1, 3 or 4 terms"), ((0, 1), (1.0, 1.0), "1, 3 or 4 terms"),
    ((0, 1, 2, 3, 4), (1.0,) * 5, "1, 3 or 4 terms"), ((0, 1, 2), (1.0, 1.0), "one weight"),
    ((0, 1, -2), (1.0,) * 3, "non-negative integer"), ((0, True, 2), (1.0,) * 3, "integer"),
    ((0, 1.0, 2), (1.0,) * 3, "integer"), ((0, 1, 0), (1.0,) * 3, "each feature once"),
    ((0, 1, 2), (1.0, 0.0, 1.0), "weight w2"), ((0,), (math.inf,), "weight w1"),
])
def test_a_bad_oblique_form_is_refused_naming_the_problem(features, weights_, words):
    with pytest.raises(ValueError, match=words):
        ObliqueForm(features, weights_)


def test_four_terms_are_the_most_a_form_reads():
    assert MAX_TERMS == 4
    assert len(linear_form([(k, 1.0) for k in range(4)]).terms) == 4
    assert form_from_json({"features": [0], "weights": [1]}).features == (0,)
    assert form_from_json({"features": [3, 2, 1, 0], "weights": [1, 2, 3, 4]}).terms == (
        (3, 1.0), (2, 2.0), (1, 3.0), (0, 4.0))
    for doc in (None, {"features": [], "weights": []}, {"features": [0, 1]},
                {"features": [0, 1, 2, 3, 4], "weights": [1] * 5},
                {"features": [0, 1, 2], "weights": [1, 1]}, {"features": 0, "weights": [1]},
                {"features": [0], "weights": 1}, {"features": [0], "weights": [1], "k": 1}):
        with pytest.raises(ValueError, match="linear form"):
            form_from_json(doc)


@settings(max_examples=50, deadline=None)
@given(st.lists(weights, min_size=1, max_size=4).filter(lambda w: len(w) != 2),
       st.lists(values32, min_size=5, max_size=5))
def test_an_oblique_form_adds_its_terms_left_to_right_in_double(weights_, row):
    """Law: exactly the left-to-right double sum ``((w1 x1 + w2 x2) + w3 x3) + w4 x4``, never a
    more accurate one; the features in the order given (here descending)."""
    features = tuple(range(len(weights_), 0, -1))
    form = ObliqueForm(features, tuple(weights_))
    x = np.asarray([row, row[::-1]], dtype=np.float32).astype(np.float64)
    for k in range(2):
        total = weights_[0] * x[k, features[0]]
        for f, w in zip(features[1:], weights_[1:], strict=True):
            total = total + w * x[k, f]
        assert form.value(x)[k] == total
        assert form.value(x[k]) == total


def test_a_sum_that_is_not_associative_in_double_is_added_from_the_left():
    form = ObliqueForm((0, 1, 2), (1.0, 1.0, 1.0))
    # (1e16 - 1e16) + 1 is 1; 1e16 + (-1e16 + 1) would be 0
    assert form.value(np.array([1e16, -1e16, 1.0])) == 1.0
    assert form.value(np.array([1.0, 1e16, -1e16])) == 0.0


def test_a_script_sum_of_three_or_more_parts_is_grouped_from_the_left():
    # BehaviorTree.CPP groups a + b + c as a + (b + c): the parentheses keep our order
    assert script_sum(["a"]) == "a"
    assert script_sum(["a", "b"]) == "a + b"
    assert script_sum(["a", "b", "c"]) == "(a + b) + c"
    assert script_sum(["a", "b", "c", "d"]) == "((a + b) + c) + d"


def test_a_sum_reads_as_a_reader_writes_it_with_its_bias():
    names = ["x", "y", "vx", "vy"]
    terms = ((1, 10.0), (3, -10.0))
    assert terms_text(terms, names, bias=-1.0) == "-1 + 10 * y - 10 * vy"
    assert terms_text(terms, names, bias=0.0) == "10 * y - 10 * vy"
    assert terms_text(terms, names) == "10 * y - 10 * vy"
    assert terms_text((), names, bias=0.0) == "0"
    assert terms_text((), names, bias=2.5) == "2.5"
    assert terms_text(((0, -1.0), (2, 1.0), (1, -1.0)), names) == "-x + vx - y"
    assert terms_text(((0, 1.0), (2, 2.0)), names, bias=0.5) == "0.5 + x + 2 * vx"
    assert terms_text(((0, -1.0),), names, bias=3.0) == "3 - x"
    assert terms_text(((0, 1.0), (1, 0.0)), names) == "x + 0 * y"  # a zero term is added


# ------------------------------------------------------------------------- feature maps
def test_a_feature_map_appends_one_derived_column_per_form():
    forms = (LinearForm(0, 2, 1.0, -1.0), LinearForm(1, 0, 0.5, 2.0))
    fmap = FeatureMap(3, forms)
    assert fmap.width == 5 and fmap.forms == forms
    assert [fmap.is_derived(c) for c in range(5)] == [False, False, False, True, True]
    assert fmap.form(3) == forms[0] and fmap.form(4) == forms[1]
    rows = np.array([[0.1, 2.0, -3.0], [1e30, 1.0, 5.5]])
    out = fmap.augment(rows)
    x = rows.astype(np.float32).astype(np.float64)  # read as float32, widened
    assert out.shape == (2, 5) and out.dtype == np.float64
    assert np.array_equal(out[:, :3], x)
    assert np.array_equal(out[:, 3], x[:, 0] - x[:, 2])
    assert np.array_equal(out[:, 4], 0.5 * x[:, 1] + 2.0 * x[:, 0])
    assert out[0, 0] == float(np.float32(0.1)) != 0.1
    one = fmap.augment(rows[0])
    assert one.shape == (5,) and np.array_equal(one, out[0])
    assert fmap.names(["x", "y", "t"]) == ("x", "y", "t", "x - t", "0.5 * y + 2 * x")
    with pytest.raises(ValueError, match="expected 3 features, got 2"):
        fmap.augment(rows[:, :2])
    plain = FeatureMap(3)
    assert plain.width == 3 and np.array_equal(plain.augment(rows), x)
    assert np.array_equal(plain.augment(rows[1]), x[1])


def test_a_feature_map_reads_only_the_task_s_features():
    FeatureMap(3, (LinearForm(2, 1), LinearForm(0, 2)))
    for form in (LinearForm(3, 0), LinearForm(0, 3)):
        with pytest.raises(ValueError, match="beyond the task's 3"):
            FeatureMap(3, (form,))


def test_a_feature_map_round_trips_and_a_bad_one_is_refused():
    fmap = FeatureMap(4, (LinearForm(0, 3, 0.5, -2.0), LinearForm(2, 1)))
    assert fmap.to_json() == {"n_features": 4, "forms": [
        {"features": [0, 3], "weights": [0.5, -2.0]}, {"features": [2, 1], "weights": [1.0, -1.0]}]}
    assert FeatureMap.from_json(fmap.to_json()) == fmap
    assert FeatureMap.from_json({"n_features": 0, "forms": []}) == FeatureMap(0)
    for doc, words in (([], "feature map must be"), ({"n_features": 2}, "feature map must be"),
                       ({"n_features": True, "forms": []}, "non-negative integer"),
                       ({"n_features": 2.0, "forms": []}, "non-negative integer"),
                       ({"n_features": -1, "forms": []}, "non-negative integer"),
                       ({"n_features": 2, "forms": {}}, "must be a list")):
        with pytest.raises(ValueError, match=words):
            FeatureMap.from_json(doc)


def test_pairs_are_every_pair_in_order_with_every_weight_pair():
    fmap = FeatureMap.pairs(3)
    assert fmap.n_features == 3 and len(fmap.forms) == 3 * len(DEFAULT_WEIGHTS)
    assert [f.features for f in fmap.forms[::len(DEFAULT_WEIGHTS)]] == [(0, 1), (0, 2), (1, 2)]
    assert [(f.w1, f.w2) for f in fmap.forms[:len(DEFAULT_WEIGHTS)]] == list(DEFAULT_WEIGHTS)
    chosen = FeatureMap.pairs(5, ((1.0, 1.0),), features=[4, 1, 3])
    assert [f.features for f in chosen.forms] == [(4, 1), (4, 3), (1, 3)]


def test_the_default_weights_are_sums_and_differences_then_halves_and_doubles():
    """The weights every relational search tries (its results rest on them): the sum and the
    difference first, then each feature halved or doubled against the other, both signs."""
    assert DEFAULT_WEIGHTS == ((1.0, 1.0), (1.0, -1.0), (1.0, 0.5), (1.0, -0.5), (0.5, 1.0),
                               (-0.5, 1.0), (1.0, 2.0), (1.0, -2.0), (2.0, 1.0), (-2.0, 1.0))


# ----------------------------------------------------------------------- exact thresholds
def _neighbours(t: float) -> list[float]:
    """The float32 values around ``t``, their midpoints and the doubles next to those."""
    with np.errstate(over="ignore"):  # the threshold of float32's largest is double's
        a = np.float32(t)
    out = [float(w) for w in (np.nextafter(a, np.float32(-np.inf)), a,
                              np.nextafter(a, np.float32(np.inf))) if np.isfinite(w)]
    mids = [(p + q) / 2 for p, q in zip(sorted(out), sorted(out)[1:], strict=False)]
    around = [float(np.nextafter(m, d)) for m in mids for d in (-np.inf, np.inf)]
    return [z for z in out + mids + around if abs(z) <= F32_MAX]


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.floats(-F32_MAX, F32_MAX), st.floats(-10, 10), st.floats(-10, 10, width=32)))
@example(0.0)
@example(1.0)
@example(0.1)
@example(-0.1)
@example(1.0 + 2.0 ** -24)  # the midpoint of 1 and the next float32: ties to 1 (even)
@example(1.0 + 3 * 2.0 ** -24)  # the midpoint above 1 + 2 ** -23: ties to 1 + 2 ** -22 (even)
@example(F32_MAX)
@example(-F32_MAX)
def test_the_exact_threshold_decides_every_double_as_the_float32_tree(t):
    """Law: ``float32(z) <= t`` exactly when ``z <= exact_threshold(t)``, for every double ``z``
    in float32's range (here the doubles around each float32 value and midpoint near ``t``)."""
    threshold = exact_threshold(t)
    for z in [*_neighbours(t), *_neighbours(threshold)]:
        assert (float(np.float32(z)) <= t) == (z <= threshold), (t, z, threshold)


def test_the_exact_threshold_of_a_tie_follows_round_half_to_even():
    ulp = 2.0 ** -23
    # 1 + ulp / 2 rounds to 1 (even): it passes "<= 1"; the threshold is that midpoint
    assert exact_threshold(1.0) == 1.0 + ulp / 2
    # 1 + 3 ulp / 2 rounds to 1 + 2 ulp (even): below it only, the threshold of 1 + ulp
    assert exact_threshold(1.0 + ulp) == float(np.nextafter(1.0 + 1.5 * ulp, -np.inf))
    assert exact_threshold(1.0 + 0.5 * ulp) == 1.0 + ulp / 2  # t between float32 values
    assert exact_threshold(F32_MAX) == float(np.finfo(np.float64).max)
    for bad in (math.inf, -math.inf, math.nan):
        with pytest.raises(ValueError, match="must be finite"):
            exact_threshold(bad)


# ------------------------------------------------------------------------------ linear commands
def _command(terms: tuple[tuple[int, float], ...]) -> Commands:
    """One command of one dimension, ``0 + terms``."""
    return Commands(("d",), ("u",), ((0.0,),), terms=((terms,),))


@pytest.mark.parametrize("weights_", [(1e269,), (-1e269,), (1e269, -1e269), (1e269,) * 4,
                                      (1e270,), (-1e300,), (1e269, 1e269, 1e270),
                                      (1e308, 1e308)])
def test_a_linear_command_is_refused_exactly_where_some_float32_observation_overflows_it(
        weights_):
    """Law: the command's weights are accepted exactly when its value stays finite on its worst
    observation (each feature float32's largest magnitude, of its weight's sign), computed by
    :meth:`Commands.evaluate`'s rule (mutant: ``FLOAT32_MAX * sum|w|`` as ``-``, finite until the
    weights' sum itself overflows)."""
    terms = tuple(enumerate(weights_))
    worst = np.array([[math.copysign(F32_MAX, w) for w in weights_]])
    overflows = not math.isfinite(sum(w * x for w, x in zip(weights_, worst[0], strict=True)))
    if overflows:
        with pytest.raises(ValueError, match="weights too large"):
            _command(terms)
    else:
        value = _command(terms).evaluate(np.array([0]), worst)
        assert np.isfinite(value).all()


def test_linear_commands_hold_one_list_of_terms_per_command_and_dimension():
    """Terms for more or fewer commands than ``values`` holds, or a command with more or fewer
    dimensions than named, are refused (mutants: ``len(terms) != len(values)`` as ``<``, and its
    ``or`` with the row check as ``and``)."""
    one = (((0, 1.0),),)  # one command's terms: one dimension, ``1 * x[0]``
    assert _command(((0, 1.0),)).terms == (one,)
    for terms in ((one, one), (), ((((0, 1.0),), ()),)):
        with pytest.raises(ValueError, match="one list of terms per command and dimension"):
            Commands(("d",), ("u",), ((0.0,),), terms=terms)
