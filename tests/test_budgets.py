"""The engine's budgets: what a search is expected to run (its first round, its
polishes, their choice episodes) and the wall time of a round of restarts on the cores."""


from __future__ import annotations

import pytest

from ibt.engine import budgets, parallel, search


@pytest.mark.parametrize("n_jobs, restarts, rounds, polishes", [
    (1, 3, 1.0, 1.0), (2, 3, 1.5, 1.5), (2, 2, 1.0, 1.0), (4, 3, 1.0, 1.0), (2, 5, 1.0, 1.0)])
def test_a_search_is_expected_to_run_its_first_round_and_its_polishes(n_jobs, restarts,
                                                                      rounds, polishes):
    """The least a search runs under a deadline: its first round (3 restarts on 2 cores share
    them, 1.5 restarts' time; on 1 core, one restart), the polishes of that round's best,
    and the choice episodes scoring both, in one core's episodes."""
    import ibt
    from ibt.tasks.catalogue import resolve_task

    cfg = ibt.config("paper")
    task = resolve_task("LunarLander-v3")
    config = budgets.search_config(cfg, task, 8, 1.0)
    choice = min(search.RESTART_CHOICE_FACTOR * config.selection_episodes, 1_500)
    assert search.search_length(cfg, task, 8, restarts=restarts, scale=1.0, n_jobs=n_jobs) == (
        rounds * config.episodes + polishes * budgets.polish_config(cfg, config).episodes
        + (rounds + polishes) * choice)


@pytest.mark.parametrize("n_jobs, items, processes, wall", [
    (2, 3, 3, 1.5), (2, 2, 2, 1.0), (1, 3, 1, 3.0), (2, 4, 2, 2.0), (4, 5, 5, 1.25),
    (4, 9, 4, 3.0), (2, 1, 2, 1.0)])
def test_a_round_of_fewer_than_twice_the_cores_runs_a_process_each(n_jobs, items, processes,
                                                                    wall):
    """3 restarts on 2 cores share them as 3 processes (1.5 rounds' time), not 2 and then 1."""
    assert parallel.processes(n_jobs, items) == processes
    assert parallel.wall(items, n_jobs) == wall
