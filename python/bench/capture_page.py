"""Screenshots the page of a running `voxhap serve` after it has run a while (the README picture).

Usage: python capture_page.py URL OUT.png [--wait S] [--size 1280,860] [--chromium PATH]

Opens URL in headless Chromium (DevTools protocol over --remote-debugging-pipe, standard library only),
waits S seconds of real time (default 20, so the page's rates and the 10 s force plot have filled), then
writes a PNG of the viewport. Used for docs/images/page.png:

    voxhap serve --http 127.0.0.1:18094 --no-foxglove --duration 60 &
    python python/bench/capture_page.py http://127.0.0.1:18094/ docs/images/page.png
"""

import argparse
import base64
import itertools
import json
import os
import shutil
import subprocess
import sys
import time


class Pipe:
    def __init__(self, to_chrome, from_chrome):
        self.out, self.inp, self.ids, self.buffer = to_chrome, from_chrome, itertools.count(1), b""

    def call(self, method, session=None, **params):
        message_id = next(self.ids)
        message = {"id": message_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self.out, json.dumps(message).encode() + b"\0")
        while True:
            while b"\0" not in self.buffer:
                chunk = os.read(self.inp, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed the DevTools pipe")
                self.buffer += chunk
            raw, self.buffer = self.buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == message_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url")
    parser.add_argument("out")
    parser.add_argument("--wait", type=float, default=20.0)
    parser.add_argument("--size", default="1280,860")
    parser.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("google-chrome"))
    args = parser.parse_args()
    if not args.chromium:
        sys.exit("no chromium found (--chromium PATH)")
    chrome_in, to_chrome = os.pipe()
    from_chrome, chrome_out = os.pipe()

    def plumb():
        # Through fresh copies: a pipe end that already is fd 3 or 4 would keep its close-on-exec flag.
        read_end, write_end = os.dup(chrome_in), os.dup(chrome_out)
        os.dup2(read_end, 3)
        os.dup2(write_end, 4)

    chrome = subprocess.Popen(
        [args.chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         f"--window-size={args.size}", "--remote-debugging-pipe", "about:blank"],
        preexec_fn=plumb, close_fds=False,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    os.close(chrome_in)
    os.close(chrome_out)
    try:
        pipe = Pipe(to_chrome, from_chrome)
        target = next(t for t in pipe.call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        session = pipe.call("Target.attachToTarget", targetId=target["targetId"], flatten=True)["sessionId"]
        width, height = (int(v) for v in args.size.split(","))
        pipe.call("Emulation.setDeviceMetricsOverride", session, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)
        pipe.call("Page.navigate", session, url=args.url)
        time.sleep(args.wait)
        shot = pipe.call("Page.captureScreenshot", session, format="png")
        with open(args.out, "wb") as handle:
            handle.write(base64.b64decode(shot["data"]))
        print(f"wrote {args.out} ({args.url} after {args.wait:g} s)")
    finally:
        chrome.terminate()
        chrome.wait(timeout=10)


if __name__ == "__main__":
    main()
