"""Teacher-student distillation on PyTorch, CPU (``[distill] teachers``, docs/distill.md).

:class:`DistillTrainer` is MOPPO with the policy loss swapped: the student acts (Gaussian samples
of its own actor, as in a MOPPO rollout), so it learns on the states it visits itself (DAgger
without the teacher in the loop); the teacher of each sample's clip (the training loop hands the
teachers over as ``env.teacher``) labels every observation with its Gaussian action; and the actor
minimizes ``KL(teacher || student)`` per sample, summed over action dimensions, averaged over the
minibatch, which pulls the student's mean to the teacher's (in units of the student's std) and its
std to the teacher's. Each teacher sees the student's observation, ``w`` included, so the student
learns the teachers' whole weight-conditioned behaviour. The critic learns as in MOPPO (GAE
targets from the student's own rollouts, the same value loss), so a distilled run is an ordinary
run afterwards: evaluate, pareto, tune, deploy, or further MOPPO training from its checkpoint.

With ``[distill] rewards = true`` the student also learns from the rewards (kickstarting,
Schmitt et al. 2018): its actor's loss is MOPPO's (clipped surrogate of the scalarized advantage,
entropy bonus) plus ``kl_coef`` x the same KL, the coefficient falling linearly to 0 over
``kl_fade_iterations`` (counted from the run's first iteration, so a resumed run fades on
schedule). The teachers keep what the rewards alone would let go of, the rewards may improve on
them (measured: docs/repertoire.md, "Kickstarting: the teachers kept beside MOPPO").

Rollout, returns, minibatches, data-parallel replicas and checkpoints are MOPPO's; the learning
rate is ``[distill] learning_rate``, fixed (MOPPO's KL rule would shrink it to its floor while
the student, rightly, moves far from its last policy at every step). A checkpoint also records which
checkpoint of which teacher taught it; resuming with teachers that moved on is refused.

Shapes: B = rollout samples, k = minibatch samples, A = action dim, C = critic channels.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from amorctl.core.config import NetworkConfig, PPOConfig
from amorctl.core.contracts import Snapshot, tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.ppo_math import gaussian_kl
from amorctl.core.vecenv import teacher_of
from amorctl.plugins.backends.torch_cpu.batch import Batch
from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer


class ClipLog:
    """The env, noting before each step the clip every env tracks (the clip of the observation
    the step's action answers); everything else is the env's."""

    def __init__(self, env: Any, view: Any) -> None:
        self.env, self._view = env, view
        self._steps: list[np.ndarray] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def tracking_view(self) -> Any:
        return self._view

    def step(self, actions: np.ndarray) -> tuple[Any, ...]:
        self._steps.append(np.array(self._view.clip_index(), dtype=np.int64))
        return self.env.step(actions)

    def take(self) -> np.ndarray:
        """[T, N] the clips noted since the last call, in step order."""
        steps, self._steps = self._steps, []
        return np.stack(steps)


class DistillTrainer(MOPPOTrainer):
    """The student of ``env.teacher``; implements :class:`~amorctl.core.contracts.Trainer`."""

    def __init__(
        self,
        env: Any,
        network: NetworkConfig,
        ppo: PPOConfig,
        seed: int,
        learning_rate: float,
        bf16: bool = False,
        distributed: bool = False,
        kickstart: tuple[float, int] | None = None,
    ) -> None:
        """``kickstart``: (kl_coef, kl_fade_iterations) to learn from the rewards too, or None to
        imitate the teachers alone."""
        teacher, view = teacher_of(env), tracking_view(env)
        if teacher is None or view is None:
            raise AmorError(
                "[distill] teachers: the training env carries no teachers (the training loop attaches them)"
            )
        self.teacher = teacher
        self.kickstart = kickstart
        self.clip_log = ClipLog(env, view)
        #: the rollout's teacher labels: action mean [B, A], log std [B, A]
        self.labels: tuple[torch.Tensor, torch.Tensor] | None = None
        super().__init__(self.clip_log, network, ppo, seed, bf16=bf16, distributed=distributed)
        self.learning_rate = learning_rate
        for group in self.optimizer.param_groups:
            group["lr"] = learning_rate

    def collect_rollout(self) -> tuple[Batch, dict[str, float]]:
        """MOPPO's rollout, then the teachers' labels of its observations (timed as ``teacher``,
        part of the policy's share)."""
        batch, times = super().collect_rollout()
        clips = self.clip_log.take().reshape(-1)
        start = time.perf_counter()
        mean, log_std = self.teacher(batch.obs.numpy(), clips)
        self.labels = (torch.as_tensor(mean), torch.as_tensor(log_std))
        times["policy"] += time.perf_counter() - start
        return batch, times

    def _adapt_learning_rate(self, kl: float) -> None:
        """The student's learning rate stays fixed (``[distill] learning_rate``), kickstarting too:
        after a student, MOPPO's KL rule held the rate at 1e-6 to 4e-6 whatever its floor
        (docs/repertoire.md, "Kickstarting: the teachers kept beside MOPPO")."""

    def kl_coef(self) -> float:
        """The teachers' KL weight this iteration: 1 when imitating; with kickstarting,
        ``kl_coef x max(0, 1 - iteration / kl_fade_iterations)`` (no fade when that is 0)."""
        if self.kickstart is None:
            return 1.0
        coef, fade = self.kickstart
        return coef if fade == 0 else coef * max(0.0, 1.0 - self.iteration_count / fade)

    def minibatch_loss(self, batch: Batch, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """On the samples ``idx``: ``KL(teacher || student)`` + ``value_coef`` x MOPPO's value loss;
        kickstarting: MOPPO's loss + :meth:`kl_coef` x that KL."""
        assert self.labels is not None, "collect a rollout first"
        mean, values = self._forward(batch.obs[idx])
        assert values is not None
        teacher_mean, teacher_log_std = self.labels[0][idx], self.labels[1][idx]
        log_std = self.actor.log_std
        distill_loss = gaussian_kl(teacher_mean, teacher_log_std, mean, log_std, xp=torch).mean()
        if self.kickstart is None:
            value_loss = self.value_loss(values, batch, idx)
            loss = distill_loss + self.cfg.value_coef * value_loss
            with torch.no_grad():
                stats = {
                    "loss/total": loss.detach(),
                    "loss/policy": distill_loss.detach(),
                    "loss/value": value_loss.detach(),
                    "kl": gaussian_kl(batch.means[idx], batch.old_log_std, mean, log_std, xp=torch).mean(),
                }
        else:
            coef = self.kl_coef()
            loss, stats = self.reward_loss(batch, idx, mean, values)
            loss = loss + coef * distill_loss
            stats["loss/total"] = loss.detach()
            stats["distill/kl"] = distill_loss.detach()
            stats["distill/kl_coef"] = torch.tensor(coef)
        stats["distill/action_mae"] = (mean - teacher_mean).abs().mean().detach()
        return loss, stats

    def state_dict(self) -> Snapshot:
        """MOPPO's state, with the teachers' checkpoints (``distill_teachers``)."""
        state = super().state_dict()
        state.meta["distill_teachers"] = self.teacher.fingerprint()
        return state

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore :meth:`state_dict`; AmorError when the teachers are not the ones it was taught by."""
        taught_by = state.meta.get("distill_teachers")
        now = self.teacher.fingerprint()
        if taught_by != now:
            raise AmorError(
                f"[distill] teachers: this student was taught by {taught_by}, the teachers are now {now}; "
                "resuming would change its targets silently: start a new student run instead"
            )
        super().load_state_dict(state)
