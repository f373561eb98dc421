"""Data-parallel plumbing of MOPPO (``torchrun``, docs/distributed.md): the default process group
every rank's trainer averages over, with every collective timed."""

from __future__ import annotations

import hashlib
import time
from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl.core.errors import AmorError


class Replicas:
    """The ``torch.distributed`` default process group a data-parallel trainer averages over.

    Every collective is timed (``seconds``), so the iteration's communication share is measured.
    """

    def __init__(self) -> None:
        import torch.distributed as dist

        self.dist = dist
        self.rank = dist.get_rank()
        self.size = dist.get_world_size()
        self.seconds = 0.0

    def _run(self, fn: Any, *args: Any, **kwargs: Any) -> None:
        t0 = time.perf_counter()
        try:
            fn(*args, **kwargs)
        except RuntimeError as exc:  # a peer died or timed out: one clear line, never a hang
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise AmorError(
                f"rank {self.rank}/{self.size}: MOPPO {getattr(fn, '__name__', 'collective')} failed, "
                f"another rank died or stopped answering: {first}",
                exit_code=3,
            ) from None
        self.seconds += time.perf_counter() - t0

    def sum_(self, tensor: torch.Tensor) -> torch.Tensor:
        """All-reduce ``tensor`` in place (sum over ranks); returns it."""
        self._run(self.dist.all_reduce, tensor, op=self.dist.ReduceOp.SUM)
        return tensor

    def average_gradients(
        self, params: list[nn.Parameter], stats: dict[str, torch.Tensor], n: int
    ) -> dict[str, torch.Tensor]:
        """Replace this rank's gradients of ``params`` and its minibatch statistics (means over its
        ``n`` samples) by the sample-weighted means over all ranks, in one all-reduce."""
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        values = torch.stack([v.float() for v in stats.values()])
        flat = torch.cat([*(g.reshape(-1) for g in grads), values, torch.ones(1)]) * float(n)
        self.sum_(flat)
        flat = flat / flat[-1]
        offset = 0
        for p, g in zip(params, grads, strict=True):
            p.grad = flat[offset : offset + g.numel()].view_as(g).clone()
            offset += g.numel()
        return {key: flat[offset + i] for i, key in enumerate(stats)}

    def fold_normalizer(self, normalizer: Any, obs: torch.Tensor) -> None:
        """Fold the moments of all ranks' observations [B, D] into ``normalizer``
        (a :class:`~amorctl.core.torch_norm.RunningNormalizer`)."""
        x = obs.to(torch.float64).reshape(-1, normalizer.mean.shape[0])
        sums = self.sum_(torch.cat([torch.tensor([float(x.shape[0])], dtype=torch.float64), x.sum(0)]))
        count = float(sums[0])
        if count == 0:
            return
        mean = sums[1:] / count
        var = self.sum_(((x - mean) ** 2).sum(0)) / count
        normalizer.fold(mean, var, count)

    def return_moments(
        self, returns: torch.Tensor, advantages: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """All ranks' mean and mean square of the value targets, and mean square of the
        advantages, each [C], from this rank's [B, C] (for the return scale)."""
        r, a = returns.double(), advantages.double()
        count = torch.tensor([float(r.shape[0])], dtype=torch.float64)
        sums = self.sum_(torch.cat([count, r.sum(0), (r * r).sum(0), (a * a).sum(0)]))
        mean, sq, adv_sq = (sums[1:] / sums[0]).reshape(3, r.shape[1])
        return mean, sq, adv_sq

    def broadcast_modules(self, modules: dict[str, nn.Module]) -> None:
        """Overwrite every rank's parameters and buffers with rank 0's."""
        for module in modules.values():
            for tensor in module.state_dict().values():
                self._run(self.dist.broadcast, tensor, src=0)

    def check_identical(self, modules: dict[str, nn.Module], iteration: int) -> None:
        """Raise AmorError unless every rank holds byte-identical parameters and buffers."""
        digest = hashlib.sha256()
        for module in modules.values():
            for key, tensor in module.state_dict().items():
                digest.update(key.encode() + tensor.detach().contiguous().numpy().tobytes())
        words = torch.from_numpy(np.frombuffer(digest.digest(), dtype=np.int64).copy())
        low, high = words.clone(), words.clone()
        self._run(self.dist.all_reduce, low, op=self.dist.ReduceOp.MIN)
        self._run(self.dist.all_reduce, high, op=self.dist.ReduceOp.MAX)
        if not torch.equal(low, high):
            raise AmorError(
                f"data-parallel training: the ranks' parameters differ at iteration {iteration} "
                "(non-deterministic kernels or a lost update); stopping instead of training on"
            )
