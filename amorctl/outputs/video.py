"""Headless MuJoCo videos: the character, its reference as a translucent ghost, and the weights.

:func:`render_video` draws each frame with ``mujoco.Renderer`` (offscreen OpenGL), adds the
reference pose as a second, translucent copy of the character's geoms (``mjv_addGeoms`` from a
second ``MjData``, recoloured), draws the current weights as a bar chart in the top-left corner,
and encodes an MP4 with imageio + imageio-ffmpeg (libx264).

MuJoCo picks its OpenGL platform once per process, when it is imported (``MUJOCO_GL``), so the
frames are rendered in a short-lived child process (``python -m amorctl.outputs.video``) that tries
``MUJOCO_GL=egl`` then ``osmesa`` (or only the one the user set). When neither works it raises one
:class:`AmorError` saying what to install. Shadows are off: software rendering is ~15x faster
without them.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError

GL_INSTALL_HINT = (
    "no headless OpenGL backend works here (tried MUJOCO_GL={tried}); install one with "
    "`apt-get install libosmesa6 libgl1-mesa-dri libegl1` (Debian/Ubuntu), or set MUJOCO_GL to a "
    "working backend"
)
_GL_FAILED = 3  # the child's exit code when no OpenGL context could be made
GHOST_RGBA = (0.35, 0.65, 1.0)  # the reference ghost's colour; alpha is ``ghost_alpha``
BAR_COLOURS = np.array(
    [
        [31, 119, 180],
        [255, 127, 14],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [140, 86, 75],
        [227, 119, 194],
        [127, 127, 127],
        [188, 189, 34],
        [23, 190, 207],
    ],
    dtype=np.uint8,
)


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`render_video` wrote: the file, frame count, size, frame rate, GL backend used."""

    path: Path
    frames: int
    width: int
    height: int
    fps: float
    gl_backend: str


def gl_candidates() -> list[str]:
    """The MUJOCO_GL values to try: the user's, else ``egl`` then ``osmesa``."""
    user = os.environ.get("MUJOCO_GL", "").strip().lower()
    return [user] if user else ["egl", "osmesa"]


def render_video(
    path: str | os.PathLike[str],
    character: str,
    qpos: np.ndarray,
    *,
    ref_qpos: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    objective_names: Sequence[str] = (),
    fps: float = 50.0,
    width: int = 480,
    height: int = 360,
    ghost_alpha: float = 0.35,
    ghost_offset: Sequence[float] = (0.0, 0.0, 0.0),
    timeout_s: float = 600.0,
) -> VideoInfo:
    """Render an MP4 of a character following ``qpos``, with an optional ghost and weight bars.

    Args:
        path: the output ``.mp4`` (written atomically: a temporary file renamed at the end).
        character: the character plugin's name (its MJCF is compiled as training does).
        qpos: [T, nq] simulator poses, one per frame.
        ref_qpos: [T, nq] reference poses drawn as a translucent ghost (None: no ghost).
        weights: [T, m] weights drawn as a bar chart per frame (None: no chart).
        objective_names: the m labels of the bars.
        fps: frames per second of the video (the control rate plays in real time).
        width, height: frame size in pixels (even numbers suit H.264).
        ghost_alpha: opacity of the ghost, in (0, 1].
        ghost_offset: [3] metres added to the ghost's root position (e.g. beside the character).
        timeout_s: limit for the rendering child process.

    Returns:
        :class:`VideoInfo`.

    Raises:
        AmorError: bad shapes, no OpenGL backend (with what to install), or a failed encoding.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[0] < 1:
        raise AmorError(f"qpos must be [T, nq] with T >= 1, got shape {q.shape}")
    arrays: dict[str, np.ndarray] = {"qpos": q}
    if ref_qpos is not None:
        rq = np.asarray(ref_qpos, dtype=np.float64)
        if rq.shape != q.shape:
            raise AmorError(f"ref_qpos has shape {rq.shape}, qpos {q.shape}")
        arrays["ref_qpos"] = rq
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != q.shape[0] or w.shape[1] != len(objective_names):
            raise AmorError(
                f"weights must be [T={q.shape[0]}, m={len(objective_names)}], got shape {w.shape}"
            )
        arrays["weights"] = w
    if not 0 < ghost_alpha <= 1:
        raise AmorError(f"ghost_alpha must be in (0, 1], got {ghost_alpha}")
    width, height = int(width) // 2 * 2, int(height) // 2 * 2
    if width < 16 or height < 16:
        raise AmorError(f"video size {width}x{height} is too small")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    options = {
        "character": character,
        "names": list(objective_names),
        "fps": float(fps),
        "width": width,
        "height": height,
        "ghost_alpha": float(ghost_alpha),
        "ghost_offset": [float(v) for v in ghost_offset],
    }
    with tempfile.TemporaryDirectory(prefix="amorctl-render-") as tmp:
        job = Path(tmp) / "job.npz"
        np.savez(job, options=np.array(json.dumps(options)), **arrays)
        partial = Path(tmp) / "video.mp4"
        backend = _render_in_child(job, partial, out, timeout_s)
        import shutil

        from amorctl.core.files import atomic_path

        with atomic_path(out) as final:
            shutil.copyfile(partial, final)
    return VideoInfo(out, q.shape[0], width, height, float(fps), backend)


def _render_in_child(job: Path, partial: Path, out: Path, timeout_s: float) -> str:
    """Render ``job`` into ``partial`` in a child process, trying each GL backend; returns the one
    that worked. AmorError when none works (with what to install) or the rendering fails."""
    tried: list[str] = []
    errors: list[str] = []
    for backend in gl_candidates():
        tried.append(backend)
        env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "amorctl.outputs.video", str(job), str(partial)],
                env=env,
                capture_output=True,
                text=True,
                timeout=timeout_s,
                check=False,
            )
        except subprocess.TimeoutExpired:
            raise AmorError(f"rendering {out} took longer than {timeout_s:.0f} s") from None
        if proc.returncode == 0:
            return backend
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        if proc.returncode != _GL_FAILED:
            raise AmorError(f"rendering {out} failed (MUJOCO_GL={backend}): {last}")
        errors.append(f"{backend}: {last}")
    raise AmorError(GL_INSTALL_HINT.format(tried="/".join(tried)) + f" ({'; '.join(errors)})")


# ---------------------------------------------------------------------------- the child process
def draw_weight_bars(frame: np.ndarray, weights: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """Draw ``weights`` [m] as labelled horizontal bars onto ``frame`` [H, W, 3] uint8 (in place).

    A translucent dark panel in the top-left corner; bar length is proportional to the weight
    (a full bar is weight 1), the value is printed beside it. Returns ``frame``.
    """
    from PIL import Image, ImageDraw

    m = len(names)
    h, w = frame.shape[:2]
    row = max(10, min(18, (h // 3) // max(m, 1)))
    label_w, bar_w, pad = 6 * max((len(n) for n in names), default=1) + 6, max(40, w // 5), 4
    panel_w, panel_h = label_w + bar_w + 44, row * m + 2 * pad
    panel_w, panel_h = min(panel_w, w), min(panel_h, h)
    region = frame[:panel_h, :panel_w].astype(np.float32)
    frame[:panel_h, :panel_w] = (0.45 * region).astype(np.uint8)  # darken: a translucent panel
    for k in range(m):
        y0 = pad + k * row + 2
        y1 = min(y0 + row - 4, panel_h)
        length = round(float(np.clip(weights[k], 0.0, 1.0)) * bar_w)
        x0 = min(label_w, panel_w)
        frame[y0:y1, x0 : min(x0 + length, panel_w)] = BAR_COLOURS[k % len(BAR_COLOURS)]
    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    for k, name in enumerate(names):
        y = pad + k * row + max(0, (row - 11) // 2)
        draw.text((3, y), name, fill=(255, 255, 255))
        draw.text((label_w + bar_w + 4, y), f"{float(weights[k]):.2f}", fill=(255, 255, 255))
    frame[:] = np.asarray(image)
    return frame


def _render_job(job: Path, out: Path) -> None:
    """The child process: render the frames of ``job`` and encode them to ``out``."""
    import mujoco

    from amorctl.registry import get_registry
    from amorctl.sim.batch_sim import build_model

    data_in = np.load(job)
    options = json.loads(str(data_in["options"]))
    qpos = data_in["qpos"]
    ref = data_in["ref_qpos"] if "ref_qpos" in data_in.files else None
    weights = data_in["weights"] if "weights" in data_in.files else None
    spec = get_registry().character(options["character"])
    model = build_model(spec)
    width, height = options["width"], options["height"]
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as exc:  # no GL context: the parent tries the next backend
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        raise SystemExit(_GL_FAILED) from None

    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, spec.root_body)
    r = int(model.jnt_qposadr[model.body_jntadr[root]])
    data, ghost = mujoco.MjData(model), mujoco.MjData(model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance = 4.0 * spec.standing_height + 1.0
    cam.azimuth, cam.elevation = 90.0, -12.0
    opt, pert = mujoco.MjvOption(), mujoco.MjvPerturb()
    offset = np.asarray(options["ghost_offset"], dtype=np.float64)
    rgba = np.array([*GHOST_RGBA, options["ghost_alpha"]], dtype=np.float32)
    lookat = qpos[0, r : r + 3].copy()
    frames = []
    try:
        for t in range(qpos.shape[0]):
            data.qpos[:] = qpos[t]
            mujoco.mj_forward(model, data)
            lookat = 0.9 * lookat + 0.1 * qpos[t, r : r + 3]  # a camera that follows smoothly
            cam.lookat[:] = [lookat[0], lookat[1], 0.6 * spec.standing_height]
            renderer.update_scene(data, cam, scene_option=opt)
            scene = renderer.scene
            scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            if ref is not None:
                ghost.qpos[:] = ref[t]
                ghost.qpos[r : r + 3] += offset
                mujoco.mj_forward(model, ghost)
                first = scene.ngeom
                mujoco.mjv_addGeoms(model, ghost, opt, pert, int(mujoco.mjtCatBit.mjCAT_DYNAMIC), scene)
                for geom in scene.geoms[first : scene.ngeom]:
                    geom.rgba[:] = rgba
            frame = renderer.render().copy()
            if weights is not None:
                draw_weight_bars(frame, weights[t], options["names"])
            frames.append(frame)
    finally:
        with contextlib.suppress(Exception):  # osmesa's context can fail to free at exit: harmless
            renderer.close()
    import imageio.v2 as imageio

    imageio.mimwrite(out, frames, fps=options["fps"], codec="libx264", macro_block_size=1)


if __name__ == "__main__":
    _render_job(Path(sys.argv[1]), Path(sys.argv[2]))
