"""What a character costs to train: the ``cost`` line of ``characters check`` (docs/characters.md).

Physics steps per control step, the collision geoms that are meshes, and a short timed measurement
of the batched simulation training uses (:func:`sim_step_rate`, one thread), next to the reference
character's; when the model is costly, each remedy is measured too: a lower ``physics_hz`` (its
rate, and whether the standing pose still holds at it) and colliders without meshes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import mujoco
import numpy as np

from amorctl.core.specs import CharacterSpec
from amorctl.sim.character_info import fmt_list, standing_targets

#: The cost check's timed stepping: environments, wall time of each of two windows (s, the faster
#: counts: other processes on the machine slow one down), one thread.
COST_ENVS = 32
COST_SECONDS = 0.15
#: Slower than this fraction of the reference character's simulation rate counts as slow.
SLOW_FRACTION = 0.5
#: Without a reference character: fewer simulated env steps/s (one thread) than this is slow.
SLOW_STEPS_PER_S = 1500.0
#: The physics rate suggested to a slow model (the paper's, and both built-in characters').
SUGGESTED_PHYSICS_HZ = 250


def sim_step_rate(
    character: CharacterSpec,
    *,
    seconds: float = COST_SECONDS,
    num_envs: int = COST_ENVS,
    mesh_contacts: bool = True,
) -> float:
    """Env (control) steps per second of the batched simulation of ``character`` on one thread,
    every env holding the standing pose: the faster of two windows of about ``seconds`` each,
    after one warm-up step (simulation only: training adds the networks and observations).
    ``mesh_contacts=False`` turns the contacts of the character's mesh geoms off first (what
    primitive colliders could buy)."""
    from amorctl.sim.batch_sim import BatchSim

    sim = BatchSim(character, num_envs, nthread=1)
    try:
        if not mesh_contacts:
            for g in mesh_collision_geoms(sim.model):
                sim.model.geom_contype[g] = sim.model.geom_conaffinity[g] = 0
        n = num_envs
        stand = np.tile(standing_targets(character), (n, 1))
        sim.set_state(
            np.arange(n),
            np.tile([0.0, 0.0, character.standing_height], (n, 1)),
            np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            stand,
            np.zeros_like(stand),
        )
        sim.step(stand)
        best = 0.0
        for _window in range(2):
            steps, start = 0, time.perf_counter()
            while steps < 3 or time.perf_counter() - start < seconds:
                sim.step(stand)
                steps += 1
            best = max(best, n * steps / (time.perf_counter() - start))
        return best
    finally:
        sim.close()


def collision_geoms(model: mujoco.MjModel) -> list[int]:
    """Geoms of the character (not the world body) that take part in contacts."""
    return [
        g
        for g in range(model.ngeom)
        if model.geom_bodyid[g] != 0 and (model.geom_contype[g] or model.geom_conaffinity[g])
    ]


def mesh_collision_geoms(model: mujoco.MjModel) -> list[int]:
    """The :func:`collision_geoms` that are meshes (costly to collide: convex hulls)."""
    return [g for g in collision_geoms(model) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]


def _suggested_physics_hz(character: CharacterSpec) -> int | None:
    """The largest multiple of ``control_hz`` not above :data:`SUGGESTED_PHYSICS_HZ`, when it is
    below the character's ``physics_hz`` (None: nothing to gain)."""
    rate = character.control_hz * max(1, SUGGESTED_PHYSICS_HZ // character.control_hz)
    return rate if rate < character.physics_hz else None


def cost_check(
    character: CharacterSpec,
    model: mujoco.MjModel,
    reference: CharacterSpec | None,
    rate_runner: Callable[..., float],
    holds_at: Callable[[CharacterSpec], bool] | None,
) -> tuple[str, str, dict[str, Any]]:
    """What a control step costs: physics steps per control step, mesh colliders and the simulated
    env steps/s on one thread of this machine; slow (below :data:`SLOW_FRACTION` of the reference
    character's rate, or :data:`SLOW_STEPS_PER_S` without one) or more physics steps per control
    step than the reference's (above :data:`SUGGESTED_PHYSICS_HZ` without one) warns with what to
    change, each suggestion measured: a lower ``physics_hz`` (its rate, and whether the standing
    pose holds at it: ``holds_at``, None skips that) and colliders without meshes (the rate with
    mesh contacts off). Returns (status "pass" | "warn", one-line detail, values)."""
    substeps = character.substeps
    colliders, meshes = collision_geoms(model), mesh_collision_geoms(model)
    mesh_bodies = sorted({model.body(int(model.geom_bodyid[g])).name for g in meshes})
    rate = rate_runner(character)
    values: dict[str, Any] = {
        "physics_steps_per_control_step": substeps,
        "physics_hz": character.physics_hz,
        "control_hz": character.control_hz,
        "collision_geoms": len(colliders),
        "mesh_collision_geoms": len(meshes),
        "mesh_collision_bodies": mesh_bodies,
        "env_steps_per_s": rate,
        "threads": 1,
    }
    detail = (
        f"{substeps} physics steps per control step ({character.physics_hz} Hz / {character.control_hz} Hz); "
        f"{len(meshes)} of {len(colliders)} collision geoms are meshes"
        + (f" ({fmt_list(mesh_bodies, 3)})" if mesh_bodies else "")
        + f"; simulation ≈ {rate:,.0f} env steps/s on 1 thread here"
    )
    if reference is not None and reference.name != character.name:
        ref_rate = rate_runner(reference)
        values.update(reference=reference.name, reference_env_steps_per_s=ref_rate, ratio=rate / ref_rate)
        detail += f" ({reference.name}: {ref_rate:,.0f}, {rate / ref_rate:.2f}×)"
        why = [f"under {SLOW_FRACTION:g}× {reference.name}'s rate"] * (rate < SLOW_FRACTION * ref_rate)
        if substeps > reference.substeps:
            why.append(
                f"{substeps} physics steps per control step, {reference.name} takes {reference.substeps}"
            )
    else:
        why = [f"under {SLOW_STEPS_PER_S:,.0f} env steps/s"] * (rate < SLOW_STEPS_PER_S)
        if character.physics_hz > SUGGESTED_PHYSICS_HZ:
            why.append(f"physics at {character.physics_hz} Hz, above {SUGGESTED_PHYSICS_HZ} Hz")
    slow = bool(why)
    values["slow"] = slow
    if not slow:
        return "pass", detail + " (training adds the networks)", values
    suggestions = []
    lower = _suggested_physics_hz(character)
    if lower is not None:
        faster = replace(character, physics_hz=lower)
        at_lower = rate_runner(faster)
        values.update(suggested_physics_hz=lower, env_steps_per_s_at_suggested=at_lower)
        holds = ""
        if holds_at is not None:
            ok = holds_at(faster)
            values["hold_at_suggested"] = ok
            holds = (
                ", and the standing pose holds at that rate"
                if ok
                else ", but the standing pose does not hold at that rate (raise kd or keep the rate)"
            )
        suggestions.append(
            f"physics_hz={lower} ({lower // character.control_hz} steps per control step) measures "
            f"≈ {at_lower:,.0f}{holds}"
        )
    if meshes:
        without = rate_runner(character, mesh_contacts=False)
        values["env_steps_per_s_without_mesh_contacts"] = without
        suggestions.append(
            f"simpler collisions measure ≈ {without:,.0f} with the {len(meshes)} mesh colliders off while "
            "standing (more in contact-rich motion): give feet and limbs primitive colliders (box, "
            "capsule, sphere) and set contype=conaffinity=0 on the collision meshes"
        )
    values["suggestions"] = suggestions
    remedies = "; ".join(suggestions) or "a simpler model is the remaining lever"
    return "warn", f"{detail}: costly to train ({', '.join(why)}); {remedies}", values
