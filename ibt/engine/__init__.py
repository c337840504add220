"""The engine: the method's stages, each one cached function, and the anytime ladder.

Every caller shares it: the paper grid, the front and its searches, the continuous study
(:mod:`ibt.runs`) and ``pipeline`` (:mod:`ibt.pipeline`). It imports neither, so a study and
the pipeline that run one stage on one agent compute, and cache, the same thing.

* :mod:`ibt.engine.agent`: the agent to distil (an SB3 checkpoint or a ``MODULE:FUNCTION``
  callable), its identity for cache keys and its random baseline (discrete or Box);
* :mod:`ibt.engine.budgets`: every stage's settings for a task under a profile, in episodes;
* :mod:`ibt.engine.stages`: distil, commands (Box), refine, structure search with restarts,
  synthesise-and-measure, each one cached function;
* :mod:`ibt.engine.ladder`: distillation smallest leaf limit first, the structure search by
  bisection of the limits, stopped by a target, a deadline or a signal, always with the best
  candidate found so far;
* :mod:`ibt.engine.parallel`: restarts mapped over local cores (joblib) or a Dask cluster.
"""
