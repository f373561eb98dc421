"""The lowest world point of a collision geom: exact for primitives and meshes.

Used for standing heights (:mod:`amorctl.sim.from_mjcf`), the floor lift at preprocess and the
foot-penetration report. Meshes use their (convex-hull-relevant) vertices; a bounding sphere can be
meters off for a long, flat foot.
"""

from __future__ import annotations

import mujoco
import numpy as np


def geom_lowest_z(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> float:
    """Lowest world z of geom ``g`` after ``mj_kinematics`` (``data.geom_xpos``/``geom_xmat``)."""
    z = float(data.geom_xpos[g, 2])
    size = model.geom_size[g]
    rot_z = data.geom_xmat[g].reshape(3, 3)[2]  # row 2: the world-z component of each local axis
    kind = model.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return z - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return z - abs(rot_z[2]) * size[1] - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return z - float(np.abs(rot_z) @ size)
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return z - abs(rot_z[2]) * size[1] - float(np.sqrt(max(0.0, 1.0 - rot_z[2] ** 2))) * size[0]
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return z - float(np.sqrt((rot_z**2) @ (size**2)))
    if kind == mujoco.mjtGeom.mjGEOM_MESH and model.geom_dataid[g] >= 0:
        return z + float((mesh_vertices(model, int(model.geom_dataid[g])) @ rot_z).min())
    return z - float(model.geom_rbound[g])


def mesh_vertices(model: mujoco.MjModel, mesh: int) -> np.ndarray:
    """[V, 3] vertices of mesh ``mesh`` in its geom's frame (MuJoCo stores them re-centred so)."""
    start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    return np.asarray(model.mesh_vert[start : start + count], dtype=np.float64)


def collision_geoms(model: mujoco.MjModel) -> list[int]:
    """Geoms of the character (not the world body) that take part in contacts."""
    return [
        g
        for g in range(model.ngeom)
        if model.geom_bodyid[g] != 0
        and model.geom_type[g] not in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)
        and (model.geom_contype[g] or model.geom_conaffinity[g])
    ]


def lowest_point(model: mujoco.MjModel, data: mujoco.MjData, geoms: list[int] | None = None) -> float:
    """Lowest world z over ``geoms`` (default: every collision geom) for the current kinematics."""
    ids = collision_geoms(model) if geoms is None else geoms
    return min(geom_lowest_z(model, data, g) for g in ids)
