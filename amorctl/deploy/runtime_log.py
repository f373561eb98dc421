"""The runtime's MCAP log, streamed tick by tick with the Foxglove schemas ``amorctl tune`` uses.

Same topics and schemas as :mod:`amorctl.outputs.mcap_log` (``/tf`` foxglove.FrameTransforms of
the character and of the reference ``ref/<body>``, ``/character`` foxglove.SceneUpdate once,
``/joint_states`` and ``/reference/joint_states``, ``/weights`` with one number per objective),
``/rewards`` (``amorctl.Rewards``: t and one number per objective name, in the bundle's order; when
the runtime computes rewards, :mod:`amorctl.deploy.runtime_rewards`), plus ``/targets`` (the PD
targets sent, JSON name/position), ``/tracking`` (per-tick joint error and whether the watchdog
held) and ``/watchdog`` (every event: stale input, deadline misses, rejected messages, pushes,
falls).
Needs ``foxglove-sdk`` (imported when a log is opened; no torch). Written atomically: the file
appears complete when the run ends, or not at all.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import mujoco
import numpy as np

from amorctl.core.files import atomic_path
from amorctl.deploy.runtime import Event, TickRecord
from amorctl.outputs.mcap_log import (
    REF_PREFIX,
    TOPIC_JOINTS,
    TOPIC_REF_JOINTS,
    TOPIC_REWARDS,
    TOPIC_SCENE,
    TOPIC_TF,
    TOPIC_WEIGHTS,
    WORLD_FRAME,
    _joint_schema,
    _named_schema,
    _scene_update,
)

TOPIC_TARGETS = "/targets"
TOPIC_TRACKING = "/tracking"
TOPIC_WATCHDOG = "/watchdog"


def _object_schema(title: str, **types: str) -> dict[str, Any]:
    """A JSON schema of an object with these properties and JSON types (``t="number"``...)."""
    return {"title": title, "type": "object", "properties": {k: {"type": v} for k, v in types.items()}}


_GEOM_TYPES = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
}


def _geoms(model: mujoco.MjModel) -> list[dict[str, Any]]:
    """Visible non-plane geoms as the scene helper reads them (type, body index without the
    world body, local pos/quat, size, rgba)."""
    return [
        dict(
            type=_GEOM_TYPES[int(model.geom_type[g])],
            body=int(model.geom_bodyid[g]) - 1,
            pos=model.geom_pos[g].copy(),
            quat=model.geom_quat[g].copy(),
            size=model.geom_size[g].copy(),
            rgba=model.geom_rgba[g].copy(),
        )
        for g in range(model.ngeom)
        if int(model.geom_type[g]) in _GEOM_TYPES and model.geom_bodyid[g] != 0
    ]


class McapLogger:
    """Context manager: ``with McapLogger(path, runtime) as log: runtime.logger = log; ...``."""

    def __init__(self, path: str | Path, runtime: Any, metadata: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.rt = runtime
        self.metadata = metadata or {}
        model = runtime.sim.base_model
        self.model = model
        self.data = mujoco.MjData(model)
        self.body_names = tuple(
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in range(1, model.nbody)
        )
        self.joints = list(runtime.bundle.meta["joint_names"])
        self.names = runtime.names
        self._stack = contextlib.ExitStack()
        self._scene_logged = False

    def __enter__(self) -> McapLogger:
        import foxglove
        from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel

        tmp = self._stack.enter_context(atomic_path(self.path))
        self.ctx = ctx = foxglove.Context()  # channels close when their context is collected
        self.writer = foxglove.open_mcap(tmp, allow_overwrite=True, context=ctx)
        self.writer.write_metadata(
            "amorctl.deploy.runtime",
            {
                "objectives": ",".join(self.names),
                "dt": repr(self.rt.dt),
                "bundle": str(self.rt.bundle.path),
                **self.metadata,
            },
        )
        self.tf = FrameTransformsChannel(TOPIC_TF, context=ctx)
        self.scene = SceneUpdateChannel(TOPIC_SCENE, context=ctx)
        self.joints_ch = foxglove.Channel(
            TOPIC_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
        )
        self.ref_ch = foxglove.Channel(
            TOPIC_REF_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
        )
        self.targets_ch = foxglove.Channel(
            TOPIC_TARGETS, schema=_joint_schema("amorctl.JointTargets"), context=ctx
        )
        self.w_ch = foxglove.Channel(
            TOPIC_WEIGHTS, schema=_named_schema("amorctl.Weights", self.names), context=ctx
        )
        self.rewards_ch = None
        if getattr(self.rt, "reward_meter", None) is not None:
            self.rewards_ch = foxglove.Channel(
                TOPIC_REWARDS, schema=_named_schema("amorctl.Rewards", self.names), context=ctx
            )
        tracking = _object_schema("amorctl.Tracking", t="number", joint_error_deg="number", held="boolean")
        self.track_ch = foxglove.Channel(TOPIC_TRACKING, schema=tracking, context=ctx)
        self.dog_ch = foxglove.Channel(
            TOPIC_WATCHDOG,
            schema=_object_schema("amorctl.WatchdogEvent", t="number", kind="string", detail="string"),
            context=ctx,
        )
        return self

    def __exit__(self, *exc: Any) -> None:
        try:
            self.writer.close()
        finally:
            self._stack.__exit__(*exc)

    def _poses(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.xpos[1:].copy(), self.data.xquat[1:].copy()

    def tick(self, rec: TickRecord) -> None:
        """Log one control tick."""
        from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

        lt = round(rec.t * 1e9) + 1
        if not self._scene_logged:
            scene = SimpleNamespace(body_names=self.body_names, geoms=_geoms(self.model))
            self.scene.log(_scene_update(scene), log_time=lt)
            self._scene_logged = True
        sim, mot, f = self.rt.sim, self.rt.motions, rec.frame
        ref_q = rec.qpos.copy()
        ref_q[sim.root_qpos : sim.root_qpos + 3] = mot.root_pos[f]
        ref_q[sim.root_qpos + 3 : sim.root_qpos + 7] = mot.root_quat[f]
        ref_q[sim.joint_qpos] = mot.joint_pos[f]
        stamp = Timestamp(sec=lt // 1_000_000_000, nsec=lt % 1_000_000_000)
        transforms = []
        for prefix, q in (("", rec.qpos), (REF_PREFIX, ref_q)):
            pos, quat = self._poses(q)
            for b, body in enumerate(self.body_names):
                p, r = pos[b], quat[b]
                transforms.append(
                    FrameTransform(
                        timestamp=stamp,
                        parent_frame_id=WORLD_FRAME,
                        child_frame_id=prefix + body,
                        translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                        rotation=Quaternion(x=float(r[1]), y=float(r[2]), z=float(r[3]), w=float(r[0])),
                    )
                )
        self.tf.log(FrameTransforms(transforms=transforms), log_time=lt)
        t = float(rec.t)
        self.joints_ch.log(
            {"name": self.joints, "position": rec.joint_pos.tolist(), "velocity": rec.joint_vel.tolist()},
            log_time=lt,
        )
        self.ref_ch.log(
            {"name": self.joints, "position": rec.ref_joint_pos.tolist(), "velocity": []}, log_time=lt
        )
        self.targets_ch.log(
            {"name": self.joints, "position": rec.pd_target.tolist(), "velocity": []}, log_time=lt
        )
        self.w_ch.log({"t": t, **dict(zip(self.names, rec.weights.tolist(), strict=True))}, log_time=lt)
        if self.rewards_ch is not None and rec.rewards is not None:
            self.rewards_ch.log(
                {"t": t, **dict(zip(self.names, rec.rewards.tolist(), strict=True))}, log_time=lt
            )
        err = float(np.degrees(np.abs(rec.joint_pos - rec.ref_joint_pos).mean()))
        self.track_ch.log({"t": t, "joint_error_deg": err, "held": bool(rec.held)}, log_time=lt)

    def event(self, event: Event) -> None:
        """Log one watchdog / episode event."""
        self.dog_ch.log(event.to_dict(), log_time=round(event.t * 1e9) + 1)
