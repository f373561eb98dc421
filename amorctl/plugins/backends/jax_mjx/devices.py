"""Data parallelism: one 1-D mesh over the devices, envs split along it, parameters replicated.

``jax.jit`` partitions the training program over the mesh from the input shardings (GSPMD): the
env axis of the env state and of the rollout batch is split across devices, the parameters and
the optimizer state are replicated, and XLA turns the reductions (gradients, advantage
normalization, statistics) into all-reduces. The result is the one-device result up to float
reduction order.

Multi-host: call :func:`initialize_distributed` (``jax.distributed.initialize``) in every process
before the backend is made (``AMORCTL_JAX_DISTRIBUTED=1`` does it from the environment's
coordinator settings); the mesh then spans every process's devices. See docs/backends.md.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "envs"
DISTRIBUTED_ENV = "AMORCTL_JAX_DISTRIBUTED"


def initialize_distributed() -> None:
    """``jax.distributed.initialize()`` once, when ``AMORCTL_JAX_DISTRIBUTED=1`` (its coordinator
    address, process count and id come from JAX's own environment variables or the cluster)."""
    if os.environ.get(DISTRIBUTED_ENV, "") not in ("", "0") and not jax.distributed.is_initialized():
        jax.distributed.initialize()


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
    """Place every leaf of ``tree`` on all devices of the mesh."""
    return jax.device_put(tree, replicated(mesh))


def shard_envs(mesh: Mesh, tree: Any, axis: int = 0) -> Any:
    """Split every array leaf of ``tree`` along ``axis`` (scalars are replicated)."""

    def put(x: Any) -> Any:
        x = jax.numpy.asarray(x)
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
        if name == "old_log_std":
            out[name] = jax.device_put(value, replicated(mesh))
        elif name in ("rewards", "next_values", "terminated", "truncated"):
            out[name] = jax.device_put(value, env_sharding(mesh, 1, value.ndim))
        else:
            out[name] = jax.device_put(value, env_sharding(mesh, 0, value.ndim))
    return type(batch)(**out)
