"""The sim2sim runtime: a deploy bundle driving a MuJoCo character, weights changeable live.

Imports only numpy, mujoco, onnxruntime, the standard library and torch-free amorctl modules
(core/, sim/actuators, sim/batch_sim, deploy/bundle, deploy/runtime_*), so it runs where torch is
not installed (tested with torch made unimportable). One control tick (docs/deploy.md):

1. weights: the constant vector, the schedule at the motion clock, or the newest valid live
   message (drained from the UDP socket now; applies from this tick);
2. watchdog: stale live input (no accepted message for ``stale_timeout`` s) or a latched
   deadline fault -> hold: PD to the last sent targets with extra damping, the motion clock and
   reference pause, the policy is not evaluated;
3. otherwise the observation is built exactly as in training (proprio frame from the simulated
   state and end-effector sensors, the last two PD targets, the next reference frame and its
   latent, ``w``) and the ONNX policy gives the PD targets; in ``realtime`` mode a result later
   than the tick's deadline is discarded (held instead) and ``max_misses`` misses in a row latch
   the hold for the rest of the episode;
4. the targets are clamped to the joint ranges, delayed by the randomized extra latency, and
   the character is stepped ``physics_hz / control_hz`` physics steps with its actuator model;
   pushes (a horizontal force on the root body) act; a fall (root below the reference's by the
   fall drop) or a diverged simulation ends the episode;
5. with ``rewards=True`` the bundle's objective set scores the step against the reference frame
   it reached (:mod:`amorctl.deploy.runtime_rewards`, numpy kernels; loads that one plugin).
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.deploy.bundle import Bundle
from amorctl.deploy.randomize import Randomization, identity, sample
from amorctl.deploy.runtime_input import UdpWeights, weights_at
from amorctl.deploy.runtime_sim import CharacterSim

if TYPE_CHECKING:  # the schedule module (tomlkit) is imported only when one is used
    from amorctl.core.schedule import Schedule


@dataclass(frozen=True)
class Event:
    """A watchdog or episode event: ``kind`` is one of ``stale_input``, ``input_restored``,
    ``deadline_miss``, ``watchdog_latched``, ``bad_action``, ``push``, ``fell``, ``diverged``,
    ``rejected_input``."""

    t: float
    kind: str
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"t": self.t, "kind": self.kind, "detail": self.detail}


@dataclass(frozen=True)
class TickRecord:
    """One control tick (J joints, m objectives, nq simulator positions).

    ``t`` time of the observation (s since the episode start), ``weights`` [m] in force,
    ``pd_target`` [J] sent this tick, ``joint_pos`` / ``joint_vel`` [J] after the step,
    ``ref_joint_pos`` [J] of the reference frame the step tracked, ``frame`` its library index,
    ``qpos`` [nq] after the step, ``held`` whether the watchdog held the pose, ``rewards`` [m]
    the objective set's rewards of the step (None unless the runtime computes rewards).
    """

    t: float
    weights: np.ndarray
    pd_target: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    ref_joint_pos: np.ndarray
    frame: int
    qpos: np.ndarray
    held: bool
    rewards: np.ndarray | None = None


class Logger(Protocol):
    """What the runtime logs to (:class:`amorctl.deploy.runtime_log.McapLogger`)."""

    def tick(self, record: TickRecord) -> None: ...

    def event(self, event: Event) -> None: ...


@dataclass
class EpisodeResult:
    """One episode of the runtime."""

    motion: str
    steps: int
    seconds: float
    fell_at: float | None
    diverged: bool
    joint_mae_deg: float
    action_rate: float
    policy_ms: list[float]
    events: list[Event]
    held_steps: int
    input: dict[str, Any] | None = None
    dynamics: dict[str, Any] = field(default_factory=dict)
    records: list[TickRecord] = field(default_factory=list)
    returns: dict[str, float] | None = None
    late_ticks: int | None = None  # realtime: ticks whose targets were decided after their deadline

    @property
    def survived(self) -> bool:
        return self.fell_at is None and not self.diverged

    def to_dict(self) -> dict[str, Any]:
        ms = np.asarray(self.policy_ms) if self.policy_ms else np.zeros(1)
        return {
            "motion": self.motion,
            "steps": self.steps,
            "seconds": self.seconds,
            "survived": self.survived,
            "fell_at": self.fell_at,
            "diverged": self.diverged,
            "joint_mae_deg": self.joint_mae_deg,
            "action_rate": self.action_rate,
            "held_steps": self.held_steps,
            "late_ticks": self.late_ticks,
            "on_time": None if self.late_ticks is None else 1.0 - self.late_ticks / max(self.steps, 1),
            "policy_ms_median": float(np.median(ms)),
            "policy_ms_p99": float(np.percentile(ms, 99)),
            "events": [e.to_dict() for e in self.events if e.kind != "push"],
            "pushes": sum(e.kind == "push" for e in self.events),
            "input": self.input,
            "dynamics": self.dynamics,
            "returns": self.returns,
        }


@dataclass
class _Episode:
    """What :meth:`Runtime.run` keeps over one episode: ``t`` the current tick's time (s), the
    watchdog's state, the motion clock (``motion_steps``) and the figures of the result."""

    record: bool
    reward_sum: np.ndarray  # [m]
    t: float = 0.0
    events: list[Event] = field(default_factory=list)
    records: list[TickRecord] = field(default_factory=list)
    policy_ms: list[float] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    rates: list[float] = field(default_factory=list)
    motion_steps: int = 0
    misses: int = 0
    held_steps: int = 0
    late_ticks: int = 0
    latched: bool = False
    stale_now: bool = False
    diverged: bool = False
    fell_at: float | None = None
    last_sent: np.ndarray | None = None


class Runtime:
    """A bundle's policy on its character in MuJoCo (module docstring).

    Args:
        bundle: a read bundle of a character run (:func:`amorctl.deploy.bundle.read_bundle`).
        randomization: per-episode dynamics ranges (None: nominal dynamics).
        realtime: pace ticks to the wall clock and enforce the policy deadline.
        max_misses: consecutive deadline misses that latch the watchdog hold.
        logger: receives every tick and event (None: no log).
        rewards: compute the objective set's rewards every tick (needs the bundle's objective-set
            plugin installed; :mod:`amorctl.deploy.runtime_rewards`).
    """

    def __init__(
        self,
        bundle: Bundle,
        *,
        randomization: Randomization | None = None,
        realtime: bool = False,
        max_misses: int = 3,
        logger: Logger | None = None,
        rewards: bool = False,
    ) -> None:
        if bundle.spec is None or bundle.motions is None:
            raise AmorError(f"{bundle.path}: the bundle has no character or motions; the runtime needs both")
        if max_misses < 1:
            raise AmorError(f"--max-misses must be >= 1, got {max_misses}")
        meta = bundle.meta
        self.bundle = bundle
        self.motions = bundle.motions
        self.sim = CharacterSim(bundle.spec, bundle.motions)
        self.names = bundle.objectives
        self.m = len(self.names)
        self.dt = 1.0 / float(meta["control_hz"])
        self.fall_drop = float(meta["termination"]["fall_height_drop"])
        self.layout = {k: (int(a), int(b)) for k, (a, b) in meta["observation_layout"].items()}
        self.obs_dim = max(b for _, b in self.layout.values())
        self.groups = {
            name: [(p, int(a), int(b)) for p, (a, b) in spec["parts"].items()]
            for name, spec in meta["inputs"].items()
        }
        self.output = meta["action"]["output"]
        self.future = [int(o) for o in meta["context"]["future_frame_offsets"]]
        self.randomization = randomization or Randomization()
        self.realtime = bool(realtime)
        self.max_misses = int(max_misses)
        self.logger = logger
        self.policy: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] = bundle.evaluate
        self.clock: Callable[[], float] = time.perf_counter
        self.reward_meter = None
        if rewards:
            from amorctl.deploy.runtime_rewards import load_reward_meter

            self.reward_meter = load_reward_meter(bundle)
        self.sleep: Callable[[float], None] = time.sleep

    # --- one observation -----------------------------------------------------------------

    def observation(self, w: np.ndarray) -> np.ndarray:
        """[D] float32 observation of the current state with weights ``w`` [m]."""
        mot, nxt = self.motions, self.ref_idx + 1
        last = self.clip_end - 1
        parts = {
            "proprio": self.sim.frame(),
            "prev_targets": np.concatenate([self.target_prev, self.target_prev2]),
            "ref_frame": mot.frames[nxt],
            "latent": mot.z[nxt],
            "future_frames": np.concatenate(
                [mot.frames[min(nxt + o, last)] for o in self.future] or [np.zeros(0)]
            ),
            "weights": w,
        }
        obs = np.zeros(self.obs_dim, dtype=np.float32)
        for name, (a, b) in self.layout.items():
            obs[a:b] = parts[name]
        return obs

    def feeds(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """The ONNX inputs {name: [1, n] float32} of one observation [D]."""
        return {
            name: np.concatenate([obs[a:b] for _, a, b in parts])[None].astype(np.float32)
            for name, parts in self.groups.items()
        }

    # --- episodes --------------------------------------------------------------------------

    def reset(self, clip: int, seed: int) -> dict[str, Any]:
        """Start an episode at ``clip``'s first frame with the dynamics drawn from ``seed``."""
        mot = self.motions
        self.clip = clip
        self.clip_start = int(mot.clip_starts[clip])
        self.clip_end = self.clip_start + int(mot.clip_lengths[clip])
        if self.clip_end - self.clip_start < 2:
            raise AmorError(f"motion {mot.names[clip]!r} has fewer than 2 frames")
        nbody, jn = self.sim.base_model.nbody, self.sim.num_joints
        rng = np.random.default_rng(seed)
        dyn = sample(self.randomization, rng, nbody, jn) if self.randomization.ranges else identity(nbody, jn)
        self.sim.reset(self.clip_start, dyn)
        self.dyn = dyn
        self.push_rng = np.random.default_rng([seed, 1])
        self.next_push = self._push_gap()
        self.ref_idx = self.clip_start
        pose = mot.joint_pos[self.clip_start].copy()
        self.target_prev, self.target_prev2 = pose.copy(), pose.copy()
        self.joint_vel_prev = mot.joint_vel[self.clip_start].copy()
        self.pending = collections.deque([pose.copy()] * dyn.latency_steps, maxlen=dyn.latency_steps + 1)
        return dyn.to_dict()

    def _push_gap(self) -> float:
        lo, hi = self.dyn.push_interval
        return (
            float(self.push_rng.uniform(lo, hi)) if np.isfinite(hi) and self.dyn.push_force[1] > 0 else np.inf
        )

    def run(
        self,
        weights: np.ndarray | Schedule | UdpWeights,
        *,
        motion: str | None = None,
        seconds: float | None = None,
        seed: int = 0,
        stop_on_fall: bool = True,
        record: bool = False,
        should_stop: Callable[[], bool] | None = None,
    ) -> EpisodeResult:
        """One episode from ``motion``'s first frame for ``seconds`` (default: the clip's length).

        Args:
            weights: constant [m], a schedule (at the motion clock), or a live endpoint.
            seed: seed of the episode's dynamics draw and pushes.
            stop_on_fall: end at a fall; otherwise restart the clip in its reference state.
            record: keep every :class:`TickRecord` in the result.
            should_stop: polled every tick (Ctrl-C handling in the CLI).
        """
        clip = self.motions.resolve(motion)
        name = self.motions.names[clip]
        fps = float(self.bundle.meta["control_hz"])
        seconds = self.motions.seconds(clip, fps) if seconds is None else float(seconds)
        if not np.isfinite(seconds) or seconds <= 0:
            raise AmorError(f"--seconds must be a positive number, got {seconds}")
        live = weights if isinstance(weights, UdpWeights) else None
        if hasattr(weights, "objective_names") and tuple(weights.objective_names) != self.names:
            raise AmorError(f"schedule {weights.source} is for objectives {list(weights.objective_names)}")
        n_steps = max(1, int(np.ceil(seconds / self.dt - 1e-9)))
        dynamics = self.reset(clip, seed)
        ep = _Episode(record=record, reward_sum=np.zeros(self.m))
        if live is not None:
            live.on_reject = lambda msg: self._emit(ep, Event(ep.t, "rejected_input", msg))
            live.budget_s = min(live.budget_s, 0.25 * self.dt)  # a flood cannot eat the tick
        start = self.clock()
        for k in range(n_steps):
            ep.t = t_now = k * self.dt
            if should_stop is not None and should_stop():
                break
            deadline = None
            if self.realtime:
                tick_start = start + k * self.dt
                wait = tick_start - self.clock()
                if wait > 0:  # idle: a live input reads what arrives meanwhile
                    (live.wait if live is not None else self.sleep)(wait)
                deadline = tick_start + self.dt
            w = self._tick_weights(ep, weights, live, name)
            hold = ep.latched or ep.stale_now
            target = None if hold else self._act(ep, w, deadline)
            if target is None:  # held by the watchdog, a late result or a bad action
                hold = True
                target = self.target_prev.copy()
                ep.held_steps += 1
            if deadline is not None and self.clock() > deadline:
                ep.late_ticks += 1
            self.pending.append(target)
            sent = self.pending[0]
            self._maybe_push(ep)
            div = self.sim.step(sent, hold=hold)
            reached, fell = self._track(ep, w, target, hold, div)
            if not hold:
                ep.motion_steps += 1
                self.ref_idx = reached
                if reached >= self.clip_end - 1:  # the clip ended: the reference starts it again
                    self.ref_idx = self.clip_start
            if div or fell:
                self._emit(ep, Event(t_now + self.dt, "diverged" if div else "fell", f"frame {reached}"))
                ep.diverged |= div
                if ep.fell_at is None and not div:
                    ep.fell_at = t_now + self.dt
                if stop_on_fall or div:
                    break
                dynamics = self.reset(clip, seed)
                self.next_push += t_now + self.dt  # reset() schedules from the episode's start
                ep.motion_steps, ep.misses = 0, 0  # a new episode: the schedule's clock restarts
        return self._result(ep, name, dynamics, live)

    def _emit(self, ep: _Episode, event: Event) -> None:
        ep.events.append(event)
        if self.logger is not None:
            self.logger.event(event)

    def _tick_weights(
        self, ep: _Episode, weights: np.ndarray | Schedule | UdpWeights, live: UdpWeights | None, name: str
    ) -> np.ndarray:
        """The weights [m] in force this tick: the newest live message (noting the input going stale
        or coming back), else the constant vector or the schedule at the motion clock."""
        if live is None:
            return weights_at(weights, ep.motion_steps * self.dt, name)
        live.poll()
        stale = live.stale()
        if stale != ep.stale_now:
            detail = f"no valid message for > {live.stale_timeout:g} s" if stale else ""
            self._emit(ep, Event(ep.t, "stale_input" if stale else "input_restored", detail))
            ep.stale_now = stale
        return live.weights

    def _act(self, ep: _Episode, w: np.ndarray, deadline: float | None) -> np.ndarray | None:
        """The policy's PD targets [J] for weights ``w`` [m], clamped to the joint ranges; None when
        the result came after ``deadline`` (``max_misses`` in a row latch the hold) or is not finite."""
        obs = self.observation(w.astype(np.float32))
        t0 = self.clock()
        out = self.policy(self.feeds(obs))[self.output][0].astype(np.float64)
        t1 = self.clock()
        ep.policy_ms.append(1e3 * (t1 - t0))
        if deadline is not None and t1 > deadline:
            ep.misses += 1
            self._emit(ep, Event(ep.t, "deadline_miss", f"policy result {1e3 * (t1 - deadline):.2f} ms late"))
            if ep.misses >= self.max_misses and not ep.latched:
                ep.latched = True
                self._emit(
                    ep, Event(ep.t, "watchdog_latched", f"{ep.misses} deadline misses in a row; holding")
                )
            return None
        if not np.isfinite(out).all():
            self._emit(ep, Event(ep.t, "bad_action", "non-finite policy output; holding"))
            return None
        ep.misses = 0
        return np.clip(out, self.sim.joint_low, self.sim.joint_high)

    def _maybe_push(self, ep: _Episode) -> None:
        """Push the root (random direction, force and duration) when the next push is due."""
        if ep.t + 1e-9 < self.next_push:
            return
        angle = self.push_rng.uniform(0.0, 2.0 * np.pi)
        force = self.push_rng.uniform(*self.dyn.push_force)
        duration = self.push_rng.uniform(*self.dyn.push_duration)
        self.sim.push(force * np.array([np.cos(angle), np.sin(angle)]), duration)
        self._emit(
            ep, Event(ep.t, "push", f"{force:.2f} N for {duration:.2f} s at {np.degrees(angle):.0f} deg")
        )
        self.next_push = ep.t + self._push_gap()

    def _track(
        self, ep: _Episode, w: np.ndarray, target: np.ndarray, hold: bool, div: bool
    ) -> tuple[int, bool]:
        """Measure the step just taken against the reference frame it reached (errors, action rate,
        rewards), remember the targets and velocities the next observation needs, record the tick.

        Returns:
            (the reference frame reached, whether the character fell).
        """
        reached = self.ref_idx if hold else self.ref_idx + 1
        jp = self.sim.joint_pos()
        ref_jp = self.motions.joint_pos[reached]
        ep.errors.append(np.abs(jp - ref_jp).mean())
        if ep.last_sent is not None:
            ep.rates.append(float(((target - ep.last_sent) ** 2).sum()))
        ep.last_sent = target
        jv = self.sim.joint_vel()
        fell = self.sim.root_height() < self.motions.root_pos[reached, 2] - self.fall_drop
        r = None
        if self.reward_meter is not None:
            r = self.reward_meter(
                self.sim.frame(),
                int(reached),
                self.sim.torque,
                target,
                self.target_prev,
                self.target_prev2,
                (jv - self.joint_vel_prev) / self.dt,
                alive=not fell,
                diverged=div,
            )
            ep.reward_sum += r
        self.joint_vel_prev = jv
        self.target_prev2, self.target_prev = self.target_prev, target
        rec = TickRecord(
            t=ep.t,
            weights=np.asarray(w, dtype=np.float64).copy(),
            pd_target=target.copy(),
            joint_pos=jp,
            joint_vel=jv,
            ref_joint_pos=ref_jp.copy(),
            frame=int(reached),
            qpos=self.sim.qpos,
            held=hold,
            rewards=r,
        )
        if ep.record:
            ep.records.append(rec)
        if self.logger is not None:
            self.logger.tick(rec)
        return reached, fell

    def _result(
        self, ep: _Episode, name: str, dynamics: dict[str, Any], live: UdpWeights | None
    ) -> EpisodeResult:
        steps = len(ep.errors)
        return EpisodeResult(
            motion=name,
            steps=steps,
            seconds=steps * self.dt,
            fell_at=ep.fell_at,
            diverged=ep.diverged,
            joint_mae_deg=float(np.degrees(np.mean(ep.errors))) if ep.errors else float("nan"),
            action_rate=float(np.mean(ep.rates)) if ep.rates else 0.0,
            policy_ms=ep.policy_ms,
            events=ep.events,
            held_steps=ep.held_steps,
            late_ticks=ep.late_ticks if self.realtime else None,
            input=None if live is None else live.report(),
            dynamics=dynamics,
            records=ep.records,
            returns=None
            if self.reward_meter is None
            else dict(zip(self.names, ep.reward_sum.tolist(), strict=True)),
        )
