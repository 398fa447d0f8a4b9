"""The viewer's access checks (issue 13, item 8): a token in the URL, the page's own
Origin, a loopback Host. A WebSocket client from another Origin is refused; the
viewer's own page in Chromium connects; a page on another origin in the same
Chromium cannot, even knowing the port and the token."""

from __future__ import annotations

import asyncio
import contextlib
import http.server
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer needs viser (pip install 'skincap[view]')")
import viser  # noqa: E402
import websockets  # noqa: E402

from skincap.errors import SkincapError  # noqa: E402
from skincap.viz.scene import MarkerLayer, Scene  # noqa: E402
from skincap.viz.viewer import guard as guard_module  # noqa: E402
from skincap.viz.viewer import serve_scene  # noqa: E402
from skincap.viz.viewer.guard import AccessGuard  # noqa: E402

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--no-first-run"]  # fmt: skip


def _small_scene() -> Scene:
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(30, 5, 3)) * 0.1 + [0.0, 1.0, 0.0]
    layer = MarkerLayer(
        "walk.c3d",
        30.0,
        Path("walk.c3d"),
        positions=pos,
        labels=[f"M{i}" for i in range(5)],
        invented=np.zeros((30, 5), dtype=bool),
    )
    return Scene([layer])


@pytest.fixture(scope="module")
def handle() -> Iterator[object]:
    h = serve_scene(_small_scene(), port=0, play=False)
    yield h
    h.stop()


def _http(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(
            urllib.request.Request(url, headers=headers or {}), timeout=10
        ) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _ws(port: int, path: str, origin: str | None) -> str:
    """'open: <bytes of the first message>' or 'refused: <status>'."""

    async def attempt() -> str:
        try:
            async with websockets.connect(
                f"ws://127.0.0.1:{port}{path}",
                origin=origin,  # type: ignore[arg-type]
                subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                open_timeout=10,
            ) as conn:
                first = await asyncio.wait_for(conn.recv(), 10)
                return f"open: {len(first)}"
        except websockets.exceptions.InvalidStatus as exc:
            return f"refused: {exc.response.status_code}"

    return asyncio.run(attempt())


# --------------------------------------------------------------- the URL and HTTP
def test_url_carries_an_unguessable_token_and_binds_loopback(handle) -> None:  # type: ignore[no-untyped-def]
    token = handle.guard.token
    assert handle.url == f"http://127.0.0.1:{handle.port}/{token}/"
    assert len(token) >= 32 and token.replace("-", "").replace("_", "").isalnum()
    other = serve_scene(_small_scene(), port=0, play=False)
    try:
        assert other.guard.token != token  # fresh per viewer
    finally:
        other.stop()
    sock = handle.server._websock_server  # the bind itself: loopback only
    assert sock._host == "127.0.0.1"


def test_page_needs_the_token(handle) -> None:  # type: ignore[no-untyped-def]
    status, body = _http(handle.url)
    assert status == 200 and b"<html" in body.lower()
    base = f"http://127.0.0.1:{handle.port}"
    for path in ("/", "/index.html", f"/{handle.guard.token[:-1]}/", f"/x{handle.guard.token}/"):
        status, body = _http(base + path)
        assert status == 403 and b"access token" in body, path


def test_path_traversal_is_still_refused(handle) -> None:  # type: ignore[no-untyped-def]
    for rest in ("../../../etc/passwd", "..%2f..%2fetc%2fpasswd", "%2e%2e/%2e%2e/etc/passwd",
                 "..\\..\\etc\\passwd", "a/../../b"):  # fmt: skip
        status, body = _http(handle.url + rest)
        assert status == 404 and b"root:" not in body, rest


def test_dns_rebinding_host_is_refused(handle) -> None:  # type: ignore[no-untyped-def]
    status, body = _http(handle.url, {"Host": f"evil.example:{handle.port}"})
    assert status == 403 and b"is not this viewer" in body
    status, _ = _http(handle.url, {"Host": f"localhost:{handle.port}"})
    assert status == 200


# -------------------------------------------------------------------- WebSockets
def test_websocket_from_another_origin_is_refused(handle) -> None:  # type: ignore[no-untyped-def]
    port, path = handle.port, f"/{handle.guard.token}"
    own = f"http://127.0.0.1:{port}"
    assert _ws(port, path, "http://evil.example") == "refused: 403"
    assert _ws(port, path, f"http://127.0.0.1:{port + 1}") == "refused: 403"
    assert _ws(port, path, "null") == "refused: 403"  # a sandboxed or file:// page
    assert _ws(port, path, None) == "refused: 403"
    assert _ws(port, "/", own) == "refused: 403"  # the right Origin without the token
    assert _ws(port, "/wrong-token", own) == "refused: 403"
    # the viewer's own Origin with the token receives the scene
    opened = _ws(port, path, own)
    assert opened.startswith("open: ") and int(opened.split()[1]) > 0
    deadline = time.monotonic() + 5
    while handle.client_count() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert handle.client_count() == 0


def test_guard_check_unit_cases() -> None:
    g = AccessGuard("127.0.0.1", token="T0k")
    ws = {"Upgrade": "websocket"}
    assert g.check("/T0k/", {"Host": "127.0.0.1:8080"}, 8080) == (None, "/")
    assert g.check("/T0k/a/b.js?x=1", {"Host": "localhost:8080"}, 8080) == (None, "/a/b.js?x=1")
    assert (
        g.check("/T0k", {"Host": "[::1]:8080", **ws, "Origin": "http://[::1]:8080"}, 8080)[0]
        is None
    )
    assert g.check("/T0k?v=1", {"Host": "127.0.0.1:8080"}, 8080) == (None, "/?v=1")
    refused = [
        ("/t0k/", {"Host": "127.0.0.1:8080"}),  # case matters
        ("/T0k/", {"Host": "127.0.0.1:8081"}),  # another port
        ("/T0k/", {"Host": "evil.example:8080"}),
        ("/T0k/", {}),
        ("/T0k", {"Host": "127.0.0.1:8080", **ws, "Origin": "http://localhost:8080"}),
        ("/T0k", {"Host": "127.0.0.1:8080", **ws, "Origin": "https://127.0.0.1:8080"}),
        ("//T0k/", {"Host": "127.0.0.1:8080"}),
        ("T0k/", {"Host": "127.0.0.1:8080"}),
    ]
    for path, headers in refused:
        assert g.check(path, headers, 8080)[0] is not None, (path, headers)
    # served to the local network: any Host, but the WebSocket's Origin must match it
    lan = AccessGuard("0.0.0.0", token="T0k")
    assert lan.check("/T0k/", {"Host": "studio-pc:8080"}, 8080)[0] is None
    assert (
        lan.check(
            "/T0k", {"Host": "studio-pc:8080", **ws, "Origin": "http://studio-pc:8080"}, 8080
        )[0]
        is None
    )
    assert (
        lan.check("/T0k", {"Host": "studio-pc:8080", **ws, "Origin": "http://evil.example"}, 8080)[
            0
        ]
        is not None
    )


def test_viewer_refuses_to_run_unguarded(monkeypatch: pytest.MonkeyPatch) -> None:
    """A viser that no longer goes through websockets' serve(): stop, do not serve open."""
    from skincap.viz.viewer import server

    monkeypatch.setattr(server, "guarding_viser", lambda guard: contextlib.nullcontext())
    with pytest.raises(SkincapError, match="cannot guard"):
        serve_scene(_small_scene(), port=0, play=False)


def test_the_serve_wrapper_lasts_only_while_viser_starts() -> None:
    import websockets.asyncio.server as ws_server

    original = ws_server.serve
    g = AccessGuard("127.0.0.1")
    with guard_module.guarding_viser(g):
        assert ws_server.serve is not original
    assert ws_server.serve is original and not g.installed


# ------------------------------------------------------------- Chromium, real pages
@contextlib.contextmanager
def _page_server(html: str) -> Iterator[str]:
    """Serve ``html`` at http://127.0.0.1:<free port>/ from a thread; yield the URL."""
    body = html.encode()

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's naming
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.slow
def test_own_page_connects_and_foreign_page_cannot_in_chromium(handle) -> None:  # type: ignore[no-untyped-def]
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright)")
    if not CHROMIUM.exists():
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    ws_url = f"ws://127.0.0.1:{handle.port}/{handle.guard.token}"
    # a hostile page that knows the port and even the token: only its Origin differs
    hostile = f"""<!doctype html><html><body><script>
      window.result = "pending";
      const s = new WebSocket("{ws_url}", ["viser-v{viser.__version__}"]);
      s.onopen = () => {{ window.result = "open"; }};
      s.onmessage = () => {{ window.result = "data"; }};
      s.onerror = () => {{ if (window.result === "pending") window.result = "refused"; }};
    </script></body></html>"""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            # served for real from another local origin (another port on 127.0.0.1): a
            # public origin would be stopped by Chromium's own local-network-access
            # rules before the viewer's check is ever reached, and Firefox has none
            with _page_server(hostile) as foreign:
                page.goto(foreign)
                page.wait_for_function("window.result !== 'pending'", timeout=30_000)
                assert page.evaluate("window.result") == "refused"
            assert handle.client_count() == 0

            # the URL the viewer printed: its page loads and its WebSocket connects
            response = page.goto(handle.url)
            assert response is not None and response.status == 200
            deadline = time.monotonic() + 60
            while handle.client_count() < 1 and time.monotonic() < deadline:
                time.sleep(0.1)
            assert handle.client_count() == 1, "the viewer's own page never connected"

            # the bare port without the token: no page
            response = page.goto(f"http://127.0.0.1:{handle.port}/")
            assert response is not None and response.status == 403
        finally:
            browser.close()
