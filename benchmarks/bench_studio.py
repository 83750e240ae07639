"""The studio's latency (issue 37): a slider moved in a real browser → the views redrawn.

    python benchmarks/bench_studio.py [--moves 300] [--interval-ms 16] [--driver mouse|page] [--append]

Starts ``scheimpflug studio --no-browser --port 0`` (its own process), opens the page in Debian's
Chromium headless (Playwright, ``--headless --no-sandbox --disable-gpu``) and drags sliders: with the
mouse (``--driver mouse``: ``--moves`` mouse steps, each followed by a wait of ``--interval-ms``) or
from a timer in the page (``--driver page``: an ``input`` event every ``--interval-ms``), over the
focal length, the sheet angle and the sensor tilt error in turn.  Every step fires an ``input``
event; the page asks the server (``GET /api/studio``, the engine of ``design``) — one request on its
way at a time, the newest state asked for when it returns (the newest wins) — and redraws all views.
Latency per drawn answer: from the ``input`` event's time stamp to the first animation frame after
the redraw (``window.studio.latencies``), i.e. request, engine, JSON, every view and the table
redrawn, the frame about to be painted; and per input event, to the first redraw of it or a newer
one.  Also the server alone (the same queries by urllib, one at a time) and ``--previews`` preview
frames (the twin's render, 4 × 4 binned, after one warm-up).  ``--append`` appends the figures and
the command to ``benchmarks/RESULTS.md``.
"""

import argparse
import datetime
import math
import os
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

SLIDERS = ("lens.focal_length_mm", "laser.tan_phi", "sensor.tilt_error_deg")


def _pct(values, q):
    s = sorted(values)
    return s[min(len(s) - 1, max(0, round(q / 100 * (len(s) - 1))))]


def _drag(page, name, moves, interval_ms):
    box = page.locator(f'input[type=range][name="{name}"]').bounding_box()
    y = box["y"] + box["height"] / 2
    x0, x1 = box["x"] + 0.15 * box["width"], box["x"] + 0.85 * box["width"]
    page.mouse.move(x0, y)
    page.mouse.down()
    for i in range(moves):
        t = i / max(moves - 1, 1)
        page.mouse.move(x0 + (x1 - x0) * (0.5 - 0.5 * math.cos(6.283 * 2 * t)), y)
        page.wait_for_timeout(interval_ms)
    page.mouse.up()
    page.wait_for_function("() => !window.studio.state.inflight && window.studio.drawnSeq === window.studio.state.seq",
                           timeout=30000)


_JS_DRAG = """async ([name, moves, interval]) => {
  const s = document.querySelector(`input[type=range][name="${name}"]`);
  const lo = Number(s.min), hi = Number(s.max);
  for (let i = 0; i < moves; i++) {
    const t = i / Math.max(moves - 1, 1);
    s.value = String(lo + (hi - lo) * (0.15 + 0.7 * (0.5 - 0.5 * Math.cos(6.283 * 2 * t))));
    s.dispatchEvent(new Event("input", { bubbles: true }));
    await new Promise((r) => setTimeout(r, interval));
  }
}"""


def _drag_in_page(page, name, moves, interval_ms):
    """Input events from a timer in the page: exactly ``interval_ms`` apart (the mouse path is slower)."""
    page.evaluate(_JS_DRAG, [name, moves, interval_ms])
    page.wait_for_function("() => !window.studio.state.inflight && window.studio.drawnSeq === window.studio.state.seq",
                           timeout=30000)


def _every_input(sent, drawn):
    """Per input event: its time to the first redraw of its own or a newer request."""
    out = []
    for x in sent:
        later = [d["at"] for d in drawn if d["seq"] >= x["seq"]]
        if later:
            out.append(min(later) - x["t0"])
    return out


def _previews(url, n):
    """Wall times of ``n`` preview frames (cylinder, 0° and 30° in turn), the first one untimed (warm-up)."""
    times = {0: [], 30: []}
    for i in range(n + 1):
        angle = 30 if i % 2 else 0
        t = time.perf_counter()
        with urllib.request.urlopen(f"{url}api/preview.png?part=cylinder&angle_deg={angle}", timeout=60) as r:
            r.read()
        if i:
            times[angle].append(time.perf_counter() - t)
    return times


def _server_alone(url, queries):
    times = []
    for q in queries:
        t = time.perf_counter()
        with urllib.request.urlopen(f"{url}api/studio?{q}", timeout=10) as r:
            r.read()
        times.append((time.perf_counter() - t) * 1e3)
    return times


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--moves", type=int, default=300, help="mouse steps in all (split over the sliders)")
    ap.add_argument("--interval-ms", type=float, default=16.0)
    ap.add_argument("--driver", choices=("mouse", "page"), default="mouse",
                    help="mouse: Playwright moves the mouse (each step a round trip to the browser, so steps come "
                         "slower than --interval-ms); page: a timer in the page sets the slider and fires `input` "
                         "exactly --interval-ms apart")
    ap.add_argument("--chromium", default=os.environ.get("STUDIO_CHROMIUM") or shutil.which("chromium"))
    ap.add_argument("--previews", type=int, default=4, help="preview frames to time after the drags (0: none)")
    ap.add_argument("--append", action="store_true", help="append the figures to benchmarks/RESULTS.md")
    args = ap.parse_args()
    load = os.getloadavg()[0]

    studio = subprocess.Popen([sys.executable, "-m", "scheimpflug", "studio", "--no-browser", "--port", "0"],
                              stdout=subprocess.PIPE, text=True)      # the command itself, in its own process
    url = studio.stdout.readline().split(" at ", 1)[1].split()[0]
    try:
        run = _run(args, url)
    finally:
        studio.send_signal(signal.SIGINT)
        studio.wait(timeout=10)
    _report(args, load, *run)


def _run(args, url):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=args.chromium, args=["--headless", "--no-sandbox", "--disable-gpu"])
        chromium = browser.version
        page = browser.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(url)
        page.wait_for_function("() => window.studio && window.studio.drawnSeq > 0", timeout=15000)
        _drag(page, SLIDERS[0], 20, args.interval_ms)           # warm-up: JIT, caches
        page.evaluate("window.studio.latencies.length = 0; window.studio.inputs0 = window.studio.state.seq")
        drag = _drag if args.driver == "mouse" else _drag_in_page
        t0 = time.perf_counter()
        for name in SLIDERS:
            drag(page, name, args.moves // len(SLIDERS), args.interval_ms)
        wall = time.perf_counter() - t0
        lat = page.evaluate("window.studio.latencies")
        inputs = page.evaluate("window.studio.state.seq - window.studio.inputs0")
        sent = page.evaluate("window.studio.inputs.filter(x => x.seq > window.studio.inputs0)")
        queries = [page.evaluate("window.studio.state.lastQuery")] * 50      # the last design drawn
        browser.close()
    return chromium, wall, lat, inputs, sent, _server_alone(url, queries), _previews(url, args.previews)


def _report(args, load, chromium, wall, lat, inputs, sent, server, previews):
    ms = [x["ms"] for x in lat]
    every = _every_input(sent, lat)
    rate = wall / max(inputs, 1) * 1e3
    lines = [
        f"{args.driver}: input events {inputs}, one every {rate:.0f} ms, views drawn {len(ms)} "
        f"({inputs - len(ms)} input events overtaken by a newer one while a request was on its way: newest wins), "
        f"{wall:.1f} s of dragging",
        f"slider input → views redrawn [ms]: median {statistics.median(ms):.1f}, p95 {_pct(ms, 95):.1f}, "
        f"max {max(ms):.1f}",
        f"every input event → the first redraw showing it or a newer one [ms]: median "
        f"{statistics.median(every):.1f}, p95 {_pct(every, 95):.1f}, max {max(every):.1f}",
        f"server alone, GET /api/studio [ms]: median {statistics.median(server):.1f}, p95 {_pct(server, 95):.1f}",
    ]
    lines += [f"preview frame, cylinder at {a}°, 4 × 4 binned, GET /api/preview.png [s]: "
              + ", ".join(f"{t:.2f}" for t in ts) for a, ts in previews.items() if ts]
    import importlib.metadata as md

    env = (f"load average {load:.2f} before, Chromium {chromium}, Playwright {md.version('playwright')}, "
           f"Python {platform.python_version()}, {os.cpu_count()} cores ({platform.machine()}), "
           f"{datetime.date.today().isoformat()}")
    print(env)
    print("\n".join(lines))
    if args.append:
        cmd = (f"python benchmarks/bench_studio.py --moves {args.moves} --interval-ms {args.interval_ms:g} "
               f"--driver {args.driver} --previews {args.previews}")
        how = (f"with the mouse (Playwright: a step, then a wait of {args.interval_ms:g} ms)"
               if args.driver == "mouse"
               else f"from a timer in the page, an `input` event every {args.interval_ms:g} ms")
        title = "the mouse" if args.driver == "mouse" else f"{1e3 / rate:.0f} input events a second"
        block = (f"\n## Studio: slider → redrawn views, {title} (issue 37)\n\n    " + cmd + "\n\n"
                 "A real browser drags three sliders (focal length, sheet angle, sensor tilt error) " + how + "; "
                 "each `input` event asks the server for the rig (the engine of `design`) and redraws the meridian "
                 "plane, the field, the datasheet and the curves; one request is on its way at a time, and when it "
                 "returns the newest state is asked for (newest wins). Latency: the `input` event's time stamp to "
                 "the first animation frame after the redraw. " + env + ".\n\n"
                 + "\n".join(f"- {ln}" for ln in lines) + "\n\nTarget (issue 37): ≤ 100 ms at the 95th percentile.\n")
        path = Path(__file__).with_name("RESULTS.md")
        with path.open("a", encoding="utf-8") as fh:      # append only: other benchmarks append too
            fh.write(block)
        print(f"appended to {path}")


if __name__ == "__main__":
    main()
