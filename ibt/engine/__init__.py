"""The engine: the method's stages, each one cached function, and the anytime ladder.

Every caller shares it: the paper grid, the front and its searches, the continuous study
(:mod:`ibt.runs`) and ``pipeline`` (:mod:`ibt.pipeline`). It imports neither, so a study and
the pipeline that run one stage on one agent compute, and cache, the same thing.

* :mod:`ibt.engine.agent`: the agent to distil (an SB3 checkpoint or a ``MODULE:FUNCTION``
  callable), its identity for cache keys and its random baseline (discrete or Box);
* :mod:`ibt.engine.budgets`: every stage's settings for a task under a profile, in episodes;
* :mod:`ibt.engine.learners`: the registry of learners (``axis``, ``relational``, ``box``):
  the action space each accepts, its cache kind, its settings, loop, tree and refinement;
* the stages, a module each, each stage one cached function keyed in one place:
  :mod:`ibt.engine.distil` (the interactive loop at a leaf limit), :mod:`ibt.engine.commands`
  (a Box task's leaves merged into named commands), :mod:`ibt.engine.refine` (by return),
  :mod:`ibt.engine.search` (the structure search with restarts, polished),
  :mod:`ibt.engine.polish` (polished again with time left), :mod:`ibt.engine.synthesis` (a
  tree's verified BTs) and :mod:`ibt.engine.measure` (every policy's returns);
  :mod:`ibt.engine.keys` holds the identities their keys share;
* :mod:`ibt.engine.ladder`: distillation smallest leaf limit first, the structure search by
  bisection of the limits, stopped by a target, a deadline or a signal, always with the best
  candidate found so far;
* :mod:`ibt.engine.parallel`: restarts mapped over local cores (joblib) or a Dask cluster.
"""
