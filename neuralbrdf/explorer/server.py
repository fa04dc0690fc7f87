"""The viewer's local web server: one page, plotly.js, and the views as JSON (the standard library's
:class:`http.server.ThreadingHTTPServer`; nothing is fetched from the internet).

=====================  ==================================================================
path                   answer
=====================  ==================================================================
``/``                  the page (``static/index.html``, ``viewer.js``, ``viewer.css``)
``/plotly.min.js``     plotly.js as the ``plotly`` Python package ships it
``/api/scene``         the sources, the measurement, the controls and what each view depends on
``/api/views``         ``?views=NAME,...&CONTROL=VALUE...[&known=NAME:KEY,...]``: those views at
                       that state, each with its key and the server's time to compute it
                       (``server_ms``); ``{"unchanged": true}`` for a view whose key is known
=====================  ==================================================================

A bad query is answered with status 400 and ``{"error": ONE LINE}``.  The server binds to
``127.0.0.1`` unless told otherwise; port 0 asks the system for a free port.

**From outside.**  A request is answered only when its ``Host`` header names the viewer's own port
with an IP address, ``localhost`` or the host it was bound to (status 403 otherwise), so a page on
another site cannot read the scene through DNS rebinding, as local development servers refuse it.
At most :data:`MAX_WORKERS` requests are served at once (more wait in a listen backlog of
:data:`BACKLOG`), and a connection that sends nothing for :data:`SOCKET_TIMEOUT_S` seconds is
closed, so neither a burst of requests nor half-open connections exhaust the process.
"""

from __future__ import annotations

import errno
import ipaddress
import json
import socket
import socketserver
import sys
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

from neuralbrdf.errors import InputError, one_line
from neuralbrdf.explorer.views import Scene

STATIC = Path(__file__).with_name("static")
#: Files of the page: URL path -> (file under ``static/``, content type).
PAGE_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
    "/viewer.css": ("viewer.css", "text/css; charset=utf-8"),
}
PLOTLY_PATH = "/plotly.min.js"
DEFAULT_HOST = "127.0.0.1"
#: Requests served at once, the connections the system queues beyond them, and the seconds a
#: connection may stay silent (module docstring).
MAX_WORKERS = 32
BACKLOG = 256
SOCKET_TIMEOUT_S = 10.0


def plotly_js() -> bytes:
    """The plotly.js bundle shipped inside the ``plotly`` package (for offline use)."""
    return (resources.files("plotly") / "package_data" / "plotly.min.js").read_bytes()


class _Server(ThreadingHTTPServer):
    daemon_threads = True  # a browser's open connections never keep the process alive
    request_queue_size = BACKLOG

    def __init__(self, address, scene: Scene) -> None:
        self.scene = scene
        self.host_given = address[0].lower()
        self._workers = threading.BoundedSemaphore(MAX_WORKERS)
        self.files = {path: ((STATIC / name).read_bytes(), kind) for path, (name, kind) in PAGE_FILES.items()}
        self.files[PLOTLY_PATH] = (plotly_js(), "text/javascript; charset=utf-8")
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        super().__init__(address, _Handler)

    def server_bind(self) -> None:
        """Bind without :class:`~http.server.HTTPServer`'s reverse name lookup of the host (a DNS query
        that can hang on a machine without a network)."""
        socketserver.TCPServer.server_bind(self)
        self.server_name, self.server_port = self.server_address[:2]

    def process_request(self, request, client_address) -> None:
        """Serve in a new thread once one of the :data:`MAX_WORKERS` is free (until then the
        connection waits, and the ones behind it wait in the backlog)."""
        self._workers.acquire()
        try:
            super().process_request(request, client_address)
        except RuntimeError:  # no thread could be started: its slot is free again (a Ctrl-C while one
            self._workers.release()  # starts is not caught: that thread runs and frees its own slot)
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._workers.release()

    def addressed_here(self, host_header: str | None) -> bool:
        """Whether a request's ``Host`` names this viewer (module docstring)."""
        if not host_header:
            return False
        host, _, port = host_header.rpartition(":")
        if not port.isdigit() or int(port) != self.server_port:
            return False
        host = host.removeprefix("[").removesuffix("]").lower()
        if host in ("localhost", self.host_given):
            return True
        try:
            ipaddress.ip_address(host)
        except ValueError:
            return False
        return True


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    timeout = SOCKET_TIMEOUT_S

    def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
        try:
            if not self.server.addressed_here(self.headers.get("Host")):
                self._json(HTTPStatus.FORBIDDEN, {"error": f"this viewer answers requests to its own address (port "
                                                           f"{self.server.server_port}), not to Host "
                                                           f"{str(self.headers.get('Host'))[:100]!r}"})
                return
            self._answer(urlsplit(self.path))
        except (BrokenPipeError, ConnectionResetError):  # the page went away: nobody to answer
            pass
        except Exception as error:  # a defect: one line to the terminal and to the page, never a traceback
            print(f"neuralbrdf view: error: {self.path}: {one_line(error)}", file=sys.stderr, flush=True)
            self._json(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": one_line(error)})

    def _answer(self, url) -> None:
        if url.path in self.server.files:
            body, kind = self.server.files[url.path]
            self._send(HTTPStatus.OK, body, kind, cache=url.path == PLOTLY_PATH)
        elif url.path == "/api/scene":
            self._json(HTTPStatus.OK, self.server.scene.describe())
        elif url.path == "/api/views":
            try:
                self._json(HTTPStatus.OK, self._views(dict(parse_qsl(url.query))))
            except InputError as error:
                self._json(HTTPStatus.BAD_REQUEST, {"error": str(error)})
        else:
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page {url.path!r}"})

    def _views(self, query: dict[str, str]) -> dict:
        scene = self.server.scene
        state = scene.defaults.updated(query)
        known = dict(entry.split(":", 1) for entry in query.get("known", "").split(",") if ":" in entry)
        answer = {}
        for name in filter(None, query.get("views", "").split(",")):
            start = time.perf_counter()
            payload = dict(scene.view(name, state, known.get(name)))
            payload["server_ms"] = round(1e3 * (time.perf_counter() - start), 2)
            answer[name] = payload
        return {"views": answer}

    def _json(self, status: HTTPStatus, payload: dict) -> None:
        self._send(status, json.dumps(payload, allow_nan=False).encode("utf-8"), "application/json")

    def _send(self, status: HTTPStatus, body: bytes, kind: str, cache: bool = False) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format, *args) -> None:  # noqa: A002 (the standard library's signature)
        """Requests are not logged: the terminal shows only the address and the stop."""


class Viewer:
    """A running viewer of ``scene`` at :attr:`url`: :meth:`serve_forever` in the calling thread
    (the command line), or :meth:`start` in a background thread (Python), then :meth:`stop`."""

    def __init__(self, scene: Scene, host: str = DEFAULT_HOST, port: int = 0) -> None:
        if not 0 <= port <= 65535:
            raise InputError(f"expected a port from 0 to 65535 (0: a free one), got {port}", key="--port")
        try:
            self._server = _Server((host, port), scene)
        except OSError as error:
            reason = "the port is in use (0 picks a free one)" if error.errno == errno.EADDRINUSE else (
                error.strerror or str(error))
            raise InputError(f"cannot listen on {host} port {port}: {reason}", key="--port") from None
        self.scene = scene
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` the socket is bound to."""
        return self._server.server_address[:2]

    @property
    def url(self) -> str:
        host, port = self.address
        return f"http://{f'[{host}]' if ':' in host else host}:{port}/"

    def serve_forever(self) -> None:
        """Answer requests until :meth:`stop` (from another thread) or an exception (Ctrl-C)."""
        self._server.serve_forever()

    def start(self) -> Viewer:
        """Answer requests in a background thread; returns at once."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.serve_forever, name="neuralbrdf-view", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop answering and close the socket."""
        if self._thread is not None:
            self._server.shutdown()
            self._thread.join()
            self._thread = None
        self._server.server_close()

    def __enter__(self) -> Viewer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def __repr__(self) -> str:
        return f"Viewer({self.url!r}, {len(self.scene.sources)} sources)"
