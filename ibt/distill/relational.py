"""A decision tree whose splits may be relational (issue 26): CART on derived features.

A :class:`RelationalTreeClassifier` is a scikit-learn tree fitted on observations augmented
with derived columns (:class:`ibt.bt.linear.FeatureMap`), so column ``k >= n_features`` of its
``tree_`` is the linear form ``feature_map_.form(k)``. ``predict``/``apply``/``predict_proba``
/``decision_path`` take *observed* rows (``n_features`` columns) and augment them first by the
floating-point rule of :mod:`ibt.bt.linear`; everything that reads ``tree_`` (rules, Espresso,
synthesis, refinement) sees augmented column indices.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.linear import FeatureMap


class RelationalTreeClassifier(DecisionTreeClassifier):
    """CART over a :class:`FeatureMap`'s augmented columns; decides on observed rows."""

    feature_map_: FeatureMap

    def fit_relational(self, X: np.ndarray, y: np.ndarray, feature_map: FeatureMap,
                       sample_weight: np.ndarray | None = None) -> RelationalTreeClassifier:
        """Fit on ``feature_map.augment(X)``; remember the map."""
        self.feature_map_ = feature_map
        super().fit(feature_map.augment(X), y, sample_weight=sample_weight)
        return self

    def _augmented(self, X: Any) -> np.ndarray:
        x = np.atleast_2d(np.asarray(X, dtype=np.float64))
        if x.shape[1] == self.feature_map_.width and self.feature_map_.forms:
            raise ValueError("a relational tree takes observed rows "
                             f"({self.feature_map_.n_features} features), not augmented ones")
        return self.feature_map_.augment(x)

    def predict(self, X: Any, check_input: bool = True) -> np.ndarray:
        return super().predict(self._augmented(X), check_input=check_input)

    def predict_proba(self, X: Any, check_input: bool = True) -> Any:
        return super().predict_proba(self._augmented(X), check_input=check_input)

    def apply(self, X: Any, check_input: bool = True) -> np.ndarray:
        return super().apply(self._augmented(X), check_input=check_input)

    def decision_path(self, X: Any, check_input: bool = True) -> Any:
        return super().decision_path(self._augmented(X), check_input=check_input)


def feature_map_of(tree: Any) -> FeatureMap | None:
    """A relational tree's feature map, ``None`` for an axis-aligned tree."""
    return getattr(tree, "feature_map_", None)
