"""Who may use the live page: loopback by default, the page's own Origin, a token elsewhere.

Threats: any website open in the user's browser can open a websocket to
``ws://127.0.0.1:PORT`` and drive the page (change filter parameters, start a recording,
write files); a site whose name resolves to 127.0.0.1 (DNS rebinding) reaches the server
with its own ``Host``; on a non-loopback address every machine on the network can.

Rules, checked by :meth:`AccessPolicy.refusal` on every HTTP request and websocket handshake
before viser sees it; a refused request gets ``403 Forbidden`` with the reason:

1. **Host** (loopback binds): the ``Host`` header must name this machine (``localhost``,
   ``127.0.0.1``, ``[::1]`` or the bound address): a rebinding site's name is refused.
2. **Origin**: a websocket handshake that carries an ``Origin`` (every browser sends one)
   must come from the page's own origin, ``http(s)://`` + its ``Host``. A handshake without
   ``Origin`` comes from a program, not a web page, and passes rule 2 (rule 3 still applies).
3. **Token** (required off loopback, optional on it): every request carries the token,
   either in the URL (``?token=...``, the URL margtrack prints) or in the cookie that the
   first response to such a URL sets (``HttpOnly; SameSite=Strict``, one name per port),
   compared in constant time.

viser (1.1) starts its websockets server inside ``ViserServer()``, with its own
``process_request`` (the page's files). :func:`guarded_viser_server` builds the server while
``websockets.asyncio.server.serve`` is wrapped (under a lock, restored at once) so that the
check runs before viser's handler from the first connection on; if the wrap was not used
(another viser layout), it stops the server and raises instead of serving unguarded.
viser's *share* button (a public tunnel to the page through viser's relay) is hidden and
its request refused.
"""

from __future__ import annotations

import hmac
import http
import http.cookies
import inspect
import ipaddress
import re
import secrets
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qs, urlsplit

__all__ = [
    "AccessPolicy",
    "exposure_warning",
    "guarded_viser_server",
    "is_loopback",
    "new_token",
    "page_url",
    "udp_exposure_warning",
]

_LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
_TOKEN_CHARS = re.compile(r"[A-Za-z0-9_\-]{12,256}")
_INSTALL_LOCK = threading.Lock()


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is reachable from this machine only."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A random URL-safe token (128 bits)."""
    return secrets.token_urlsafe(16)


def exposure_warning(host: str) -> str | None:
    """What serving the page on ``host`` exposes, or None for a loopback address."""
    if is_loopback(host):
        return None
    where = "every network interface" if host in ("0.0.0.0", "::", "") else host
    return (f"the page is served on {where}: anyone on the network who has its URL with the "
            "token can watch the sensors and drive the page (change filter parameters, start "
            "recordings that write files). Share the URL only with people you trust; use "
            "--host 127.0.0.1 (the default) to keep the page on this machine.")


def udp_exposure_warning(host: str) -> str | None:
    """What listening for UDP sensor lines on ``host`` exposes, or None on loopback."""
    if is_loopback(host):
        return None
    return (f"the UDP listener accepts sensor lines on {host}: any machine that can reach the "
            "port can inject samples (there is no authentication on UDP). Use it on a trusted "
            "network only.")


def page_url(host: str, port: int, token: str | None) -> str:
    """The URL to open: ``host`` (this machine's name for a wildcard bind), port and token."""
    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    if ":" in shown and not shown.startswith("["):
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/" + (f"?token={token}" if token else "")


def _host_name(host_header: str) -> str:
    """Host header value without port or IPv6 brackets, lower case."""
    value = host_header.strip().lower()
    if value.startswith("["):
        return value[1:value.find("]")] if "]" in value else value[1:]
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def _values(headers: Any, name: str) -> list[str]:
    """Every value of header ``name`` (websockets' Headers or a plain mapping)."""
    if hasattr(headers, "get_all"):
        return list(headers.get_all(name))
    value = headers.get(name)
    return [] if value is None else [value]


@dataclass(frozen=True)
class AccessPolicy:
    """The checks of the module docstring for a server bound to ``bind_host``.

    token : required on every request when set (:meth:`for_bind` sets one off loopback).
    """

    bind_host: str
    token: str | None = None
    guarded: list[int] = field(default_factory=list, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.token is not None and not _TOKEN_CHARS.fullmatch(self.token):
            raise ValueError("the token must be 12 to 256 characters of letters, digits, '_' "
                             "or '-' (leave it out to get a random one)")
        if self.token is None and not is_loopback(self.bind_host):
            raise ValueError(f"serving on the non-loopback address {self.bind_host} needs a "
                             "token; pass one or let margtrack generate it")

    @classmethod
    def for_bind(cls, host: str, token: str | bool | None = None) -> AccessPolicy:
        """The policy for ``host``: ``token`` None (a random one off loopback, none on it),
        True (a random one), False (none; refused off loopback) or the token itself."""
        if token is None:
            token = not is_loopback(host)
        if token is True:
            return cls(host, new_token())
        if token is False:
            return cls(host, None)
        return cls(host, str(token))

    def cookie_name(self, port: int) -> str:
        """Name of the token cookie of the page on ``port`` (cookies are per host, not port)."""
        return f"margtrack_token_{port}"

    def _token_ok(self, path: str, headers: Any, port: int) -> tuple[bool, bool]:
        """(token present and right, it came in the URL)."""
        assert self.token is not None
        query = parse_qs(urlsplit(path).query).get("token", [])
        if query:
            ok = hmac.compare_digest(query[-1].encode(), self.token.encode())
            return ok, ok
        jar = http.cookies.SimpleCookie()
        for raw in _values(headers, "Cookie"):
            try:
                jar.load(raw)
            except http.cookies.CookieError:
                continue
        morsel = jar.get(self.cookie_name(port))
        if morsel is None:
            return False, False
        return hmac.compare_digest(morsel.value.encode(), self.token.encode()), False

    def refusal(self, path: str, headers: Any, port: int) -> str | None:
        """Why a request for ``path`` with ``headers`` must be refused, or None to let it in."""
        hosts, origins = _values(headers, "Host"), _values(headers, "Origin")
        if len(hosts) != 1 or len(origins) > 1:
            return ("margtrack live: request refused: it must carry one Host header and at "
                    f"most one Origin (got {len(hosts)} and {len(origins)})")
        host_header = hosts[0]
        host = _host_name(host_header)
        if is_loopback(self.bind_host) and host not in _LOOPBACK_NAMES | {
                _host_name(self.bind_host)}:
            return (f"margtrack live: Host {host_header!r} refused; open the page as "
                    f"http://127.0.0.1:{port}/ or http://localhost:{port}/")
        origin = origins[0] if origins else None
        upgrade = ",".join(_values(headers, "Upgrade")).lower()
        if "websocket" in upgrade and origin is not None:
            own = {f"http://{host_header.strip().lower()}", f"https://{host_header.strip().lower()}"}
            if origin.strip().lower() not in own:
                return (f"margtrack live: websocket from origin {origin!r} refused; only the "
                        f"page's own origin (http://{host_header}) may connect")
        if self.token is not None:
            ok, _ = self._token_ok(path, headers, port)
            if not ok:
                return ("margtrack live: this page needs its token; open the URL that "
                        "`margtrack live` printed (it ends in ?token=...)")
        return None

    def wrap(self, inner: Callable[..., Any] | None) -> Callable[..., Any]:
        """A websockets ``process_request`` that applies :meth:`refusal`, then ``inner``."""
        self.guarded.append(1)

        async def process_request(connection: Any, request: Any) -> Any:
            port = int(connection.local_address[1])
            reason = self.refusal(request.path, request.headers, port)
            if reason is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN, reason + "\n")
            response = inner(connection, request) if inner is not None else None
            if inspect.isawaitable(response):
                response = await response
            if response is not None and self.token is not None:
                _, in_url = self._token_ok(request.path, request.headers, port)
                if in_url:
                    response.headers["Set-Cookie"] = (
                        f"{self.cookie_name(port)}={self.token}; Path=/; HttpOnly; "
                        "SameSite=Strict")
            return response

        return process_request


def _no_share(*args: Any, **kwargs: Any) -> None:
    """Replaces ``ViserServer.request_share_url``: the page is never tunnelled out."""
    return None


def guarded_viser_server(host: str, port: int, policy: AccessPolicy, verbose: bool = False
                         ) -> Any:
    """A started ``viser.ViserServer`` on ``host:port`` whose every request passes ``policy``.

    Raises ``RuntimeError`` (after stopping the server) if the check could not be installed.
    """
    try:
        import viser
        import websockets.asyncio.server as ws_server
    except ImportError:
        raise ImportError("the live view needs viser: pip install viser (or margtrack[live])"
                          ) from None
    if _host_name(policy.bind_host) != _host_name(host):
        raise ValueError(f"the policy is for {policy.bind_host}, the server binds {host}")
    before = len(policy.guarded)
    with _INSTALL_LOCK:
        original = ws_server.serve

        def serve(handler: Any, *args: Any, process_request: Any = None, **kwargs: Any) -> Any:
            return original(handler, *args, process_request=policy.wrap(process_request),
                            **kwargs)

        ws_server.serve = serve  # type: ignore[assignment,misc]
        try:
            server = viser.ViserServer(host=host, port=port, verbose=verbose)
        finally:
            ws_server.serve = original  # type: ignore[misc]
    # viser's "share" button asks the server to open a public tunnel to the page: hide it
    # and refuse the request, which any connected client could send
    server.gui.configure_theme(show_share_button=False)
    server.request_share_url = _no_share
    if len(policy.guarded) == before:
        server.stop()
        raise RuntimeError(f"viser {viser.__version__} did not start its server through "
                           "websockets.asyncio.server.serve, so the page's access check could "
                           "not be installed; refusing to serve (pin viser 1.1)")
    return server
