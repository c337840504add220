"""``pipeline``, the product: a user's agent in, a recommended BT and its report out.

* :mod:`ibt.pipeline.recommend`: the wall-clock budget, the anytime ladder of the engine
  (:mod:`ibt.engine.ladder`) run on the agent, and the recommendation rule (the smallest
  verified BT that keeps the target on the choice episodes, confirmed on fresh ones);
* :mod:`ibt.pipeline.outputs`: its files (the recommended and the most faithful BT as JSON and
  BehaviorTree.CPP XML, picture, front, the BT acting as a GIF, the plan, the report with its
  rules and agreement), written as one set;
* :mod:`ibt.pipeline.owned_folder`: the output folder the run owns, claimed, written atomically
  and released, safe against concurrent runs and signals.
"""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
