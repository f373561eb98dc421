"""Model files as they come: sensors by name, spec gains applied, a floor, per-joint
armature and friction, mesh-accurate lowest points, clear refusals."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.core.specs import ActuatorModel, CharacterSpec, JointSpec
from amorctl.sim.batch_sim import BatchSim
from amorctl.sim.geom_bottom import geom_lowest_z
from amorctl.sim.model import load_model
from amorctl.sim.prepare import FLOOR_NAME, ee_sensor_name, sensor_addresses

#: A two-link "robot" with its own IMU sensors declared before anything of amorctl's, position
#: actuators whose gains differ from the spec's, joint armature and friction, and no floor.
MJCF = """
<mujoco>
  <default><joint armature="0.02" frictionloss="0.3" damping="0.5"/></default>
  <worldbody>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <site name="imu"/>
      <geom type="box" size="0.1 0.1 0.1" mass="2"/>
      <body name="arm" pos="0 0 -0.2">
        <joint name="hip" axis="0 1 0" range="-1 1" actuatorfrcrange="-3 3"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>
        <body name="foot" pos="0 0 -0.35">
          <joint name="ankle" axis="1 0 0" range="-0.5 0.5"/>
          <geom type="sphere" size="0.04"/>
        </body>
      </body>
      <body name="hand" pos="0.2 0 0"><geom type="sphere" size="0.02"/></body>
    </body>
  </worldbody>
  <sensor>
    <gyro site="imu"/>
    <accelerometer site="imu"/>
    <framequat objtype="site" objname="imu"/>
  </sensor>
  <actuator>
    <position name="hip" joint="hip" kp="10" kv="1"/>
    <position name="ankle_motor" joint="ankle" kp="5" forcerange="-2 2"/>
  </actuator>
</mujoco>
"""


def spec_for(path: Path, **kw) -> CharacterSpec:
    base = CharacterSpec(
        name="twolink",
        description="test",
        mjcf_path=path,
        root_body="base",
        joints=(
            JointSpec("hip", "lower", (-1.0, 1.0), kp=40.0, kd=4.0, torque_limit=20.0, armature=0.1),
            JointSpec("ankle", "feet", (-0.5, 0.5), kp=30.0, kd=3.0, torque_limit=15.0, friction_coulomb=0.0),
        ),
        end_effectors=("hand", "hand", "foot", "foot"),
        actuator=ActuatorModel(kind="pd"),
        standing_height=1.0,
        min_standing_height=0.5,
        keypoints={"root": "base", "head": "base", "left_hand": "hand", "right_hand": "hand",
                   "left_foot": "foot", "right_foot": "foot"},
    )  # fmt: skip
    return dataclasses.replace(base, **kw)


@pytest.fixture
def model_file(tmp_path: Path) -> Path:
    path = tmp_path / "twolink.xml"
    path.write_text(MJCF)
    return path


def test_spec_gains_limits_and_joint_properties_are_applied(model_file: Path) -> None:
    m = load_model(spec_for(model_file))
    hip, ankle = m.actuator("hip").id, m.actuator("ankle_motor").id  # the ankle's found by transmission
    np.testing.assert_allclose(m.actuator_gainprm[[hip, ankle], 0], [40.0, 30.0])
    np.testing.assert_allclose(m.actuator_biasprm[[hip, ankle], 1:3], [[-40.0, -4.0], [-30.0, -3.0]])
    np.testing.assert_allclose(m.actuator_forcerange[[hip, ankle]], [[-20, 20], [-15, 15]])
    assert m.actuator_forcelimited[[hip, ankle]].all()
    assert not m.jnt_actfrclimited[m.joint("hip").id]  # the file's ±3 N·m would have capped the spec's 20
    dof = {j: m.jnt_dofadr[m.joint(j).id] for j in ("hip", "ankle")}
    assert m.dof_armature[dof["hip"]] == pytest.approx(0.1)  # stated: written
    assert m.dof_armature[dof["ankle"]] == pytest.approx(0.02)  # None: the file's
    assert m.dof_frictionloss[dof["ankle"]] == 0.0 and m.dof_frictionloss[dof["hip"]] == pytest.approx(0.3)


def test_a_floor_is_added_only_when_missing_and_asked(model_file: Path) -> None:
    m = load_model(spec_for(model_file))
    assert m.geom(FLOOR_NAME).type == mujoco.mjtGeom.mjGEOM_PLANE
    off = load_model(spec_for(model_file, add_floor=False))
    assert mujoco.mj_name2id(off, mujoco.mjtObj.mjOBJ_GEOM, FLOOR_NAME) == -1
    with_floor = model_file.with_name("floor.xml")
    with_floor.write_text(
        MJCF.replace("<worldbody>", '<worldbody><geom name="ground" type="plane" size="5 5 .1"/>')
    )
    m2 = load_model(spec_for(with_floor))
    assert mujoco.mj_name2id(m2, mujoco.mjtObj.mjOBJ_GEOM, FLOOR_NAME) == -1


def test_sensors_are_read_at_their_own_addresses(model_file: Path) -> None:
    spec = spec_for(model_file)
    sim = BatchSim(spec, 2, nthread=1)
    adr = sensor_addresses(sim.model, spec)
    assert adr.ee[0, 0] == 10  # after the file's gyro (3), accelerometer (3), framequat (4)
    assert sim.model.sensor(ee_sensor_name(2, "foot", "pos")).adr[0] == adr.ee[2, 0]
    out = None
    for _ in range(5):
        out = sim.step(np.zeros((2, 2)))
    data = mujoco.MjData(sim.model)
    data.qpos[:] = sim.qpos[0]
    data.qvel[:] = sim.qvel[0]
    mujoco.mj_kinematics(sim.model, data)
    # Sensors are computed at the start of the last substep: within one substep of motion.
    np.testing.assert_allclose(out.ee_pos[0, 2], data.xpos[sim.model.body("foot").id], atol=0.02)
    assert np.abs(out.ee_quat[0]).max() <= 1.0 + 1e-9
    np.testing.assert_allclose(np.linalg.norm(out.ee_quat[0], axis=-1), 1.0, atol=1e-9)
    sim.close()


def test_jax_mjx_reads_sensors_at_their_own_addresses(model_file: Path) -> None:
    """The jax-mjx backend looks amorctl's sensors up by name as well: with the file's IMU first,
    its end-effector readings are the bodies' poses and its PD torques the actuator forces."""
    pytest.importorskip("mujoco.mjx")
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    from amorctl.plugins.backends.jax_mjx.physics import MjxPhysics

    phys = MjxPhysics(spec_for(model_file))
    assert np.asarray(phys.ee_adr)[:, 0].tolist() == [10, 20, 30, 40]
    assert np.asarray(phys.torque_adr).tolist() == [50, 51]
    data = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (2, *jnp.shape(x))), phys.template)
    target = jnp.array([[0.3, -0.2], [0.1, 0.2]], jnp.float32)
    data, torque, sens, _ = jax.jit(phys.control_step)(
        data, jnp.zeros((1, 2, 2)), jnp.zeros((), jnp.int32), target
    )
    ee = np.asarray(sens)[:, np.asarray(phys.ee_adr)]  # [N, E, 10], as MjxTracking.step reads them
    ids = [phys.model.body(b).id for b in ("hand", "hand", "foot", "foot")]
    np.testing.assert_allclose(ee[..., :3], np.asarray(data.xpos)[:, ids], atol=1e-6)
    np.testing.assert_allclose(ee[..., 3:7], np.asarray(data.xquat)[:, ids], atol=1e-6)
    actuator_force = np.asarray(data.qfrc_actuator)[:, np.asarray(phys.joint_dof)]
    np.testing.assert_allclose(np.asarray(torque)[:, -1], actuator_force, rtol=1e-5)
    assert np.abs(actuator_force).min() > 0.1  # the joints are driven: the comparison means something
    # What reading from address 0 would have given (the IMU's gyro), not the hand's position:
    assert np.abs(np.asarray(sens)[:, :3] - ee[:, 0, :3]).max() > 1e-3


def test_missing_joint_missing_actuator_and_wrong_actuator_type_are_refused(model_file: Path) -> None:
    spec = spec_for(model_file)
    bad = dataclasses.replace(
        spec, joints=(*spec.joints[:1], dataclasses.replace(spec.joints[1], name="knee"))
    )
    with pytest.raises(
        AmorError, match=r"twolink\.xml: character 'twolink' names joint\(s\) the model lacks: knee"
    ):
        load_model(bad)
    no_act = model_file.with_name("noact.xml")
    no_act.write_text(
        MJCF.replace('<position name="ankle_motor" joint="ankle" kp="5" forcerange="-2 2"/>', "")
    )
    with pytest.raises(AmorError, match=r"noact\.xml: no actuator drives joint\(s\) ankle"):
        load_model(spec_for(no_act))
    motor = model_file.with_name("motor.xml")
    motor.write_text(
        MJCF.replace('<position name="hip" joint="hip" kp="10" kv="1"/>', '<motor name="hip" joint="hip"/>')
    )
    with pytest.raises(
        AmorError, match=r"motor\.xml: actuator 'hip' of joint 'hip' is a motor actuator.*kind='pd'"
    ):
        load_model(spec_for(motor))
    servo = load_model(spec_for(model_file, actuator=ActuatorModel(kind="servo")))  # positions become motors
    assert (servo.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE).all()
    np.testing.assert_allclose(servo.actuator_gainprm[:, 0], 1.0)


def test_mesh_lowest_point_matches_mujocos_own_distance_to_the_floor(tmp_path: Path) -> None:
    """A mesh foot (a long thin box as a mesh) tilted: the lowest vertex, not the bounding sphere."""
    verts = " ".join(f"{x} {y} {z}" for x in (-0.15, 0.15) for y in (-0.05, 0.05) for z in (-0.02, 0.02))
    xml = f"""<mujoco><asset><mesh name="sole" vertex="{verts}"/></asset><worldbody>
      <geom name="floor" type="plane" size="5 5 .1"/>
      <body name="foot" pos="0.1 0.2 0.5" euler="0.3 0.4 0.2">
        <freejoint/><geom name="m" type="mesh" mesh="sole"/>
      </body>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    g = m.geom("m").id
    lowest = geom_lowest_z(m, d, g)
    dist = mujoco.mj_geomDistance(m, d, g, m.geom("floor").id, 10.0, None)
    assert lowest == pytest.approx(dist, abs=1e-6)
    assert d.geom_xpos[g, 2] - m.geom_rbound[g] < lowest - 0.05  # the old bounding-sphere answer was off


def test_from_mjcf_asks_only_for_what_the_model_cannot_say(
    model_file: Path, tmp_path: Path, monkeypatch
) -> None:
    from amorctl.sim.from_mjcf import character_from_mjcf, plugin_cache_dir

    monkeypatch.setenv("AMORCTL_CACHE_DIR", str(tmp_path / "cache"))
    kw = {"name": "twolink", "end_effectors": ("hand", "hand", "foot", "foot"), "keypoints": {"head": "base"}}
    with pytest.raises(AmorError, match=r"twolink\.xml: character 'twolink': no group for joint\(s\) ankle"):
        character_from_mjcf(model_file, groups={"hip": "lower"}, **kw)
    spec = character_from_mjcf(model_file, groups={"hip": "lower", "*": "feet"}, **kw)
    hip, ankle = spec.joints
    assert (hip.kp, hip.kd, hip.torque_limit) == (10.0, 1.0, 3.0)  # the joint's actuatorfrcrange
    assert (ankle.kp, ankle.kd, ankle.torque_limit) == (5.0, 0.0, 2.0)  # the actuator's forcerange
    assert hip.armature == pytest.approx(0.02) and ankle.friction_viscous == pytest.approx(0.5)
    assert spec.physics_hz == 500 and spec.keypoints["left_foot"] == "foot"
    assert list(plugin_cache_dir("from_mjcf").glob("*.json"))  # cached for the next registration
    unlimited = model_file.with_name("unlimited.xml")
    unlimited.write_text(MJCF.replace(' actuatorfrcrange="-3 3"', ""))
    with pytest.raises(AmorError, match=r"no torque limit for joint\(s\) hip \(pass torque_limits=\.\.\.\)"):
        character_from_mjcf(unlimited, groups={"*": "lower"}, **kw)
    assert (
        character_from_mjcf(unlimited, groups={"*": "lower"}, torque_limits={"hip": 9.0}, **kw)
        .joints[0]
        .torque_limit
        == 9.0
    )
    with pytest.raises(AmorError, match="no body named 'palm'"):
        character_from_mjcf(
            model_file, groups={"*": "lower"}, **{**kw, "end_effectors": ("palm", "hand", "foot", "foot")}
        )
