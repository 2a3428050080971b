"""A screenshot of Rerun's own web viewer showing a recording, from headless Chromium.

    python3 -m pip install 'rerun-sdk==0.41.*' websockets      # and Debian's chromium
    rerun mcap convert run.mcap -o run.rrd
    rerun --serve-web --renderer webgl run.rrd &                # http://127.0.0.1:9090
    python3 scripts/rerun-screenshot.py \
        'http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy&renderer=webgl' \
        viewer.png 40

Chromium draws through its software rasteriser (SwiftShader); the viewer needs some seconds
to compile and load, hence the wait (the last argument, seconds). Chromium is driven over its
DevTools protocol.
"""
import base64
import json
import subprocess
import sys
import time
import urllib.request

from websockets.sync.client import connect
url, out, wait = sys.argv[1], sys.argv[2], float(sys.argv[3])
chrome = subprocess.Popen(["chromium", "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--window-size=1600,1000",
    "--remote-debugging-port=9333", "--remote-allow-origins=*", "about:blank"],
    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
try:
    for _ in range(50):
        try:
            tabs = json.load(urllib.request.urlopen("http://127.0.0.1:9333/json"))
            break
        except OSError:
            time.sleep(0.2)
    page = [t for t in tabs if t["type"] == "page"][0]
    with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
        ids = iter(range(1, 1_000_000))

        def call(method, **params):
            n = next(ids)
            ws.send(json.dumps({"id": n, "method": method, "params": params}))
            while True:
                m = json.loads(ws.recv())
                if m.get("id") == n:
                    return m.get("result", {})
        call("Emulation.setDeviceMetricsOverride", width=1600, height=1000, deviceScaleFactor=1, mobile=False)
        call("Page.navigate", url=url)
        time.sleep(wait)
        shot = call("Page.captureScreenshot", format="png")
        open(out, "wb").write(base64.b64decode(shot["data"]))
finally:
    chrome.kill()
