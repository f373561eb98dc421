"""The motion VAE (VMP-style): a window of 2W+1 frames centred at t -> latent z_t.

Windows never cross clips. At clip edges the window is padded by repeating the clip's first or
last frame (index clamping): the window at frame t holds frames clamp(t + k, 0, T - 1) for
k = -W..W. Frames are standardised per feature with the training set's mean and std (a std below
1e-6, such as an always-zero toe joint, is replaced by 1).

The encoder and decoder are MLPs (ELU). Loss = mean squared reconstruction error of the
standardised window + ``kl_weight`` * KL(q(z | M) || N(0, I)) (summed over latent dimensions,
averaged over the batch). Whole clips are held out for the reported reconstruction error; the
stored encoder is the one trained without them, and z_t is the posterior mean for every frame.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save
from torch import nn

from amorctl.core.errors import AmorError


@dataclass(frozen=True)
class VaeConfig:
    """Motion-VAE settings; the defaults are what ``amorctl preprocess`` uses."""

    window: int = 15  # W: the window holds 2W+1 frames (31 frames = 0.62 s at 50 Hz)
    latent_dim: int = 32  # L: size of z_t
    kl_weight: float = 1e-3  # weight of the KL term against the reconstruction MSE
    hidden: int = 256  # width of the two hidden layers of encoder and decoder
    epochs: int = 150  # passes over the training windows
    batch_size: int = 256
    learning_rate: float = 1e-3
    holdout_fraction: float = 0.1  # share of clips held out (at least 1), when ``holdout`` is empty
    holdout: tuple[str, ...] = ()  # names of the clips to hold out; overrides holdout_fraction
    seed: int = 0


class MotionEncoder(nn.Module):
    """[B, 2W+1, D] standardised windows -> (mean, log-variance), each [B, L]."""

    def __init__(self, window_frames: int, frame_dim: int, hidden: int, latent_dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Flatten(),
            nn.Linear(window_frames * frame_dim, hidden),
            nn.ELU(),
            nn.Linear(hidden, hidden),
            nn.ELU(),
            nn.Linear(hidden, 2 * latent_dim),
        )

    def forward(self, windows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mu, logvar = self.net(windows).chunk(2, dim=-1)
        return mu, logvar.clamp(-10.0, 10.0)


class MotionDecoder(nn.Module):
    """[B, L] latents -> [B, 2W+1, D] standardised windows."""

    def __init__(self, window_frames: int, frame_dim: int, hidden: int, latent_dim: int) -> None:
        super().__init__()
        self.shape = (window_frames, frame_dim)
        self.net = nn.Sequential(
            nn.Linear(latent_dim, hidden),
            nn.ELU(),
            nn.Linear(hidden, hidden),
            nn.ELU(),
            nn.Linear(hidden, window_frames * frame_dim),
        )

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z).view(-1, *self.shape)


def window_indices(starts: np.ndarray, lengths: np.ndarray, window: int) -> np.ndarray:
    """[F, 2W+1] flat frame indices of every frame's window, edges padded by clamping per clip."""
    rows = []
    offsets = np.arange(-window, window + 1)
    for s, n in zip(starts, lengths, strict=True):
        t = np.arange(n)[:, None] + offsets[None]
        rows.append(s + np.clip(t, 0, n - 1))
    return np.concatenate(rows, axis=0) if rows else np.zeros((0, 2 * window + 1), dtype=np.int64)


@dataclass
class TrainedVae:
    """The result of :func:`train_vae`: encoder, decoder, normalisation and the measured errors."""

    config: VaeConfig
    encoder: MotionEncoder
    decoder: MotionDecoder
    mean: np.ndarray  # [D]
    std: np.ndarray  # [D]
    heldout_clips: list[int]
    heldout_error: float | None  # MSE (standardised units) on held-out clips, trained encoder
    heldout_per_clip: list[float]  # the same per held-out clip
    untrained_error: float | None  # the same with the initial (untrained) weights
    train_error: float


def split_clips(num_clips: int, cfg: VaeConfig, names: Sequence[str] = ()) -> list[int]:
    """Indices of the clips held out: those named in ``cfg.holdout`` (resolved against ``names``),
    else a seeded random ``holdout_fraction`` of them (none if there is only one clip)."""
    if cfg.holdout:
        from amorctl.motion.resolve import resolve_name

        held = sorted({list(names).index(resolve_name(h, names, "the clips")) for h in cfg.holdout})
        if len(held) >= num_clips:
            raise AmorError("the VAE needs at least one clip that is not held out")
        return held
    if num_clips < 2 or cfg.holdout_fraction <= 0:
        return []
    count = min(num_clips - 1, max(1, round(cfg.holdout_fraction * num_clips)))
    rng = np.random.default_rng(cfg.seed)
    return sorted(int(i) for i in rng.permutation(num_clips)[:count])


def _recon_error(
    enc: MotionEncoder, dec: MotionDecoder, frames: torch.Tensor, idx: np.ndarray, batch: int = 1024
) -> float:
    """Mean squared error of decoding the posterior mean, over windows ``idx`` [N, 2W+1]."""
    total, count = 0.0, 0
    with torch.no_grad():
        for i in range(0, idx.shape[0], batch):
            w = frames[torch.from_numpy(idx[i : i + batch])]
            mu, _ = enc(w)
            total += float(((dec(mu) - w) ** 2).sum())
            count += w.numel()
    return total / max(count, 1)


def train_vae(
    frames: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    cfg: VaeConfig,
    progress: Callable[[int, int, float], None] | None = None,
    names: Sequence[str] = (),
) -> TrainedVae:
    """Train on all clips but the held-out ones. frames [F, D]; starts, lengths [K]; names [K].

    ``progress(step, total_steps, loss)`` is called after every optimiser step.
    """
    if cfg.window < 0 or cfg.latent_dim < 1 or cfg.epochs < 0 or cfg.batch_size < 1 or cfg.kl_weight < 0:
        raise AmorError(f"invalid VAE settings: {cfg}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    held = split_clips(len(starts), cfg, names)
    train_clips = [k for k in range(len(starts)) if k not in held]
    train_rows = np.concatenate([np.arange(starts[k], starts[k] + lengths[k]) for k in train_clips])
    mean = frames[train_rows].mean(axis=0)
    std = frames[train_rows].std(axis=0)
    std = np.where(std < 1e-6, 1.0, std)
    norm = torch.from_numpy(((frames - mean) / std).astype(np.float32))
    train_idx = window_indices(starts[train_clips], lengths[train_clips], cfg.window)
    held_idx = window_indices(starts[held], lengths[held], cfg.window) if held else None

    window_frames, frame_dim = 2 * cfg.window + 1, frames.shape[1]
    enc = MotionEncoder(window_frames, frame_dim, cfg.hidden, cfg.latent_dim)
    dec = MotionDecoder(window_frames, frame_dim, cfg.hidden, cfg.latent_dim)
    untrained = _recon_error(enc, dec, norm, held_idx) if held_idx is not None else None
    opt = torch.optim.Adam([*enc.parameters(), *dec.parameters()], lr=cfg.learning_rate)
    steps_per_epoch = max(1, int(np.ceil(train_idx.shape[0] / cfg.batch_size)))
    total = cfg.epochs * steps_per_epoch
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(
        opt, T_max=max(total, 1), eta_min=cfg.learning_rate * 0.05
    )
    step = 0
    for _ in range(cfg.epochs):
        order = rng.permutation(train_idx.shape[0])
        for b in range(steps_per_epoch):
            w = norm[torch.from_numpy(train_idx[order[b * cfg.batch_size : (b + 1) * cfg.batch_size]])]
            mu, logvar = enc(w)
            z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)
            recon = ((dec(z) - w) ** 2).mean()
            kl = (-0.5 * (1 + logvar - mu**2 - logvar.exp()).sum(dim=-1)).mean()
            loss = recon + cfg.kl_weight * kl
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            step += 1
            if progress is not None:
                progress(step, total, float(loss.detach()))
    enc.eval()
    dec.eval()
    return TrainedVae(
        config=cfg,
        encoder=enc,
        decoder=dec,
        mean=mean,
        std=std,
        heldout_clips=held,
        heldout_error=_recon_error(enc, dec, norm, held_idx) if held_idx is not None else None,
        heldout_per_clip=[
            _recon_error(enc, dec, norm, window_indices(starts[[k]], lengths[[k]], cfg.window)) for k in held
        ],
        untrained_error=untrained,
        train_error=_recon_error(enc, dec, norm, train_idx),
    )


def encode(
    encoder: MotionEncoder,
    mean: np.ndarray,
    std: np.ndarray,
    frames: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    window: int,
    batch: int = 1024,
) -> np.ndarray:
    """z_t = posterior mean for every frame. frames [F, D] -> [F, L] (float32)."""
    norm = torch.from_numpy(((frames - mean) / std).astype(np.float32))
    idx = window_indices(starts, lengths, window)
    out = []
    with torch.no_grad():
        for i in range(0, idx.shape[0], batch):
            mu, _ = encoder(norm[torch.from_numpy(idx[i : i + batch])])
            out.append(mu.numpy())
    return np.concatenate(out, axis=0) if out else np.zeros((0, 0), dtype=np.float32)


def encoder_to_bytes(vae: TrainedVae, frame_dim: int) -> bytes:
    """Encoder weights + normalisation as safetensors; settings in the safetensors metadata."""
    tensors = {f"encoder.{k}": v.detach().contiguous() for k, v in vae.encoder.state_dict().items()}
    tensors["norm.mean"] = torch.from_numpy(vae.mean.astype(np.float32))
    tensors["norm.std"] = torch.from_numpy(vae.std.astype(np.float32))
    meta = {
        "config": json.dumps(asdict(vae.config)),
        "frame_dim": str(frame_dim),
        "format": "amorctl.motion_vae.v1",
    }
    return st_save(tensors, metadata=meta)


@dataclass
class LoadedEncoder:
    """An encoder read back from safetensors, ready for :meth:`encode`."""

    config: VaeConfig
    encoder: MotionEncoder
    mean: np.ndarray
    std: np.ndarray

    def encode(self, frames: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """z [F, L] for frames [F, D] of clips given by starts / lengths."""
        return encode(self.encoder, self.mean, self.std, frames, starts, lengths, self.config.window)


def safetensors_metadata(data: bytes) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors byte string (its JSON header)."""
    size = int.from_bytes(data[:8], "little")
    return dict(json.loads(data[8 : 8 + size]).get("__metadata__", {}))


def encoder_from_bytes(data: bytes) -> LoadedEncoder:
    """Inverse of :func:`encoder_to_bytes`."""
    metadata = safetensors_metadata(data)
    if metadata.get("format") != "amorctl.motion_vae.v1":
        raise AmorError("the motion-VAE weights are not in amorctl's format (amorctl.motion_vae.v1)")
    tensors = st_load(data)
    cfg = VaeConfig(**json.loads(metadata["config"]))
    frame_dim = int(metadata["frame_dim"])
    enc = MotionEncoder(2 * cfg.window + 1, frame_dim, cfg.hidden, cfg.latent_dim)
    enc.load_state_dict(
        {k.removeprefix("encoder."): v for k, v in tensors.items() if k.startswith("encoder.")}
    )
    enc.eval()
    return LoadedEncoder(
        cfg,
        enc,
        tensors["norm.mean"].numpy().astype(np.float64),
        tensors["norm.std"].numpy().astype(np.float64),
    )
