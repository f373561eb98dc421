"""Where the runtime's weights come from: constant, a schedule, or live JSON over loopback UDP.

Live messages are UTF-8 JSON datagrams, one weight vector each (docs/deploy.md)::

    {"weights": {"up": 1, "smooth": 3}}     # by name; names left out get 0
    {"weights": [0.2, 0.1, 0.1, 0.1, 0.1, 0.1, 0.3]}   # all m, in objective order

A message is rejected (counted by reason, never raised) unless it is a JSON object whose
``weights`` are finite, non-negative numbers, named by known objectives (or exactly m of them in
a list), not all zero. Accepted weights are projected onto the simplex (divided by their sum) and
apply from the next control tick. The socket binds 127.0.0.1 unless another host is given.
Torch-free: standard library and numpy only.
"""

from __future__ import annotations

import json
import math
import socket
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amorctl.core.errors import AmorError

if TYPE_CHECKING:  # the schedule module (tomlkit) is imported only when one is used
    from amorctl.core.schedule import Schedule

#: largest datagram read; longer ones are truncated and fail to parse (rejected)
MAX_MESSAGE = 65536


class Rejected(ValueError):
    """A live message that failed validation; ``reason`` is a short category for the counters."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def parse_message(data: bytes, names: Sequence[str]) -> np.ndarray:
    """Validate one live message; returns [m] float64 weights on the simplex.

    Raises:
        Rejected: with reason ``bad_json``, ``bad_shape``, ``unknown_name``, ``wrong_count``,
            ``not_number``, ``not_finite``, ``negative`` or ``all_zero``.
    """
    names = list(names)
    try:
        msg = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Rejected("bad_json", str(exc)) from None
    if not isinstance(msg, dict) or "weights" not in msg:
        raise Rejected("bad_shape", 'expected an object {"weights": ...}')
    raw = msg["weights"]
    if isinstance(raw, dict):
        unknown = [k for k in raw if k not in names]
        if unknown:
            raise Rejected(
                "unknown_name", f"unknown objective {unknown[0]!r} (objectives: {', '.join(names)})"
            )
        values = [raw.get(n, 0.0) for n in names]
    elif isinstance(raw, list):
        if len(raw) != len(names):
            raise Rejected("wrong_count", f"{len(raw)} weights, expected {len(names)}")
        values = raw
    else:
        raise Rejected("bad_shape", "weights must be an object by name or a list")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise Rejected("not_number", "every weight must be a number")
    w = np.asarray(values, dtype=np.float64)
    if not all(math.isfinite(v) for v in w):
        raise Rejected("not_finite", "weights must be finite")
    if (w < 0).any():
        raise Rejected("negative", "weights must be >= 0")
    total = float(w.sum())
    if total <= 0:
        raise Rejected("all_zero", "at least one weight must be positive")
    return w / total


@dataclass
class InputStats:
    """Counters of a live input."""

    received: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    last_error: str = ""

    @property
    def rejected_total(self) -> int:
        return int(sum(self.rejected.values()))

    def to_dict(self) -> dict[str, object]:
        return {
            "received": self.received,
            "accepted": self.accepted,
            "rejected": self.rejected_total,
            "rejected_by_reason": dict(self.rejected),
            "last_error": self.last_error,
        }


class UdpWeights:
    """A non-blocking UDP endpoint the runtime drains once per control tick.

    Args:
        names: the m objective names.
        initial: [m] weights in force until the first accepted message.
        host, port: where to bind (port 0: any free port; see :attr:`address`).
        stale_timeout: seconds without an accepted message after which :meth:`stale` is true
            (counted from the start until the first message).
        clock: monotonic seconds (tests inject their own).
        on_reject: called with each rejection's message (logging).
    """

    def __init__(
        self,
        names: Sequence[str],
        initial: np.ndarray,
        host: str = "127.0.0.1",
        port: int = 0,
        stale_timeout: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        on_reject: Callable[[str], None] | None = None,
    ) -> None:
        if not stale_timeout > 0:
            raise AmorError(f"--stale-timeout must be positive, got {stale_timeout}")
        self.names = tuple(names)
        self.weights = np.asarray(initial, dtype=np.float64).copy()
        self.stats = InputStats()
        self.stale_timeout = float(stale_timeout)
        self.clock = clock
        self.on_reject = on_reject
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, int(port)))
        except OSError as exc:
            self.sock.close()
            raise AmorError(f"--listen udp://{host}:{port}: cannot bind ({exc.strerror or exc})") from None
        self.sock.setblocking(False)
        self.last_accepted = clock()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) actually bound."""
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def poll(self) -> bool:
        """Drain every pending message; the newest valid one sets :attr:`weights`.
        Returns True if a message was accepted."""
        accepted = False
        while True:
            try:
                data = self.sock.recv(MAX_MESSAGE)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP errors surfaced on a UDP socket: not a message
                break
            self.stats.received += 1
            try:
                self.weights = parse_message(data, self.names)
            except Rejected as rej:
                self.stats.rejected[rej.reason] += 1
                self.stats.last_error = str(rej)
                if self.on_reject is not None:
                    self.on_reject(str(rej))
                continue
            self.stats.accepted += 1
            self.last_accepted = self.clock()
            accepted = True
        return accepted

    def stale(self) -> bool:
        """No accepted message for longer than the stale timeout."""
        return self.clock() - self.last_accepted > self.stale_timeout

    def close(self) -> None:
        self.sock.close()


def parse_listen(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port). AmorError for anything else."""
    prefix = "udp://"
    if not url.startswith(prefix) or ":" not in url[len(prefix) :]:
        raise AmorError(f"--listen {url!r}: expected udp://HOST:PORT, e.g. udp://127.0.0.1:9870")
    host, _, port = url[len(prefix) :].rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise AmorError(f"--listen {url!r}: port {port!r} is not a number") from None
    if not 0 <= number < 65536:
        raise AmorError(f"--listen {url!r}: port must be in 0..65535")
    return host.strip("[]"), number


def weights_at(source: np.ndarray | Schedule, t: float, motion: str | None) -> np.ndarray:
    """Constant weights [m], or a schedule's at motion time ``t`` seconds; [m] float64."""
    if hasattr(source, "weights_at"):  # a Schedule
        return source.weights_at(t, motion)
    return np.asarray(source, dtype=np.float64)
