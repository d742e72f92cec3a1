"""Who may talk to the server: the token, the browser's Origin and the Host header (against DNS rebinding).

A page on a domain that an attacker points at 127.0.0.1 (DNS rebinding) is same-origin with the server as
far as the browser knows; only the Host header still names the attacker's domain. :class:`HostGuard` answers
every request whose Host is not the bound address, a loopback name, an IP literal of a wildcard bind, this
machine's name (wildcard bind) or a host of ``--origins`` with 421 (HTTP) or a refused handshake (403,
WebSocket), before any route runs.
"""

from __future__ import annotations

import hmac
import ipaddress
import socket
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any
from urllib.parse import urlsplit

LOOPBACK = {"localhost", "127.0.0.1", "::1"}
Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]


def token_ok(expected: str | None, presented: str | None) -> bool:
    if expected is None:
        return True
    return presented is not None and hmac.compare_digest(presented.encode(), expected.encode())


def origin_ok(origins: tuple[str, ...], origin: str | None, host: str | None) -> bool:
    """Browsers send Origin: allow the server's own address, loopback pages and configured origins."""
    if origin is None:
        return True  # not a browser (the Java client, websockets); the token guards those
    if origin in origins:
        return True
    parts = urlsplit(origin)
    return parts.hostname in LOOPBACK or (host is not None and parts.netloc == host)


def host_name(host: str) -> str:
    """The name part of a Host header value (``[::1]:6006`` -> ``::1``, ``Example.org.:80`` -> ``example.org``)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    if host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.rstrip(".")


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def _is_wildcard(bound: str) -> bool:
    return bound in ("", "0.0.0.0", "::")


class Hosts:
    """The Host names this server answers to."""

    def __init__(self, bound: str, origins: tuple[str, ...] = ()) -> None:
        self.wildcard = _is_wildcard(bound)
        names = set(LOOPBACK) | {host_name(bound)} | {urlsplit(o).hostname or "" for o in origins}
        if self.wildcard:
            names |= {socket.gethostname().lower()}
        self.names = {n for n in names if n}

    def allows(self, host: str | None) -> bool:
        if host is None:
            return True  # not a browser: every browser sends Host
        name = host_name(host)
        return name in self.names or (self.wildcard and _is_ip(name))


class HostGuard:
    """ASGI middleware: requests with a foreign Host never reach the app (421; a WebSocket handshake 403)."""

    def __init__(self, app: Callable[[Scope, Receive, Send], Awaitable[None]], hosts: Hosts) -> None:
        self.app, self.hosts = app, hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            raw = dict(scope.get("headers") or []).get(b"host")
            host = raw.decode("latin-1") if raw is not None else None
            if not self.hosts.allows(host):
                await self._refuse(scope, send)
                return
        await self.app(scope, receive, send)

    @staticmethod
    async def _refuse(scope: Scope, send: Send) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": "host not allowed"})
            return
        body = (
            b"host not allowed: open the server by its address (e.g. http://127.0.0.1:6006/) "
            b"or add the page's origin with --origins\n"
        )
        await send(
            {
                "type": "http.response.start",
                "status": 421,
                "headers": [
                    (b"content-type", b"text/plain; charset=utf-8"),
                    (b"content-length", b"%d" % len(body)),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
