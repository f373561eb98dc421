"""Data parallelism: one 1-D mesh over the devices, envs split along it, parameters replicated.

``jax.jit`` partitions the training program over the mesh from the input shardings (GSPMD): the
env axis of the env state and of the rollout batch is split across devices, the parameters and
the optimizer state are replicated, and XLA turns the reductions (gradients, advantage
normalization, statistics) into all-reduces. The result is the one-device result up to float
reduction order.

Multi-host: :func:`initialize_distributed` (``jax.distributed.initialize``) runs in every process
before the first mesh is made when ``AMORCTL_JAX_DISTRIBUTED=1``; the mesh then spans every
process's devices. Every process runs the same program on the same host values (SPMD):
:func:`to_global` lifts host inputs onto the mesh, :func:`to_host` reads whole arrays back
(``process_allgather`` for arrays split across processes). See docs/backends.md.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from amorctl.core.errors import AmorError

AXIS = "envs"
DISTRIBUTED_ENV = "AMORCTL_JAX_DISTRIBUTED"


def initialize_distributed() -> None:
    """``jax.distributed.initialize`` once, when ``AMORCTL_JAX_DISTRIBUTED=1``.

    The coordinator address, process count and this process's id come from
    ``JAX_COORDINATOR_ADDRESS`` (host:port of process 0), ``JAX_NUM_PROCESSES`` and
    ``JAX_PROCESS_ID`` when set, else from the cluster (SLURM, Cloud TPU: JAX finds them itself).
    On CPUs, cross-process collectives use gloo (JAX's CPU default has none)."""
    if os.environ.get(DISTRIBUTED_ENV, "") in ("", "0") or jax.distributed.is_initialized():
        return
    kwargs: dict[str, Any] = {}
    for name, key, kind in (
        ("JAX_COORDINATOR_ADDRESS", "coordinator_address", str),
        ("JAX_NUM_PROCESSES", "num_processes", int),
        ("JAX_PROCESS_ID", "process_id", int),
    ):
        value = os.environ.get(name, "")
        if value:
            try:
                kwargs[key] = kind(value)
            except ValueError:
                raise AmorError(f"{name}={value!r}: expected an integer") from None
    if os.environ.get("JAX_PLATFORMS", "").startswith("cpu"):
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(**kwargs)
    except (RuntimeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AmorError(f"{DISTRIBUTED_ENV}=1: jax.distributed.initialize failed: {first}") from None


def multi_process() -> bool:
    """True when this is one of several JAX processes (multi-host training)."""
    return jax.process_count() > 1


def to_global(mesh: Mesh, tree: Any) -> Any:
    """Inputs for a jitted call over ``mesh``: with several processes, every leaf that is not yet
    an array over the mesh (host values, process-local arrays; the same value in every process)
    is replicated over it. One process: ``tree`` unchanged."""
    if not multi_process():
        return tree

    def put(x: Any) -> Any:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return x
        return jax.device_put(np.asarray(x), replicated(mesh))

    return jax.tree_util.tree_map(put, tree)


def to_host(x: Any) -> np.ndarray:
    """A numpy copy of the whole array, also when its shards live in other processes
    (``process_allgather``, a collective: every process must call it)."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


def local_mesh(num_devices: int | None = None) -> Mesh:
    """A 1-D mesh over the first ``num_devices`` devices (all devices of all processes by default)."""
    initialize_distributed()
    devs = jax.devices()
    if num_devices is not None:
        devs = devs[:num_devices]
    return Mesh(np.asarray(devs), (AXIS,))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, PartitionSpec())


def env_sharding(mesh: Mesh, axis: int = 0, ndim: int = 1) -> NamedSharding:
    """Split ``axis`` (the env or sample axis) of an ``ndim``-dimensional array over the mesh."""
    spec = [None] * ndim
    spec[axis] = AXIS
    return NamedSharding(mesh, PartitionSpec(*spec))


def replicate(mesh: Mesh, tree: Any) -> Any:
    """Place every leaf of ``tree`` on all devices of the mesh (with several processes, from the
    host value every process holds)."""
    if multi_process():
        tree = jax.tree_util.tree_map(lambda x: x if _spans(x) else np.asarray(x), tree)
    return jax.device_put(tree, replicated(mesh))


def _spans(x: Any) -> bool:
    return isinstance(x, jax.Array) and not x.is_fully_addressable


def shard_envs(mesh: Mesh, tree: Any, axis: int = 0) -> Any:
    """Split every array leaf of ``tree`` along ``axis`` (scalars are replicated)."""

    def put(x: Any) -> Any:
        x = np.asarray(x) if multi_process() and not _spans(x) else jax.numpy.asarray(x)
        if x.ndim <= axis:
            return jax.device_put(x, replicated(mesh))
        return jax.device_put(x, env_sharding(mesh, axis, x.ndim))

    return jax.tree_util.tree_map(put, tree)


def shard_batch(mesh: Mesh, batch: Any) -> Any:
    """A rollout batch with its sample axis (or the env axis of [T, N, ...] arrays) split over the
    mesh; ``old_log_std`` replicated. A no-op on one device."""
    if mesh.size == 1:
        return batch
    out = {}
    for name, value in batch._asdict().items():
        if multi_process() and not _spans(value):
            value = np.asarray(value)  # a host value, the same in every process
        if name == "old_log_std":
            out[name] = jax.device_put(value, replicated(mesh))
        elif name in ("rewards", "next_values", "terminated", "truncated"):
            out[name] = jax.device_put(value, env_sharding(mesh, 1, value.ndim))
        else:
            out[name] = jax.device_put(value, env_sharding(mesh, 0, value.ndim))
    return type(batch)(**out)
