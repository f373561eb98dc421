"""The rollout log of ``amorctl tune``: an MCAP file with Foxglove schemas, written atomically.

Body poses go on ``/tf`` as ``foxglove.FrameTransforms`` and the character's geoms once on
``/character`` as a ``foxglove.SceneUpdate``, so the file plays in Foxglove; joint states,
actions, weights and per-objective rewards are JSON channels (see docs/tune.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amorctl.core.files import atomic_path

if TYPE_CHECKING:
    from amorctl.tune.session import TuneRollout

#: Topics of the rollout log (see docs/tune.md).
TOPIC_TF = "/tf"
TOPIC_SCENE = "/character"
TOPIC_JOINTS = "/joint_states"
TOPIC_REF_JOINTS = "/reference/joint_states"
TOPIC_ACTIONS = "/actions"
TOPIC_WEIGHTS = "/weights"
TOPIC_REWARDS = "/rewards"
WORLD_FRAME = "world"
REF_PREFIX = "ref/"


def _named_schema(title: str, names: tuple[str, ...]) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": {"t": {"type": "number"}, **{n: {"type": "number"} for n in names}},
    }


def _joint_schema(title: str) -> dict[str, Any]:
    arr = {"type": "array", "items": {"type": "number"}}
    return {
        "title": title,
        "type": "object",
        "properties": {
            "name": {"type": "array", "items": {"type": "string"}},
            "position": arr,
            "velocity": arr,
        },
    }


def write_rollout_mcap(
    rollout: TuneRollout, path: str | Path, metadata: dict[str, str] | None = None
) -> None:
    """Write the rollout as an MCAP file that plays in Foxglove, atomically.

    Channels (one message per control step unless said otherwise; log time = step time in ns):
    ``/tf`` foxglove.FrameTransforms (world -> each body, and world -> ``ref/<body>`` for the
    reference), ``/character`` foxglove.SceneUpdate (once: the geoms as cubes, spheres and
    cylinders attached to the body frames, the reference's translucent), ``/joint_states`` and
    ``/reference/joint_states`` (JSON: name, position, velocity), ``/actions`` (JSON: values),
    ``/weights`` and ``/rewards`` (JSON: t and one number per objective name, so Foxglove's Plot
    panel plots ``/weights.up``). Runs without a character have only the last three.
    """
    import foxglove
    from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel

    names = rollout.objective_names
    ns = (np.round(rollout.times * 1e9)).astype(np.int64) + 1  # log times > 0
    with atomic_path(path) as tmp:
        ctx = foxglove.Context()
        with foxglove.open_mcap(tmp, allow_overwrite=True, context=ctx) as writer:
            writer.write_metadata(
                "amorctl.tune.session",
                {
                    "objectives": ",".join(names),
                    "motion": rollout.motion or "",
                    "dt": repr(rollout.dt),
                    **(metadata or {}),
                },
            )
            actions = foxglove.Channel(
                TOPIC_ACTIONS,
                schema={
                    "title": "amorctl.Actions",
                    "type": "object",
                    "properties": {"t": {"type": "number"}, "values": {"type": "array"}},
                },
                context=ctx,
            )
            w_ch = foxglove.Channel(
                TOPIC_WEIGHTS, schema=_named_schema("amorctl.Weights", names), context=ctx
            )
            r_ch = foxglove.Channel(
                TOPIC_REWARDS, schema=_named_schema("amorctl.Rewards", names), context=ctx
            )
            character = len(rollout.body_names) > 0
            if character:
                tf = FrameTransformsChannel(TOPIC_TF, context=ctx)
                scene = SceneUpdateChannel(TOPIC_SCENE, context=ctx)
                joints = foxglove.Channel(
                    TOPIC_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
                )
                ref_joints = foxglove.Channel(
                    TOPIC_REF_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
                )
                scene.log(_scene_update(rollout), log_time=int(ns[0]))
            jn = list(rollout.joint_names)
            for k, t in enumerate(rollout.times):
                lt = int(ns[k])
                actions.log({"t": float(t), "values": rollout.actions[k].tolist()}, log_time=lt)
                w_ch.log(
                    {"t": float(t), **dict(zip(names, rollout.weights[k].tolist(), strict=True))}, log_time=lt
                )
                r_ch.log(
                    {"t": float(t), **dict(zip(names, rollout.rewards[k].tolist(), strict=True))}, log_time=lt
                )
                if not character:
                    continue
                tf.log(_frame_transforms(rollout, k, lt), log_time=lt)
                joints.log(
                    {
                        "name": jn,
                        "position": rollout.joint_pos[k].tolist(),
                        "velocity": rollout.joint_vel[k].tolist(),
                    },
                    log_time=lt,
                )
                ref_joints.log(
                    {"name": jn, "position": rollout.ref_joint_pos[k].tolist(), "velocity": []}, log_time=lt
                )


def _frame_transforms(rollout: TuneRollout, k: int, log_time: int) -> Any:
    """foxglove.FrameTransforms of step ``k``: world -> each body, then world -> ``ref/<body>``."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    stamp = Timestamp(sec=int(log_time // 1_000_000_000), nsec=int(log_time % 1_000_000_000))
    transforms = []
    for prefix, pos, quat in (
        ("", rollout.body_pos[k], rollout.body_quat[k]),
        (REF_PREFIX, rollout.ref_body_pos[k], rollout.ref_body_quat[k]),
    ):
        for b, body in enumerate(rollout.body_names):
            p, q = pos[b], quat[b]
            transforms.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=WORLD_FRAME,
                    child_frame_id=prefix + body,
                    translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                    rotation=Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
                )
            )
    return FrameTransforms(transforms=transforms)


def _scene_update(rollout: TuneRollout) -> Any:
    """One foxglove.SceneUpdate drawing every geom on its body frame (character and reference)."""
    from foxglove.messages import (
        Color,
        CubePrimitive,
        CylinderPrimitive,
        Pose,
        Quaternion,
        SceneEntity,
        SceneUpdate,
        SpherePrimitive,
        Vector3,
    )

    entities = []
    for prefix, alpha_scale in (("", 1.0), (REF_PREFIX, 0.3)):
        for b, body in enumerate(rollout.body_names):
            cubes, spheres, cylinders = [], [], []
            for g in rollout.geoms:
                if g["body"] != b:
                    continue
                p, q, s, c = g["pos"], g["quat"], g["size"], g["rgba"]
                pose = Pose(
                    position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                    orientation=Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
                )
                rgba = (0.4, 0.7, 1.0, 0.3) if prefix else tuple(float(v) for v in c)
                color = Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3] * (1.0 if prefix else alpha_scale))
                if g["type"] == "box":
                    size = Vector3(x=2 * float(s[0]), y=2 * float(s[1]), z=2 * float(s[2]))
                    cubes.append(CubePrimitive(pose=pose, size=size, color=color))
                elif g["type"] in ("sphere", "ellipsoid"):
                    r = [float(s[0])] * 3 if g["type"] == "sphere" else [float(v) for v in s]
                    size = Vector3(x=2 * r[0], y=2 * r[1], z=2 * r[2])
                    spheres.append(SpherePrimitive(pose=pose, size=size, color=color))
                else:  # capsule / cylinder: radius s[0], half-length s[1] along the local z axis
                    extra = 2 * float(s[0]) if g["type"] == "capsule" else 0.0
                    size = Vector3(x=2 * float(s[0]), y=2 * float(s[0]), z=2 * float(s[1]) + extra)
                    cylinders.append(
                        CylinderPrimitive(pose=pose, size=size, bottom_scale=1.0, top_scale=1.0, color=color)
                    )
            entities.append(
                SceneEntity(
                    frame_id=prefix + body,
                    id=prefix + body,
                    frame_locked=True,
                    cubes=cubes,
                    spheres=spheres,
                    cylinders=cylinders,
                )
            )
    return SceneUpdate(entities=entities)


def read_rollout_mcap(path: str | Path) -> dict[str, list[Any]]:
    """Decoded messages by topic of a rollout log, in log order: JSON channels as dicts,
    protobuf (Foxglove schema) channels as protobuf messages. Uses only ``mcap`` readers."""
    import json

    from mcap.decoder import DecoderFactory as McapDecoderFactory
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    class _JsonDecoders(McapDecoderFactory):
        def decoder_for(self, message_encoding: str, schema: Any) -> Any:
            return json.loads if message_encoding == "json" else None

    out: dict[str, list[Any]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory(), _JsonDecoders()])
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append(decoded)
    return out
