"""Where the runtime's weights come from: constant, a schedule, or live JSON over loopback UDP.

Live messages are UTF-8 JSON datagrams, one weight vector each (docs/deploy.md)::

    {"weights": {"up": 1, "smooth": 3}}     # by name; names left out get 0
    {"weights": [0.2, 0.1, 0.1, 0.1, 0.1, 0.1, 0.3]}   # all m, in objective order

A message is rejected (counted by reason, never raised) unless it is a JSON object whose
``weights`` are finite, non-negative numbers, named by known objectives (or exactly m of them in
a list), not all zero. Accepted weights are projected onto the simplex (divided by their sum) and
apply from the next control tick. The socket binds 127.0.0.1 unless another host is given; with a
shared token (:mod:`amorctl.core.live_auth`, required beyond loopback) every datagram must be
signed (``<HMAC-SHA256 hex> <JSON with a growing "seq">``) or it is counted and ignored.

Under a flood the input stays bounded: each poll reads for at most ``budget_s`` seconds (the rest
waits in the socket buffer for the next tick; what overflows it the kernel drops and counts), and
at most ``reports_per_s`` rejections a second reach ``on_reject`` (the counters count them all).
Torch-free: standard library and numpy only.
"""

from __future__ import annotations

import collections
import contextlib
import json
import math
import os
import select
import socket
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.live_auth import BadDatagram, check_bind, open_datagram

if TYPE_CHECKING:  # the schedule module (tomlkit) is imported only when one is used
    from amorctl.core.schedule import Schedule

#: largest datagram read; longer ones are truncated and fail to parse (rejected)
MAX_MESSAGE = 65536
#: receive buffer asked for (bytes): some thousand datagrams between two reads
RECEIVE_BUFFER = 1 << 21
#: longest weight message accepted (bytes): room for hundreds of named weights, none for a flood of
#: huge ones (refused as ``too_long`` before any parsing)
MAX_WEIGHTS_BYTES = 8192


class Rejected(ValueError):
    """A live message that failed validation; ``reason`` is a short category for the counters."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def parse_message(data: bytes, names: Sequence[str]) -> np.ndarray:
    """Validate one live message; returns [m] float64 weights on the simplex.

    Raises:
        Rejected: with reason ``too_long``, ``bad_json``, ``bad_shape``, ``unknown_name``,
            ``wrong_count``, ``not_number``, ``not_finite``, ``negative`` or ``all_zero`` (with a token, also
            ``unsigned``, ``bad_mac``, ``bad_seq`` and ``replayed``: :class:`UdpWeights`).
    """
    return _parse(data, names)[0]


def _parse(data: bytes, names: Sequence[str]) -> tuple[np.ndarray, dict]:
    """:func:`parse_message`, also returning the decoded JSON object."""
    names = list(names)
    if len(data) > MAX_WEIGHTS_BYTES:  # refused unparsed: a flood of huge datagrams stays cheap
        raise Rejected("too_long", f"{len(data)} bytes; a weight message has at most {MAX_WEIGHTS_BYTES}")
    try:
        msg = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # ValueError: also huge ints
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
    try:
        floats = [float(v) for v in values]
    except OverflowError:  # an integer beyond float range
        raise Rejected("not_finite", "weights must be finite") from None
    if not all(math.isfinite(v) for v in floats):
        raise Rejected("not_finite", "weights must be finite")
    if any(v < 0 for v in floats):
        raise Rejected("negative", "weights must be >= 0")
    total = sum(floats)
    if total <= 0:
        raise Rejected("all_zero", "at least one weight must be positive")
    if not math.isfinite(total):  # finite weights whose sum overflows
        raise Rejected("not_finite", "the weights' sum is not finite")
    return np.asarray(floats, dtype=np.float64) / total, msg


@dataclass
class InputStats:
    """Counters of a live input."""

    received: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    last_error: str = ""
    signed: bool = False  # a token is set: only signed datagrams count
    deferred_polls: int = 0  # polls that ran out of their time budget with datagrams still queued
    unreported: int = 0  # rejections counted but not passed to on_reject (rate limit)
    kernel_drops: int | None = None  # datagrams the kernel dropped (socket buffer full; Linux)
    poll_ms_max: float = 0.0  # the longest poll

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
            "signed": self.signed,
            "deferred_polls": self.deferred_polls,
            "unreported": self.unreported,
            "kernel_drops": self.kernel_drops,
            "poll_ms_max": self.poll_ms_max,
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
        on_reject: called with each rejection's message (logging), at most ``reports_per_s`` a
            second of :func:`time.monotonic`.
        token: the shared token; every datagram must then be signed
            (:func:`amorctl.core.live_auth.sign_datagram`) with a ``seq`` above the last accepted.
            Required (:func:`amorctl.core.live_auth.check_bind`) when ``host`` is not loopback.
        budget_s: longest time one :meth:`poll` reads (the runtime sets a quarter of its tick).
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
        token: str | None = None,
        budget_s: float = 0.005,
        reports_per_s: int = 20,
    ) -> None:
        if not stale_timeout > 0:
            raise AmorError(f"--stale-timeout must be positive, got {stale_timeout}")
        self.token = check_bind(host, token, f"--listen udp://{host}:{port}")
        self.names = tuple(names)
        self.weights = np.asarray(initial, dtype=np.float64).copy()
        self.stats = InputStats(signed=self.token is not None)
        self.stale_timeout = float(stale_timeout)
        self.clock = clock
        self.on_reject = on_reject
        self.budget_s = float(budget_s)
        self.reports_per_s = int(reports_per_s)
        self._reports: collections.deque[float] = collections.deque()
        self.last_seq: int | None = None
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, int(port)))
        except OSError as exc:
            self.sock.close()
            raise AmorError(f"--listen udp://{host}:{port}: cannot bind ({exc.strerror or exc})") from None
        self.sock.setblocking(False)
        with contextlib.suppress(OSError):  # room for a burst between reads (the kernel may cap it)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
        self.last_accepted = clock()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) actually bound."""
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def poll(self) -> bool:
        """Read pending messages for at most :attr:`budget_s`; the newest valid one sets
        :attr:`weights`. Returns True if a message was accepted."""
        accepted = False
        start = time.perf_counter()
        n = 0
        while True:
            n += 1
            if n % 8 == 0 and time.perf_counter() - start > self.budget_s:
                self.stats.deferred_polls += 1  # the rest waits for the next tick
                break
            try:
                data = self.sock.recv(MAX_MESSAGE)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP errors surfaced on a UDP socket: not a message
                break
            self.stats.received += 1
            try:
                self.weights = self._validate(data)
            except Rejected as rej:
                self._reject(rej)
                continue
            except Exception as exc:  # a datagram must never stop the control loop: count it
                self._reject(Rejected("invalid", f"{type(exc).__name__}: {exc}"))
                continue
            self.stats.accepted += 1
            self.last_accepted = self.clock()
            accepted = True
        self.stats.poll_ms_max = max(self.stats.poll_ms_max, 1e3 * (time.perf_counter() - start))
        return accepted

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` (a real-time runtime's idle time between ticks), reading datagrams as
        they arrive, so a burst is read while it comes rather than overflowing the socket buffer."""
        end = time.perf_counter() + seconds
        while (left := end - time.perf_counter()) > 0:
            readable, _, _ = select.select([self.sock], [], [], left)
            if readable:
                budget, self.budget_s = self.budget_s, min(self.budget_s, max(end - time.perf_counter(), 0.0))
                try:
                    self.poll()
                finally:
                    self.budget_s = budget

    def _validate(self, data: bytes) -> np.ndarray:
        """One datagram's weights; with a token, its HMAC and sequence number checked first."""
        if self.token is None:
            return parse_message(data, self.names)
        try:
            payload = open_datagram(data, self.token)
        except BadDatagram as bad:
            raise Rejected(bad.reason, str(bad).split(": ", 1)[1]) from None
        w, msg = _parse(payload, self.names)
        seq = msg.get("seq")
        if not isinstance(seq, int) or isinstance(seq, bool):
            raise Rejected("bad_seq", "a signed message needs an integer 'seq'")
        if self.last_seq is not None and seq <= self.last_seq:
            raise Rejected("replayed", f"seq {seq} is not above the last accepted {self.last_seq}")
        self.last_seq = seq
        return w

    def _reject(self, rej: Rejected) -> None:
        """Count a rejection; report it to ``on_reject`` unless that has had its share this second."""
        self.stats.rejected[rej.reason] += 1
        self.stats.last_error = str(rej)
        if self.on_reject is None:
            return
        now = time.monotonic()
        while self._reports and now - self._reports[0] > 1.0:
            self._reports.popleft()
        if len(self._reports) >= self.reports_per_s:
            self.stats.unreported += 1
            return
        self._reports.append(now)
        self.on_reject(str(rej))

    def stale(self) -> bool:
        """No accepted message for longer than the stale timeout."""
        return self.clock() - self.last_accepted > self.stale_timeout

    def report(self) -> dict[str, object]:
        """The counters as a dict (:meth:`InputStats.to_dict`), the kernel's drops read now."""
        self.stats.kernel_drops = kernel_drops(self.sock)
        return self.stats.to_dict()

    def close(self) -> None:
        self.sock.close()


def kernel_drops(sock: socket.socket) -> int | None:
    """Datagrams the kernel dropped for ``sock`` (its receive buffer was full): the ``drops``
    column of ``/proc/net/udp{,6}`` (Linux); None where that is not available."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        for table in ("/proc/net/udp", "/proc/net/udp6"):
            with open(table, encoding="ascii") as f:
                for line in f.readlines()[1:]:
                    cols = line.split()
                    if len(cols) > 12 and cols[9] == inode:
                        return int(cols[12])
    except (OSError, ValueError):
        return None
    return None


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
