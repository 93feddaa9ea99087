"""A control panel served by the running process (``--web [HOST:]PORT``).

One page, an operator's console: what runs (source, detector, strategy, frame
size and rate), live views (the input with detections drawn, the projector
pattern), live figures, a chart of latency and particle count on one time axis,
buttons that do what the report's keys did (light on/off, record start/stop,
stop), and controls for settings that apply from the next frame (the strategy's
hole level, the detector's sensitivity), each checked against its range.  Views are
MJPEG streams: each stream's JPEG is encoded once per preview frame, in a server
thread, from the latest published frame, and every viewer is sent the same bytes
-- the real-time loop only hands over references, however many watch.  Binds to
127.0.0.1 unless a host is given; serves its page, its streams, ``/stats`` and
``/controls``, ``/action/<name>`` and ``/control/<name>?value=V`` and nothing else (no files); anything else gets a 4xx.

Hardening: a request whose ``Host`` is not this panel's address is refused (403:
no DNS rebinding), as is one whose ``Origin`` is a foreign site; an action also
and a control need the run's token, which only the page carries (``X-Antiscatter-Token``), so
no other web page the operator opens can press a button.  Connections are
capped and time out when idle; request bodies, chunked transfer, other methods
and other HTTP versions are refused with a 4xx and the connection closed.
"""

from __future__ import annotations

import collections
import hmac
import ipaddress
import json
import secrets
import socket
import threading
import time
from http import HTTPStatus
import html
import math
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable
from urllib.parse import parse_qs, urlsplit

import cv2
import numpy as np

from .errors import UsageError

__all__ = ["ControlPanel", "Control", "parse_address"]

#: the header an action must carry the run's token in
TOKEN_HEADER = "X-Antiscatter-Token"
#: seconds after which a stream with no new frame sends its last one again
REPEAT_S = 1.0
_LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
_WILDCARDS = frozenset({"0.0.0.0", "::", ""})


def parse_address(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); the host defaults to 127.0.0.1 (this machine)."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        raise UsageError(f"--web {text!r}: expected PORT or HOST:PORT, e.g. 8080 or 0.0.0.0:8080") from None
    if not 0 <= port <= 65535:
        raise UsageError(f"--web {text!r}: port {port} outside 0..65535")
    return host or "127.0.0.1", port


def _split_host(value: str) -> tuple[str, int | None]:
    """A ``Host`` header's (name, port): the name lower-cased, unbracketed; the port 80 if absent, None if bad."""
    value = value.strip().lower()
    if value.startswith("["):  # [v6] or [v6]:port
        name, _, rest = value[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ("" if not rest else "x")
    else:
        name, sep, port_text = value.rpartition(":")
        if not sep:
            name, port_text = value, ""
    if not port_text:
        return name, 80
    return name, int(port_text) if port_text.isdigit() else None


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Control:
    """A setting the operator may change while the run goes on (a number in ``low..high``).

    label: what the page calls it; unit: shown beside it ("" for none); step: the input's step.
    get: its value now; set: applies a checked value from the next frame, returns the message shown.
    """

    label: str
    unit: str
    low: float
    high: float
    step: float
    get: Callable[[], float]
    set: Callable[[float], str]

    def check(self, text: str) -> float:
        """``text`` as a value in range, or ValueError with the one-line message the page shows."""
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and self.low <= value <= self.high):
            unit = f" {self.unit}" if self.unit else ""
            raise ValueError(f"{self.label}: got {text!r}, allowed {self.low:g} to {self.high:g}{unit}")
        return value


_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>antiscatter — {title}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="antiscatter-token" content="{token}">
<style>
body {{ font-family: sans-serif; background: #111; color: #eee; margin: 1em; }}
.views {{ display: flex; gap: 1em; flex-wrap: wrap; }}
.views figure {{ margin: 0; }} img {{ max-width: 46vw; background: #222; border: 1px solid #444; }}
button {{ font-size: 1.1em; margin-right: .5em; padding: .4em 1em; }}
#stats td, #info td {{ padding: .1em .8em .1em 0; }} #info td:first-child {{ color: #999; }}
canvas {{ background: #1b1b1b; border: 1px solid #444; }}
#controls label {{ margin-right: .4em; }} #controls input {{ width: 5em; margin-right: .3em; }}
#status.error {{ color: #f66; }}
</style></head><body>
<h1>antiscatter — {title}</h1>
<table id="info">{info}</table>
<p><button id="light" onclick="act('light')">Light on/off</button>
<button id="record" onclick="act('record')">Record start/stop</button>
<button id="stop" onclick="act('stop')">Stop</button> <span id="status"></span></p>
<div class="views">
<figure><img id="input" src="/stream/input.mjpg" alt="input with detections"><figcaption>input, detections in red</figcaption></figure>
<figure><img id="pattern" src="/stream/pattern.mjpg" alt="projector pattern"><figcaption>projector pattern</figcaption></figure>
</div>
<form id="controls" onsubmit="return false"></form>
<table id="stats"></table>
<canvas id="chart" width="720" height="300"></canvas>
<script>
const TOKEN = document.querySelector('meta[name="antiscatter-token"]').content;
function say(text, error) {{
  const e = document.getElementById('status'); e.textContent = text; e.className = error ? 'error' : '';
}}
async function post(path) {{
  const r = await fetch(path, {{method: 'POST', headers: {{'{header}': TOKEN}}}});
  let message = 'failed: ' + r.status;
  try {{ message = (await r.json()).message; }} catch (e) {{}}
  say(message, !r.ok);
}}
function act(name) {{ return post('/action/' + name); }}
function setControl(name) {{
  return post('/control/' + name + '?value=' + encodeURIComponent(document.getElementById('control-' + name).value));
}}
async function controls() {{
  const list = await (await fetch('/controls')).json();
  document.getElementById('controls').innerHTML = list.map(c =>
    '<label for="control-' + c.name + '">' + c.label + (c.unit ? ' (' + c.unit + ')' : '') + '</label>' +
    '<input id="control-' + c.name + '" type="number" step="' + c.step + '" value="' + c.value + '">' +
    '<button id="set-' + c.name + '" data-name="' + c.name + '" onclick="setControl(this.dataset.name)">Set</button> ').join('');
}}
function nice(top) {{  // an axis maximum of 1, 2 or 5 times a power of ten
  const p = Math.pow(10, Math.floor(Math.log10(Math.max(top, 1e-9))));
  return [1, 2, 5, 10].map(m => m * p).find(v => v >= top);
}}
function draw(history) {{
  // one panel a series, one time axis (seconds before the last sample) under both
  const c = document.getElementById('chart'), g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height); g.font = '11px sans-serif';
  const series = [['latency_ms', 'latency', 'ms', '#f66'], ['particles', 'particles', 'a frame', '#6cf']];
  const left = 52, right = c.width - 8, bottom = c.height - 22, gap = 16;
  const height = (bottom - 8 - gap) / series.length;
  const t = history.map(h => h.t), last = t.length ? t[t.length - 1] : 0;
  const span = Math.max(t.length ? last - t[0] : 1, 1);
  const x = v => right - (last - v) / span * (right - left);
  series.forEach(([key, name, unit, colour], k) => {{
    const top = 8 + k * (height + gap), v = history.map(h => h[key]);
    const max = nice(Math.max(...v, 0));
    const y = value => top + height - value / max * height;
    g.strokeStyle = '#555'; g.fillStyle = '#aaa'; g.beginPath();
    for (const tick of [0, max / 2, max]) {{
      g.moveTo(left, y(tick)); g.lineTo(right, y(tick)); g.fillText(String(+tick.toPrecision(3)), 4, y(tick) + 4);
    }}
    g.stroke(); g.fillStyle = colour; g.fillText(name + ' (' + unit + ')', left + 4, top + 10);
    g.strokeStyle = colour; g.beginPath();
    history.forEach((h, i) => {{ i ? g.lineTo(x(h.t), y(h[key])) : g.moveTo(x(h.t), y(h[key])); }});
    g.stroke();
  }});
  g.fillStyle = '#aaa';
  for (let k = 0; k <= 4; k++) {{
    const ago = span * k / 4; g.fillText('-' + ago.toFixed(ago < 10 ? 1 : 0) + ' s', x(last - ago) - 14, c.height - 6);
  }}
}}
async function poll() {{
  try {{
    const s = await (await fetch('/stats')).json();
    const rows = Object.entries(s).filter(([k]) => k != 'history');
    document.getElementById('stats').innerHTML = rows.map(([k, v]) => '<tr><td>' + k + '</td><td id="stat-' + k + '">' +
      (typeof v == 'number' ? (Number.isInteger(v) ? v : v.toFixed(2)) : v) + '</td></tr>').join('');
    draw(s.history || []);
  }} catch (e) {{ say('disconnected', true); }}
  setTimeout(poll, 500);
}}
controls();
poll();
</script></body></html>
"""

_BUSY_BODY = b"503 Service Unavailable: too many connections\n"
_BUSY = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: %d\r\n"
         b"Retry-After: 5\r\nConnection: close\r\n\r\n%s" % (len(_BUSY_BODY), _BUSY_BODY))


class _Server(ThreadingHTTPServer):
    """A thread per connection, at most ``max_connections`` of them; the rest get 503 at once."""

    daemon_threads = True
    request_queue_size = 128  # a page's viewers connect together

    def __init__(self, address: tuple[str, int], handler: type, *, max_connections: int) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.max_connections = max_connections
        self.connections: set[socket.socket] = set()
        self._connections_lock = threading.Lock()
        super().__init__(address, handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        with self._connections_lock:
            full = len(self.connections) >= self.max_connections
            if not full:
                self.connections.add(request)
        if not full:
            super().process_request(request, client_address)
            return
        try:  # a few bytes into a fresh socket's empty buffer: never blocks the accepting thread
            request.setblocking(False)
            request.send(_BUSY)
        except OSError:
            pass
        self.shutdown_request(request)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._connections_lock:
                self.connections.discard(request)

    def close_connections(self) -> None:
        """Cut every open connection (idle keep-alives, streams): their threads end at once."""
        with self._connections_lock:
            connections = list(self.connections)
        for connection in connections:
            try:
                connection.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class _Encoding:
    """One stream's latest JPEG, shared by all its viewers (``seq`` counts the encodings)."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.seq = 0
        self.data = b""
        self.version = -1  # the published frame it was made from
        self.stamp = float("-inf")  # time.monotonic() of the last encoding attempt, seconds
        self.busy = False


class ControlPanel:
    """The web control panel of one run (see the module docstring).

    Parameters
    ----------
    address : str
        ``[HOST:]PORT``; the port is bound here, so a bad or busy one fails before anything else.
    title : str
        Shown in the page's title.
    actions : dict
        Button name -> function called from a server thread, returning the message shown (keep it
        a flag flip).  May be filled in before ``start()``.
    controls : dict
        Name -> :class:`Control`: settings the page offers; a value out of range is refused (400)
        with its message.  May be filled in before ``start()``.
    info : dict
        What runs (label -> text: source, detector, strategy, frame size and rate), shown at the
        page's top.  May be filled in before ``start()``.
    preview_fps : float
        Frames per second of each stream, default 10 (encoded once each, whatever the viewers).
    jpeg_quality : int
        1..100, default 70.
    max_connections : int
        Open connections at most, default 64; more get 503 (bounds the server's threads).
    idle_timeout_s : float
        Seconds a connection may sit idle or half-sent (or a viewer not read) before it is
        closed, default 10.
    start : bool
        Serve at once (default); False binds the port only, for ``start()`` once the actions exist.
    """

    def __init__(self, address: str, *, title: str, actions: dict[str, Callable[[], str]] | None = None,
                 controls: dict[str, Control] | None = None, info: dict[str, str] | None = None,
                 preview_fps: float = 10.0, jpeg_quality: int = 70, max_connections: int = 64,
                 idle_timeout_s: float = 10.0, start: bool = True) -> None:
        self.host, self.port = parse_address(address)
        if max_connections < 1:
            raise ValueError(f"max_connections: got {max_connections}, allowed >= 1")
        if not idle_timeout_s > 0:
            raise ValueError(f"idle_timeout_s: got {idle_timeout_s}, allowed > 0")
        self.title = title
        self.actions = {} if actions is None else actions
        self.controls = {} if controls is None else controls
        self.info = {} if info is None else info
        self.preview_period = 1.0 / preview_fps
        self.jpeg_quality = jpeg_quality
        self.token = secrets.token_urlsafe(24)  # per run: only the page (same origin) can read it
        self._lock = threading.Lock()
        self._version = 0
        self._input: np.ndarray | None = None
        self._detections: Any = None
        self._pattern: np.ndarray | None = None
        self._stats: dict[str, Any] = {}
        self._encodings = {"input": _Encoding(), "pattern": _Encoding()}
        self.history: collections.deque = collections.deque(maxlen=120)
        self.closed = False
        handler = _make_handler(self, idle_timeout_s)
        try:
            self.server = _Server((self.host, self.port), handler, max_connections=max_connections)
        except (OSError, OverflowError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            raise UsageError(f"--web {address}: cannot listen on {self.host}:{self.port} ({reason})") from None
        self.port = self.server.server_address[1]
        self.hosts = self._accepted_hosts()
        self._thread: threading.Thread | None = None
        if start:
            self.start()

    def start(self) -> None:
        """Serve requests (in a daemon thread) on the port bound at construction."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.2},
                                            name="antiscatter-web", daemon=True)
            self._thread.start()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _accepted_hosts(self) -> frozenset[str]:
        """Names a request's ``Host`` may give: loopback, the bound host, and for a wildcard bind this
        machine's name (IP literals are accepted too then: a rebinding attack needs a domain name)."""
        names = set(_LOOPBACK_NAMES) | {self.host.lower()}
        if self.host in _WILDCARDS:
            hostname = socket.gethostname().lower()
            names |= {hostname, f"{hostname}.local"}
        return frozenset(names)

    def host_allowed(self, value: str) -> bool:
        """Whether a ``Host`` header (``name[:port]``) names this panel: an accepted name and its port."""
        name, port = _split_host(value)
        if port != self.port:
            return False
        return name in self.hosts or (self.host in _WILDCARDS and _is_ip(name))

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

    def page(self) -> str:
        """The page, with what runs (``info``) filled in."""
        info = "".join(f"<tr><td>{html.escape(k)}</td><td id=\"info-{html.escape(k.replace(' ', '-'))}\">"
                       f"{html.escape(str(v))}</td></tr>" for k, v in self.info.items())
        return _PAGE.format(title=html.escape(self.title), token=self.token, header=TOKEN_HEADER, info=info)

    def control_list(self) -> list[dict[str, Any]]:
        """The controls with their ranges and values now (what ``/controls`` serves)."""
        return [{"name": name, "label": c.label, "unit": c.unit, "low": c.low, "high": c.high, "step": c.step,
                 "value": c.get()} for name, c in self.controls.items()]

    def set_control(self, name: str, text: str) -> tuple[bool, str]:
        """(accepted, message): ``text`` checked against control ``name``'s range, then applied."""
        control = self.controls[name]
        try:
            value = control.check(text)
        except ValueError as exc:
            return False, str(exc)
        return True, control.set(value)

    def stats(self) -> dict[str, Any]:
        """The latest figures and the chart's history (what ``/stats`` serves)."""
        with self._lock:
            return {**self._stats, "history": list(self.history)}

    # ------------------------------------------------------- the server's side
    def _jpeg(self, which: str) -> tuple[int, bytes | None]:
        """(published version, JPEG of that stream's latest frame or None before the first)."""
        with self._lock:
            version, image, detections, pattern = self._version, self._input, self._detections, self._pattern
        if which == "pattern":
            if pattern is None:
                return version, None
            view = pattern
        else:
            if image is None:
                return version, None
            view = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
            if detections is not None:
                for (x, y), r in zip(detections.centres.tolist(), detections.radii.tolist()):
                    cv2.circle(view, (int(round(x)), int(round(y))), max(int(round(r)), 1), (0, 0, 255), 1)
        if view.shape[1] > 960:  # previews need no more
            scale = 960 / view.shape[1]
            view = cv2.resize(view, (960, int(round(view.shape[0] * scale))), interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".jpg", view, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        return version, (data.tobytes() if ok else None)

    def next_jpeg(self, which: str, sent: int) -> tuple[int, bytes] | None:
        """The stream's first encoding newer than ``sent`` (its ``seq``), shared by all viewers.

        Waits for it; the first viewer to find the stream due (a preview period since the last
        encoding, and a new frame published) encodes it for everyone.  With no new frame for
        ``REPEAT_S`` the last one is given again (the viewer sees the stream alive).  None once the
        panel closes.
        """
        shared = self._encodings[which]
        repeat_at = time.monotonic() + REPEAT_S
        while True:
            with shared.cond:
                while True:
                    if self.closed:
                        return None
                    if shared.seq > sent or (shared.seq and time.monotonic() >= repeat_at):
                        return shared.seq, shared.data
                    wait = shared.stamp + self.preview_period - time.monotonic()
                    if shared.busy:
                        shared.cond.wait(1.0)
                    elif wait > 0:
                        shared.cond.wait(wait)
                    elif self._version == shared.version:  # (read without the lock: a stale value only delays)
                        shared.cond.wait(self.preview_period)
                    else:
                        shared.busy = True
                        break
            version, data = shared.version, None
            try:
                version, data = self._jpeg(which)
            finally:
                with shared.cond:
                    shared.busy = False
                    shared.stamp = time.monotonic()
                    if data is not None:
                        shared.seq, shared.data, shared.version = shared.seq + 1, data, version
                    shared.cond.notify_all()

    def _stream(self, handler: BaseHTTPRequestHandler, which: str) -> None:
        """Serve one viewer the stream's shared encodings as MJPEG until it leaves or the panel closes."""
        boundary = "antiscatterframe"
        handler.send_response(HTTPStatus.OK)
        handler.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={boundary}")
        handler.send_header("Cache-Control", "no-store")
        handler.send_header("Connection", "close")
        handler.end_headers()
        sent = 0
        try:
            while (latest := self.next_jpeg(which, sent)) is not None:
                sent, data = latest
                handler.wfile.write(f"--{boundary}\r\nContent-Type: image/jpeg\r\n"
                                    f"Content-Length: {len(data)}\r\n\r\n".encode() + data + b"\r\n")
        except OSError:  # the viewer went away, or stopped reading for the idle timeout
            pass
        handler.close_connection = True

    def __enter__(self) -> "ControlPanel":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop serving, end every stream and connection, free the port."""
        self.closed = True
        for shared in self._encodings.values():
            with shared.cond:
                shared.cond.notify_all()
        if self._thread is not None:
            self.server.shutdown()
        self.server.close_connections()
        self.server.server_close()


def _make_handler(panel: ControlPanel, idle_timeout_s: float) -> type[BaseHTTPRequestHandler]:
    """The request handler of ``panel``: checks every request, then serves the page, streams, stats, actions."""

    class Handler(BaseHTTPRequestHandler):
        server_version = "antiscatter"
        protocol_version = "HTTP/1.1"
        timeout = idle_timeout_s  # every read and write on the connection

        def log_message(self, *args: Any) -> None:  # quiet
            pass

        def parse_request(self) -> bool:
            """The request line and headers, then what every request must pass (else a 4xx, closed)."""
            if not super().parse_request():
                return False
            headers = self.headers
            if self.request_version not in ("HTTP/1.0", "HTTP/1.1"):
                return self._refuse(HTTPStatus.BAD_REQUEST, f"unsupported version {self.request_version}")
            if self.command not in ("GET", "POST"):
                return self._refuse(HTTPStatus.METHOD_NOT_ALLOWED, f"method {self.command} not allowed",
                                    allow="GET, POST")
            if "Transfer-Encoding" in headers:  # no bodies taken, so no chunked ones to frame
                return self._refuse(HTTPStatus.LENGTH_REQUIRED, "no request bodies are taken")
            lengths = headers.get_all("Content-Length") or []
            if len(lengths) > 1 or not all(v.strip().isdigit() for v in lengths):
                return self._refuse(HTTPStatus.BAD_REQUEST, "bad Content-Length")
            if lengths and int(lengths[0]) > 0:
                return self._refuse(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "no request bodies are taken")
            hosts = headers.get_all("Host") or []
            if len(hosts) != 1:
                return self._refuse(HTTPStatus.BAD_REQUEST, "expected one Host header")
            if not panel.host_allowed(hosts[0]):
                return self._refuse(HTTPStatus.FORBIDDEN, "Host is not this panel's address")
            origin = headers.get("Origin")
            if origin is not None and origin.strip().lower() != "http://" + hosts[0].strip().lower():
                return self._refuse(HTTPStatus.FORBIDDEN, "foreign Origin")
            return True

        def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
            if code == HTTPStatus.HTTP_VERSION_NOT_SUPPORTED:  # a 4xx: the client's request is at fault
                code, message = HTTPStatus.BAD_REQUEST, message or "unsupported HTTP version"
            if self.request_version == "HTTP/0.9" and len(self.requestline.split()) == 3:
                self.request_version = "HTTP/1.0"  # a version was given, if a bad one: answer with a status line
            super().send_error(code, message, explain)

        def do_GET(self) -> None:  # noqa: N802
            if self.path == "/":
                self._send(HTTPStatus.OK, "text/html; charset=utf-8", panel.page().encode())
            elif self.path == "/controls":
                self._send(HTTPStatus.OK, "application/json", json.dumps(panel.control_list()).encode())
            elif self.path == "/stats":
                self._send(HTTPStatus.OK, "application/json", json.dumps(panel.stats()).encode())
            elif self.path in ("/stream/input.mjpg", "/stream/pattern.mjpg"):
                panel._stream(self, "input" if "input" in self.path else "pattern")
            else:
                self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")

        def do_POST(self) -> None:  # noqa: N802
            url = urlsplit(self.path)
            kind, _, name = url.path.lstrip("/").partition("/")
            known = panel.actions if kind == "action" else panel.controls if kind == "control" else {}
            if name not in known or (kind == "action" and url.query):
                self._send(HTTPStatus.NOT_FOUND, "text/plain", f"no such {kind or 'action'}\n".encode())
                return
            token = self.headers.get(TOKEN_HEADER, "")
            if not hmac.compare_digest(token.encode("utf-8", "replace"), panel.token.encode()):
                self._refuse(HTTPStatus.FORBIDDEN, f"missing or wrong {TOKEN_HEADER}")
                return
            if kind == "action":
                ok, message = True, panel.actions[name]()
            else:
                values = parse_qs(url.query, keep_blank_values=True).get("value", [])
                ok, message = (panel.set_control(name, values[0]) if len(values) == 1
                               else (False, f"{name}: expected one ?value="))
            self._send(HTTPStatus.OK if ok else HTTPStatus.BAD_REQUEST, "application/json",
                       json.dumps({"message": message}).encode())

        def _refuse(self, status: HTTPStatus, reason: str, *, allow: str = "") -> bool:
            """Answer ``status`` with ``reason`` and close the connection; returns False (request refused)."""
            body = f"{status.value} {status.phrase}: {reason}\n".encode()
            self.send_response(status)
            if allow:
                self.send_header("Allow", allow)
            self.send_header("Content-Type", "text/plain; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Connection", "close")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)
            return False

        def _send(self, status: HTTPStatus, kind: str, body: bytes) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

    return Handler
