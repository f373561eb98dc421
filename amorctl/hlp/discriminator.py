"""D(O_t | z_t): a z-conditioned discriminator over observation windows, its loss and its reward.

Architecture (CALM-style conditioning): z [L] goes through a small ELU MLP (``z_hidden``; empty:
z itself), is concatenated with the normalized window [V*F], and an ELU MLP (``hidden``) ends in
one logit. D = sigmoid(logit).

Loss per step (paper eq. 8 plus the regularizers public AMP/CALM code uses):
    BCE(dataset windows -> 1) + BCE(negatives -> 0)
    + c_gp * E_dataset ||d logit / d(O_norm, z)||^2      (gradient penalty on dataset samples ONLY)
    + logit_l2 * ||W_logit||^2 + weight_decay * sum ||W||^2
Negatives are policy windows (current rollout and the replay buffer) and dataset windows paired
with a mismatched z. Reward: r^D = -log(max(1 - sigmoid(logit), clamp)).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl.core.contracts import Snapshot
from amorctl.hlp.policy import hlp_normalizer
from amorctl.hlp.state import load_module, load_optimizer, module_arrays, optimizer_arrays


class Discriminator(nn.Module):
    """logit(O, z) for raw windows [B, W] and latents [B, L]; ``norm`` is updated by the caller.

    Args:
        window_size: W = V * F.  latent_dim: L.
        hidden: ELU widths after the concatenation (empty: a linear D).
        z_hidden: ELU widths of the z encoder (empty: z is concatenated as it is).
    """

    def __init__(
        self, window_size: int, latent_dim: int, hidden: tuple[int, ...], z_hidden: tuple[int, ...]
    ) -> None:
        super().__init__()
        self.norm = hlp_normalizer(window_size, clip=10.0)
        z_layers: list[nn.Module] = []
        width = latent_dim
        for h in z_hidden:
            z_layers += [nn.Linear(width, h), nn.ELU()]
            width = h
        self.z_net = nn.Sequential(*z_layers)
        body: list[nn.Module] = []
        width += window_size
        for h in hidden:
            body += [nn.Linear(width, h), nn.ELU()]
            width = h
        self.body = nn.Sequential(*body)
        self.logit = nn.Linear(width, 1)

    def forward_normalized(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Logits [B] of already normalized windows [B, W] and latents [B, L]."""
        return self.logit(self.body(torch.cat([x, self.z_net(z)], dim=-1))).squeeze(-1)

    def forward(self, windows: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Logits [B] of raw windows [B, W] and latents [B, L]."""
        return self.forward_normalized(self.norm(windows), z)

    def weights(self) -> list[torch.Tensor]:
        """Every Linear weight matrix (the weight-decay term)."""
        return [m.weight for m in self.modules() if isinstance(m, nn.Linear)]


def gradient_penalty(disc: Discriminator, windows: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """E ||d logit / d(O_norm, z)||^2 over the given (dataset) samples [B, W], [B, L]: the
    derivative is taken at the normalized window and the raw latent, D's inputs."""
    x = disc.norm(windows).detach().requires_grad_(True)
    zz = z.detach().clone().requires_grad_(True)
    logits = disc.forward_normalized(x, zz)
    gx, gz = torch.autograd.grad(logits.sum(), (x, zz), create_graph=True)
    return (gx.pow(2).sum(-1) + gz.pow(2).sum(-1)).mean()


@dataclass
class LossTerms:
    """One discriminator loss evaluation (tensors, so the total can be backpropagated)."""

    total: torch.Tensor
    bce_dataset: torch.Tensor
    bce_negative: torch.Tensor
    gp: torch.Tensor
    logits_dataset: torch.Tensor  # [B+]
    logits_negative: torch.Tensor  # [B-]


def discriminator_loss(
    disc: Discriminator,
    pos: tuple[torch.Tensor, torch.Tensor],
    neg: tuple[torch.Tensor, torch.Tensor],
    grad_penalty: float,
    logit_l2: float,
    weight_decay: float,
) -> LossTerms:
    """The loss of the module docstring for positives ``pos`` and negatives ``neg`` (windows, z)."""
    bce = nn.functional.binary_cross_entropy_with_logits
    lp = disc(*pos)
    ln = disc(*neg)
    bce_pos = bce(lp, torch.ones_like(lp))
    bce_neg = bce(ln, torch.zeros_like(ln))
    gp = gradient_penalty(disc, *pos) if grad_penalty > 0 else torch.zeros(())
    l2_logit = disc.logit.weight.pow(2).sum()
    decay = sum(w.pow(2).sum() for w in disc.weights())
    total = bce_pos + bce_neg + grad_penalty * gp + logit_l2 * l2_logit + weight_decay * decay
    return LossTerms(total, bce_pos, bce_neg, gp, lp, ln)


def reward_from_logits(logits: np.ndarray, clamp: float = 1e-4) -> np.ndarray:
    """r^D = -log(max(1 - sigmoid(logit), clamp)) [N] float32."""
    d = 1.0 / (1.0 + np.exp(-np.asarray(logits, dtype=np.float64)))
    return (-np.log(np.maximum(1.0 - d, clamp))).astype(np.float32)


class ReplayBuffer:
    """A ring buffer of policy windows and their latents (capacity C): [C, W], [C, L]."""

    def __init__(self, capacity: int, window_size: int, latent_dim: int) -> None:
        self.windows = np.zeros((capacity, window_size), dtype=np.float32)
        self.z = np.zeros((capacity, latent_dim), dtype=np.float32)
        self.size = 0
        self.head = 0

    def add(self, windows: np.ndarray, z: np.ndarray) -> None:
        """Append [k, W], [k, L] (the oldest are overwritten when full)."""
        cap = len(self.windows)
        if len(windows) >= cap:
            windows, z = windows[-cap:], z[-cap:]
        idx = (self.head + np.arange(len(windows))) % cap
        self.windows[idx], self.z[idx] = windows, z
        self.head = int((self.head + len(windows)) % cap)
        self.size = int(min(cap, self.size + len(windows)))

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        rows = rng.integers(self.size, size=n)
        return self.windows[rows], self.z[rows]

    def state(self) -> Snapshot:
        return Snapshot(
            {"windows": self.windows[: self.size].copy(), "z": self.z[: self.size].copy()},
            {"head": self.head, "size": self.size},
        )

    def load(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        self.size, self.head = int(meta["size"]), int(meta["head"])
        self.windows[: self.size] = arrays["windows"]
        self.z[: self.size] = arrays["z"]


class DiscriminatorLearner:
    """D, its optimizer and the batch recipe (positives / policy / replay / mismatched negatives).

    Args:
        window_size, latent_dim: W and L.
        hidden, z_hidden, grad_penalty, logit_l2, weight_decay, learning_rate: see
            :class:`amorctl.hlp.config.DiscriminatorConfig`.
        seed: torch seed of the initial weights.
    """

    def __init__(
        self,
        window_size: int,
        latent_dim: int,
        hidden: tuple[int, ...],
        z_hidden: tuple[int, ...],
        grad_penalty: float,
        logit_l2: float,
        weight_decay: float,
        learning_rate: float,
        seed: int,
    ) -> None:
        with torch.random.fork_rng(devices=[]):  # seeded init without touching the global RNG
            torch.manual_seed(seed)
            self.disc = Discriminator(window_size, latent_dim, hidden, z_hidden)
        self.opt = torch.optim.Adam(self.disc.parameters(), lr=learning_rate)
        self.grad_penalty, self.logit_l2, self.weight_decay = grad_penalty, logit_l2, weight_decay

    @torch.no_grad()
    def logits(self, windows: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Logits [N] float32 of raw windows [N, W] and latents [N, L]."""
        return self.disc(torch.as_tensor(windows), torch.as_tensor(z)).numpy()

    def step(
        self, pos: tuple[np.ndarray, np.ndarray], neg: tuple[np.ndarray, np.ndarray], update_norm: bool = True
    ) -> dict[str, float]:
        """One Adam step on a batch; the normalizer first folds in the batch's windows, dataset and
        negatives alike (as AMP's input normalizer sees both: with dataset statistics alone, a
        feature that barely varies in the dataset puts every policy window many standard
        deviations away, and D separates the classes on it at once). Returns loss terms,
        accuracies, mean logits."""
        pos_t = (torch.as_tensor(pos[0]), torch.as_tensor(pos[1]))
        neg_t = (torch.as_tensor(neg[0]), torch.as_tensor(neg[1]))
        if update_norm:
            self.disc.norm.update(torch.cat([pos_t[0], neg_t[0]]))
        terms = discriminator_loss(
            self.disc, pos_t, neg_t, self.grad_penalty, self.logit_l2, self.weight_decay
        )
        self.opt.zero_grad(set_to_none=True)
        terms.total.backward()
        self.opt.step()
        lp, ln = terms.logits_dataset.detach(), terms.logits_negative.detach()
        return {
            "loss": terms.total.item(),
            "bce_dataset": terms.bce_dataset.item(),
            "bce_negative": terms.bce_negative.item(),
            "gp": terms.gp.item(),
            "accuracy_dataset": float((lp > 0).float().mean()),
            "accuracy_negative": float((ln < 0).float().mean()),
            "logit_dataset": float(lp.mean()),
            "logit_negative": float(ln.mean()),
        }

    def state(self) -> Snapshot:
        arrays = module_arrays("disc", self.disc)
        opt_arrays, opt_meta = optimizer_arrays("disc_opt", self.opt)
        arrays.update(opt_arrays)
        return Snapshot(arrays, {"disc_opt": opt_meta})

    def load(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        load_module("disc", self.disc, arrays)
        load_optimizer("disc_opt", self.opt, arrays, meta["disc_opt"])
