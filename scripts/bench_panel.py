"""Does the web panel slow the real-time loop?  Frame rate with both streams being watched vs without.

Usage: python scripts/bench_panel.py [--frames 900] [--fps 0]
Runs `antiscatter run` on the simulator twice (interleaved, three times each):
without --web, and with --web while a client reads both MJPEG streams and polls
/stats as the page does.  Reports the median frames per second of each and the ratio.
"""

from __future__ import annotations

import argparse
import http.client
import re
import statistics
import subprocess
import sys
import threading
import time


def watch(host: str, port: int, stop: threading.Event) -> None:
    def stream(path: str) -> None:
        conn = http.client.HTTPConnection(host, port, timeout=10)
        conn.request("GET", path)
        response = conn.getresponse()
        while not stop.is_set():
            if not response.read(65536):
                break
        conn.close()

    def stats() -> None:
        while not stop.is_set():
            try:
                conn = http.client.HTTPConnection(host, port, timeout=5)
                conn.request("GET", "/stats")
                conn.getresponse().read()
                conn.close()
            except OSError:
                break
            time.sleep(0.5)

    for target in (lambda: stream("/stream/input.mjpg"), lambda: stream("/stream/pattern.mjpg"), stats):
        threading.Thread(target=target, daemon=True).start()


def one(frames: int, fps: float, web: bool) -> float:
    args = [sys.executable, "-m", "antiscatter", "run", "--output", "none", "--frames", str(frames),
            "--fps", str(fps)] + (["--web", "127.0.0.1:0"] if web else [])
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop = threading.Event()
    if web:
        while True:
            line = proc.stderr.readline()
            match = re.match(r"control panel: http://([\d.]+):(\d+)/", line)
            if match:
                watch(match.group(1), int(match.group(2)), stop)
                break
    out, _ = proc.communicate()
    stop.set()
    return float(re.search(r"frames per second: ([\d.]+)", out).group(1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=900)
    parser.add_argument("--fps", type=float, default=0.0)
    args = parser.parse_args()
    without, with_page = [], []
    for _ in range(3):
        without.append(one(args.frames, args.fps, False))
        with_page.append(one(args.frames, args.fps, True))
    a, b = statistics.median(without), statistics.median(with_page)
    print(f"without panel: {without} -> median {a:.1f} frames/s")
    print(f"with both streams watched: {with_page} -> median {b:.1f} frames/s ({b / a:.3f} of without)")


if __name__ == "__main__":
    main()
