"""The control panel under attack: Host / Origin / token checks, strict HTTP framing, bounded
connections, its port bound before the run starts, and panel recordings that never overwrite a
file nor stop the run."""

import csv
import http.client
import io
import json
import re
import socket
import threading
import time
import urllib.request

import numpy as np
import pytest

from antiscatter.sources.simulated import SimulatorSource
from antiscatter.web import TOKEN_HEADER, ControlPanel

from conftest import run_cli

IDLE_S = 0.5  # the panels' idle timeout here, seconds


@pytest.fixture
def panel():
    light = {"on": True}

    def toggle() -> str:
        light["on"] = not light["on"]
        return f"light {'on' if light['on'] else 'off'}"

    p = ControlPanel("0", title="test", actions={"light": toggle}, idle_timeout_s=IDLE_S, max_connections=4)
    p.light = light
    yield p
    p.close()


def exchange(panel, data: bytes, *, timeout: float = 5.0) -> bytes:
    """Send raw bytes, read until the server closes the connection (or ``timeout`` passes)."""
    with socket.create_connection((panel.host, panel.port), timeout=timeout) as s:
        s.sendall(data)
        reply = b""
        try:
            while chunk := s.recv(65536):
                reply += chunk
        except (TimeoutError, ConnectionResetError):
            pass
    return reply


def status_of(reply: bytes) -> int:
    match = re.match(rb"HTTP/1\.[01] (\d{3}) ", reply)
    assert match, reply[:200]
    return int(match.group(1))


def request(panel, method: str, path: str, headers: dict[str, str]) -> bytes:
    """One request with exactly these headers (``Host`` included when given), no body."""
    lines = [f"{method} {path} HTTP/1.1", *(f"{k}: {v}" for k, v in headers.items()), "Connection: close"]
    return exchange(panel, ("\r\n".join(lines) + "\r\n\r\n").encode())


def own(panel) -> str:
    return f"127.0.0.1:{panel.port}"


# --------------------------------------------------------------------- Host, Origin, token
ACTION_CASES = [  # (case, headers given the panel, expected status, light on afterwards)
    ("valid token", lambda p: {"Host": own(p), TOKEN_HEADER: p.token}, 200, False),
    ("valid token, own origin", lambda p: {"Host": own(p), "Origin": f"http://{own(p)}", TOKEN_HEADER: p.token},
     200, False),
    ("localhost", lambda p: {"Host": f"localhost:{p.port}", "Origin": f"http://localhost:{p.port}",
                             TOKEN_HEADER: p.token}, 200, False),
    ("foreign origin", lambda p: {"Host": own(p), "Origin": "http://evil.example", TOKEN_HEADER: p.token}, 403, True),
    ("foreign origin, same host other port", lambda p: {"Host": own(p), "Origin": "http://127.0.0.1:1",
                                                        TOKEN_HEADER: p.token}, 403, True),
    ("null origin", lambda p: {"Host": own(p), "Origin": "null", TOKEN_HEADER: p.token}, 403, True),
    ("foreign host", lambda p: {"Host": f"evil.example:{p.port}", TOKEN_HEADER: p.token}, 403, True),
    ("rebound host and origin", lambda p: {"Host": f"evil.example:{p.port}", "Origin": f"http://evil.example:{p.port}",
                                           TOKEN_HEADER: p.token}, 403, True),
    ("missing token", lambda p: {"Host": own(p)}, 403, True),
    ("missing token, own origin", lambda p: {"Host": own(p), "Origin": f"http://{own(p)}"}, 403, True),
    ("wrong token", lambda p: {"Host": own(p), TOKEN_HEADER: p.token[:-1] + "x"}, 403, True),
    ("no host", lambda p: {TOKEN_HEADER: p.token}, 400, True),
]


@pytest.mark.parametrize("case, headers, code, light_on", ACTION_CASES, ids=[c[0] for c in ACTION_CASES])
def test_action_needs_own_host_origin_and_token(panel, case, headers, code, light_on):
    reply = request(panel, "POST", "/action/light", {**headers(panel), "Content-Length": "0"})
    assert status_of(reply) == code
    assert panel.light["on"] is light_on
    if code == 200:
        assert json.loads(reply.split(b"\r\n\r\n", 1)[1])["message"] == "light off"


GET_CASES = [  # (case, Host header, extra headers, expected status)
    ("own host", "127.0.0.1:{port}", {}, 200),
    ("localhost", "localhost:{port}", {}, 200),
    ("ipv6 loopback", "[::1]:{port}", {}, 200),
    ("foreign host", "evil.example:{port}", {}, 403),
    ("foreign host, no port", "evil.example", {}, 403),
    ("own host, other port", "127.0.0.1:1", {}, 403),
    ("foreign origin", "127.0.0.1:{port}", {"Origin": "http://evil.example"}, 403),
]


@pytest.mark.parametrize("case, host, extra, code", GET_CASES, ids=[c[0] for c in GET_CASES])
@pytest.mark.parametrize("path", ["/stats", "/"])
def test_reads_need_own_host(panel, case, host, extra, code, path):
    reply = request(panel, "GET", path, {"Host": host.format(port=panel.port), **extra})
    assert status_of(reply) == code


@pytest.mark.parametrize("bind, host, allowed", [
    ("127.0.0.1", "127.0.0.1:{port}", True), ("127.0.0.1", "LOCALHOST:{port}", True),
    ("127.0.0.1", "192.168.1.5:{port}", False), ("127.0.0.1", "127.0.0.1", False),
    ("127.0.0.1", "127.0.0.1:{port}0", False), ("127.0.0.1", "127.0.0.1:x", False),
    ("0.0.0.0", "192.168.1.5:{port}", True), ("0.0.0.0", "[fe80::1]:{port}", True),
    ("0.0.0.0", "evil.example:{port}", False), ("0.0.0.0", "192.168.1.5:1", False),
])
def test_accepted_hosts(bind, host, allowed):
    p = ControlPanel(f"{bind}:0", title="t", start=False)  # (bound, not served)
    try:
        assert p.host_allowed(host.format(port=p.port)) is allowed
    finally:
        p.close()


def test_page_carries_the_token_and_the_script_sends_it(panel):
    page = request(panel, "GET", "/", {"Host": own(panel)}).decode()
    assert f'<meta name="antiscatter-token" content="{panel.token}">' in page
    assert f"'{TOKEN_HEADER}': TOKEN" in page
    other = ControlPanel("0", title="other")
    try:
        assert other.token != panel.token and len(panel.token) >= 24  # one per run
    finally:
        other.close()


# ------------------------------------------------------------------------- HTTP framing
def raw(panel, head: str) -> bytes:
    return (head.format(host=own(panel), token=panel.token).replace("\n", "\r\n") + "\r\n").encode()


FRAMING_CASES = [  # (case, raw request, expected status, Allow header expected)
    ("HEAD", "HEAD / HTTP/1.1\nHost: {host}\n", 405, True),
    ("OPTIONS", "OPTIONS /action/light HTTP/1.1\nHost: {host}\n", 405, True),
    ("unknown method", "BREW /pot HTTP/1.1\nHost: {host}\n", 405, True),
    ("PUT", "PUT / HTTP/1.1\nHost: {host}\nContent-Length: 0\n", 405, True),
    ("HTTP/2.0", "GET /stats HTTP/2.0\nHost: {host}\n", 400, False),
    ("HTTP/1.2", "GET /stats HTTP/1.2\nHost: {host}\n", 400, False),
    ("HTTP/9.9", "GET /stats HTTP/9.9\nHost: {host}\n", 400, False),
    ("bad version", "GET /stats HTTP/one\nHost: {host}\n", 400, False),
    ("two lengths", "POST /action/light HTTP/1.1\nHost: {host}\nContent-Length: 0\nContent-Length: 0\n", 400, False),
    ("GET with a body", "GET /stats HTTP/1.1\nHost: {host}\nContent-Length: 5\n\nhello", 413, False),
]


@pytest.mark.parametrize("case, head, code, allow", FRAMING_CASES, ids=[c[0] for c in FRAMING_CASES])
def test_what_is_not_served_gets_a_4xx_and_is_closed(panel, case, head, code, allow):
    reply = exchange(panel, raw(panel, head))  # returns once the server closes the connection
    assert status_of(reply) == code
    assert len(re.findall(rb"(?:^|\r\n)HTTP/1\.[01] \d{3} ", reply)) == 1
    if allow:
        assert re.search(rb"\r\nAllow: GET, POST\r\n", reply)
    if case == "HEAD":
        assert reply.endswith(b"\r\n\r\n")  # no body after the head


SMUGGLED = ("POST /action/light HTTP/1.1\nHost: {host}\n" + TOKEN_HEADER + ": {token}\nContent-Length: 0\n\n")


@pytest.mark.parametrize("case, framing, code", [
    ("chunked", "Transfer-Encoding: chunked\n\n{size:x}\n{body}\n0\n\n", 411),
    ("content-length", "Content-Length: {size}\n\n{body}", 413),
])
def test_a_body_is_never_parsed_as_a_second_request(panel, case, framing, code):
    body = SMUGGLED.format(host=own(panel), token=panel.token).replace("\n", "\r\n")
    head = "POST /action/light HTTP/1.1\nHost: {host}\n" + TOKEN_HEADER + ": {token}\n"
    data = head.format(host=own(panel), token=panel.token).replace("\n", "\r\n")
    data += framing.replace("\n", "\r\n").format(size=len(body), body=body)
    reply = exchange(panel, data.encode())
    assert status_of(reply) == code
    assert reply.count(b"HTTP/1.1 ") == 1  # one answer: the smuggled request was not read
    assert panel.light["on"] is True


# --------------------------------------------------------------------- connections
def test_idle_and_half_sent_connections_are_closed_after_the_timeout(panel):
    for sent in (b"", b"GET /stats HTTP/1.1\r\nHost: 127.0.0.1"):
        started = time.monotonic()
        reply = exchange(panel, sent, timeout=5 * IDLE_S + 2)
        waited = time.monotonic() - started
        assert reply == b"" and IDLE_S * 0.8 <= waited <= IDLE_S + 1.5, (sent, reply, waited)
    # a kept-alive connection is closed too once idle
    conn = http.client.HTTPConnection(panel.host, panel.port, timeout=5)
    conn.request("GET", "/stats")
    response = conn.getresponse()
    assert response.status == 200 and not response.will_close and json.loads(response.read())
    started = time.monotonic()
    assert conn.sock.recv(100) == b""
    assert time.monotonic() - started <= IDLE_S + 1.5
    conn.close()


def wait_for(predicate, timeout=3.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_connections_are_capped(panel):
    threads_before = threading.active_count()
    idle = [socket.create_connection((panel.host, panel.port), timeout=5) for _ in range(4)]
    try:
        wait_for(lambda: len(panel.server.connections) == 4)
        extra = [socket.create_connection((panel.host, panel.port), timeout=5) for _ in range(30)]
        for s in extra:
            reply = s.recv(200)
            assert status_of(reply) == 503 and b"Connection: close" in reply
            s.close()
        assert threading.active_count() - threads_before <= 4  # a thread per connection served, no more
        assert len(panel.server.connections) == 4
    finally:
        for s in idle:
            s.close()
    wait_for(lambda: not panel.server.connections)
    assert status_of(request(panel, "GET", "/stats", {"Host": own(panel)})) == 200


def test_every_viewer_gets_the_same_encoding(panel):
    import numpy as np

    panel.publish(image=np.zeros((60, 80, 3), np.uint8), pattern=np.zeros((80, 128), np.uint8))
    encoded = []
    original = panel._jpeg
    panel._jpeg = lambda which: encoded.append(which) or original(which)
    results = []

    def view():
        results.append(panel.next_jpeg("input", 0))

    viewers = [threading.Thread(target=view) for _ in range(3)]  # (the fixture caps at 4 connections)
    for v in viewers:
        v.start()
    for v in viewers:
        v.join(5)
    assert encoded == ["input"] and len({r for r in results}) == 1 and results[0][1][:2] == b"\xff\xd8"


# --------------------------------------------------------------------- the run's panel
class _Log(io.StringIO):
    """stderr of an in-process run: ``url`` is set once the panel is served."""

    def __init__(self) -> None:
        super().__init__()
        self.served = threading.Event()
        self.url = ""

    def write(self, text: str) -> int:
        match = re.search(r"control panel: (\S+)", text)
        if match:
            self.url = match.group(1)
            self.served.set()
        return super().write(text)


class _Operator:
    """Presses the panel's buttons from a thread while the run holds the main one."""

    def __init__(self, log: _Log) -> None:
        assert log.served.wait(20), "the panel was never served"
        self.url = log.url
        page = urllib.request.urlopen(self.url, timeout=5).read().decode()
        self.token = re.search(r'name="antiscatter-token" content="([^"]+)"', page).group(1)

    def press(self, action: str) -> str:
        req = urllib.request.Request(self.url + "action/" + action, method="POST", headers={TOKEN_HEADER: self.token})
        return json.loads(urllib.request.urlopen(req, timeout=5).read())["message"]

    def stats(self) -> dict:
        return json.loads(urllib.request.urlopen(self.url + "stats", timeout=5).read())


def run_with_operator(args: list[str], script) -> tuple[int, str, str, list]:
    """``antiscatter run ARGS --web 127.0.0.1:0`` in-process; ``script(operator)`` runs in a thread."""
    from contextlib import redirect_stderr, redirect_stdout

    from antiscatter.cli import main

    log, out, said, failure = _Log(), io.StringIO(), [], []

    def operate():
        try:
            said.extend(script(_Operator(log)) or [])
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            failure.append(exc)
            try:
                _Operator(log).press("stop")
            except Exception:  # noqa: BLE001
                pass

    thread = threading.Thread(target=operate, daemon=True)
    thread.start()
    with redirect_stdout(out), redirect_stderr(log):
        try:
            code = main(["run", "--output", "none", *args, "--web", "127.0.0.1:0"])
        except SystemExit as exc:
            code = int(exc.code or 0)
    thread.join(10)
    if failure:
        raise failure[0]
    return code, out.getvalue(), log.getvalue(), said


def wait_stats(operator, key, value, timeout=10.0):
    wait_for(lambda: operator.stats().get(key) == value, timeout)


@pytest.mark.parametrize("port", ["99999", "busy"])
def test_a_bad_or_busy_port_fails_before_anything_is_touched(tmp_path, port):
    metrics = tmp_path / "m.csv"
    metrics.write_text("earlier,run\n1,2\n")
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    address = f"127.0.0.1:{busy.getsockname()[1]}" if port == "busy" else port
    try:  # a missing source would be refused first were it opened first
        result = run_cli("run", str(tmp_path / "no-such-source"), "--output", "none", "--metrics", str(metrics),
                         "--web", address)
    finally:
        busy.close()
    assert result.code == 2 and "Traceback" not in result.err
    assert len(result.err.strip().splitlines()) == 1
    assert ("outside 0..65535" if port == "99999" else "Address already in use") in result.err
    assert "--web" in result.err and "no-such-source" not in result.err
    assert metrics.read_text() == "earlier,run\n1,2\n"


def test_panel_recordings_are_numbered_never_overwrite_and_are_listed(tmp_path):
    import av

    target = tmp_path / "rec.mkv"
    target.write_bytes(b"an earlier recording")

    def script(operator):
        said = []
        for expected in ("rec-2.mkv", "rec-3.mkv"):
            said.append(operator.press("record"))
            wait_stats(operator, "recording", str(tmp_path / expected))
            time.sleep(0.5)
            said.append(operator.press("record"))
            wait_stats(operator, "recording", "no")
        operator.press("stop")
        return said

    code, out, err, said = run_with_operator(["--fps", "30", "--frames", "900", "--record-to", str(target)], script)
    assert code == 0, err
    assert said == ["recording", "recording stopped"] * 2
    assert target.read_bytes() == b"an earlier recording"
    listed = dict(re.findall(r"panel recording (\S+): (\d+) frames", out))
    assert list(listed) == [str(tmp_path / "rec-2.mkv"), str(tmp_path / "rec-3.mkv")]
    for path, frames in listed.items():
        with av.open(path) as container:
            pts = [f.pts for f in container.decode(video=0)]
        assert len(pts) == int(frames) >= 5
        # each frame at its true time (the simulator's scene time, its own rate whatever the pacing, from
        # where the recording began), in the file from 0 and in its sidecar to the ns
        rows = list(csv.DictReader(open(path.replace(".mkv", ".frames.csv"), newline="")))
        times = [int(r["time_ns"]) for r in rows]
        assert len(rows) == len(pts) and [int(r["pts"]) for r in rows] == pts
        assert np.allclose(np.diff(times), 1e9 / SimulatorSource().fps, atol=1) and pts[0] == 0
        assert pts == [round((t - times[0]) / 1e6) for t in times]


def test_an_unwritable_record_target_is_refused_before_the_run(tmp_path):
    result = run_cli("run", "--output", "none", "--frames", "3", "--record-to", "/proc/x.mkv",
                     "--web", "127.0.0.1:0")
    assert result.code == 2 and "Traceback" not in result.err and len(result.err.strip().splitlines()) == 1
    assert "--record-to" in result.err and "/proc/x.mkv" in result.err


@pytest.mark.parametrize("spoil, reason", [
    (lambda folder: folder.rmdir(), "No such file or directory"),
    (lambda folder: folder.rmdir() or folder.write_text("now a file"), "Not a directory"),
], ids=["folder removed", "folder replaced by a file"])
def test_a_record_target_spoiled_mid_run_keeps_the_run_going(tmp_path, spoil, reason):
    folder = tmp_path / "sub"
    folder.mkdir()
    target = folder / "x.mkv"

    def script(operator):
        spoil(folder)
        said = [operator.press("record")]
        wait_for(lambda: operator.stats().get("recording", "no") != "no")
        said.append(operator.stats())
        wait_for(lambda: operator.stats()["frames"] > said[-1]["frames"] + 10)  # the loop goes on
        operator.press("stop")
        return said

    code, out, err, said = run_with_operator(["--fps", "30", "--frames", "900", "--record-to", str(target)], script)
    assert code == 0, err
    message, stats = said
    assert message == f"cannot record to {target}: {reason}"
    assert stats["light"] == "on" and stats["recording"] == f"failed: {target}: {reason}"
    assert "stopped by panel" in out and f"panel recording {target}: failed ({reason})" in out
    assert f"panel recording {target} failed: {reason}; the run goes on" in err
    assert int(re.search(r"frames: (\d+)", out).group(1)) > stats["frames"] + 10


def test_a_recording_failing_mid_run_keeps_the_run_going(tmp_path, monkeypatch):
    from antiscatter import record

    class FullDisk(record.Recorder):
        def write(self, image, **times):
            if self.frames_in >= 3:
                raise OSError(28, "No space left on device")
            super().write(image, **times)

    monkeypatch.setattr(record, "Recorder", FullDisk)

    def script(operator):
        assert operator.press("record") == "recording"
        wait_stats(operator, "recording", f"failed: {tmp_path / 'rec.mkv'}: [Errno 28] No space left on device")
        frames = operator.stats()["frames"]
        wait_for(lambda: operator.stats()["frames"] > frames + 10)  # the loop goes on
        operator.press("stop")

    code, out, err, _ = run_with_operator(["--fps", "60", "--frames", "900", "--record-to", str(tmp_path / "rec.mkv")],
                                          script)
    assert code == 0, err
    assert "stopped by panel" in out
    assert f"panel recording {tmp_path / 'rec.mkv'}: failed ([Errno 28] No space left on device)" in out
