"""Who may change a running policy's weights: the live inputs' security model (docs/deploy.md,
"Security").

The deploy runtime's live UDP input (``deploy run --listen``) and the live tuning page
(``tune --live``) change what a policy does while it runs. Bound to loopback (the default) only
processes on this machine can reach them, and none needs a secret. Bound to anything else, a
shared token is required (``--token`` or the environment variable ``AMORCTL_TOKEN``, at least
:data:`MIN_TOKEN` characters), else the command is refused before it starts:

- every live-weight datagram then carries an HMAC-SHA256 of its payload keyed with the token,
  and a sequence number that must grow (:func:`sign_datagram`, :func:`open_datagram`), so a
  datagram without the right HMAC, altered in transit, or replayed is counted and ignored;
- the live page is served behind a gate that admits a browser only once it opened the page's URL
  with ``?token=...`` (``amorctl.tune.live_gate``).

Nothing is encrypted: weights are not secret, their integrity is what matters. Standard library
only (the runtime is torch-free).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import os
import re

from amorctl.core.errors import AmorError

TOKEN_ENV = "AMORCTL_TOKEN"
#: shortest token accepted (characters)
MIN_TOKEN = 16
#: hex characters of a datagram's HMAC-SHA256 prefix
MAC_HEX = 64
_SIGNED = re.compile(rb"[0-9a-f]{%d} " % MAC_HEX)


def is_loopback(host: str) -> bool:
    """Whether binding ``host`` keeps a server reachable from this machine only."""
    name = host.strip().strip("[]").lower()
    if name in ("localhost", "", "ip6-localhost"):
        return name != ""  # "" binds every address
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def check_bind(host: str, token: str | None, what: str) -> str | None:
    """Refuse a live input bound beyond loopback without a shared token; check the token.

    Args:
        host: the address to bind.
        token: the shared token (``--token`` / ``AMORCTL_TOKEN``), or None / "".
        what: the option as the user gave it (``--listen udp://0.0.0.0:9870``).

    Returns:
        the token to use (None: loopback without one).

    Raises:
        AmorError: one line saying how to set a token, or why the given one is refused.
    """
    token = token or None
    if token is not None and len(token) < MIN_TOKEN:
        raise AmorError(
            f"{what}: the token is {len(token)} characters; use at least {MIN_TOKEN} random ones "
            f"(e.g. export {TOKEN_ENV}=\"$(python -c 'import secrets; print(secrets.token_urlsafe(24))')\")"
        )
    if token is None and not is_loopback(host):
        raise AmorError(
            f"{what} binds {host or 'every address'}, beyond loopback: anyone who can reach it could "
            f"change the policy's weights; set a shared token ({TOKEN_ENV}=<at least {MIN_TOKEN} random "
            "characters> in the environment, or --token) so every packet is authenticated "
            '(docs/deploy.md, "Security"), or bind 127.0.0.1'
        )
    return token


def token_from_env() -> str | None:
    """``$AMORCTL_TOKEN`` or None."""
    return os.environ.get(TOKEN_ENV) or None


def mac(token: str, payload: bytes) -> bytes:
    """The lowercase hex HMAC-SHA256 of ``payload`` keyed with ``token`` (64 ASCII bytes)."""
    return hmac.new(token.encode("utf-8"), payload, hashlib.sha256).hexdigest().encode("ascii")


def sign_datagram(message: dict, token: str, seq: int) -> bytes:
    """A signed live datagram: ``<64 hex HMAC> <space> <JSON payload>``; the payload is
    ``message`` with ``"seq": seq`` (an integer that grows with every datagram, e.g.
    ``time.time_ns()``)."""
    payload = json.dumps({**message, "seq": int(seq)}, separators=(",", ":")).encode("utf-8")
    return mac(token, payload) + b" " + payload


class BadDatagram(ValueError):
    """A datagram that failed authentication; ``reason`` is ``unsigned`` or ``bad_mac``."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def open_datagram(data: bytes, token: str) -> bytes:
    """The payload of a signed datagram, after checking its HMAC in constant time.

    Raises:
        BadDatagram: ``unsigned`` (no ``<64 hex> <space>`` prefix) or ``bad_mac`` (wrong HMAC:
            another token, or the payload was altered).
    """
    if _SIGNED.match(data) is None:
        raise BadDatagram("unsigned", "expected '<64 hex HMAC-SHA256> <JSON>' (a token is set)")
    given, payload = data[:MAC_HEX], data[MAC_HEX + 1 :]
    if not hmac.compare_digest(given, mac(token, payload)):
        raise BadDatagram("bad_mac", "HMAC does not match the payload under the shared token")
    return payload
