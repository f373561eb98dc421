"""The deploy runtime under a flood of live-weight datagrams: are its ticks still on time?

Runs ``Runtime.run`` in real time (``--realtime``: 50 ticks/s, a deadline per tick) on a bundle
with the live UDP input on 127.0.0.1, while a second process sends ``--rate`` datagrams a second
for ``--flood-seconds`` to it: a fixed cycle of valid weight messages and malformed ones (bad JSON,
NaN, negative, unknown objective, wrong count, all zero, not an object, a 40 kB list), and with
``--token`` also unsigned, wrongly signed, tampered and replayed datagrams. Prints what was sent,
what the runtime received, accepted and rejected (by reason), what the kernel dropped, the share
of ticks on time and the longest poll of the input. All traffic stays on 127.0.0.1; the flood is
bounded in count and time.

    python benchmarks/deploy_flood.py [--bundle DIR] [--rate 20000] [--seconds 6] [--flood-seconds 4]
        [--token]

Without ``--bundle`` a bundle of a fresh one-iteration biped20 run is exported (quick preset's
network, as in ``deploy_latency.py``). ``python benchmarks/deploy_flood.py send --port P ...`` is
the sender alone (tests/test_deploy.py uses it).
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TRACKING7 = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")
#: the valid weight messages of the cycle (by name); any applied weights must be one of these
VALID = ({"up": 1, "smooth": 3}, {"lo": 2, "vel": 1}, {"feet": 1, "rbs": 1, "root": 1})
#: malformed payloads of the cycle and the reason the runtime must count each under
MALFORMED = (
    (b"{not json", "bad_json"),
    (b'{"weights": [NaN, 1, 1, 1, 1, 1, 1]}', "not_finite"),
    (b'{"weights": {"up": -1}}', "negative"),
    (b'{"weights": {"jump": 1}}', "unknown_name"),
    (b'{"weights": [1, 2]}', "wrong_count"),
    (b'{"weights": {"up": 0}}', "all_zero"),
    (b"[1, 2]", "bad_shape"),
)
HUGE = (b'{"weights": [' + b"1, " * 13000 + b"1]}", "too_long")  # 40 kB: refused unparsed
TOKEN = "flood-benchmark-token-0123456789"


def expected_weights() -> np.ndarray:
    """[len(VALID), 7] the normalized weights of the valid messages."""
    rows = np.array([[v.get(n, 0) for n in TRACKING7] for v in VALID], dtype=np.float64)
    return rows / rows.sum(axis=1, keepdims=True)


def datagrams(token: str | None) -> list[tuple[bytes | None, str]]:
    """One cycle: (datagram, expected reason or "valid"); None stands for "replay the last valid"."""
    cycle: list[tuple[bytes | None, str]] = []
    for k, (payload, reason) in enumerate(MALFORMED):
        cycle.append((json.dumps({"weights": VALID[k % len(VALID)]}).encode(), "valid"))
        cycle.append((payload, reason))
    if token is not None:  # signed payloads get their seq when sent; add the attacks on signing
        cycle += [
            (b"UNSIGNED", "unsigned"),
            (b"BADMAC", "bad_mac"),
            (b"TAMPER", "bad_mac"),
            (None, "replayed"),
        ]
    return cycle


def send(port: int, rate: float, seconds: float, token: str | None, huge_every: int = 100) -> dict:
    """Send the cycle to 127.0.0.1:``port`` at ``rate`` datagrams/s for ``seconds``; the counts."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    cycle = datagrams(token)
    counts: dict[str, int] = {}
    seq = time.time_ns()
    last_valid = b""
    n = 0
    start = time.perf_counter()
    while (now := time.perf_counter() - start) < seconds:
        due = int(now * rate)
        while n < due:
            data, kind = cycle[n % len(cycle)]
            if n % huge_every == huge_every - 1:
                data, kind = HUGE
            if token is not None:
                data, kind = _signed_variant(data, kind, token, seq + n, last_valid)
            if kind == "valid":
                last_valid = data
            try:
                sock.sendto(data, ("127.0.0.1", port))
            except OSError:  # the receiver's buffer is full (ENOBUFS): counted as not sent
                kind = "not_sent"
            counts[kind] = counts.get(kind, 0) + 1
            n += 1
        time.sleep(0.0005)
    elapsed = time.perf_counter() - start
    sock.close()
    sent = sum(v for k, v in counts.items() if k != "not_sent")
    return {"sent": sent, "seconds": elapsed, "rate": sent / elapsed, "by_kind": counts}


def _signed_variant(
    data: bytes | None, kind: str, token: str, seq: int, last_valid: bytes
) -> tuple[bytes, str]:
    """The datagram as a signing sender would send it, or the attack on signing it stands for."""
    from amorctl.core.live_auth import mac, sign_datagram

    if data is None:  # replay the last valid datagram (its seq is not above the last accepted)
        return last_valid or sign_datagram({"weights": VALID[0]}, token, 0), "replayed"
    if kind == "unsigned":
        return json.dumps({"weights": VALID[0], "seq": seq}).encode(), "unsigned"
    if kind == "bad_mac" and data == b"BADMAC":
        return sign_datagram({"weights": VALID[0]}, "another-token-of-some-length", seq), "bad_mac"
    if kind == "bad_mac":  # tampered: a valid signature over other bytes
        good = sign_datagram({"weights": VALID[1]}, token, seq)
        return good.replace(b'"lo":2', b'"lo":9'), "bad_mac"
    if kind == "valid":
        return sign_datagram(json.loads(data), token, seq), "valid"
    return mac(token, data) + b" " + data, kind  # malformed but correctly signed: its own reason


def run_flood(bundle_dir: Path, rate: float, seconds: float, flood_seconds: float, token: str | None) -> dict:
    """The runtime in real time for ``seconds`` with a sender process flooding its input."""
    from amorctl.deploy.bundle import read_bundle
    from amorctl.deploy.runtime import Runtime
    from amorctl.deploy.runtime_input import UdpWeights

    rt = Runtime(read_bundle(bundle_dir), realtime=True, max_misses=10**9)
    live = UdpWeights(rt.names, np.full(rt.m, 1.0 / rt.m), port=0, stale_timeout=60.0, token=token)
    cmd = [sys.executable, __file__, "send", "--port", str(live.address[1]), "--rate", str(rate),
           "--seconds", str(flood_seconds)] + (["--token"] if token else [])  # fmt: skip
    sender = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        time.sleep(0.3)  # the sender is importing; the flood then runs inside the episode
        result = rt.run(live, seconds=seconds, stop_on_fall=False, record=True)
        out, _ = sender.communicate(timeout=60)
    finally:
        live.close()
        if sender.poll() is None:
            sender.kill()
            sender.wait()
    info = result.to_dict()
    applied = np.array([r.weights for r in result.records])
    return {"sent": json.loads(out), "result": info, "applied": applied}


def tiny_bundle(root: Path) -> Path:
    from deploy_latency import tiny_run

    from amorctl.deploy.export import export_bundle

    export_bundle(tiny_run(root), root / "bundle")
    return root / "bundle"


def report(flood: dict) -> None:
    sent, info = flood["sent"], flood["result"]
    inp = info["input"]
    print(f"sent      {sent['sent']:,} datagrams in {sent['seconds']:.2f} s = {sent['rate']:,.0f}/s "
          f"({sent['by_kind'].get('valid', 0):,} valid)")  # fmt: skip
    print(f"received  {inp['received']:,}; accepted {inp['accepted']:,}; rejected {inp['rejected']:,}; "
          f"kernel drops {inp['kernel_drops']}; signed only: {inp['signed']}")  # fmt: skip
    print(f"rejected by reason {json.dumps(inp['rejected_by_reason'], sort_keys=True)}")
    print(f"ticks     {info['steps']} ({info['seconds']:.2f} s), late {info['late_ticks']}, "
          f"on time {100 * info['on_time']:.1f} %, held {info['held_steps']}")  # fmt: skip
    print(f"input     longest poll {inp['poll_ms_max']:.2f} ms, polls cut by the budget "
          f"{inp['deferred_polls']}, rejections not logged (rate limit) {inp['unreported']:,}")  # fmt: skip
    print(f"policy    {info['policy_ms_median']:.3f} ms median / {info['policy_ms_p99']:.3f} ms p99")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", nargs="?", default="run", choices=("run", "send"))
    parser.add_argument("--bundle", type=Path, default=None, help="bundle (default: a fresh tiny run's)")
    parser.add_argument("--port", type=int, default=0, help="send: the runtime's port")
    parser.add_argument("--rate", type=float, default=20000.0, help="datagrams per second")
    parser.add_argument("--seconds", type=float, default=6.0, help="run: episode length; send: flood length")
    parser.add_argument("--flood-seconds", type=float, default=4.0, help="run: flood length")
    parser.add_argument("--token", action="store_true", help="a shared token: signed datagrams")
    args = parser.parse_args()
    token = TOKEN if args.token else None
    if args.mode == "send":
        print(json.dumps(send(args.port, args.rate, args.seconds, token)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        bundle = args.bundle or tiny_bundle(Path(tmp))
        report(run_flood(bundle, args.rate, args.seconds, args.flood_seconds, token))


if __name__ == "__main__":
    main()
