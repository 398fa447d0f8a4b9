"""Who may talk to the viewer: a secret token in the URL, and the page's own Origin.

While ``skincap view`` runs, any web page open in the same browser could otherwise
open a WebSocket to ``127.0.0.1:<port>`` and read the loaded capture (cross-site
WebSocket hijacking: browsers let a page connect anywhere and send its own Origin).
Three checks close that, as Jupyter does:

* **Token**: every HTTP request and the WebSocket must start their path with a
  random token (``secrets.token_urlsafe``, 192 bits) that only the URL printed and
  opened by ``skincap view`` carries (``http://127.0.0.1:8080/<token>/``). viser's
  page opens its WebSocket on its own URL without the query, so the token travels
  in the path, not in ``?token=``. A page that guesses the port still cannot connect.
* **Origin**: the WebSocket handshake must come from the viewer's own page: the
  ``Origin`` header must equal ``http://`` + the ``Host`` the browser connected to.
  A missing Origin (no browser sends none) is refused too.
* **Host**: bound to a loopback address, the ``Host`` header must name a loopback
  host and the viewer's port, so a DNS-rebinding page (``evil.example`` resolving to
  127.0.0.1) is refused even before its Origin is looked at.

viser offers no hook for its handshake, so :func:`guarding_viser` wraps the
``websockets`` ``serve`` call viser makes while its server starts, and checks that
it did (the viewer refuses to run unguarded rather than run open).
"""

from __future__ import annotations

import contextlib
import hmac
import http
import inspect
import ipaddress
import secrets
from collections.abc import Callable, Iterator, Mapping
from typing import Any
from urllib.parse import urlsplit

__all__ = ["AccessGuard", "guarding_viser", "LOOPBACK_NAMES"]

#: Host names a browser may use for a viewer bound to a loopback address.
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")

#: Bytes of randomness in the token (32 URL-safe characters).
TOKEN_BYTES = 24


def _is_loopback(host: str) -> bool:
    if host in ("localhost", "::1"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class AccessGuard:
    """The viewer's token and its handshake checks.

    Parameters
    ----------
    host : str
        The interface the viewer listens on (``127.0.0.1`` by default).
    token : str, optional
        URL-safe secret; a fresh random one by default.
    """

    def __init__(self, host: str, token: str | None = None) -> None:
        self.token = token if token is not None else secrets.token_urlsafe(TOKEN_BYTES)
        self.loopback = _is_loopback(host)
        self.installed = False  # set once the wrapped serve() call has happened

    def check(self, path: str, headers: Mapping[str, str], port: int) -> tuple[str | None, str]:
        """Refusal reason (None: allowed) and the request path without the token.

        Parameters
        ----------
        path : str
            The request target, ``/<token>/rest?query``.
        headers : mapping
            Request headers (``Host``, ``Origin``, ``Upgrade``), case-insensitive.
        port : int
            The port the request arrived on.
        """
        target, sep, query = path.partition("?")
        segments = target.split("/")
        given = segments[1] if len(segments) > 1 and segments[0] == "" else ""
        if not hmac.compare_digest(given.encode(), self.token.encode()):
            return "no or wrong access token: open the URL 'skincap view' printed", ""
        rest = "/" + "/".join(segments[2:]) + (sep + query)
        host = headers.get("Host") or ""
        if self.loopback:
            parts = urlsplit(f"http://{host}")
            try:
                host_port = parts.port
            except ValueError:
                host_port = None
            name = (parts.hostname or "").lower()
            if not (_is_loopback(name) and host_port == port):
                return f"Host {host!r} is not this viewer (127.0.0.1:{port})", rest
        if (headers.get("Upgrade") or "").lower() == "websocket":
            origin = headers.get("Origin")
            if origin is None or origin.rstrip("/").lower() != f"http://{host}".lower():
                return f"Origin {origin!r} is not the viewer's own page", rest
        return None, rest

    def wrap_process_request(self, original: Callable[..., Any] | None) -> Callable[..., Any]:
        """A websockets ``process_request`` that checks, then hands on to ``original``."""
        from websockets.http11 import Request

        async def process_request(connection: Any, request: Any) -> Any:
            port = int(connection.local_address[1])
            refusal, rest = self.check(request.path, request.headers, port)
            if refusal is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"{refusal}\n")
            if original is None:
                return None
            result = original(connection, Request(path=rest, headers=request.headers))
            return await result if inspect.isawaitable(result) else result

        return process_request


@contextlib.contextmanager
def guarding_viser(guard: AccessGuard) -> Iterator[None]:
    """Make the viser server started inside check ``guard`` on every request.

    Wraps ``websockets.asyncio.server.serve`` (which viser calls from its server
    thread before ``ViserServer()`` returns) for the duration of the block only;
    ``guard.installed`` says afterwards whether viser went through it. A viser whose
    internals changed would leave it False: the caller must then stop the server
    rather than serve the capture unguarded.
    """
    import websockets.asyncio.server as ws_server

    original_serve = ws_server.serve

    def serve(*args: Any, **kwargs: Any) -> Any:
        kwargs["process_request"] = guard.wrap_process_request(kwargs.get("process_request"))
        guard.installed = True
        return original_serve(*args, **kwargs)

    ws_server.serve = serve  # type: ignore[misc,assignment]
    try:
        yield
    finally:
        ws_server.serve = original_serve  # type: ignore[misc]
