"""What the HLP is rewarded with: the discriminator reward r^D (the paper's), or one env objective.

A reward source sees every control step's transition and returns one reward per env; after each
rollout it may learn (the discriminator does its k steps there). Both save their full state.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from amorctl.core.contracts import Snapshot
from amorctl.hlp.config import DiscriminatorConfig
from amorctl.hlp.discriminator import DiscriminatorLearner, ReplayBuffer, reward_from_logits
from amorctl.hlp.windows import DatasetWindows, WindowHistory, WindowSpec


class RewardSource(Protocol):
    """The HLP's reward: ``start`` at reset, ``step`` per control step, ``update`` per rollout."""

    def start(self, obs: np.ndarray) -> None:
        """All N envs (re)started with observations [N, D]."""
        ...

    def step(
        self, obs: np.ndarray, env_rewards: np.ndarray, final_obs: np.ndarray, ended: np.ndarray
    ) -> np.ndarray:
        """Reward [N] float32 of the step that ended in ``final_obs`` [N, D] (``obs`` [N, D]: after
        auto-reset of the envs where ``ended`` [N]); ``env_rewards`` [N, m] the objectives'."""
        ...

    def update(self, rng: np.random.Generator) -> dict[str, float]:
        """Learn from this rollout (discriminator steps); metrics under ``disc/``."""
        ...

    def state(self) -> Snapshot: ...

    def load(self, state: Snapshot) -> None: ...


class ObjectiveReward:
    """The HLP rewarded with one of the env's own objectives (tests, ablations)."""

    def __init__(self, index: int) -> None:
        self.index = index

    def start(self, obs: np.ndarray) -> None:
        pass

    def step(
        self, obs: np.ndarray, env_rewards: np.ndarray, final_obs: np.ndarray, ended: np.ndarray
    ) -> np.ndarray:
        return np.asarray(env_rewards[:, self.index], dtype=np.float32)

    def update(self, rng: np.random.Generator) -> dict[str, float]:
        return {}

    def state(self) -> Snapshot:
        return Snapshot()

    def load(self, state: Snapshot) -> None:
        pass


class DiscriminatorReward:
    """r^D = -log(max(1 - D(O_t | z_t), clamp)) with D learned alongside (module
    :mod:`amorctl.hlp.discriminator`).

    Args:
        cfg: the ``[discriminator]`` settings.
        spec: window size and character sizes.
        dataset: the positives (windows of the run's dataset, restricted to the trained motions).
        proprio, latent: slices of the observation holding the frame vector and z.
        num_envs: N.  seed: torch seed of D's initial weights.
    """

    def __init__(
        self,
        cfg: DiscriminatorConfig,
        spec: WindowSpec,
        dataset: DatasetWindows,
        proprio: slice,
        latent: slice,
        num_envs: int,
        seed: int,
    ) -> None:
        self.cfg, self.spec, self.dataset = cfg, spec, dataset
        self.proprio, self.latent = proprio, latent
        latent_dim = latent.stop - latent.start
        self.history = WindowHistory(num_envs, spec)
        self.learner = DiscriminatorLearner(
            spec.size,
            latent_dim,
            cfg.hidden,
            cfg.z_hidden,
            cfg.grad_penalty,
            cfg.logit_l2,
            cfg.weight_decay,
            cfg.learning_rate,
            seed,
        )
        self.replay = ReplayBuffer(cfg.replay_size, spec.size, latent_dim)
        self._windows: list[np.ndarray] = []
        self._z: list[np.ndarray] = []
        self._logits: list[np.ndarray] = []

    def _features(self, obs: np.ndarray) -> np.ndarray:
        return self.spec.features(obs[:, self.proprio])

    def start(self, obs: np.ndarray) -> None:
        self.history.reset(np.arange(len(obs)), self._features(obs))

    def step(
        self, obs: np.ndarray, env_rewards: np.ndarray, final_obs: np.ndarray, ended: np.ndarray
    ) -> np.ndarray:
        """r^D of the full windows; 0 while an env's window still holds padding (its first V - 1
        steps), and those windows are not D's negatives (see :mod:`amorctl.hlp.windows`)."""
        self.history.push(self._features(final_obs))
        full = self.history.full()
        windows, z = self.history.windows(), np.asarray(final_obs[:, self.latent], dtype=np.float32)
        logits = self.learner.logits(windows, z)
        self._windows.append(windows[full])
        self._z.append(z[full])
        self._logits.append(logits[full])
        done = np.flatnonzero(ended)
        if len(done):
            self.history.reset(done, self._features(obs[done]))
        return np.where(full, reward_from_logits(logits, self.cfg.reward_clamp), 0.0).astype(np.float32)

    #: kinds of negatives in a batch (:meth:`batch`)
    POLICY, REPLAY, MISMATCHED = 0, 1, 2

    def batch(
        self, rng: np.random.Generator, windows: np.ndarray, z: np.ndarray
    ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray]:
        """One D batch: B dataset windows (positives) and B negatives: mismatched-z dataset windows
        (share ``mismatched_fraction``) and policy windows, ``replay_fraction`` of those from the
        replay buffer (once it holds any), the rest from this rollout's ``windows`` [K, W], ``z``.

        Returns:
            (positives (windows, z), negatives (windows, z), kind [B] of each negative:
            :attr:`POLICY`, :attr:`REPLAY` or :attr:`MISMATCHED`).
        """
        cfg, b = self.cfg, self.cfg.batch_size
        n_mis = round(b * cfg.mismatched_fraction)
        n_pol = b - n_mis
        n_rep = round(n_pol * cfg.replay_fraction) if self.replay.size else 0
        n_cur = n_pol - n_rep
        pos_w, pos_z, _ = self.dataset.sample(rng, b)
        rows = rng.integers(len(windows), size=n_cur)
        parts_w, parts_z = [windows[rows]], [z[rows]]
        kinds = [np.full(n_cur, self.POLICY)]
        if n_rep:
            rw, rz = self.replay.sample(rng, n_rep)
            parts_w.append(rw)
            parts_z.append(rz)
            kinds.append(np.full(n_rep, self.REPLAY))
        if n_mis:
            mw, mz = self.dataset.mismatched(rng, n_mis)
            parts_w.append(mw)
            parts_z.append(mz)
            kinds.append(np.full(n_mis, self.MISMATCHED))
        neg = (np.concatenate(parts_w), np.concatenate(parts_z))
        return (pos_w, pos_z), neg, np.concatenate(kinds)

    def update(self, rng: np.random.Generator) -> dict[str, float]:
        """k D steps on :meth:`batch` batches; then this rollout's windows join the replay buffer."""
        cfg = self.cfg
        if not self._windows or sum(len(w) for w in self._windows) == 0:
            self._windows, self._z, self._logits = [], [], []  # every window still warming up
            return {}
        windows, z = np.concatenate(self._windows), np.concatenate(self._z)
        rollout_logits = np.concatenate(self._logits)
        sums: dict[str, float] = {}
        for _ in range(cfg.steps_per_iteration):
            pos, neg, _ = self.batch(rng, windows, z)
            stats = self.learner.step(pos, neg)
            for k, v in stats.items():
                sums[k] = sums.get(k, 0.0) + v
        self.replay.add(windows, z)
        self._windows, self._z, self._logits = [], [], []
        k = max(cfg.steps_per_iteration, 1)
        metrics = {f"disc/{key}": v / k for key, v in sums.items()}
        metrics["disc/logit_policy_rollout"] = float(rollout_logits.mean())
        metrics["disc/accuracy_policy_rollout"] = float((rollout_logits < 0).mean())
        metrics["disc/replay_size"] = float(self.replay.size)
        return metrics

    def state(self) -> Snapshot:
        learner = self.learner.state()
        replay = self.replay.state()
        arrays = dict(learner.arrays)
        arrays.update({f"replay/{k}": v for k, v in replay.arrays.items()})
        arrays["history"] = self.history.buf.copy()
        arrays["history_count"] = self.history.count.copy()
        return Snapshot(arrays, {"learner": learner.meta, "replay": replay.meta})

    def load(self, state: Snapshot) -> None:
        a: dict[str, Any] = state.arrays
        self.learner.load(a, state.meta["learner"])
        self.replay.load({k[7:]: v for k, v in a.items() if k.startswith("replay/")}, state.meta["replay"])
        self.history.buf[:] = a["history"]
        self.history.count[:] = a["history_count"]
