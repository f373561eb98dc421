"""The motion-tracking vector environment (follows :class:`amorctl.core.vecenv.VectorEnv`).

N characters track clips of a :class:`MotionLibrary` in parallel. Every episode starts with
reference-state initialization (RSI) at a random clip and time and draws ``w ~ Dirichlet(1)``
(or uses the fixed weights it was given); the reference moves forward one frame per control step
and jumps to the start of a new random clip when its clip ends, while ``w`` stays. An episode
terminates when the character falls, drifts farther from its reference than an optional
``termination_distance``, or its simulation diverges, and is truncated at
``max_episode_steps``; envs reset themselves. Episodes: docs/environment.md; observation layout
and action: docs/observations.md; rewards: the objective set (docs/objectives.md). The env is a
:class:`amorctl.core.contracts.SnapshotEnv` (``get_state`` / ``set_state``), so tracking runs resume
bit-exactly.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from amorctl.core.config import CLIP_CONTINUATIONS
from amorctl.core.contracts import Snapshot, survival_bonus_of
from amorctl.core.env_random import BatchRandom, PerEnvRandom, Seed, env_random, restore_random
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import STATE_ARRAYS, TrackingInputs, frame_dim, frame_features, split_frame
from amorctl.core.observation import observation_layout
from amorctl.core.specs import CharacterSpec, ObjectiveSetSpec
from amorctl.core.termination import far_from_reference
from amorctl.core.vecenv import RewardSpace
from amorctl.core.weight_sampling import WeightSampler
from amorctl.core.weights import check_simplex_rows
from amorctl.envs.start_sampling import StartSampler
from amorctl.envs.survival_bonus import scale_survival_bonus
from amorctl.envs.tracking_checks import check_clips, check_library, check_weights
from amorctl.envs.tracking_view import TrackingEnvView
from amorctl.motion.clips import MotionLibrary
from amorctl.registry import get_registry
from amorctl.sim.batch_sim import BatchSim

ActionMode = Literal["absolute", "residual"]


class TrackingEnv:
    """Batched, weight-conditioned motion tracking on MuJoCo (torch-cpu backend's environment).

    Args:
        character: a :class:`CharacterSpec` or the name of an installed character.
        library: the clips to track; its character, joints and end effectors must match.
        objective_set: an :class:`ObjectiveSetSpec` or the name of an installed one.
        num_envs: N.
        max_episode_steps: time limit in control steps (truncation), default 10 s at 50 Hz.
        action_mode: ``"absolute"``: the action is the PD target q* [J] in radians;
            ``"residual"``: q* = q̂_{t+1} + action. Either way q* is clipped to the joint ranges.
        future_frames: extra reference frames in the observation, as offsets in control steps
            beyond the next target frame (e.g. ``(5, 25)``); clamped to the clip's last frame.
        fixed_weights: [m] weights used for every episode instead of Dirichlet(1) samples
            (plain-PPO baselines and evaluation); must lie on the simplex.
        fall_height_fraction: fall rule: terminated when the root height is below the
            reference's by more than this fraction of the character's standing height.
        nthread: threads of MuJoCo's rollout pool.
        clips: indices into ``library.clips`` that RSI and clip switches draw from (default:
            every clip with at least 2 frames); evaluation uses it to restrict to named motions.
        env_clips: [N] one clip index per env that env always tracks (a clip that ends restarts
            at its first frame); overrides ``clips``. Pareto sweeps give each env its motion.
        seed: seed of RSI, clip switches and weight sampling (``reset(seed)`` reseeds; [N] seeds
            give every env its own generator, :mod:`amorctl.core.env_random`).
        weight_sampler: how episodes draw ``w`` (default Dirichlet(1); docs/moppo.md, Levers).
        adaptive_starts: share of random starts drawn where the policy falls, per clip and phase
            bin of ``start_bin_seconds`` (:mod:`amorctl.envs.start_sampling`); 0 = plain RSI.
        termination_distance: also terminate when the tracking error exceeds this many metres
            (:mod:`amorctl.core.termination`); 0 = off (the paper: falls only).
        clip_continuation: what an episode tracks when its clip ends: ``"random"`` a random clip
            (of ``clips``) from its first frame; ``"same"`` its own clip again from the first
            frame, as an env of ``env_clips`` (and so evaluation) does.
        survival_bonus_scale: multiplies the objective set's survival bonus
            (:mod:`amorctl.envs.survival_bonus`); 1 = the set's own (the paper's c_alive).
    """

    def __init__(
        self,
        character: CharacterSpec | str,
        library: MotionLibrary,
        objective_set: ObjectiveSetSpec | str = "tracking7",
        *,
        num_envs: int = 256,
        max_episode_steps: int = 500,
        action_mode: ActionMode = "absolute",
        future_frames: tuple[int, ...] = (),
        fixed_weights: np.ndarray | None = None,
        fall_height_fraction: float = 1.0 / 3.0,
        nthread: int = 2,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        seed: int | None = 0,
        weight_sampler: WeightSampler | None = None,
        adaptive_starts: float = 0.0,
        start_bin_seconds: float = 1.0,
        termination_distance: float = 0.0,
        clip_continuation: str = "random",
        survival_bonus_scale: float = 1.0,
    ) -> None:
        registry = None
        if isinstance(character, str) or isinstance(objective_set, str):
            registry = get_registry()
        self.character = registry.character(character) if isinstance(character, str) else character
        spec = registry.objective_set(objective_set) if isinstance(objective_set, str) else objective_set
        ch = self.character
        check_library(ch, library)
        if action_mode not in ("absolute", "residual"):
            raise AmorError(f"action_mode must be 'absolute' or 'residual', got {action_mode!r}")
        if max_episode_steps < 1:
            raise AmorError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        if not termination_distance >= 0:
            raise AmorError(f"termination_distance must be >= 0 metres, got {termination_distance}")
        if clip_continuation not in CLIP_CONTINUATIONS:
            raise AmorError(
                f"clip_continuation must be one of {', '.join(CLIP_CONTINUATIONS)}, got {clip_continuation!r}"
            )
        if any(int(o) < 0 for o in future_frames):
            raise AmorError(f"future_frames offsets must be >= 0, got {tuple(future_frames)}")

        self.library = library
        self.objectives = scale_survival_bonus(spec.make(ch), survival_bonus_scale)
        self.m = m = len(spec.objectives)
        self.reward_space = RewardSpace(
            names=tuple(self.objectives.names),
            descriptions=tuple(self.objectives.descriptions),
            low=np.asarray(self.objectives.low, dtype=np.float64),
            high=np.asarray(self.objectives.high, dtype=np.float64),
            survival_bonus=survival_bonus_of(self.objectives),
        )
        self.fixed_weights = None if fixed_weights is None else check_weights(fixed_weights, m)
        self.weight_sampler = weight_sampler or WeightSampler(m)
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.action_mode = action_mode
        self.future_frames = tuple(int(o) for o in future_frames)
        self.fall_drop = float(fall_height_fraction) * ch.standing_height
        self.termination_distance = float(termination_distance)
        self.clip_continuation = clip_continuation
        self.sim = BatchSim(ch, n, nthread=nthread)
        self.dt = 1.0 / ch.control_hz
        jn, e = ch.num_joints, len(ch.end_effectors)
        self.num_joints, self.num_ee = jn, e
        self.joint_low = np.array([j.range[0] for j in ch.joints])
        self.joint_high = np.array([j.range[1] for j in ch.joints])

        self._init_reference(library, clips, env_clips)
        self._init_layout(library.latent_dim, m)
        self._init_state(seed)
        self.start_sampler = None
        if adaptive_starts > 0:
            bin_frames = max(1, round(start_bin_seconds * library.fps))
            self.start_sampler = StartSampler(self.clip_starts, self.clip_ends, bin_frames, adaptive_starts)

    def _init_reference(
        self, lib: MotionLibrary, clips: Sequence[int] | None, env_clips: np.ndarray | None
    ) -> None:
        """Reference arrays from the library, and the clips episodes draw from."""
        # Rewards compare the simulator's frame features with features computed from the
        # library's world-frame arrays by the same function; the context shows m_t as the library
        # stores it (they agree when the library follows its documented layout).
        self.ref_frames = frame_features(*(getattr(lib, k) for k in STATE_ARRAYS))
        self.frame_mismatch = float(np.max(np.abs(self.ref_frames - lib.frames))) if lib.num_frames else 0.0
        if self.frame_mismatch > 1e-3:
            warnings.warn(
                f"motion library frames differ from the world-frame arrays by up to "
                f"{self.frame_mismatch:.3g}; rewards use the world-frame arrays",
                stacklevel=3,
            )
        self.context_frames = np.asarray(lib.frames, dtype=np.float32)
        self.latents = np.asarray(lib.z, dtype=np.float32)
        self.clip_starts = lib.starts
        self.clip_ends = lib.starts + lib.lengths
        self.valid_clips = np.flatnonzero(lib.lengths >= 2)
        if len(self.valid_clips) == 0:
            raise AmorError("motion library has no clip with at least 2 frames")
        self.all_valid_clips = self.valid_clips
        self.env_clips: np.ndarray | None = None
        self.select_clips(clips, env_clips)

    def _init_layout(self, latent_dim: int, m: int) -> None:
        """The observation layout (docs/observations.md) and the observation and action sizes."""
        jn = self.num_joints
        d = frame_dim(jn, self.num_ee)
        self.frame_dim = d
        self.obs_layout = observation_layout(d, jn, latent_dim, self.future_frames, m)
        self.obs_dim = self.obs_layout["weights"].stop
        self.action_dim = jn

    def _init_state(self, seed: int | None) -> None:
        """The per-env state arrays (zeros until the first reset) and the generator."""
        n, m, jn, e = self.num_envs, self.m, self.num_joints, self.num_ee
        self._rand: BatchRandom | PerEnvRandom = env_random(seed, n)
        self.ref_idx = np.zeros(n, dtype=np.int64)  # frame the current state corresponds to
        self.clip_end = np.zeros(n, dtype=np.int64)  # exclusive end of that frame's clip
        self.clip_id = np.zeros(n, dtype=np.int64)
        self.episode_steps = np.zeros(n, dtype=np.int64)
        self._weights = np.zeros((n, m), dtype=np.float32)
        self.target_prev = np.zeros((n, jn))  # a_{t-1}
        self.target_prev2 = np.zeros((n, jn))  # a_{t-2}
        self.joint_vel_prev = np.zeros((n, jn))
        self.ee_pos = np.zeros((n, e, 3))
        self.ee_quat = np.zeros((n, e, 4))
        self.ee_lin_vel = np.zeros((n, e, 3))
        self.diverged_total = 0

    # --- VectorEnv API ----------------------------------------------------------------------------

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: each env's current episode weights (a copy: ``step`` redraws in place)."""
        return self._weights.copy()

    def reset(self, seed: Seed = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew (RSI, fresh weights), reseeding when ``seed`` is given (one int, or
        [N] ints: one generator per env). Returns obs [N, obs_dim] float32, info."""
        if seed is not None:
            self._rand = env_random(seed, self.num_envs)
        self.diverged_total = 0
        ids = np.arange(self.num_envs)
        self._reset_envs(ids)
        return self._observe(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control step; see :class:`amorctl.core.vecenv.VectorEnv` for the returned arrays.

        ``info`` holds ``final_obs`` [N, obs_dim], ``fell`` [N] bool (terminated by the fall
        rule), ``far`` [N] bool (terminated by ``termination_distance``, not by a fall),
        ``diverged`` [N] bool (simulation blew up: terminated, rewards zeroed, env reset),
        ``diverged_total`` (count since the last ``reset``) and ``clip_switched`` [N] bool.
        """
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, self.action_dim):
            raise AmorError(
                f"actions must have shape {(self.num_envs, self.action_dim)}, got {actions.shape}"
            )
        nxt = self.ref_idx + 1  # the frame this step should reach (the context's target)
        target = actions if self.action_mode == "absolute" else self.library.joint_pos[nxt] + actions
        target = np.clip(target, self.joint_low, self.joint_high)

        out = self.sim.step(target)
        self.ee_pos, self.ee_quat, self.ee_lin_vel = (
            out.ee_pos.copy(),
            out.ee_quat.copy(),
            out.ee_lin_vel.copy(),
        )
        sim_frames = self._sim_frames()
        ref_frames = self.ref_frames[nxt]
        joint_vel = self.sim.joint_vel()
        inputs = TrackingInputs(
            sim=split_frame(sim_frames, self.num_joints, self.num_ee),
            ref=split_frame(ref_frames, self.num_joints, self.num_ee),
            torque=out.torque,
            pd_target=target,
            pd_target_prev=self.target_prev,
            pd_target_prev2=self.target_prev2,
            joint_acc=(joint_vel - self.joint_vel_prev) / self.dt,
        )
        with np.errstate(invalid="ignore", over="ignore"):
            fell = sim_frames[:, 0] < ref_frames[:, 0] - self.fall_drop
            far = far_from_reference(inputs.sim, inputs.ref, self.termination_distance)
            diverged = out.diverged
            terminated = fell | far | diverged
            rewards = self.objectives(inputs, (~terminated).astype(np.float64))
        rewards = np.where(diverged[:, None], 0.0, rewards).astype(np.float32)
        failed = (fell | far) & ~diverged
        if self.start_sampler is not None:
            self.start_sampler.record(nxt[failed])

        self.episode_steps += 1
        truncated = (self.episode_steps >= self.max_episode_steps) & ~terminated
        self.target_prev2, self.target_prev = self.target_prev, target
        self.joint_vel_prev = joint_vel.copy()
        self.ref_idx = nxt
        switched = nxt >= self.clip_end - 1  # reached its clip's last frame: continue on a new clip
        if switched.any():
            same = self.clip_continuation == "same"
            self._start_clips(np.flatnonzero(switched), at_start=True, same_clip=same)

        obs = self._observe(sim_frames)
        final_obs = obs.copy()
        done = np.flatnonzero(terminated | truncated)
        if len(done):
            self._reset_envs(done)
            obs[done] = self._observe(ids=done)
            final_obs[np.flatnonzero(diverged)] = obs[np.flatnonzero(diverged)]
            self.diverged_total += int(diverged.sum())
        info = {
            "final_obs": final_obs,
            "fell": fell & ~diverged,
            "far": far & ~fell & ~diverged,
            "diverged": diverged,
            "diverged_total": self.diverged_total,
            "clip_switched": switched,
        }
        return obs, rewards, terminated, truncated, info

    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        """Restrict which clips episodes use from the next reset on (see ``clips`` / ``env_clips``
        in the class docstring); both None restores every clip. ``from_start``: episodes begin at
        the clip's first frame instead of a random one (evaluation, tuning). AmorError for a bad
        index."""
        lib = self.library
        self.from_start = bool(from_start)
        self.valid_clips = (
            self.all_valid_clips if clips is None else check_clips(np.asarray(clips, np.int64).ravel(), lib)
        )
        self.env_clips = None
        if env_clips is not None:
            per_env = check_clips(np.asarray(env_clips, dtype=np.int64).ravel(), lib)
            if per_env.shape != (self.num_envs,):
                raise AmorError(f"env_clips must have one clip per env ({self.num_envs}), got {per_env.size}")
            self.env_clips = per_env

    def tracking_view(self) -> TrackingEnvView:
        """The :class:`~amorctl.core.contracts.TrackingView` analysis reads this env through."""
        return TrackingEnvView(self)

    def close(self) -> None:
        """Release the simulation's thread pool."""
        self.sim.close()

    # --- snapshots (amorctl.core.contracts.SnapshotEnv) ---------------------------------------------------

    #: Per-env arrays the next step reads, saved under their names without the leading underscore.
    SNAPSHOT_ARRAYS = (
        "ref_idx", "clip_end", "clip_id", "episode_steps", "_weights", "target_prev", "target_prev2",
        "joint_vel_prev", "ee_pos", "ee_quat", "ee_lin_vel",
    )  # fmt: skip

    def get_state(self) -> Snapshot:
        """Everything the next :meth:`step` depends on, as arrays plus JSON-ready metadata.

        Arrays: :attr:`SNAPSHOT_ARRAYS` (reference frame index, clip end and id, episode step
        counter, weights, the previous two PD targets, previous joint velocities, end-effector
        pose and velocity) and the simulation's under ``sim/`` (:meth:`BatchSim.snapshot`: full
        MuJoCo physics state, solver warm start, controls, servo command delay and its head).
        Meta: the generator state (``rng``, numpy's ``bit_generator.state``), ``diverged_total``
        and the clip selection (``valid_clips``, ``env_clips``). Everything else is fixed by the
        constructor arguments, which a resumed run repeats. Checkpoints store it as safetensors +
        JSON; :meth:`set_state` restores it, after which the env steps bit-identically.
        """
        arrays = {name.lstrip("_"): getattr(self, name).copy() for name in self.SNAPSHOT_ARRAYS}
        arrays.update({f"sim/{k}": v for k, v in self.sim.snapshot().items()})
        meta = {
            "rng": self._rand.state(),
            "diverged_total": int(self.diverged_total),
            "valid_clips": [int(c) for c in self.valid_clips],
            "env_clips": None if self.env_clips is None else [int(c) for c in self.env_clips],
            "from_start": self.from_start,
        }
        if self.weight_sampler.adaptive:
            meta["weight_sampler"] = self.weight_sampler.state()
        if self.start_sampler is not None:
            meta["start_sampler"] = self.start_sampler.state()
        return Snapshot(arrays, meta)

    def set_state(self, state: Snapshot) -> None:
        """Restore :meth:`get_state` (taken from an env built with the same arguments).

        Raises:
            AmorError: an array is missing or of another shape (another character, env count or
                objective set), a row of weights is off the simplex (NaN, negative, not summing
                to 1), or the clip selection does not fit the library.
        """
        restored = {}
        for name in self.SNAPSHOT_ARRAYS:
            key, current = name.lstrip("_"), getattr(self, name)
            if key not in state.arrays:
                raise AmorError(f"env snapshot has no array {key!r}")
            value = np.asarray(state.arrays[key])
            if value.shape != current.shape:
                raise AmorError(
                    f"env snapshot array {key!r} has shape {value.shape}, expected {current.shape}"
                )
            restored[name] = np.array(value, dtype=current.dtype)
        check_simplex_rows(restored["_weights"], "env snapshot array 'weights'")
        meta = state.meta
        self.select_clips(meta.get("valid_clips"), meta.get("env_clips"), meta.get("from_start", False))
        self.sim.restore({k[len("sim/") :]: v for k, v in state.arrays.items() if k.startswith("sim/")})
        for name, value in restored.items():
            setattr(self, name, value)
        self._rand = restore_random(meta["rng"])
        self.diverged_total = int(meta["diverged_total"])
        if self.weight_sampler.adaptive:
            self.weight_sampler.load_state(meta["weight_sampler"])
        if self.start_sampler is not None:
            if "start_sampler" not in meta:
                raise AmorError("env snapshot has no adaptive-start state (saved without adaptive_starts)")
            self.start_sampler.load_state(meta["start_sampler"])

    # --- internals --------------------------------------------------------------------------------

    def _start_clips(self, ids: np.ndarray, at_start: bool, same_clip: bool = False) -> None:
        """Point envs ``ids`` at a random clip (``same_clip``: the one they track now): its first
        frame, or a random frame but the last."""
        if self.env_clips is not None:
            clips = self.env_clips[ids]
        elif same_clip:
            clips = self.clip_id[ids]
        else:
            clips = self.valid_clips[self._rand.integers(ids, len(self.valid_clips))]
        start, end = self.clip_starts[clips], self.clip_ends[clips]
        offset = 0 if at_start else self._rand.integers(ids, end - start - 1)
        frames = start + offset
        if not at_start and self.start_sampler is not None and self.env_clips is None:
            chosen, hard_clips, hard_frames = self.start_sampler.draw(self._rand, ids, self.valid_clips)
            clips, frames = np.array(clips), np.array(frames)  # writable copies
            clips[chosen], frames[chosen] = hard_clips, hard_frames
            end = self.clip_ends[clips]
        self.clip_id[ids] = clips
        self.clip_end[ids] = end
        self.ref_idx[ids] = frames

    def _reset_envs(self, ids: np.ndarray) -> None:
        """RSI and fresh weights for envs ``ids`` [k]."""
        self._start_clips(ids, at_start=self.from_start)
        f = self.ref_idx[ids]
        lib = self.library
        self.sim.set_state(
            ids,
            lib.root_pos[f],
            lib.root_quat[f],
            lib.root_lin_vel[f],
            lib.root_ang_vel[f],
            lib.joint_pos[f],
            lib.joint_vel[f],
        )
        self.ee_pos[ids] = lib.ee_pos[f]
        self.ee_quat[ids] = lib.ee_quat[f]
        self.ee_lin_vel[ids] = lib.ee_lin_vel[f]
        self.target_prev[ids] = lib.joint_pos[f]
        self.target_prev2[ids] = lib.joint_pos[f]
        self.joint_vel_prev[ids] = lib.joint_vel[f]
        self.episode_steps[ids] = 0
        if self.fixed_weights is not None:
            self._weights[ids] = self.fixed_weights
        else:
            self._weights[ids] = self.weight_sampler.draw(self._rand, ids)

    def _sim_frames(self, ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        """[k, D] heading-frame features of the simulated state."""
        s = self.sim
        return frame_features(
            s.root_pos()[ids],
            s.root_quat()[ids],
            s.root_lin_vel()[ids],
            s.root_ang_vel()[ids],
            s.joint_pos()[ids],
            s.joint_vel()[ids],
            self.ee_pos[ids],
            self.ee_quat[ids],
            self.ee_lin_vel[ids],
        )

    def _observe(self, sim_frames: np.ndarray | None = None, ids: np.ndarray | None = None) -> np.ndarray:
        """Observations [k, obs_dim] float32 of envs ``ids`` (all when None)."""
        sel = slice(None) if ids is None else ids
        if sim_frames is None:
            sim_frames = self._sim_frames(sel)
        nxt = self.ref_idx[sel] + 1
        parts = [
            sim_frames,
            self.target_prev[sel],
            self.target_prev2[sel],
            self.context_frames[nxt],
            self.latents[nxt],
        ]
        last = self.clip_end[sel] - 1
        parts += [self.context_frames[np.minimum(nxt + o, last)] for o in self.future_frames]
        parts.append(self._weights[sel])
        return np.concatenate(parts, axis=-1, dtype=np.float32)
