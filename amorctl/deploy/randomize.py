"""Per-episode dynamics randomization of the sim2sim runtime: the TOML format and its sampling.

A file names ranges ``[low, high]``; each episode draws one value per range (per link / per
joint where the key says so) from its own seed, so two runs with the same seeds meet the same
dynamics. Every table and key is optional; a missing one means "no randomization of that". ::

    [friction]
    scale = [0.6, 1.2]          # x sliding friction of every geom (one draw per episode)
    [mass]
    scale = [0.9, 1.1]          # x mass (and inertia) of each link, drawn per link
    [com]
    offset = [-0.01, 0.01]      # m, added to each link's centre of mass, per link and axis
    [pd_gains]
    kp_scale = [0.85, 1.15]     # x stiffness, per joint
    kd_scale = [0.85, 1.15]     # x damping, per joint
    [motor_strength]
    scale = [0.85, 1.0]         # x torque limit, per joint
    [armature]
    scale = [0.8, 1.2]          # x joint armature (reflected rotor inertia), per joint
    [latency]
    extra_steps = [0, 2]        # whole control steps the PD targets arrive late (integers)
    [push]
    force = [3.0, 8.0]          # N, horizontal force on the root body, random direction
    duration = [0.1, 0.2]       # s the force acts
    interval = [3.0, 5.0]       # s between pushes

Validation (AmorError naming the file and key): unknown tables or keys, a range that is not two
finite numbers with low <= high, negative scales, a non-integer latency, a non-positive push
duration or interval. Format and rationale: docs/deploy.md.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.errors import AmorError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: table -> key -> (minimum allowed value, integer only)
SCHEMA: dict[str, dict[str, tuple[float, bool]]] = {
    "friction": {"scale": (0.0, False)},
    "mass": {"scale": (0.0, False)},
    "com": {"offset": (-math.inf, False)},
    "pd_gains": {"kp_scale": (0.0, False), "kd_scale": (0.0, False)},
    "motor_strength": {"scale": (0.0, False)},
    "armature": {"scale": (0.0, False)},
    "latency": {"extra_steps": (0.0, True)},
    "push": {"force": (0.0, False), "duration": (1e-3, False), "interval": (1e-3, False)},
}


@dataclass(frozen=True)
class Randomization:
    """Validated ranges: ``ranges[(table, key)] = (low, high)``; empty means none."""

    ranges: dict[tuple[str, str], tuple[float, float]] = field(default_factory=dict)
    source: str = "<none>"

    def get(self, table: str, key: str, neutral: float) -> tuple[float, float]:
        return self.ranges.get((table, key), (neutral, neutral))

    def to_dict(self) -> dict[str, dict[str, list[float]]]:
        out: dict[str, dict[str, list[float]]] = {}
        for (t, k), (lo, hi) in self.ranges.items():
            out.setdefault(t, {})[k] = [lo, hi]
        return out


@dataclass(frozen=True)
class Sample:
    """One episode's dynamics. Per-link arrays are [nbody] (entry 0, the world, is unused),
    per-joint ones [J]; ``latency_steps`` extra control steps; ``push_*`` the ranges pushes draw from."""

    friction_scale: float
    mass_scale: np.ndarray
    com_offset: np.ndarray
    kp_scale: np.ndarray
    kd_scale: np.ndarray
    strength_scale: np.ndarray
    armature_scale: np.ndarray
    latency_steps: int
    push_force: tuple[float, float]
    push_duration: tuple[float, float]
    push_interval: tuple[float, float]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (means of per-link / per-joint draws)."""
        return {
            "friction_scale": self.friction_scale,
            "mass_scale_mean": float(self.mass_scale[1:].mean()) if len(self.mass_scale) > 1 else 1.0,
            "kp_scale_mean": float(self.kp_scale.mean()),
            "strength_scale_mean": float(self.strength_scale.mean()),
            "latency_steps": self.latency_steps,
        }


def load_randomization(path: str | Path) -> Randomization:
    """Read and validate a randomization TOML file (module docstring)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise AmorError(f"{path}: randomization file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise AmorError(f"{path}: not a readable TOML file ({exc})") from None
    ranges: dict[tuple[str, str], tuple[float, float]] = {}
    for table, entries in raw.items():
        if table not in SCHEMA:
            raise AmorError(f"{path}: unknown table [{table}] (known: {', '.join(SCHEMA)})")
        if not isinstance(entries, dict):
            raise AmorError(f"{path}: [{table}] must be a table")
        for key, value in entries.items():
            if key not in SCHEMA[table]:
                raise AmorError(
                    f"{path}: [{table}] has unknown key {key!r} (known: {', '.join(SCHEMA[table])})"
                )
            lowest, integer = SCHEMA[table][key]
            where = f"{path}: [{table}] {key}"
            if (
                not isinstance(value, list)
                or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            ):
                raise AmorError(f"{where} must be a range [low, high] of two numbers, got {value!r}")
            lo, hi = float(value[0]), float(value[1])
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise AmorError(f"{where}: bounds must be finite, got {value!r}")
            if lo > hi:
                raise AmorError(f"{where}: low {lo} is above high {hi}")
            if lo < lowest:
                raise AmorError(f"{where}: must be >= {lowest:g}, got {lo}")
            if integer and (lo != int(lo) or hi != int(hi)):
                raise AmorError(f"{where}: must be whole control steps, got {value!r}")
            ranges[(table, key)] = (lo, hi)
    return Randomization(ranges, str(path))


def sample(rand: Randomization, rng: np.random.Generator, nbody: int, num_joints: int) -> Sample:
    """Draw one episode's dynamics from ``rand`` (identity where a range is absent)."""

    def draw(table: str, key: str, neutral: float, size: int | tuple[int, ...] | None = None) -> Any:
        lo, hi = rand.get(table, key, neutral)
        return rng.uniform(lo, hi, size=size)

    lat_lo, lat_hi = rand.get("latency", "extra_steps", 0.0)
    return Sample(
        friction_scale=float(draw("friction", "scale", 1.0)),
        mass_scale=draw("mass", "scale", 1.0, nbody),
        com_offset=draw("com", "offset", 0.0, (nbody, 3)),
        kp_scale=draw("pd_gains", "kp_scale", 1.0, num_joints),
        kd_scale=draw("pd_gains", "kd_scale", 1.0, num_joints),
        strength_scale=draw("motor_strength", "scale", 1.0, num_joints),
        armature_scale=draw("armature", "scale", 1.0, num_joints),
        latency_steps=int(rng.integers(int(lat_lo), int(lat_hi) + 1)),
        push_force=rand.get("push", "force", 0.0),
        push_duration=rand.get("push", "duration", 0.1),
        push_interval=rand.get("push", "interval", math.inf),
    )


def identity(nbody: int, num_joints: int) -> Sample:
    """The nominal dynamics (no randomization)."""
    return sample(Randomization(), np.random.default_rng(0), nbody, num_joints)
