"""A deploy bundle carries its character's model: the MJCF, its includes, the meshes and
textures it references (meshdir / texturedir / assetdir resolved as MuJoCo does) and the licence
found beside it; the copy compiles to the model that was trained."""

from __future__ import annotations

import dataclasses
import struct
import zlib
from pathlib import Path

import mujoco
import pytest

from amorctl.core.errors import AmorError
from amorctl.deploy.bundle import compiled_model_hash
from amorctl.deploy.export_meta import copy_model
from amorctl.sim.model_files import model_files

TETRA = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def _png(path: Path) -> None:
    """A 2 x 2 RGB PNG (written by hand: no imaging library needed)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\0" + bytes([200, 120, 40] * 2) for _ in range(2))
    ihdr = struct.pack(">IIBBBBB", 2, 2, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


def robot_package(root: Path, meshdir: str = "meshes") -> Path:
    """``root/robot_pkg``: LICENSE at the top, the model in ``models/bot/`` with an include chain
    (``parts/body.xml`` includes ``parts/materials.xml``, found relative to the main file), two
    meshes of which one is used, a texture under ``assetdir``; returns the main MJCF."""
    pkg = root / "robot_pkg"
    bot = pkg / "models" / "bot"
    (bot / "parts").mkdir(parents=True)
    (bot / "assets" / meshdir).mkdir(parents=True)
    (pkg / "LICENSE").write_text("Apache-2.0 (test robot)\n")
    (pkg / "README.md").write_text("not part of the model\n")
    (bot / "assets" / meshdir / "foot.obj").write_text(TETRA)
    (bot / "assets" / meshdir / "unused.obj").write_text(TETRA)
    _png(bot / "assets" / "skin.png")
    (bot / "bot.xml").write_text(
        f"""<mujoco model="bot">
  <compiler assetdir="assets" meshdir="assets/{meshdir}"/>
  <include file="parts/body.xml"/>
  <worldbody>
    <body name="torso" pos="0 0 0.5">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" material="skin"/>
      <body name="foot" pos="0 0 -0.2">
        <joint name="knee" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom type="mesh" mesh="foot"/>
      </body>
    </body>
  </worldbody>
  <actuator><position name="knee" joint="knee" kp="10" forcerange="-5 5"/></actuator>
</mujoco>
"""
    )
    (bot / "parts" / "body.xml").write_text('<mujoco><include file="parts/materials.xml"/></mujoco>\n')
    (bot / "parts" / "materials.xml").write_text(
        """<mujoco><asset>
  <mesh name="foot" file="foot.obj"/>
  <texture name="skin" type="2d" file="skin.png"/>
  <material name="skin" texture="skin"/>
</asset></mujoco>
"""
    )
    return bot / "bot.xml"


def test_model_files_are_what_mujoco_reads_plus_the_licence(tmp_path: Path) -> None:
    main = robot_package(tmp_path)
    found = model_files(main)
    pkg = (tmp_path / "robot_pkg").resolve()
    assert found.root == pkg and found.mjcf == main.resolve()
    assert [found.relative(p).as_posix() for p in found.files] == [
        "models/bot/bot.xml",
        "models/bot/parts/body.xml",
        "models/bot/parts/materials.xml",
        "models/bot/assets/meshes/foot.obj",
        "models/bot/assets/skin.png",
    ]  # not unused.obj, not the README
    assert [found.relative(p).as_posix() for p in found.licences] == ["LICENSE"]


def test_the_copy_compiles_to_the_same_model_away_from_the_original(tmp_path: Path) -> None:
    from amorctl.sim.from_mjcf import character_from_mjcf

    main = robot_package(tmp_path / "src")
    spec = character_from_mjcf(
        main,
        name="bot",
        groups={"*": "lower"},
        end_effectors=("torso", "torso", "foot", "foot"),
        keypoints={"head": "torso"},
        licence="Apache-2.0",
        cache=False,
    )
    want = compiled_model_hash(spec)
    bundle = tmp_path / "bundle"
    entry = copy_model(spec, bundle, want)
    assert entry["mjcf"] == "model/models/bot/bot.xml"
    assert entry["licence_files"] == ["model/LICENSE"] and entry["licence"] == "Apache-2.0"
    assert (
        len(entry["model_files"]) == 6
        and "model/models/bot/assets/meshes/unused.obj" not in entry["model_files"]
    )
    (tmp_path / "src").rename(tmp_path / "gone")  # the original is no longer where it was
    copied = dataclasses.replace(spec, mjcf_path=bundle / entry["mjcf"])
    assert compiled_model_hash(copied) == want
    assert mujoco.MjModel.from_xml_path(str(bundle / entry["mjcf"])).ntex == 1


def test_absolute_and_missing_references_are_refused_saying_what_to_change(tmp_path: Path) -> None:
    main = robot_package(tmp_path)
    text = main.read_text()
    main.write_text(text.replace('meshdir="assets/meshes"', f'meshdir="{main.parent / "assets" / "meshes"}"'))
    with pytest.raises(
        AmorError,
        match=r"bot\.xml: <compiler> meshdir '/.*meshes' is an absolute path, so a copy of the model would "
        r"still read it from this machine: make it relative to the model file",
    ):
        model_files(main)
    main.write_text(text)
    (main.parent / "assets" / "meshes" / "foot.obj").unlink()
    with pytest.raises(AmorError, match=r"bot\.xml: MuJoCo could not parse it|foot\.obj"):
        model_files(main)
