"""``characters check``: is a character's spec consistent with its model, and does it stand?

Each check gives one :class:`Check` (pass / warn / fail plus a one-line detail and numbers). What
is checked: the model compiles as amorctl prepares it, every joint has its actuator and the spec
lists joints in qpos order, the actuator type fits the actuator kind, a floor, amorctl's sensors
resolved at their own addresses (and reading what MuJoCo's kinematics says), the spec's gains and
limits against the file's, the joint ranges, the standing height by forward kinematics, a 5 s PD
hold of the standing pose, suggestions for the ``smooth`` torque scale from the holding
torques and the mass (relative to a reference character of the same scale profile), and what the
model will cost to train (:mod:`amorctl.sim.cost`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import mujoco
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.sim.character_info import fmt_list, standing_targets
from amorctl.sim.geom_bottom import lowest_point
from amorctl.sim.prepare import FLOOR_NAME, has_floor, joint_actuators, sensor_addresses

Status = Literal["pass", "warn", "fail"]
#: Standing height by FK vs the spec: within this it passes, within 5x it warns, m.
HEIGHT_TOLERANCE = 0.01
HOLD_SECONDS = 5.0


@dataclass(frozen=True)
class Check:
    """One line of the report."""

    name: str
    status: Status
    detail: str
    values: dict[str, Any] = field(default_factory=dict)


@dataclass
class HoldResult:
    """A PD hold of the standing pose: root heights [T] (m), torque² sums [T] ((N·m)², Σ_j τ_j²
    averaged over each control step's physics substeps, what ``smooth_torque`` scales), diverged."""

    heights: np.ndarray
    sq_torque: np.ndarray
    diverged: bool

    @property
    def mean_sq_torque(self) -> float:
        """Mean over control steps of Σ_j τ_j², (N·m)²."""
        return float(self.sq_torque.mean())


def hold_standing_pose(character: CharacterSpec, seconds: float = HOLD_SECONDS) -> HoldResult:
    """Start standing (root at ``standing_height``, upright) and hold the pose by PD for ``seconds``."""
    from amorctl.sim.batch_sim import BatchSim

    sim = BatchSim(character, 1, nthread=1)
    try:
        stand = standing_targets(character)[None]
        sim.set_state(
            np.arange(1),
            np.array([[0.0, 0.0, character.standing_height]]),
            np.array([[1.0, 0.0, 0.0, 0.0]]),
            np.zeros((1, 3)),
            np.zeros((1, 3)),
            stand,
            np.zeros_like(stand),
        )
        steps = max(1, round(seconds * character.control_hz))
        heights, sq_torque, diverged = np.zeros(steps), np.zeros(steps), False
        for t in range(steps):
            out = sim.step(stand)
            diverged |= bool(out.diverged[0])
            heights[t] = sim.root_pos()[0, 2]
            sq_torque[t] = (out.torque[0] ** 2).sum(axis=-1).mean()
        return HoldResult(heights, sq_torque, diverged)
    finally:
        sim.close()


def _model_table(character: CharacterSpec) -> tuple[mujoco.MjModel, dict[str, Any]]:
    """The file compiled as it is, plus its actuator per joint (names) and its own sensor count."""
    path = character.mjcf_path
    spec = mujoco.MjSpec.from_file(str(path))
    acts = joint_actuators(spec, character, path)
    floor = has_floor(spec)
    model = spec.compile()
    return model, {"actuators": {j: a.name for j, a in acts.items()}, "floor": floor}


def check_character(
    character: CharacterSpec,
    *,
    hold: bool = True,
    reference: CharacterSpec | None = None,
    smooth_torque_scale: float | None = None,
    hold_runner: Callable[[CharacterSpec], HoldResult] = hold_standing_pose,
    cost: bool = True,
    rate_runner: Callable[..., float] | None = None,
) -> list[Check]:
    """Run every check; never raises for a bad character (a failed check says why).

    Args:
        hold: run the 5 s PD hold test (and the torque-based suggestion).
        reference: a character of the same scale profile whose ``smooth`` scales are known to work
            (biped20 for "robot", humanoid36 for "humanoid"); None skips the suggestion and the
            cost check compares with :data:`SLOW_STEPS_PER_S` instead.
        smooth_torque_scale: the ``smooth_torque`` scale the objective set uses for ``character``.
        cost: run the cost check (timed simulation, :func:`amorctl.sim.cost.cost_check`).
        rate_runner: measures simulated env steps/s (default :func:`amorctl.sim.cost.sim_step_rate`;
            tests pass a fake).
    """
    from amorctl.sim.batch_sim import build_model

    checks: list[Check] = []
    path = character.mjcf_path
    try:
        raw, table = _model_table(character)
        model = build_model(character)
    except (AmorError, ValueError) as exc:
        return [Check("model", "fail", str(exc))]
    checks.append(
        Check(
            "model",
            "pass",
            f"{path.name} compiles: nq={model.nq} nv={model.nv} nu={model.nu}",
            {"path": str(path)},
        )
    )

    checks.append(_actuators_check(character, raw, table["actuators"]))
    checks.append(_floor_check(character, bool(table["floor"])))
    checks.append(_sensors_check(character, raw, model))
    checks.append(_gains_check(character, raw, table["actuators"]))
    checks.append(_ranges_check(character, raw))
    checks.append(_standing_check(character, model))
    if cost:
        from amorctl.sim.cost import cost_check, sim_step_rate

        def holds_at(spec: CharacterSpec) -> bool:
            result = hold_runner(spec)
            return not result.diverged and float(result.heights.min()) > spec.min_standing_height

        status, detail, values = cost_check(
            character, model, reference, rate_runner or sim_step_rate, holds_at if hold else None
        )
        checks.append(Check("cost", status, detail, values))
    if hold:
        result = hold_runner(character)
        checks.append(_hold_check(character, result))
        if reference is not None and smooth_torque_scale is not None:
            checks.append(
                _smooth_suggestion(character, model, result, reference, smooth_torque_scale, hold_runner)
            )
    return checks


def _actuators_check(character: CharacterSpec, raw: mujoco.MjModel, acts: Mapping[str, str]) -> Check:
    """Every spec joint has its actuator; the spec's order against the model's qpos and actuator
    order; hinges without an actuator (they keep ``qpos0``)."""
    names = list(character.joint_names())
    qpos_order = sorted(names, key=lambda n: int(raw.jnt_qposadr[raw.joint(n).id]))
    act_order = sorted(names, key=lambda n: raw.actuator(acts[n]).id)
    hinges = [raw.joint(j).name for j in range(raw.njnt) if raw.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    passive = [h for h in hinges if h not in names]
    renamed = {j: a for j, a in acts.items() if a != j}
    detail = f"{len(names)} joints, each with its actuator"
    if renamed:
        detail += f" ({len(renamed)} found by transmission, e.g. {next(iter(renamed.items()))})"
    status: Status = "pass"
    if qpos_order != names:
        status, detail = "warn", detail + "; spec order differs from the model's qpos order"
    if act_order != names:  # harmless: amorctl maps actuators by joint, never by index
        detail += "; the model's actuator order differs from the joint order (mapped by name)"
    if passive:
        status, detail = "warn", detail + f"; unactuated hinges keep qpos0: {fmt_list(passive)}"
    return Check(
        "actuators", status, detail, {"qpos_order": qpos_order == names, "actuator_order": act_order == names}
    )


def _floor_check(character: CharacterSpec, model_has_floor: bool) -> Check:
    if model_has_floor:
        return Check("floor", "pass", "the model has its own floor")
    if character.add_floor:
        return Check("floor", "pass", f"none in the model: amorctl adds plane {FLOOR_NAME!r} at z = 0")
    return Check("floor", "fail", "no floor in the model and add_floor=False: it falls forever")


def _sensors_check(character: CharacterSpec, raw: mujoco.MjModel, model: mujoco.MjModel) -> Check:
    """amorctl's sensors resolve by name and read what kinematics says (end effectors at qpos0)."""
    try:
        adr = sensor_addresses(model, character)
    except AmorError as exc:
        return Check("sensors", "fail", str(exc))
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_forward(model, data)
    ids = [model.body(b).id for b in character.end_effectors]
    err = float(np.abs(data.sensordata[adr.ee[:, :3]] - data.xpos[ids]).max())
    own = int(raw.nsensor)
    ok = err < 1e-9
    return Check(
        "sensors",
        "pass" if ok else "fail",
        f"{own} model sensor(s) kept; amorctl's {adr.ee.size + adr.torque.size} values at sensordata "
        f"[{int(adr.ee.min())}..{int(max(adr.ee.max(), adr.torque.max(initial=0)))}] "
        + ("read the body positions" if ok else f"differ from body positions by {err:.3g} m"),
        {"model_sensors": own, "first_address": int(adr.ee.min()), "max_error_m": err},
    )


def _hold_check(character: CharacterSpec, result: HoldResult) -> Check:
    """The PD hold of the standing pose keeps the root above ``min_standing_height``."""
    low = float(result.heights.min())
    ok = not result.diverged and low > character.min_standing_height
    return Check(
        "hold",
        "pass" if ok else "fail",
        f"{HOLD_SECONDS:g} s PD hold of the standing pose: root height min {low:.3f} m, "
        f"end {result.heights[-1]:.3f} m (must stay > min_standing_height "
        f"{character.min_standing_height:.3f} m)" + ("; simulation diverged" if result.diverged else ""),
        {"min_height_m": low, "end_height_m": float(result.heights[-1]), "diverged": result.diverged},
    )


def _gains_check(character: CharacterSpec, raw: mujoco.MjModel, acts: Mapping[str, str]) -> Check:
    """Spec kp / kd / torque limit vs the model file's (PD characters: the spec's are applied)."""
    diffs = []
    for j in character.joints:
        a = raw.actuator(acts[j.name]).id
        gear = abs(float(raw.actuator_gear[a, 0])) or 1.0
        if raw.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_AFFINE:
            continue  # a motor: the file states no gains
        kp, kd = float(raw.actuator_gainprm[a, 0]) * gear, -float(raw.actuator_biasprm[a, 2]) * gear
        limits = []
        if raw.actuator_forcelimited[a]:
            limits.append(float(np.abs(raw.actuator_forcerange[a]).max()) * gear)
        jid = raw.joint(j.name).id
        if raw.jnt_actfrclimited[jid]:
            limits.append(float(np.abs(raw.jnt_actfrcrange[jid]).max()))
        limit = min(limits) if limits else float("inf")
        if not (np.isclose(kp, j.kp) and np.isclose(kd, j.kd) and np.isclose(limit, j.torque_limit)):
            diffs.append(f"{j.name} kp {j.kp:g}/{kp:g} kd {j.kd:g}/{kd:g} limit {j.torque_limit:g}/{limit:g}")
    if not diffs:
        return Check("gains", "pass", "spec kp, kd and torque limits equal the model file's")
    what = "applied (spec wins)" if character.actuator.kind == "pd" else "used by the servo model"
    return Check(
        "gains",
        "warn",
        f"{len(diffs)} joint(s) differ from the model file, spec/model: {fmt_list(diffs, 2)}; "
        f"spec values {what}",
        {"differing": diffs},
    )


def _ranges_check(character: CharacterSpec, raw: mujoco.MjModel) -> Check:
    diffs = []
    for j in character.joints:
        jid = raw.joint(j.name).id
        if raw.jnt_limited[jid] and not np.allclose(raw.jnt_range[jid], j.range, atol=1e-6):
            diffs.append(
                f"{j.name} {tuple(round(x, 3) for x in j.range)} vs {tuple(raw.jnt_range[jid].round(3))}"
            )
    if diffs:
        return Check(
            "ranges",
            "warn",
            f"{len(diffs)} spec range(s) differ from the model's joint limits (the model's limits act): "
            + fmt_list(diffs, 2),
        )
    return Check("ranges", "pass", "spec joint ranges agree with the model's limits")


def _standing_check(character: CharacterSpec, model: mujoco.MjModel) -> Check:
    """Root height of the standing pose with the lowest collision point at z = 0, vs the spec."""
    data = mujoco.MjData(model)
    root = model.body(character.root_body).id
    qadr = int(model.jnt_qposadr[model.body_jntadr[root]])
    data.qpos[:] = model.qpos0
    data.qpos[qadr : qadr + 7] = [0, 0, 0, 1, 0, 0, 0]
    for name, angle in character.standing_pose.items():
        data.qpos[model.jnt_qposadr[model.joint(name).id]] = angle
    mujoco.mj_kinematics(model, data)
    fk = -lowest_point(model, data)
    diff = abs(fk - character.standing_height)
    status: Status = (
        "pass" if diff <= HEIGHT_TOLERANCE else ("warn" if diff <= 5 * HEIGHT_TOLERANCE else "fail")
    )
    return Check(
        "standing_height",
        status,
        f"by forward kinematics {fk:.4f} m, spec {character.standing_height:.4f} m (difference {diff:.4f} m)",
        {"fk_m": fk, "spec_m": character.standing_height},
    )


def _smooth_suggestion(
    character: CharacterSpec,
    model: mujoco.MjModel,
    result: HoldResult,
    reference: CharacterSpec,
    scale: float,
    hold_runner: Callable[[CharacterSpec], HoldResult],
) -> Check:
    """Scale ``smooth_torque`` so that holding the pose costs what it costs the reference."""
    from amorctl.sim.batch_sim import build_model

    ref_hold = result if reference.name == character.name else hold_runner(reference)
    ratio_torque = ref_hold.mean_sq_torque / max(result.mean_sq_torque, 1e-12)
    mass = float(model.body_subtreemass[0])
    ref_mass = float(build_model(reference).body_subtreemass[0])
    ratio_mass = (ref_mass / mass) ** 2
    by_torque, by_mass = scale * ratio_torque, scale * ratio_mass
    far = not 0.1 <= ratio_torque <= 10.0
    return Check(
        "smooth_scales",
        "warn" if far else "pass",
        f"smooth_torque {scale:.3g} now; suggested {by_torque:.3g} from holding torques "
        f"(Σ τ² {result.mean_sq_torque:.3g} vs {reference.name}'s {ref_hold.mean_sq_torque:.3g} (N·m)²), "
        f"{by_mass:.3g} from mass ({mass:.1f} vs {ref_mass:.1f} kg)"
        + (": set objective_scales={'tracking7': {'smooth_torque': ...}}" if far else ""),
        {"current": scale, "by_torque": by_torque, "by_mass": by_mass, "reference": reference.name},
    )


def worst(checks: list[Check]) -> Status:
    """The worst status of a report."""
    order = {"pass": 0, "warn": 1, "fail": 2}
    return max((c.status for c in checks), key=order.__getitem__, default="pass")


def checks_json(checks: list[Check]) -> list[dict[str, Any]]:
    """JSON-ready list of the checks."""
    return [asdict(c) for c in checks]
