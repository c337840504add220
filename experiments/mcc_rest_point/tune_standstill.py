"""How the standing-start rules of ``run.py standstill`` were tuned: CMA-ES on a NumPy copy of
MountainCarContinuous's dynamics (state stored in float32 each step, as the task does) over
3,000 random start positions, then 20,000 other starts for the best sample. Prints each
generation's best sample and the held-out check (about 4 minutes of one core)::

    python experiments/mcc_rest_point/tune_standstill.py

A scratch tool: the final-episode numbers in RESULTS.md come from ``run.py standstill``, on the
task itself.
"""

from __future__ import annotations

from collections.abc import Callable

import cma
import numpy as np

Rule = Callable[[np.ndarray, np.ndarray], np.ndarray]


def returns(rule: Rule, starts: np.ndarray, kick: float | None, steps: int = 999
            ) -> np.ndarray:
    """Each start's return under ``rule`` (a force from float32 position and velocity), with
    ``force := kick`` where the velocity is within 1e-6 of 0 (None: no such rule)."""
    x, v = starts.astype(np.float64), np.zeros(len(starts))
    total, done = np.zeros(len(starts)), np.zeros(len(starts), bool)
    for _ in range(steps):
        xo, vo = x.astype(np.float32), v.astype(np.float32)
        force = np.clip(rule(xo, vo), -1, 1).astype(np.float32)
        if kick is not None:
            force = np.where(np.abs(vo) < 1e-6, np.float32(kick), force)
        live = ~done
        total += np.where(live, -0.1 * force.astype(np.float64) ** 2, 0)
        v = np.where(live, np.clip(v + force * 0.0015 - 0.0025 * np.cos(3 * x), -0.07, 0.07), v)
        x = np.where(live, np.clip(x + v, -1.2, 0.6), x)
        v = np.where(live & (x == -1.2) & (v < 0), 0, v)
        x, v = x.astype(np.float32).astype(np.float64), v.astype(np.float32).astype(np.float64)
        reached = live & (x >= 0.45) & (v >= 0)
        total += np.where(reached, 100, 0)
        done |= reached
    return total


def main() -> None:
    starts = np.random.default_rng(1).uniform(-0.6, -0.4, 3000)

    def score(p: np.ndarray) -> tuple[float, int]:
        b, c, k, kick = p
        r = returns(lambda x, v: b + c * x + k * v, starts, kick)
        return float(r.mean()), int((r < 50).sum())

    es = cma.CMAEvolutionStrategy([-0.05, -0.1, 9, -0.5], 0.3,
                                  {"seed": 1, "verbose": -9, "CMA_stds": [0.05, 0.1, 2, 0.3]})
    for generation in range(30):
        samples = es.ask()
        scores = [score(p) for p in samples]
        es.tell(samples, [-mean for mean, _ in scores])
        best = int(np.argmax([mean for mean, _ in scores]))
        print(generation, np.round(samples[best], 3), scores[best], flush=True)
    b, c, k, kick = es.result.xbest
    held = returns(lambda x, v: b + c * x + k * v,
                   np.random.default_rng(7).uniform(-0.6, -0.4, 20000), kick)
    print("best sample", np.round(es.result.xbest, 3), "on 20,000 other starts:",
          round(float(held.mean()), 3), int((held < 50).sum()), "failures")


if __name__ == "__main__":
    main()
