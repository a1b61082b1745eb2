"""Who may use the live page: real websocket and HTTP clients against a real viser server.

Each test starts a guarded viser server on 127.0.0.1 (port 0) and connects with the
``websockets`` client (installed with viser) and urllib, so the check runs exactly where a
browser's connection would meet it.
"""

from __future__ import annotations

import socket
import urllib.error
import urllib.request

import pytest

viser = pytest.importorskip("viser", reason="the live page needs viser (pip install viser)")
websockets = pytest.importorskip("websockets", reason="websockets comes with viser")
from websockets.sync.client import connect  # noqa: E402

from margtrack.live.security import (  # noqa: E402
    AccessPolicy,
    exposure_warning,
    guarded_viser_server,
    is_loopback,
    page_url,
    udp_exposure_warning,
)

SUBPROTOCOLS = [f"viser-v{viser.__version__}"]


@pytest.fixture
def server_factory():
    servers = []

    def start(policy: AccessPolicy):
        server = guarded_viser_server(policy.bind_host, 0, policy)
        servers.append(server)
        return server, server.get_port()

    yield start
    for server in servers:
        server.stop()


def _ws(port: int, origin: str | None, host: str = "127.0.0.1", path: str = "/",
        headers: dict[str, str] | None = None):
    """Open a websocket to ``host`` (its name in the Host header; the TCP connection goes to
    127.0.0.1, as with a name that resolves there) and read viser's first message (proof
    that the page's server accepted)."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    with connect(f"ws://{host}:{port}{path}", sock=sock, origin=origin,
                 subprotocols=SUBPROTOCOLS, additional_headers=headers, open_timeout=10) as ws:
        return ws.recv(timeout=10)


def _refusal(excinfo) -> tuple[int, str]:
    response = excinfo.value.response
    return response.status_code, bytes(response.body).decode()


def test_a_foreign_origin_is_refused_and_the_pages_own_accepted(server_factory):
    server, port = server_factory(AccessPolicy.for_bind("127.0.0.1"))
    assert server.request_share_url() is None  # no public tunnel to the page, ever
    with pytest.raises(websockets.exceptions.InvalidStatus) as excinfo:
        _ws(port, "http://evil.example")
    status, body = _refusal(excinfo)
    assert status == 403
    assert "origin 'http://evil.example' refused" in body
    # the same site on the page's port, and another local port, are foreign origins too
    for foreign in (f"http://evil.example:{port}", "http://127.0.0.1:1", "null"):
        with pytest.raises(websockets.exceptions.InvalidStatus):
            _ws(port, foreign)
    assert _ws(port, f"http://127.0.0.1:{port}")  # the page's own origin
    assert _ws(port, f"http://localhost:{port}", host="localhost")
    assert _ws(port, None)  # a program (no Origin): no web page can make this request
    # the page itself is served
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as response:
        assert response.status == 200 and b"<html" in response.read(200).lower()


def test_dns_rebinding_host_is_refused_on_loopback(server_factory):
    _, port = server_factory(AccessPolicy.for_bind("127.0.0.1"))
    # evil.example resolving to 127.0.0.1: Host and Origin agree, but the name is not ours
    with pytest.raises(websockets.exceptions.InvalidStatus) as excinfo:
        _ws(port, f"http://evil.example:{port}", host="evil.example")
    assert _refusal(excinfo) == (
        403, f"margtrack live: Host 'evil.example:{port}' refused; open the page as "
        f"http://127.0.0.1:{port}/ or http://localhost:{port}/\n")
    request = urllib.request.Request(f"http://127.0.0.1:{port}/",
                                     headers={"Host": f"evil.example:{port}"})
    with pytest.raises(urllib.error.HTTPError) as http_error:
        urllib.request.urlopen(request, timeout=10)
    assert http_error.value.code == 403
    assert "Host 'evil.example" in http_error.value.read().decode()


def test_token_required_refuses_requests_without_it(server_factory):
    policy = AccessPolicy.for_bind("127.0.0.1", token=True)  # as off loopback, on loopback
    assert policy.token and len(policy.token) >= 16
    _, port = server_factory(policy)
    own = f"http://127.0.0.1:{port}"
    for url in (f"{own}/", f"{own}/?token=wrong-token-123", f"{own}/?token="):
        with pytest.raises(urllib.error.HTTPError) as excinfo:
            urllib.request.urlopen(url, timeout=10)
        assert excinfo.value.code == 403
        assert "needs its token" in excinfo.value.read().decode()
    with pytest.raises(websockets.exceptions.InvalidStatus) as ws_error:
        _ws(port, own)
    assert _refusal(ws_error)[0] == 403
    bad_cookie = {"Cookie": f"{policy.cookie_name(port)}=not-the-token-1234"}
    with pytest.raises(websockets.exceptions.InvalidStatus):
        _ws(port, own, headers=bad_cookie)
    # the printed URL works and sets the cookie the page's websocket then carries
    with urllib.request.urlopen(f"{own}/?token={policy.token}", timeout=10) as response:
        assert response.status == 200
        cookie = response.headers["Set-Cookie"]
    assert cookie.startswith(f"{policy.cookie_name(port)}={policy.token};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert _ws(port, own, headers={"Cookie": cookie.split(";")[0]})
    assert _ws(port, own, path=f"/?token={policy.token}")
    # a foreign origin is refused even with the token
    with pytest.raises(websockets.exceptions.InvalidStatus):
        _ws(port, "http://evil.example", headers={"Cookie": cookie.split(";")[0]})


def test_non_loopback_bind_gets_a_token_and_a_warning():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.20")
    policy = AccessPolicy.for_bind("0.0.0.0")
    assert policy.token is not None
    assert AccessPolicy.for_bind("127.0.0.1").token is None
    with pytest.raises(ValueError, match="needs a token"):
        AccessPolicy.for_bind("0.0.0.0", token=False)
    with pytest.raises(ValueError, match="12 to 256 characters"):
        AccessPolicy.for_bind("127.0.0.1", token="short")
    with pytest.raises(ValueError, match="12 to 256 characters"):
        AccessPolicy.for_bind("127.0.0.1", token="has spaces in it!")
    assert exposure_warning("127.0.0.1") is None
    warning = exposure_warning("0.0.0.0")
    assert "every network interface" in warning and "--host 127.0.0.1" in warning
    assert udp_exposure_warning("127.0.0.1") is None
    assert "inject samples" in udp_exposure_warning("0.0.0.0")
    assert page_url("127.0.0.1", 8080, None) == "http://127.0.0.1:8080/"
    assert page_url("::1", 8080, "abcdefghijkl") == "http://[::1]:8080/?token=abcdefghijkl"


def test_run_live_on_every_interface_warns_and_needs_the_token():
    """0.0.0.0 is bound for a moment only: the requests go to 127.0.0.1, then it stops."""
    from margtrack.live.simulator import PeopleSimulation, SimulatorSource
    from margtrack.live.viewer_session import run_live

    warnings: list[str] = []
    source = SimulatorSource(PeopleSimulation(preset="left_arm", motion="wave"), speed=1.0)
    session = run_live(source, "bachmann", port=0, host="0.0.0.0", block=False,
                       warn=warnings.append)
    try:
        port = session.server.get_port()
        assert session.token and session.url.endswith(f":{port}/?token={session.token}")
        assert len(warnings) == 1 and "every network interface" in warnings[0]
        with pytest.raises(urllib.error.HTTPError) as excinfo:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10)
        assert excinfo.value.code == 403
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/?token={session.token}",
                                    timeout=10) as response:
            assert response.status == 200
    finally:
        session.stop()
