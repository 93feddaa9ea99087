"""The control panel: its own routes only, 4xx for the rest, loopback by default, live data, actions."""

import http.client
import json
import socket
import time

import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.errors import UsageError
from antiscatter.web import Control, ControlPanel, parse_address

from conftest import PanelProcess


@pytest.fixture
def panel():
    pressed = []
    p = ControlPanel("0", title="test", actions={"light": lambda: pressed.append("light") or "light off"},
                     preview_fps=50)
    p.pressed = pressed
    yield p
    p.close()


def request(panel, method, path, body=None, headers=None):
    conn = http.client.HTTPConnection(panel.host, panel.port, timeout=5)
    conn.request(method, path, body=body, headers=headers or {})
    response = conn.getresponse()
    data = response.read() if "mjpg" not in path else response.read(4096)
    conn.close()
    return response.status, response.getheader("Content-Type"), data


def test_binds_to_loopback_by_default(panel):
    assert panel.host == "127.0.0.1" and panel.server.server_address[0] == "127.0.0.1"
    assert parse_address("8080") == ("127.0.0.1", 8080)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    with pytest.raises(UsageError, match="expected PORT or HOST:PORT"):
        parse_address("eighty")


def test_page_stats_stream_and_actions(panel):
    status, kind, body = request(panel, "GET", "/")
    assert status == 200 and "text/html" in kind and b"Record start/stop" in body
    image = np.zeros((60, 80, 3), np.uint8)
    panel.publish(image=image, detections=Detections([[40, 30]], [5]), pattern=np.full((80, 128), 255, np.uint8),
                  stats={"frames": 7, "fps": 30.0}, sample={"latency_ms": 2.0, "particles": 1.0})
    status, kind, body = request(panel, "GET", "/stats")
    stats = json.loads(body)
    assert status == 200 and stats["frames"] == 7 and stats["history"][0]["particles"] == 1.0
    status, kind, body = request(panel, "GET", "/stream/input.mjpg")
    assert status == 200 and "multipart/x-mixed-replace" in kind and b"\xff\xd8" in body  # a JPEG
    status, _, body = request(panel, "POST", "/action/light", body=b"", headers={"X-Antiscatter-Token": panel.token})
    assert status == 200 and json.loads(body)["message"] == "light off" and panel.pressed == ["light"]


def test_controls_are_listed_checked_and_applied():
    level = [0.1]
    control = Control("hole level", "of full light", 0.0, 1.0, 0.05, lambda: level[0],
                      lambda v: level.__setitem__(0, v) or f"hole level {v:g} from the next frame")
    with ControlPanel("0", title="test", controls={"level": control}, info={"source": "sim:<mixed>"}) as p:
        token = {"X-Antiscatter-Token": p.token}
        status, _, body = request(p, "GET", "/")
        assert status == 200 and b"sim:&lt;mixed&gt;" in body and b'id="controls"' in body  # escaped
        status, _, body = request(p, "GET", "/controls")
        assert status == 200 and json.loads(body) == [{"name": "level", "label": "hole level", "unit": "of full light",
                                                       "low": 0.0, "high": 1.0, "step": 0.05, "value": 0.1}]
        status, _, body = request(p, "POST", "/control/level?value=0.25", headers=token)
        assert status == 200 and json.loads(body)["message"] == "hole level 0.25 from the next frame"
        assert level == [0.25]
        for bad in ("1.5", "-0.1", "nan", "inf", "lots", ""):
            status, _, body = request(p, "POST", f"/control/level?value={bad}", headers=token)
            assert status == 400, bad
            assert json.loads(body)["message"] == f"hole level: got {bad!r}, allowed 0 to 1 of full light"
        assert level == [0.25]  # nothing refused was applied
        status, _, _ = request(p, "POST", "/control/level?value=0.5")  # no token
        assert status == 403 and level == [0.25]
        status, _, body = request(p, "POST", "/control/level?value=0.5&value=0.6", headers=token)
        assert status == 400 and level == [0.25]
        for path in ("/control/gain?value=1", "/action/level", "/control/level/x?value=0.5"):
            assert request(p, "POST", path, headers=token)[0] == 404, path


@pytest.mark.parametrize("method, path, code", [("GET", "/etc/passwd", 404), ("GET", "/../../x", 404),
                                                ("POST", "/action/format_disk", 404), ("POST", "/stats", 404),
                                                ("PUT", "/", 405), ("DELETE", "/action/light", 405)])
def test_anything_else_is_refused(panel, method, path, code):
    status, _, _ = request(panel, method, path)
    assert status == code


def test_malformed_request_gets_400(panel):
    with socket.create_connection((panel.host, panel.port), timeout=5) as s:
        s.sendall(b"THIS IS NOT HTTP\r\n\r\n")  # no version: answered HTTP/0.9 style, body only
        reply = s.recv(400)
    assert b"Error code: 400" in reply
    with socket.create_connection((panel.host, panel.port), timeout=5) as s:
        s.sendall(b"POST /action/light HTTP/1.1\r\nHost: x\r\nContent-Length: nine\r\n\r\n")
        reply = s.recv(200)
    assert reply.startswith(b"HTTP/1.1 400")


def test_run_with_panel_records_and_stops(tmp_path):
    with PanelProcess(["run", "--output", "none", "--fps", "30", "--record-to", "rec.mkv"], tmp_path) as panel:
        time.sleep(1.0)
        assert panel.post("record") == "recording"
        time.sleep(1.0)
        first = panel.stats()
        time.sleep(0.7)
        second = panel.stats()
        assert second["frames"] > first["frames"] and second["recording"] == "rec.mkv"
        panel.post("stop")
        out, err = panel.proc.communicate(timeout=30)
    assert panel.proc.returncode == 0, err
    assert "stopped by panel" in out
    import av
    with av.open(str(tmp_path / "rec.mkv")) as container:
        assert sum(1 for _ in container.decode(video=0)) > 10
