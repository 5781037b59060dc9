#!/usr/bin/env python3
"""markerd's web page in a real browser.

Starts the built markerd on the simulated rig with [web] on, loads the page
in Debian's chromium (headless, driven over the DevTools protocol on a pipe:
--remote-debugging-pipe, so python3's standard library is all it takes),
and checks what a person would see: the page loads and updates, the preview
shows live frames of the camera's size, and the rig's state on the page
follows the rig as markerctl homes and moves it. Then SIGTERM stops markerd
with the page still streaming, and markerd must exit 0.

Exit 0 on success, 1 on a failure (saying which check failed), 77 (skipped)
only when no chromium is installed. Timeouts are hang guards, not
measurements.
"""

import argparse
import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time

SKIP = 77


def fail(message):
    print(f"FAIL: {message}", flush=True)
    sys.exit(1)


class Chromium:
    """A headless chromium spoken to over --remote-debugging-pipe: JSON
    messages ending in NUL, written to its fd 3, read from its fd 4."""

    def __init__(self, binary, profile, log):
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def child_pipes():
            # Copies above the pipes' own numbers first, so that moving them
            # to 3 and 4 never closes one of them; dup2's copies are
            # inheritable, every other descriptor here is not.
            reader, writer = os.dup(to_browser_r), os.dup(from_browser_w)
            os.dup2(reader, 3)
            os.dup2(writer, 4)

        args = [binary, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
                "--no-default-browser-check", "--disable-extensions", "--disable-background-networking",
                "--mute-audio", f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"]
        self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                        close_fds=False, preexec_fn=child_pipes)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 1
        self.session = None

    def call(self, method, params=None, session=True, timeout=60):
        message = {"id": self._next_id, "method": method, "params": params or {}}
        self._next_id += 1
        if session and self.session:
            message["sessionId"] = self.session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == message["id"]:
                    if "error" in reply:
                        fail(f"chromium: {method}: {reply['error']}")
                    return reply.get("result", {})
            left = deadline - time.monotonic()
            if left <= 0:
                fail(f"chromium did not answer {method} within {timeout} s")
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if ready:
                chunk = os.read(self._from_browser, 1 << 16)
                if not chunk:
                    fail(f"chromium closed its pipe (exit {self.process.poll()}) while answering {method}")
                self._buffer += chunk

    def open(self, url):
        target = self.call("Target.createTarget", {"url": "about:blank"}, session=False)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True},
                                 session=False)["sessionId"]
        self.call("Page.navigate", {"url": url})

    def evaluate(self, expression):
        result = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                "awaitPromise": True})
        if "exceptionDetails" in result:
            fail(f"the page's script failed: {result['exceptionDetails']}")
        return result["result"].get("value")

    def close(self):
        try:
            self.call("Browser.close", session=False, timeout=10)
        except SystemExit:
            pass
        try:
            self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def wait_for(what, check, timeout=120, interval=0.2):
    """The first true value check() returns; a failure naming `what` and the
    last value when none comes within the hang guard."""
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        last = check()
        if last:
            return last
        time.sleep(interval)
    fail(f"{what}: not within {timeout} s (last: {last!r})")


def text(browser, element):
    return browser.evaluate(f"document.getElementById('{element}').textContent")


# The preview as drawn: its size, and a checksum of its pixels and their
# range (a picture, not a blank), read back through a canvas.
PREVIEW = """(() => {
  const img = document.getElementById('preview');
  if (!img.complete && img.naturalWidth === 0) return null;
  if (img.naturalWidth === 0) return null;
  const canvas = document.createElement('canvas');
  canvas.width = img.naturalWidth;
  canvas.height = img.naturalHeight;
  const g = canvas.getContext('2d');
  g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, canvas.width, canvas.height).data;
  let sum = 0, low = 255, high = 0;
  for (let i = 0; i < d.length; i += 4) {
    sum = (sum * 31 + d[i] + 3 * d[i + 1] + 7 * d[i + 2]) % 1000000007;
    low = Math.min(low, d[i + 1]);
    high = Math.max(high, d[i + 1]);
  }
  return {width: img.naturalWidth, height: img.naturalHeight, sum, low, high};
})()"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--markerd", required=True)
    parser.add_argument("--markerctl", required=True)
    parser.add_argument("--source", required=True, help="the source tree (config/)")
    parser.add_argument("--chromium", default=os.environ.get("CHROMIUM"))
    parser.add_argument("--keep", action="store_true", help="keep the temporary directory")
    args = parser.parse_args()
    args.source = os.path.abspath(args.source)

    chromium = args.chromium or next((p for p in map(shutil.which, ("chromium", "chromium-browser")) if p), None)
    if not chromium:
        print("SKIP: chromium is not installed (tools/install-deps.sh installs Debian's chromium)", flush=True)
        return SKIP

    work = tempfile.mkdtemp(prefix="markerd-web-")
    for sub in ("logs", "state", "locks", "profile"):
        os.makedirs(os.path.join(work, sub))
    rig = open(os.path.join(args.source, "config/rig-sim.toml")).read()
    # The rig's time 20 times faster: homing and moves take a second or two.
    rig, count = re.subn(r"(?m)^time_scale\s*=.*$", "time_scale = 20.0", rig)
    if count != 1:
        fail("config/rig-sim.toml has no time_scale line to speed up")
    with open(os.path.join(work, "rig.toml"), "w") as f:
        f.write(rig)
    with open(os.path.join(work, "markerd.toml"), "w") as f:
        f.write(f"""rig = "rig.toml"

[marker]
family = "frame8"
id = 165
size_m = 0.08
mounting = "paper"

[camera]
source = "sim"
model = "{args.source}/config/cameras/thesis-640x480.yaml"
frame_timeout_ms = 5000

[camera.sim]
fps = 15
noise_sigma = 2.0
supersample = 1

[log]
directory = "logs"

[control]
socket = "control.sock"

[sweep]
directory = "state"

[web]
enabled = true
listen = "127.0.0.1:0"
""")
    env = dict(os.environ, MARKERD_LOCK_DIR=os.path.join(work, "locks"),
               MARKERD_SOCKET=os.path.join(work, "control.sock"))
    markerd_log = open(os.path.join(work, "markerd.log"), "w")
    chromium_log = open(os.path.join(work, "chromium.log"), "w")
    markerd = subprocess.Popen([args.markerd, "--config", os.path.join(work, "markerd.toml")], env=env,
                               stdin=subprocess.DEVNULL, stdout=markerd_log, stderr=markerd_log)
    browser = None

    def markerctl(*words, timeout=120):
        run = subprocess.run([args.markerctl, *words], env=env, capture_output=True, text=True, timeout=timeout)
        if run.returncode != 0:
            fail(f"markerctl {' '.join(words)}: exit {run.returncode}: {run.stderr.strip()}")
        return run.stdout

    try:
        def web_url():
            if markerd.poll() is not None:
                fail(f"markerd exited with {markerd.returncode}: {open(markerd_log.name).read()[-2000:]}")
            if not os.path.exists(os.path.join(work, "control.sock")):
                return None
            run = subprocess.run([args.markerctl, "status", "--json"], env=env, capture_output=True, text=True,
                                 timeout=60)
            return run.returncode == 0 and (json.loads(run.stdout).get("web") or {}).get("url")
        url = wait_for("markerd's status naming the web page's address", web_url)
        if not url.startswith("http://127.0.0.1:"):
            fail(f"the page is not on the loopback address: {url}")
        print(f"markerd serves {url}", flush=True)

        browser = Chromium(chromium, os.path.join(work, "profile"), chromium_log)
        browser.open(url)
        wait_for("the page's title", lambda: browser.evaluate("document.title") == "markerd")
        wait_for("the page's first state update", lambda: int(text(browser, "updates") or 0) > 0)
        wait_for("the page saying it is live", lambda: text(browser, "connection") == "live")
        print("the page loads and updates", flush=True)

        first = wait_for("a frame in the preview", lambda: browser.evaluate(PREVIEW))
        if (first["width"], first["height"]) != (640, 480):
            fail(f"the preview is {first['width']}x{first['height']}, the camera's frames 640x480")
        if first["high"] - first["low"] < 50:
            fail(f"the preview is blank (green from {first['low']} to {first['high']})")
        wait_for("the preview changing (a live stream, not one picture)",
                 lambda: browser.evaluate(PREVIEW)["sum"] != first["sum"])
        sequence = int(wait_for("a frame number on the page", lambda: text(browser, "frame-sequence").isdigit()
                                and text(browser, "frame-sequence")))
        wait_for("the frame number advancing", lambda: int(text(browser, "frame-sequence")) > sequence)
        print("the preview shows live 640x480 frames", flush=True)

        before = text(browser, "rail-position")
        markerctl("rig", "home")
        wait_for("the page showing the rail homed", lambda: "not homed" not in text(browser, "rail-state")
                 and "settled" in text(browser, "rail-state"))
        markerctl("rig", "move", "--rail", "500mm", "--turntable", "20deg")
        wait_for("the page showing the rail at 500 mm", lambda: text(browser, "rail-position") == "500.0 mm")
        wait_for("the page showing the turntable at 20 deg", lambda: text(browser, "turntable-position") == "20.0 deg")
        wait_for("the page's ground truth following the rig",
                 lambda: text(browser, "truth") == "distance 0.800 m, yaw 20.0 deg")
        wait_for("the page naming the marker detected",
                 lambda: re.match(r"frame8 165 at 0\.\d+ m", text(browser, "detections")))
        print(f"the page follows the rig: rail {before} -> {text(browser, 'rail-position')}, "
              f"{text(browser, 'truth')}, {text(browser, 'detections')}", flush=True)

        # SIGTERM while the page streams: markerd stops its web server with
        # the rest and exits 0.
        markerd.send_signal(signal.SIGTERM)
        try:
            code = markerd.wait(timeout=120)
        except subprocess.TimeoutExpired:
            fail("markerd did not stop within 120 s of SIGTERM with a preview streaming")
        if code != 0:
            fail(f"markerd exited {code} on SIGTERM: {open(markerd_log.name).read()[-2000:]}")
        print("markerd stopped on SIGTERM with the preview streaming", flush=True)
        print("PASS", flush=True)
        return 0
    except SystemExit:
        # What markerd and chromium said, for the failure's reader.
        for log in (markerd_log, chromium_log):
            log.flush()
            with open(log.name, errors="replace") as f:
                print(f"--- the end of {os.path.basename(log.name)}:\n{f.read()[-3000:]}", flush=True)
        raise
    finally:
        if browser:
            browser.close()
        if markerd.poll() is None:
            markerd.kill()
            markerd.wait()
        if args.keep:
            print(f"kept {work}", flush=True)
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
