"""Stable-Baselines3 experts: hyperparameters, training, saving, loading, and the Expert protocol.

An :class:`Expert` acts on raw observation batches and exposes the scores the distillation
weights come from: Q-values for DQN, log pi(a|s) for PPO and A2C (the paper's stand-in for Q).
Observation normalisation, where training used ``VecNormalize``, is wrapped inside the expert,
so callers always pass raw observations.

Hyperparameters are part of each task's catalogue entry (``Task.experts``, written in
:mod:`ibt.tasks.builtin`, where their sources are named).

**A checkpoint is code**: loading one runs the code its pickles name, so load only checkpoints
from a trusted source; what is never unpickled and how a loaded checkpoint is checked against
its task (spaces, normalisation sidecar) is in :mod:`ibt.experts.checkpoint`.
"""

from __future__ import annotations

import functools
import json
import shlex
import shutil
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ibt.experts.checkpoint import (
    MAX_CHECKPOINT_BYTES,
    NOT_UNPICKLED,
    check_regular_file,
    checkpoint_algo,
    needs_obs_norm,
    norm_sidecar_path,
    read_obs_norm,
    space_difference,
)
from ibt.files import atomic_target, atomic_write_text
from ibt.paths import DATA_DIR
from ibt.tasks.settings import ALGOS, Hyperparams
from ibt.tasks.task import Task


def linear_schedule(start: float):
    """The zoo's ``lin_X``: decays linearly from ``start`` to 0 over training."""

    def schedule(progress_remaining: float) -> float:
        return progress_remaining * start

    return schedule


def algo_kwargs(hp: Hyperparams) -> dict[str, Any]:
    """The SB3 constructor's keyword arguments of a hyperparameter row (``lin_X`` strings
    become linear schedules)."""
    out = {}
    for key, value in hp.kwargs:
        if isinstance(value, str) and value.startswith("lin_"):
            value = linear_schedule(float(value[4:]))
        out[key] = value
    return out


def hyperparams(task: Task, algo: str) -> Hyperparams:
    """How the task's ``algo`` expert is trained (its catalogue entry)."""
    return task.hyperparams(check_algo(algo))


def check_algo(algo: str) -> str:
    name = algo.lower()
    if name not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; expected one of {', '.join(ALGOS)}")
    return name


def _sb3_class(algo: str):
    from stable_baselines3 import A2C, DQN, PPO, SAC, TD3

    return {"dqn": DQN, "ppo": PPO, "a2c": A2C, "sac": SAC, "td3": TD3}[check_algo(algo)]


def expert_path(task: Task, algo: str, root: Path | None = None) -> Path:
    """``data/experts/<task>/<algo>.zip`` (or under ``root``)."""
    return (root or DATA_DIR / "experts") / task.name / f"{check_algo(algo)}.zip"


class Expert:
    """A trained SB3 policy queried on raw observation batches.

    On a task with discrete actions it acts by the argmax of its scores; on a Box task
    (``task.continuous``) :meth:`act` returns action vectors ``(batch, dims)`` inside the Box,
    and the weights of :meth:`label` come from :meth:`action_loss` (see there)."""

    #: random actions whose mean loss is a state's weight on a Box task (fixed: deterministic)
    SPREAD_ACTIONS = 16

    def __init__(self, task: Task, algo: str, model: Any, obs_norm: dict | None = None) -> None:
        self.task = task
        self.algo = check_algo(algo)
        self.model = model
        self.obs_norm = obs_norm
        self.continuous = task.continuous
        self._device: Any = None  # the policy's device, looked up once
        from gymnasium import spaces

        space = getattr(model, "observation_space", None)
        self._flat_shape = (tuple(space.shape) if isinstance(space, spaces.Box)
                            and len(space.shape) == 1 else None)
        self.n_actions = (int(np.prod(model.action_space.shape)) if self.continuous
                          else int(model.action_space.n))

    def _obs_tensor(self, obs: np.ndarray):
        obs = np.asarray(obs)
        if self.obs_norm is not None:
            mean = np.asarray(self.obs_norm["mean"])
            std = np.sqrt(np.asarray(self.obs_norm["var"]) + self.obs_norm["epsilon"])
            obs = np.clip((obs - mean) / std, -self.obs_norm["clip"], self.obs_norm["clip"])
            obs = obs.astype(np.float32)
        if self._flat_shape is not None:
            # obs_to_tensor's own steps for a flat Box (array, batch shape, as_tensor), without
            # its device lookup, which walks the parameters on every call
            import torch

            if self._device is None:
                self._device = self.model.policy.device
            return torch.as_tensor(np.array(obs).reshape((-1, *self._flat_shape)),
                                   device=self._device)
        tensor, _ = self.model.policy.obs_to_tensor(obs)
        return tensor

    def scores(self, obs: np.ndarray) -> np.ndarray:
        """``(batch, n_actions)``: Q-values (DQN) or log pi(a|s) (PPO, A2C)."""
        import torch

        if self.continuous:
            raise TypeError(f"{self.task.name} acts in a Box: an expert there has no per-action "
                            "scores; use act, label or action_loss")
        from stable_baselines3.common.policies import BaseModel

        with torch.no_grad():
            tensor = self._obs_tensor(obs)
            policy = self.model.policy
            if self.algo == "dqn":
                out = policy.q_net(tensor)
            else:
                # policy.get_distribution(tensor), without building a Categorical (its argument
                # validation costs more than the network); the same operations in the same
                # order, so the numbers are bit-identical
                features = BaseModel.extract_features(policy, tensor, policy.pi_features_extractor)
                logits = policy.action_net(policy.mlp_extractor.forward_actor(features))
                logits = logits - logits.logsumexp(dim=-1, keepdim=True)
                out = torch.log_softmax(logits, dim=-1)
        return out.cpu().numpy().astype(np.float64).reshape(-1, self.n_actions)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions for a batch: argmax of the scores (discrete), or action
        vectors ``(batch, dims)`` inside the Box (continuous)."""
        if self.continuous:
            return self._box_actions(obs)
        return np.argmax(self.scores(obs), axis=1)

    def label(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Actions and importance weights: ``max_a score - min_a score`` (discrete, one forward
        pass); on a Box task the mean :meth:`action_loss` of :attr:`SPREAD_ACTIONS` fixed
        uniform random actions (the spread of the critic around the expert's action)."""
        if self.continuous:
            actions = self._box_actions(obs)
            rng = np.random.default_rng(0)  # the same random actions on every call
            low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
            k, n = self.SPREAD_ACTIONS, len(actions)
            tried = np.repeat(rng.uniform(low, high, size=(k, len(low))), n, axis=0)
            losses = self.action_loss(np.concatenate([np.asarray(obs)] * k), tried)
            return actions, losses.reshape(k, n).mean(axis=0)
        scores = self.scores(obs)
        return np.argmax(scores, axis=1), scores.max(axis=1) - scores.min(axis=1)

    # --- Box tasks --------------------------------------------------------------------------

    def _box_actions(self, obs: np.ndarray) -> np.ndarray:
        """SB3's deterministic ``predict`` on a batch, as float32 ``(batch, dims)``: a squashed
        actor's output (SAC, TD3) mapped onto the Box, a Gaussian's mean (PPO) clipped to it."""
        import torch

        with torch.no_grad():
            tensor = self._obs_tensor(obs)
            policy = self.model.policy
            if self.algo == "sac" and not policy.actor.use_sde:
                # the actor's deterministic action, tanh of its Gaussian's mean, without the
                # log-std head and the distribution it builds: the same operations on the mean,
                # so the numbers are bit-identical (``policy.actor(tensor, deterministic=True)``)
                actor = policy.actor
                features = actor.extract_features(tensor, actor.features_extractor)
                scaled = torch.tanh(actor.mu(actor.latent_pi(features))).cpu().numpy()
                actions = policy.unscale_action(scaled)
            elif self.algo in ("sac", "td3"):  # a squashed Gaussian's mean; TD3's own actor
                keywords = {"deterministic": True} if self.algo == "sac" else {}
                scaled = policy.actor(tensor, **keywords).cpu().numpy()
                actions = policy.unscale_action(scaled)
            else:
                dist = policy.get_distribution(tensor)
                actions = dist.get_actions(deterministic=True).cpu().numpy()
        low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
        return np.clip(actions.reshape(len(actions), -1), low, high).astype(np.float32)

    def action_loss(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """How much worse ``actions`` are than the expert's own, per state (>= 0).

        SAC/TD3: ``Q(s, pi*(s)) - Q(s, a)`` under the expert's critic (the smaller of its twin
        Q-networks, as in their targets); PPO/A2C: ``log pi(pi*(s)|s) - log pi(a|s)`` of its
        Gaussian policy, ``pi*(s)`` its deterministic action (the mean clipped to the Box);
        both clipped at 0."""
        import torch

        if not self.continuous:
            raise TypeError("action_loss is for Box tasks; a discrete expert has scores")
        a = np.array(actions, dtype=np.float32).reshape(len(obs), -1)  # a writable copy
        with torch.no_grad():
            tensor = self._obs_tensor(obs)
            policy = self.model.policy
            if self.algo in ("sac", "td3"):
                own = torch.as_tensor(policy.scale_action(self._box_actions(obs)))
                given = torch.as_tensor(policy.scale_action(a))

                def q(act: Any) -> Any:
                    return torch.min(torch.cat(policy.critic(tensor, act), dim=1), dim=1).values

                loss = (q(own) - q(given)).cpu().numpy()
            else:
                own = torch.as_tensor(self._box_actions(obs))  # its mean, clipped to the Box
                dist = policy.get_distribution(tensor)
                loss = (dist.log_prob(own) - dist.log_prob(torch.as_tensor(a))).cpu().numpy()
        return np.maximum(loss.astype(np.float64).reshape(-1), 0.0)



def load_expert(task: Task, algo: str, path: str | Path | None = None) -> Expert:
    """Load a committed (or given) checkpoint; each file is read once per process.

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` for a corrupt checkpoint
    or one whose action/observation spaces do not match the task.
    """
    algo = check_algo(algo)
    path = Path(path) if path is not None else expert_path(task, algo)
    if not path.exists():
        raise FileNotFoundError(f"no expert checkpoint at {path}; {_train_hint(task, algo, path)}")
    if not path.is_dir():
        check_regular_file(path, MAX_CHECKPOINT_BYTES, "SB3 checkpoint")
    stat = path.stat()
    return _load_cached(task, algo, str(path.resolve()), stat.st_mtime_ns, stat.st_size)


def _train_hint(task: Task, algo: str, path: Path | None = None) -> str:
    """How to get a checkpoint for (task, algo) at ``path``: a command that works."""
    if algo not in dict(task.experts):
        return ("train one with Stable-Baselines3 (model.save) and pass it with --checkpoint "
                "(`python -m ibt train` trains the experts of the task catalogue only)")
    command = f"python -m ibt train {task.name} --algo {algo}"
    default = expert_path(task, algo)
    if path is None or path.resolve() == default.resolve():
        return f"train one with `{command}` (it writes {default})"
    if path.name == f"{algo}.zip" and path.parent.name == task.name:
        return f"train one with `{command} --experts-dir {shlex.quote(str(path.parent.parent))}`"
    where = path.parent / task.name / f"{algo}.zip"
    return (f"train one with `{command} --experts-dir {shlex.quote(str(path.parent))}` and pass "
            f"--checkpoint {shlex.quote(str(where))}")




@functools.lru_cache(maxsize=64)
def _load_cached(task: Task, algo: str, path: str, _mtime: int, _size: int) -> Expert:
    import torch

    # Experts answer small batches: torch's thread pool only adds overhead (and contention when
    # processes run side by side), and one thread keeps results bit-identical across runs.
    torch.set_num_threads(1)
    if Path(path).is_dir():
        inside = sorted(Path(path).glob(f"**/{algo}.zip"))[:1]
        raise ValueError(f"{path} is a folder, not a Stable-Baselines3 checkpoint; pass the "
                         "checkpoint file" + (f", e.g. {inside[0]}" if inside else ""))
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not a Stable-Baselines3 checkpoint (not a zip archive); "
                         f"pass the .zip that model.save wrote, or {_train_hint(task, algo)}")
    saved_by = checkpoint_algo(path)
    if saved_by is not None and saved_by != algo:
        raise ValueError(f"{path} is a {saved_by.upper()} checkpoint, not a {algo.upper()} one; "
                         f"pass {saved_by} as the algorithm")
    try:
        model = _sb3_class(algo).load(path, device="cpu", custom_objects=dict(NOT_UNPICKLED))
    except Exception as err:  # SB3 raises many kinds on a damaged archive
        raise ValueError(f"{path} is a corrupt or incompatible {algo.upper()} checkpoint "
                         f"({type(err).__name__}: {err}); replace it: "
                         f"{_train_hint(task, algo)}") from None
    if task.continuous:
        shape = getattr(model.action_space, "shape", None)
        if getattr(model.action_space, "n", None) is not None or shape != (task.n_actions,):
            raise ValueError(f"{path} acts in {model.action_space}, but {task.name} acts in a "
                             f"Box of {task.n_actions} dimension(s); is this the checkpoint of "
                             "another task?")
    else:
        n = getattr(model.action_space, "n", None)
        if n is None or int(n) != task.n_actions:
            raise ValueError(f"{path} acts in {model.action_space}, but {task.name} has "
                             f"{task.n_actions} discrete actions; is this the checkpoint of "
                             "another task?")
    env = task.make_env()
    env_obs, env_act = env.observation_space, env.action_space
    env.close()
    for what, saved, expected in (("observes", model.observation_space, env_obs),
                                  ("acts in", model.action_space, env_act)):
        problem = space_difference(saved, expected)
        if problem is not None:
            raise ValueError(f"{path} {what} {saved}, but {task.name} has {expected} "
                             f"({problem}); is this the checkpoint of another task? Pass "
                             f"{task.name}'s own checkpoint")
    norm_file = norm_sidecar_path(Path(path))
    if norm_file.exists():
        obs_norm = read_obs_norm(norm_file, int(np.prod(env_obs.shape or (1,))))
    elif needs_obs_norm(task, algo):
        raise ValueError(f"{path} was trained with observation normalisation but its sidecar "
                         f"{norm_file} is missing; copy it beside the checkpoint (a checkpoint "
                         "without it acts on unnormalised observations)")
    else:
        obs_norm = None
    return Expert(task, algo, model, obs_norm)


def atomic_save_model(model: Any, path: Path) -> None:
    """Save an SB3 model via a temporary file and a rename (no half-written checkpoint)."""
    with atomic_target(path) as tmp:
        model.save(tmp)


EVAL_POINTS = 20  # checkpoints evaluated during training (the best one is kept)
EVAL_EPISODES = 10
MIN_STEPS_FOR_CHECKPOINTS = 20_000


def _final_score(callback: Any) -> float:
    """Mean reward of the callback's last evaluation (the final model's, approximately)."""
    results = getattr(callback, "evaluations_results", None)
    return float(np.mean(results[-1])) if results else -np.inf


def train_expert(task: Task, algo: str, path: str | Path | None = None, *,
                 seed: int = 0, timesteps: int | None = None, progress: bool = True
                 ) -> dict[str, Any]:
    """Train an expert with its table hyperparameters and save it atomically to ``path``.

    Without observation normalisation, the model is evaluated at 20 points during training (10
    episodes each, on their own seeds) and the best checkpoint is kept: DQN in particular can
    collapse late in training.

    Returns facts for the manifest (timesteps, seed, wall seconds, hyperparameter source).
    """
    import torch
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    algo = check_algo(algo)
    hp = hyperparams(task, algo)
    steps = int(timesteps if timesteps is not None else hp.timesteps)
    path = Path(path) if path is not None else expert_path(task, algo)
    torch.set_num_threads(1)
    start = time.perf_counter()
    train_env = dict(hp.train_env)
    venv = make_vec_env(lambda: task.make_env(**train_env), n_envs=hp.n_envs, seed=seed)
    norm_obs = hp.normalize is True  # the expert then carries the observation statistics
    if hp.normalize == "reward":
        venv = VecNormalize(venv, norm_obs=False, norm_reward=True,
                            gamma=dict(hp.kwargs).get("gamma", 0.99))
    elif hp.normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=True)
    kwargs = algo_kwargs(hp)
    policy_kwargs = {"net_arch": list(hp.net_arch), **dict(hp.policy_kwargs)}
    model = _sb3_class(algo)("MlpPolicy", venv, seed=seed, device="cpu", verbose=0,
                             policy_kwargs=policy_kwargs, **kwargs)
    # SB3's default logger creates an empty /tmp/SB3-<date> folder on every learn(): log nowhere
    model.set_logger(Logger(folder=None, output_formats=[]))
    callback = None
    # keep the best checkpoint (training is not monotone); tiny smoke/test budgets skip it, as
    # its evaluations would cost far more than the training itself
    if not norm_obs and steps >= MIN_STEPS_FOR_CHECKPOINTS:
        from stable_baselines3.common.callbacks import EvalCallback

        eval_env = make_vec_env(lambda: task.make_env(), n_envs=1, seed=seed + 10_000)
        if hp.normalize == "reward":  # the callback syncs wrappers: the same kind, raw rewards
            eval_env = VecNormalize(eval_env, norm_obs=False, norm_reward=False, training=False)
        scratch = tempfile.mkdtemp(prefix="ibt-train-")
        callback = EvalCallback(eval_env, n_eval_episodes=EVAL_EPISODES,
                                eval_freq=max(steps // EVAL_POINTS // hp.n_envs, 1),
                                deterministic=True, best_model_save_path=scratch, verbose=0)
    try:
        model.learn(total_timesteps=steps, progress_bar=progress, callback=callback)
        wall = time.perf_counter() - start
        if callback is not None:
            best = Path(str(callback.best_model_save_path)) / "best_model.zip"
            if best.exists() and callback.best_mean_reward > _final_score(callback):
                model = _sb3_class(algo).load(best, device="cpu")
    finally:  # an interrupted training leaves no scratch folder behind
        if callback is not None:
            shutil.rmtree(str(callback.best_model_save_path), ignore_errors=True)
    atomic_save_model(model, path)
    norm_file = norm_sidecar_path(path)
    if norm_obs:
        # the observation statistics (one array: a flat Box)
        assert isinstance(venv, VecNormalize) and not isinstance(venv.obs_rms, dict)
        stats = {"mean": venv.obs_rms.mean.tolist(), "var": venv.obs_rms.var.tolist(),
                 "epsilon": float(venv.epsilon), "clip": float(venv.clip_obs)}
        atomic_write_text(norm_file, json.dumps(stats))
    elif norm_file.exists():
        norm_file.unlink()
    venv.close()
    return {"task": task.name, "algo": algo, "timesteps": steps, "seed": seed,
            "n_envs": hp.n_envs, "normalize": hp.normalize,
            "net_arch": "x".join(map(str, hp.net_arch)),
            "hyperparams_source": hp.source, "wall_seconds": round(wall, 1)}
