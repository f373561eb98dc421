"""The token gate in front of the live page when it is served beyond loopback (``tune --live
--host 0.0.0.0`` with a token; the security model: :mod:`amorctl.core.live_auth`).

The page itself (viser) then listens on 127.0.0.1 at a free port; the gate listens where the user
asked and relays a TCP connection to it only after the connection's first HTTP request showed the
token: ``GET /?token=<token>`` is answered with a redirect to the same path without the token and
a cookie (``HttpOnly; SameSite=Strict``) holding an HMAC of the token, which the browser then sends
with every request and with the page's websocket handshake. Any other first request gets
``403 Forbidden`` and the connection is closed; nothing reaches the page. Standard library only.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import socket
import threading
import urllib.parse

from amorctl.core.errors import AmorError
from amorctl.core.live_auth import mac

COOKIE = "amorctl_live"
#: longest request head read before a connection is refused (bytes)
MAX_HEAD = 16384
#: seconds a client has to send its request head
HEAD_TIMEOUT_S = 10.0
FORBIDDEN = (
    b"HTTP/1.1 403 Forbidden\r\nContent-Type: text/plain; charset=utf-8\r\nConnection: close\r\n"
    b"Content-Length: %d\r\n\r\n%s"
)


class LiveGate:
    """Relay ``host:port`` to ``127.0.0.1:target_port`` for clients that show ``token``.

    Args:
        host, port: where to listen (port 0: any free port; see :attr:`port`).
        target_port: the page's port on 127.0.0.1.
        token: the shared token.

    Raises:
        AmorError: the address cannot be bound.
    """

    def __init__(self, host: str, port: int, target_port: int, token: str) -> None:
        self.host, self.target_port = host, int(target_port)
        self._cookie = mac(token, b"amorctl live page").decode("ascii")
        self._token = token
        self.refused = 0  # connections turned away
        try:
            self._sock = socket.create_server(
                (host, int(port)), family=socket.AF_INET6 if ":" in host else socket.AF_INET
            )
        except OSError as exc:
            raise AmorError(f"cannot serve the live page on {host}:{port}: {exc.strerror or exc}") from None
        self.port = int(self._sock.getsockname()[1])
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="amorctl-live-gate", daemon=True)
        self._thread.start()
        self._ready.wait(timeout=10)

    @property
    def url(self) -> str:
        """The page's address with the token (what the user opens once)."""
        return f"http://{self.host}:{self.port}/?token={urllib.parse.quote(self._token, safe='')}"

    def close(self) -> None:
        """Stop listening and end the relays."""
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        with contextlib.suppress(OSError):
            self._sock.close()

    # --- the relay --------------------------------------------------------------------------
    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        server = self._loop.run_until_complete(asyncio.start_server(self._serve, sock=self._sock))
        self._ready.set()
        try:
            self._loop.run_forever()
        finally:
            server.close()
            for task in asyncio.all_tasks(self._loop):
                task.cancel()
            with contextlib.suppress(Exception):
                self._loop.run_until_complete(asyncio.sleep(0))
            self._loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
        except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, OSError):
            await self._refuse(writer, b"")
            return
        if len(head) > MAX_HEAD:
            await self._refuse(writer, b"request head too long\n")
            return
        verdict, target = self._check(head)
        if verdict == "redirect":
            cookie = f"{COOKIE}={self._cookie}; HttpOnly; SameSite=Strict; Path=/"
            writer.write(
                f"HTTP/1.1 303 See Other\r\nLocation: {target}\r\nSet-Cookie: {cookie}\r\n"
                "Content-Length: 0\r\nConnection: close\r\n\r\n".encode("latin-1")
            )
            await _close(writer)
        elif verdict == "pass":
            await self._relay(head, reader, writer)
        else:
            await self._refuse(
                writer,
                b"amorctl live page: open the URL with ?token=... that `amorctl tune --live` printed\n",
            )

    def _check(self, head: bytes) -> tuple[str, str]:
        """("pass" | "redirect" | "refuse", where to redirect) for a request head."""
        lines = head.decode("latin-1").split("\r\n")
        parts = lines[0].split(" ")
        if len(parts) != 3:
            return "refuse", ""
        url = urllib.parse.urlsplit(parts[1])
        headers = {}
        for line in lines[1:]:
            name, sep, value = line.partition(":")
            if sep:
                headers[name.strip().lower()] = value.strip()
        cookies = {}
        for item in headers.get("cookie", "").split(";"):
            key, sep, value = item.strip().partition("=")
            if sep:
                cookies[key] = value
        if hmac.compare_digest(cookies.get(COOKIE, "").encode(), self._cookie.encode()):
            return "pass", ""
        query = urllib.parse.parse_qs(url.query)
        given = query.pop("token", [""])[0]
        if given and hmac.compare_digest(given.encode(), self._token.encode()) and parts[0] == "GET":
            rest = urllib.parse.urlencode(query, doseq=True)
            return "redirect", (url.path or "/") + (f"?{rest}" if rest else "")
        return "refuse", ""

    async def _refuse(self, writer: asyncio.StreamWriter, why: bytes) -> None:
        self.refused += 1
        with contextlib.suppress(OSError):
            writer.write(FORBIDDEN % (len(why), why))
        await _close(writer)

    async def _relay(self, head: bytes, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.target_port)
        except OSError:
            await _close(writer)
            return
        up_writer.write(head)
        await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Copy ``reader`` to ``writer`` until either side closes."""
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (OSError, asyncio.CancelledError):
        pass
    finally:
        await _close(writer)


async def _close(writer: asyncio.StreamWriter) -> None:
    with contextlib.suppress(OSError, asyncio.CancelledError):
        writer.close()
        await writer.wait_closed()
