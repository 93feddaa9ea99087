"""A control panel served by the running process (``--web [HOST:]PORT``).

One page with live views (the input with detections drawn, the projector
pattern), live figures and a latency / particle-count chart, and buttons that do
what the report's keys did: light on/off, record start/stop, stop.  Views are
MJPEG streams encoded in the server's threads at a reduced rate from the latest
published frame -- the real-time loop only hands over references.  Binds to
127.0.0.1 unless a host is given; serves its page, its streams, ``/stats`` and
``/action/<name>`` and nothing else (no files); anything else gets a 4xx.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable

import cv2
import numpy as np

from .errors import UsageError

__all__ = ["ControlPanel", "parse_address"]


def parse_address(text: str) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` -> (host, port); the host defaults to 127.0.0.1 (this machine only)."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    try:
        port = int(port_text)
    except ValueError:
        raise UsageError(f"--web {text!r}: expected PORT or HOST:PORT, e.g. 8080 or 0.0.0.0:8080") from None
    if not 0 <= port <= 65535:
        raise UsageError(f"--web {text!r}: port {port} outside 0..65535")
    return host or "127.0.0.1", port


_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>antiscatter — {title}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
body {{ font-family: sans-serif; background: #111; color: #eee; margin: 1em; }}
.views {{ display: flex; gap: 1em; flex-wrap: wrap; }}
.views figure {{ margin: 0; }} img {{ max-width: 46vw; background: #222; border: 1px solid #444; }}
button {{ font-size: 1.1em; margin-right: .5em; padding: .4em 1em; }}
#stats td {{ padding: .1em .8em .1em 0; }} canvas {{ background: #1b1b1b; border: 1px solid #444; }}
</style></head><body>
<h1>antiscatter — {title}</h1>
<p><button id="light" onclick="act('light')">Light on/off</button>
<button id="record" onclick="act('record')">Record start/stop</button>
<button id="stop" onclick="act('stop')">Stop</button> <span id="status"></span></p>
<div class="views">
<figure><img id="input" src="/stream/input.mjpg" alt="input with detections"><figcaption>input, detections in red</figcaption></figure>
<figure><img id="pattern" src="/stream/pattern.mjpg" alt="projector pattern"><figcaption>projector pattern</figcaption></figure>
</div>
<table id="stats"></table>
<canvas id="chart" width="640" height="160"></canvas>
<script>
async function act(name) {{
  const r = await fetch('/action/' + name, {{method: 'POST'}});
  document.getElementById('status').textContent = r.ok ? (await r.json()).message : 'failed: ' + r.status;
}}
function draw(history) {{
  const c = document.getElementById('chart'), g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const series = [['latency_ms', '#f66'], ['particles', '#6cf']];
  for (const [key, colour] of series) {{
    const v = history.map(h => h[key]); if (!v.length) continue;
    const top = Math.max(...v, 1e-9); g.strokeStyle = colour; g.beginPath();
    v.forEach((y, i) => {{ const px = i * c.width / Math.max(v.length - 1, 1), py = c.height - 4 - y / top * (c.height - 8);
      i ? g.lineTo(px, py) : g.moveTo(px, py); }});
    g.stroke(); g.fillStyle = colour; g.fillText(key + ' (max ' + top.toFixed(1) + ')', 6, series.findIndex(s => s[0] == key) * 14 + 12);
  }}
}}
async function poll() {{
  try {{
    const s = await (await fetch('/stats')).json();
    const rows = Object.entries(s).filter(([k]) => k != 'history');
    document.getElementById('stats').innerHTML = rows.map(([k, v]) => '<tr><td>' + k + '</td><td id="stat-' + k + '">' +
      (typeof v == 'number' ? (Number.isInteger(v) ? v : v.toFixed(2)) : v) + '</td></tr>').join('');
    draw(s.history || []);
  }} catch (e) {{ document.getElementById('status').textContent = 'disconnected'; }}
  setTimeout(poll, 500);
}}
poll();
</script></body></html>
"""


class ControlPanel:
    """The web control panel of one run (see the module docstring).

    actions: button name -> function called from the server thread (keep it a flag flip).
    preview_fps: the streams' frame rate; jpeg_quality: 1..100.
    """

    def __init__(self, address: str, *, title: str, actions: dict[str, Callable[[], str]],
                 preview_fps: float = 10.0, jpeg_quality: int = 70) -> None:
        self.host, self.port = parse_address(address)
        self.title = title
        self.actions = actions
        self.preview_period = 1.0 / preview_fps
        self.jpeg_quality = jpeg_quality
        self._lock = threading.Condition()
        self._version = 0
        self._input: np.ndarray | None = None
        self._detections: Any = None
        self._pattern: np.ndarray | None = None
        self._stats: dict[str, Any] = {}
        self.history: collections.deque = collections.deque(maxlen=120)
        self.closed = False
        panel = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "antiscatter"
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def do_GET(self) -> None:  # noqa: N802
                if self.path == "/":
                    self._send(HTTPStatus.OK, "text/html; charset=utf-8",
                               _PAGE.format(title=panel.title).encode())
                elif self.path == "/stats":
                    self._send(HTTPStatus.OK, "application/json", json.dumps(panel.stats()).encode())
                elif self.path in ("/stream/input.mjpg", "/stream/pattern.mjpg"):
                    panel._stream(self, "input" if "input" in self.path else "pattern")
                else:
                    self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")

            def do_POST(self) -> None:  # noqa: N802
                length = self.headers.get("Content-Length", "0")
                if not length.isdigit() or int(length) > 1024:
                    self._send(HTTPStatus.BAD_REQUEST, "text/plain", b"bad request\n")
                    return
                self.rfile.read(int(length))
                name = self.path.removeprefix("/action/")
                if not self.path.startswith("/action/") or name not in panel.actions:
                    self._send(HTTPStatus.NOT_FOUND, "text/plain", b"no such action\n")
                    return
                message = panel.actions[name]()
                self._send(HTTPStatus.OK, "application/json", json.dumps({"message": message}).encode())

            def _refuse(self) -> None:
                self._send(HTTPStatus.METHOD_NOT_ALLOWED, "text/plain", b"method not allowed\n")

            do_PUT = do_DELETE = do_PATCH = _refuse  # noqa: N815

            def _send(self, status: HTTPStatus, kind: str, body: bytes) -> None:
                self.send_response(status)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

        try:
            self.server = ThreadingHTTPServer((self.host, self.port), Handler)
        except OSError as exc:
            raise UsageError(f"--web {address}: cannot listen on {self.host}:{self.port} ({exc.strerror})") from None
        self.server.daemon_threads = True
        self.port = self.server.server_address[1]
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="antiscatter-web", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    # --------------------------------------------------------- the loop's side
    def publish(self, *, image: np.ndarray | None = None, detections: Any = None,
                pattern: np.ndarray | None = None, stats: dict[str, Any] | None = None,
                sample: dict[str, float] | None = None) -> None:
        """Hand over the latest frame, particles, pattern and figures (references only, no copies)."""
        with self._lock:
            if image is not None:
                self._input, self._detections = image, detections
            if pattern is not None:
                self._pattern = pattern
            if stats is not None:
                self._stats = stats
            if sample is not None:
                self.history.append(sample)
            self._version += 1
            self._lock.notify_all()

    def stats(self) -> dict[str, Any]:
        with self._lock:
            return {**self._stats, "history": list(self.history)}

    # ------------------------------------------------------- the server's side
    def _jpeg(self, which: str) -> bytes | None:
        with self._lock:
            image, detections, pattern = self._input, self._detections, self._pattern
        if which == "pattern":
            if pattern is None:
                return None
            view = pattern
        else:
            if image is None:
                return None
            view = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
            if detections is not None:
                for (x, y), r in zip(detections.centres.tolist(), detections.radii.tolist()):
                    cv2.circle(view, (int(round(x)), int(round(y))), max(int(round(r)), 1), (0, 0, 255), 1)
        if view.shape[1] > 960:  # previews need no more
            scale = 960 / view.shape[1]
            view = cv2.resize(view, (960, int(round(view.shape[0] * scale))), interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".jpg", view, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        return data.tobytes() if ok else None

    def _stream(self, handler: BaseHTTPRequestHandler, which: str) -> None:
        boundary = "antiscatterframe"
        handler.send_response(HTTPStatus.OK)
        handler.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={boundary}")
        handler.send_header("Cache-Control", "no-store")
        handler.send_header("Connection", "close")
        handler.end_headers()
        seen = -1
        try:
            while not self.closed:
                with self._lock:
                    if self._version == seen:
                        self._lock.wait(1.0)
                    seen = self._version
                started = time.monotonic()
                data = self._jpeg(which)
                if data is not None:
                    handler.wfile.write(f"--{boundary}\r\nContent-Type: image/jpeg\r\n"
                                        f"Content-Length: {len(data)}\r\n\r\n".encode() + data + b"\r\n")
                    handler.wfile.flush()
                time.sleep(max(0.0, self.preview_period - (time.monotonic() - started)))
        except (BrokenPipeError, ConnectionResetError):
            pass
        handler.close_connection = True

    def __enter__(self) -> "ControlPanel":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.closed = True
        with self._lock:
            self._lock.notify_all()
        self.server.shutdown()
        self.server.server_close()
