"""Do the web panel's viewers slow the real-time loop?  Frame rate with no viewer vs with many.

Usage: python scripts/bench_panel.py [--viewers 50] [--seconds 10] [--windows 5] [--fps 0] [--repeats 1]

Runs `antiscatter run --output none --web 127.0.0.1:0` on the simulator and measures the loop's
rate (from the panel's /stats) over ``--seconds`` with nobody watching and ``--seconds`` with
``--viewers`` MJPEG connections (half on the input stream, half on the pattern stream) reading
as fast as they can -- in alternating windows of the same run, so both sides see the same
machine load; viewers are connected and served before their window opens.  The run is then
ended with the panel's Stop button.  Prints frames per second both ways (median over
``--repeats`` runs), the ratio (the goal: >= 0.90) and what each viewer received.
"""

from __future__ import annotations

import argparse
import http.client
import json
import re
import statistics
import subprocess
import sys
import threading
import time

TOKEN_HEADER = "X-Antiscatter-Token"


class Viewer(threading.Thread):
    """One MJPEG connection read to the end; ``frames`` counts the JPEGs received."""

    def __init__(self, host: str, port: int, path: str, stop: threading.Event) -> None:
        super().__init__(daemon=True)
        self.host, self.port, self.path, self.stop = host, port, path, stop
        self.frames = 0
        self.status = 0

    def run(self) -> None:
        conn = http.client.HTTPConnection(self.host, self.port, timeout=30)
        try:
            conn.request("GET", self.path)
            response = conn.getresponse()
            self.status = response.status
            while not self.stop.is_set():
                chunk = response.read1(1 << 16)
                if not chunk:
                    break
                self.frames += chunk.count(b"Content-Type: image/jpeg")
        except OSError:
            pass
        finally:
            conn.close()


def get(host: str, port: int, path: str) -> bytes:
    conn = http.client.HTTPConnection(host, port, timeout=10)
    try:
        conn.request("GET", path)
        return conn.getresponse().read()
    finally:
        conn.close()


def frames_now(host: str, port: int) -> tuple[float, int]:
    """(time, frames the loop has done) from /stats, read as the figure changes (it is refreshed every
    10 frames, so a single read could be up to 10 frames stale)."""
    first = json.loads(get(host, port, "/stats")).get("frames", 0)
    while True:
        time.sleep(0.01)
        frames = json.loads(get(host, port, "/stats")).get("frames", 0)
        if frames != first:
            return time.monotonic(), int(frames)


def window(host: str, port: int, seconds: float, viewers: int) -> tuple[float, float, float]:
    """One measuring window: (seconds, loop frames, JPEGs received per viewer), with ``viewers``
    MJPEG connections (half on each stream) all served before it opens and closed after it."""
    stop = threading.Event()
    watching = [Viewer(host, port, ("/stream/input.mjpg", "/stream/pattern.mjpg")[i % 2], stop)
                for i in range(viewers)]
    for viewer in watching:
        viewer.start()
    deadline = time.monotonic() + 20
    while not all(v.frames for v in watching):
        if time.monotonic() > deadline:
            raise SystemExit(f"viewers not served: statuses {sorted({v.status for v in watching})}")
        time.sleep(0.05)
    t0, f0 = frames_now(host, port)
    received0 = sum(v.frames for v in watching)
    time.sleep(seconds)
    t1, f1 = frames_now(host, port)
    received = sum(v.frames for v in watching) - received0
    stop.set()
    for viewer in watching:
        viewer.join(5)
    return t1 - t0, f1 - f0, received / viewers if viewers else 0.0


def one(viewers: int, seconds: float, windows: int, fps: float) -> tuple[float, float, float]:
    """One run, windows without and with viewers alternating: (frames/s without, with, frames/s
    each viewer received)."""
    args = [sys.executable, "-m", "antiscatter", "run", "--output", "none", "--fps", str(fps),
            "--web", "127.0.0.1:0"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while True:
            line = proc.stderr.readline()
            if not line:
                raise SystemExit(f"antiscatter run ended before serving the panel: {proc.communicate()}")
            match = re.match(r"control panel: http://([\d.]+):(\d+)/", line)
            if match:
                host, port = match.group(1), int(match.group(2))
                break
        threading.Thread(target=proc.stderr.read, daemon=True).start()  # (drain)
        found = re.search(r'name="antiscatter-token" content="([^"]+)"', get(host, port, "/").decode())
        token = found.group(1) if found else ""  # (a panel from before the token: none needed)
        time.sleep(1.0)  # (start-up)
        totals = {0: [0.0, 0.0, 0.0], viewers: [0.0, 0.0, 0.0]}
        for _ in range(windows):
            for count in (0, viewers):
                span, frames, each = window(host, port, seconds / windows, count)
                total = totals[count]
                total[0] += span
                total[1] += frames
                total[2] += each
        conn = http.client.HTTPConnection(host, port, timeout=10)
        conn.request("POST", "/action/stop", headers={TOKEN_HEADER: token, "Content-Length": "0"})
        conn.getresponse().read()
        conn.close()
        proc.wait(timeout=60)
        (s0, f0, _), (s1, f1, r1) = totals[0], totals[viewers]
        return f0 / s0, f1 / s1, r1 / s1
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--viewers", type=int, default=50, help="MJPEG connections (default 50)")
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring window per run (default 10)")
    parser.add_argument("--fps", type=float, default=0.0, help="the run's --fps (default 0: as fast as it goes)")
    parser.add_argument("--windows", type=int, default=5,
                        help="windows each way per run, alternating (default 5, of seconds/windows each)")
    parser.add_argument("--repeats", type=int, default=1, help="runs (default 1)")
    args = parser.parse_args()
    alone, watched, received = [], [], []
    for _ in range(args.repeats):
        a, b, each = one(args.viewers, args.seconds, args.windows, args.fps)
        alone.append(a)
        watched.append(b)
        received.append(each)
    a, b = statistics.median(alone), statistics.median(watched)
    print(f"no viewer: {', '.join(f'{x:.1f}' for x in alone)} -> median {a:.1f} frames/s")
    print(f"{args.viewers} MJPEG viewers: {', '.join(f'{x:.1f}' for x in watched)} -> median {b:.1f} frames/s "
          f"(each viewer received {statistics.median(received):.1f} frames/s)")
    print(f"ratio: {b / a:.3f} (goal >= 0.90)")


if __name__ == "__main__":
    main()
