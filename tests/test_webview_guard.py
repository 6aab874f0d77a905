"""The web viewer's guards without a browser: user strings as text, the listening address
checked before any work, WebSocket handshakes only from the page's own origin and from host
names of this machine, SIGTERM stopping the server and freeing its port."""
from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from geoface.errors import GeofaceError
from geoface.webview.guard import check_host, md_text, origin_allowed

SPOT = Path(__file__).parent / "data" / "meshes" / "spot.obj"


def test_md_text_leaves_no_markup():
    s = md_text('<img src=x onerror="alert(1)">[a](javascript:alert(1)) **b** `c`\n# d & e')
    for bad in ("<", ">", '"', "\n"):
        assert bad not in s
    assert "&lt;img src=x onerror=&quot;alert\\(1\\)&quot;&gt;" in s
    assert "\\[a\\]\\(javascript:alert\\(1\\)\\)" in s and "\\*\\*b\\*\\*" in s and "\\`c\\`" in s
    assert "&amp;" in s
    assert md_text("spot_v2.obj") == "spot\\_v2\\.obj"


def test_origin_and_host_rules():
    ok = origin_allowed
    assert ok(None, "127.0.0.1:8080", "127.0.0.1")  # a script: no Origin
    assert ok("http://127.0.0.1:8080", "127.0.0.1:8080", "127.0.0.1")
    assert ok("http://localhost:8080", "localhost:8080", "127.0.0.1")
    assert ok("http://[::1]:8080", "[::1]:8080", "::1")
    assert not ok("http://evil.example", "127.0.0.1:8080", "127.0.0.1")  # another site's page
    assert not ok("http://127.0.0.1:9999", "127.0.0.1:8080", "127.0.0.1")  # another local port
    assert not ok("null", "127.0.0.1:8080", "127.0.0.1")  # a file:// page or sandboxed frame
    assert not ok("http://evil.example:8080", "evil.example:8080", "127.0.0.1")  # DNS rebinding
    assert not ok(None, None, "127.0.0.1")
    assert ok("http://10.1.2.3:8080", "10.1.2.3:8080", "0.0.0.0")  # served on the LAN, opened by address


@pytest.mark.parametrize("host", ["8.8.8.8", "256.1.1.1", "not a host", "", "a" * 300])
def test_bad_hosts_are_refused_at_once(host):
    t = time.monotonic()
    with pytest.raises(GeofaceError) as e:
        check_host(host)
    assert "\n" not in str(e.value) and time.monotonic() - t < 20
    assert check_host("127.0.0.1") == "127.0.0.1"


def test_cli_bad_host_is_one_line_exit_2():
    r = subprocess.run([sys.executable, "-m", "geoface", "view", "--web", str(SPOT), "--host", "256.1.1.1"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "--host 256.1.1.1" in r.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_server_refuses_other_origins_and_stops_on_sigterm():
    pytest.importorskip("viser")
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    import viser

    port = _free_port()
    p = subprocess.Popen([sys.executable, "-m", "geoface", "view", "--web", str(SPOT), "--port", str(port),
                          "--exit-after", "120"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        for line in p.stdout:
            if "http://" in line:
                break
        proto = [f"viser-v{viser.__version__}"]

        def handshake(**kw):
            try:
                with connect(f"ws://127.0.0.1:{port}", subprotocols=proto, open_timeout=20, **kw):
                    return 101
            except InvalidStatus as e:
                return e.response.status_code

        assert handshake() == 101
        assert handshake(origin=f"http://127.0.0.1:{port}") == 101
        assert handshake(origin="http://evil.example") == 403
        assert handshake(origin=f"http://evil.example:{port}", additional_headers={"Host": f"evil.example:{port}"}) == 403
        p.send_signal(signal.SIGTERM)
        assert p.wait(timeout=60) == 0
    finally:
        if p.poll() is None:
            p.kill()
    with socket.socket() as s:  # the port is free again (a new server may listen on it)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen()


def test_the_server_says_one_line():
    """No viser banner, no "Server stopped": the URL line and nothing else."""
    pytest.importorskip("viser")
    r = subprocess.run([sys.executable, "-m", "geoface", "view", "--web", str(SPOT), "--port", str(_free_port()),
                        "--exit-after", "1"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == ""
    assert len(r.stdout.strip().splitlines()) == 1 and "http://127.0.0.1:" in r.stdout, r.stdout


def test_a_busy_port_is_refused_not_exchanged():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "geoface", "view", "--web", str(SPOT), "--port", str(port),
                            "--exit-after", "1"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and f"--port {port} is in use" in r.stderr and r.stderr.count("\n") == 1
