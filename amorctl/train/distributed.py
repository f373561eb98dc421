"""Training across processes and machines with ``torch.distributed`` (launched by ``torchrun``).

``torchrun`` starts one process per rank and sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``,
``LOCAL_WORLD_SIZE``, ``MASTER_ADDR`` and ``MASTER_PORT``; :func:`session` reads them and joins
the default process group (gloo for CPU tensors, NCCL when the backend's tensors live on CUDA),
with a timeout (``AMORCTL_DIST_TIMEOUT`` seconds, default :data:`DEFAULT_TIMEOUT_S`) so a rank
that dies or hangs makes the others fail with a clear error instead of waiting forever.

What lives here is backend-agnostic: the :class:`World` a process belongs to (rank, size, a few
collectives on plain Python values), the per-rank config (:func:`local_config`: envs split evenly,
one seed per rank), checkpoint snapshots gathered from every rank at rank 0
(:func:`gather_snapshot`) and cut back into one rank's part (:func:`rank_snapshot`), and the
row split that sweeps use (:func:`rank_rows`, :func:`gather_rows`). The data-parallel update
itself (gradient and statistics all-reduces) is the backend's: see
``amorctl/plugins/backends/torch_cpu/moppo.py``. docs/distributed.md explains the whole design.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import hashlib
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError

DEFAULT_TIMEOUT_S = 600.0  # a collective that waits longer than this fails (a dead or stuck rank)
TIMEOUT_ENV = "AMORCTL_DIST_TIMEOUT"
#: Snapshot metadata keys of a checkpoint written by several ranks.
WORLD_KEY, RANKS_KEY = "dist_world_size", "dist_ranks"
_joined_a_group = False  # set once this process joined (and so later left) a process group
_RANK_PREFIX = re.compile(r"^rank(\d+)/")


def _env_int(name: str, default: int | None = None) -> int:
    raw = os.environ.get(name)
    if raw is None or raw == "":
        if default is None:
            raise AmorError(f"environment variable {name} is not set (launch with torchrun)")
        return default
    try:
        value = int(raw)
    except ValueError:
        raise AmorError(f"environment variable {name}={raw!r} is not an integer") from None
    if value < 0:
        raise AmorError(f"environment variable {name}={raw!r} must be >= 0")
    return value


def launched_world_size() -> int:
    """``WORLD_SIZE`` as torchrun set it (1 when not launched by torchrun)."""
    return max(1, _env_int("WORLD_SIZE", 1))


def launched_rank() -> int:
    """``RANK`` as torchrun set it (0 when not launched by torchrun)."""
    return _env_int("RANK", 0)


def timeout_seconds() -> float:
    """The collective timeout: ``AMORCTL_DIST_TIMEOUT`` seconds, default :data:`DEFAULT_TIMEOUT_S`."""
    raw = os.environ.get(TIMEOUT_ENV, "")
    if not raw:
        return DEFAULT_TIMEOUT_S
    try:
        value = float(raw)
    except ValueError:
        raise AmorError(f"{TIMEOUT_ENV}={raw!r}: expected a number of seconds") from None
    if not value > 0:
        raise AmorError(f"{TIMEOUT_ENV}={raw!r}: must be > 0 seconds")
    return value


class DistributedError(AmorError):
    """Another rank failed, died or stopped answering (exit status 3, never a hang)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, exit_code=3)


@dataclass(frozen=True)
class World:
    """The processes a run is spread over; rank 0 alone writes files and prints.

    ``World()`` is the single process (every collective returns its input). Collectives on a
    real world must be called by every rank in the same order, as with ``torch.distributed``.
    """

    rank: int = 0
    size: int = 1
    local_rank: int = 0
    local_size: int = 1

    @property
    def distributed(self) -> bool:
        return self.size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    # --- collectives on Python values (gloo; never on the hot path) ---------------------------
    def _call(self, what: str, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """Run a ``torch.distributed`` collective; a lost or silent peer becomes a DistributedError."""
        try:
            return fn(*args, **kwargs)
        except RuntimeError as exc:  # gloo: "Connection closed by peer", "Timed out waiting ..."
            raise lost_peer(self, what, exc) from None

    def sum(self, values: np.ndarray | list[float] | float) -> np.ndarray:
        """Element-wise sum over ranks of a float64 vector (a scalar becomes a 1-vector)."""
        array = np.atleast_1d(np.asarray(values, dtype=np.float64))
        if not self.distributed:
            return array.copy()
        import torch
        import torch.distributed as dist

        tensor = torch.from_numpy(array.copy())
        self._call("all-reduce", dist.all_reduce, tensor, op=dist.ReduceOp.SUM)
        return tensor.numpy()

    def any(self, flag: bool) -> bool:
        """True on every rank if ``flag`` is true on any rank."""
        return bool(self.sum(1.0 if flag else 0.0)[0] > 0)

    def all_gather(self, obj: Any) -> list[Any]:
        """Every rank's ``obj`` (picklable; sent between this run's own processes), in rank order."""
        if not self.distributed:
            return [obj]
        import torch.distributed as dist

        out: list[Any] = [None] * self.size
        self._call("all-gather", dist.all_gather_object, out, obj)
        return out

    def gather(self, obj: Any) -> list[Any] | None:
        """Every rank's ``obj`` at rank 0, in rank order; None on the other ranks."""
        if not self.distributed:
            return [obj]
        import torch.distributed as dist

        out: list[Any] | None = [None] * self.size if self.is_main else None
        self._call("gather", dist.gather_object, obj, out, dst=0)
        return out

    def broadcast(self, obj: Any) -> Any:
        """Rank 0's ``obj`` on every rank."""
        if not self.distributed:
            return obj
        import torch.distributed as dist

        box = [obj if self.is_main else None]
        self._call("broadcast", dist.broadcast_object_list, box, src=0)
        return box[0]

    def agreeing(self) -> _Agreement:
        """A block after which every rank knows whether any rank failed in it (see :class:`_Agreement`)."""
        return _Agreement(self)


class _Agreement:
    """``with world.agreeing(): ...``: a failure on any rank is raised on every rank, so no rank
    walks on into a collective the failed one never reaches. The failing rank raises its own
    error; the others raise a :class:`DistributedError` that quotes it."""

    def __init__(self, world: World) -> None:
        self.world = world

    def __enter__(self) -> None:
        return None

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> bool:
        if not self.world.distributed:
            return False
        if exc is not None and not isinstance(exc, Exception):
            return False  # KeyboardInterrupt / SystemExit: leave at once, the peers time out
        mine = None
        if exc is not None:
            mine = str(exc) if isinstance(exc, AmorError) else f"{type(exc).__name__}: {exc}"
        failures = [(r, m) for r, m in enumerate(self.world.all_gather(mine)) if m is not None]
        if exc is not None or not failures:
            return False  # re-raise our own error, or nothing went wrong anywhere
        rank, message = failures[0]
        raise DistributedError(f"rank {rank} failed: {message}")


def lost_peer(world: World, what: str, exc: BaseException) -> DistributedError:
    """The error a rank raises when a collective failed: another rank died or timed out."""
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return DistributedError(
        f"rank {world.rank}/{world.size}: {what} failed, another rank died or stopped answering "
        f"(timeout {timeout_seconds():g} s, {TIMEOUT_ENV}): {first}"
    )


def current() -> World:
    """The world of the initialized default process group, else the single process."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_initialized()):
        return World()
    size = dist.get_world_size()
    local_size = _env_int("LOCAL_WORLD_SIZE", size)
    return World(dist.get_rank(), size, _env_int("LOCAL_RANK", 0), max(1, local_size))


def process_group_backend(device: str = "cpu") -> str:
    """gloo for CPU tensors (the torch-cpu backend), NCCL for CUDA tensors when CUDA is there."""
    import torch

    return "nccl" if device == "cuda" and torch.cuda.is_available() else "gloo"


@contextlib.contextmanager
def session(device: str = "cpu") -> Iterator[World]:
    """Join the process group torchrun described in the environment, for the block.

    Without torchrun's variables (or with ``WORLD_SIZE=1``) this is the single process and does
    nothing. A group that is already initialized is used as it is (and left to its owner).

    Raises:
        AmorError: torchrun's variables are incomplete or the rendezvous failed (within the timeout).
    """
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        yield current()
        return
    size = launched_world_size()
    if size == 1:
        yield World()
        return
    rank = launched_rank()
    if rank >= size:
        raise AmorError(f"RANK={rank} must be < WORLD_SIZE={size}")
    for name in ("MASTER_ADDR", "MASTER_PORT"):
        if not os.environ.get(name):
            raise AmorError(f"environment variable {name} is not set (launch with torchrun)")
    timeout = datetime.timedelta(seconds=timeout_seconds())
    try:
        dist.init_process_group(
            process_group_backend(device), init_method="env://", rank=rank, world_size=size, timeout=timeout
        )
    except (RuntimeError, ValueError) as exc:
        raise DistributedError(
            f"rank {rank}/{size}: could not join the process group at "
            f"{os.environ['MASTER_ADDR']}:{os.environ['MASTER_PORT']}: {exc}"
        ) from None
    global _joined_a_group
    _joined_a_group = True
    clean = False
    try:
        yield current()
        clean = True
    finally:
        with contextlib.suppress(RuntimeError, ValueError):
            if clean:  # both ranks past their last collective before gloo's threads are torn down
                dist.barrier()  # (a rank that left early made gloo abort the other at exit)
            dist.destroy_process_group()


# --- per-rank config ------------------------------------------------------------------------------
def joined_a_group() -> bool:
    """Whether this process joined a process group through :func:`session`. Such a process must
    end without interpreter finalization (:func:`amorctl.core.process_exit.end_process`): gloo's
    native threads met at teardown aborted a rank ("terminate called without an active exception",
    SIGABRT) after its work and checkpoint were done, about once in 20 signal-stopped runs here."""
    return _joined_a_group


def rank_seed(seed: int, rank: int) -> int:
    """Rank 0 keeps ``seed`` (a 1-process run is unchanged); rank r > 0 gets an independent seed."""
    if rank == 0:
        return seed
    return int(np.random.SeedSequence([seed, rank]).generate_state(1)[0])


def local_config(config: TrainConfig, world: World) -> TrainConfig:
    """The config one rank runs: ``num_envs / world size`` envs and its own seed.

    Raises:
        AmorError: ``[env] num_envs`` is not a multiple of the world size.
    """
    if not world.distributed:
        return config
    n = config.env.num_envs
    if n % world.size:
        raise AmorError(
            f"[env] num_envs = {n} is not divisible by the {world.size} processes; "
            f"choose a multiple of {world.size}"
        )
    env = dataclasses.replace(config.env, num_envs=n // world.size)
    run = dataclasses.replace(config.run, seed=rank_seed(config.run.seed, world.rank))
    return dataclasses.replace(config, env=env, run=run)


# --- checkpoints of several ranks -----------------------------------------------------------------
def _digest(array: np.ndarray) -> str:
    a = np.ascontiguousarray(array)
    return hashlib.sha256(f"{a.dtype.str}{a.shape}".encode() + a.tobytes()).hexdigest()


def gather_snapshot(snapshot: Snapshot, world: World) -> Snapshot | None:
    """Every rank's snapshot merged at rank 0 (None on the other ranks); collective.

    An array that is byte-identical on all ranks (the networks, the optimizer) is stored once
    under its name; one that differs (observations, RNG states, episode statistics, env state) is
    stored for every rank as ``rank<r>/<name>``. The metadata is rank 0's plus
    ``dist_world_size`` and ``dist_ranks`` (each rank's metadata). A 1-process snapshot is
    returned unchanged, so single-process checkpoints keep their format.
    """
    if not world.distributed:
        return snapshot
    digests = world.all_gather({k: _digest(v) for k, v in snapshot.arrays.items()})
    names = set().union(*digests)
    shared = {k for k in names if all(k in d and d[k] == digests[0].get(k) for d in digests)}
    mine = {k: v for k, v in snapshot.arrays.items() if k not in shared}
    parts = world.gather((mine, snapshot.meta))
    if parts is None:
        return None
    arrays = {k: snapshot.arrays[k] for k in sorted(shared)}
    for rank, (own, _) in enumerate(parts):
        arrays.update({f"rank{rank}/{k}": v for k, v in own.items()})
    meta = {**snapshot.meta, WORLD_KEY: world.size, RANKS_KEY: [m for _, m in parts]}
    return Snapshot(arrays, meta)


def snapshot_world_size(snapshot: Snapshot) -> int:
    """How many ranks wrote ``snapshot`` (1 for a single-process checkpoint)."""
    return int(snapshot.meta.get(WORLD_KEY, 1))


def rank_snapshot(snapshot: Snapshot, rank: int) -> Snapshot:
    """Rank ``rank``'s own snapshot out of a merged one (the inverse of :func:`gather_snapshot`).

    Raises:
        AmorError: the snapshot holds fewer ranks than ``rank + 1``.
    """
    size = snapshot_world_size(snapshot)
    if size == 1 and WORLD_KEY not in snapshot.meta:
        return snapshot
    if not 0 <= rank < size:
        raise AmorError(f"checkpoint holds {size} ranks, not rank {rank}")
    prefix = f"rank{rank}/"
    arrays = {k: v for k, v in snapshot.arrays.items() if not _RANK_PREFIX.match(k)}
    arrays.update({k[len(prefix) :]: v for k, v in snapshot.arrays.items() if k.startswith(prefix)})
    ranks = snapshot.meta.get(RANKS_KEY)
    if not isinstance(ranks, list) or len(ranks) != size or not isinstance(ranks[rank], dict):
        raise AmorError(f"checkpoint metadata {RANKS_KEY!r} does not list {size} ranks")
    return Snapshot(arrays, dict(ranks[rank]))


# --- sweeps: rows split over ranks ----------------------------------------------------------------
def rank_rows(count: int, world: World) -> slice:
    """The contiguous block of ``count`` rows rank ``world.rank`` evaluates (sizes differ by <= 1)."""
    base, extra = divmod(count, world.size)
    start = world.rank * base + min(world.rank, extra)
    return slice(start, start + base + (1 if world.rank < extra else 0))


def gather_rows(rows: dict[str, np.ndarray], world: World) -> dict[str, np.ndarray] | None:
    """Each rank's per-row result arrays ``{name: [rows_r, ...]}`` concatenated in rank order at
    rank 0 (None elsewhere); with :func:`rank_rows` this restores the 1-process row order."""
    if not world.distributed:
        return rows
    parts = world.gather(rows)
    if parts is None:
        return None
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in rows}


class QuietLog:
    """The metrics log of ranks other than 0: they write nothing."""

    def write(self, metrics: dict[str, float]) -> None:
        """Drop ``metrics`` (rank 0 writes the reduced ones)."""

    def close(self) -> None:
        """Nothing to close."""
