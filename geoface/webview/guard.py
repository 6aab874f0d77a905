"""What keeps the web viewer's page and socket safe: user strings shown as text, never as HTML
or Markdown; a listening address checked before serving; WebSocket handshakes only from the
page's own origin, and only for host names that are this machine (so that neither another site
open in the same browser nor a DNS-rebinding name can read the scene)."""
from __future__ import annotations

import contextlib
import http
import ipaddress
import socket
import threading
from urllib.parse import urlsplit

from ..errors import GeofaceError

__all__ = ["plain_text", "md_text", "check_host", "check_port", "origin_allowed", "guarded_serve"]

_MD_SPECIAL = set("\\`*_{}[]()#+-.!|~")
_HTML = {"<": "&lt;", ">": "&gt;", "&": "&amp;", '"': "&quot;", "'": "&#39;"}


def plain_text(s) -> str:
    """``s`` with line breaks and other control characters as spaces (one line of text)."""
    return "".join(" " if ord(ch) < 32 or ch == "\x7f" else ch for ch in str(s))


def md_text(s) -> str:
    """``s`` as literal text inside viser's Markdown: HTML's characters become entities and
    Markdown's are backslash-escaped, so a file named ``<img src=x onerror=...>.obj`` or
    ``[x](javascript:...)`` shows as those characters and nothing else; line breaks become
    spaces."""
    return "".join(_HTML.get(ch, "\\" + ch if ch in _MD_SPECIAL else ch) for ch in plain_text(s))


def check_port(host: str, port: int) -> int:
    """``port`` if it is free on ``host`` (0: any free port), else a one-line GeofaceError (a busy
    port is not silently exchanged for another)."""
    if int(port) == 0:
        return 0
    infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    for family, kind, proto, _, addr in infos[:1]:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(addr[:2] if family == socket.AF_INET else addr)
            except OSError:
                raise GeofaceError(f"--port {port} is in use on {host}; choose another (--port 0: any free port)") from None
    return int(port)


def check_host(host: str) -> str:
    """``host`` if this machine can listen on it, else a :class:`GeofaceError` in one line (an
    address of another machine, ``256.1.1.1``, a name that does not resolve)."""
    if not isinstance(host, str) or not host.strip() or any(c.isspace() for c in host) or len(host) > 253:
        raise GeofaceError(f"--host {host!r} is not an address or host name")
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, OSError) as e:
        raise GeofaceError(f"--host {host}: not an address or a name this machine resolves ({e})") from None
    err = None
    for family, kind, proto, _, addr in infos:
        try:
            with socket.socket(family, kind, proto) as s:
                s.bind(addr[:2] if family == socket.AF_INET else addr)
            return host
        except OSError as e:
            err = e
    raise GeofaceError(f"--host {host}: this machine cannot listen there ({getattr(err, 'strerror', err)}); "
                       "use 127.0.0.1 (this machine only) or 0.0.0.0 (every interface)")


def _local_names(host: str) -> set[str]:
    names = {"localhost", "127.0.0.1", "::1", host.lower().strip("[]")}
    with contextlib.suppress(OSError):
        names.add(socket.gethostname().lower())
        names.add(socket.getfqdn().lower())
    return names


def _hostname(netloc: str) -> str:
    return (urlsplit("//" + netloc).hostname or "").lower()


def origin_allowed(origin: str | None, host_header: str | None, bound_host: str) -> bool:
    """Whether a request may reach the viewer.  ``Host`` must name this machine (an IP literal,
    ``localhost``, the machine's name or the address the server was given): a DNS-rebinding name
    that resolves here is refused.  A browser's ``Origin``, when sent, must be the page's own
    (same host and port as ``Host``); tools that send none (scripts, tests) are let in."""
    if not host_header:
        return False
    hn = _hostname(host_header)
    try:
        ipaddress.ip_address(hn)
        local = True
    except ValueError:
        local = hn in _local_names(bound_host)
    if not local:
        return False
    if origin is None:
        return True
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        return False  # "null" (a file:// page, a sandboxed frame) or anything odd
    return parts.netloc.lower() == host_header.lower()


_PATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def guarded_serve(bound_host: str):
    """While active, every ``websockets`` server started (viser starts its own in its
    constructor) refuses requests that :func:`origin_allowed` refuses, with 403."""
    import websockets.asyncio.server as wss

    with _PATCH_LOCK:
        original = wss.serve

        def serve(handler, *args, process_request=None, **kwargs):
            def check(connection, request):
                h = request.headers
                hosts, origins = h.get_all("Host"), h.get_all("Origin")
                if len(hosts) != 1 or len(origins) > 1 or not origin_allowed(
                        origins[0] if origins else None, hosts[0], bound_host):
                    return connection.respond(http.HTTPStatus.FORBIDDEN, "geoface view: cross-origin request refused\n")
                return None if process_request is None else process_request(connection, request)

            return original(handler, *args, process_request=check, **kwargs)

        wss.serve = serve
        try:
            yield
        finally:
            wss.serve = original
