"""The engine: the method's stages composed into the anytime ladder that ``pipeline`` runs.

* :mod:`ibt.runs.engine.agent`: the agent to distil (an SB3 checkpoint or a ``MODULE:FUNCTION``
  callable), its identity for cache keys and its random baseline (discrete or Box);
* :mod:`ibt.runs.engine.stages`: distil, commands (Box), refine, structure search with restarts,
  synthesise-and-measure, each one cached function;
* :mod:`ibt.runs.engine.ladder`: distillation smallest leaf limit first, the structure search by
  bisection of the limits, stopped by a target, a deadline or a signal, always with the best
  candidate found so far;
* :mod:`ibt.runs.engine.parallel`: restarts mapped over local cores (joblib) or a Dask cluster.
"""
