"""A screenshot of ``io.write_mcap``'s file in the Lichtblick web viewer (the open-source fork of
Foxglove Studio): docs/img/foxglove_synthetic.png, shown in docs/inputs.md.

It writes the MCAP file with ``lanegraph run graphs/paper_mcap.yaml`` (the synthetic scene, or
``--input``), or takes one given with ``--mcap``; serves the viewer's web build and the file on
127.0.0.1 (HTTP range requests, as the viewer's "Remote file" source needs); opens
``?ds=remote-file&ds.url=...&layoutUrl=...&time=...`` in headless Chromium (playwright) with a
layout of an Image panel (``/camera/left/image`` with ``/lanes/annotations``), a 3D panel
(``/lanes/scene``, frame ``road``) and a Raw Messages panel (``/lanegraph/timings``); and saves the
page as a palette PNG. Every request that does not go to 127.0.0.1 is refused and reported; the
viewer's console is printed, and the script fails when the viewer reports an error about the file.

The viewer is not a dependency of lanegraph: build it once, outside the repository, with Node 20
(the steps that made docs/img/foxglove_synthetic.png: Lichtblick 1.28.1, commit 66adecb, yarn
4.17.0 taken from npm as ``@yarnpkg/cli-dist``; only registry.npmjs.org is reached):

    git clone https://github.com/lichtblick-suite/lichtblick ../lichtblick && cd ../lichtblick
    npm pack @yarnpkg/cli-dist@4.17.0 && mkdir -p /tmp/yarn/dist
    tar xzf yarnpkg-cli-dist-4.17.0.tgz -C /tmp/yarn && ln -s /tmp/yarn/package/bin/yarn.js /tmp/yarn/dist/
    export COREPACK_ROOT=/tmp/yarn YARN_NPM_REGISTRY_SERVER=https://registry.npmjs.org \
        ELECTRON_SKIP_BINARY_DOWNLOAD=1 PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 HUSKY=0
    node /tmp/yarn/dist/yarn.js install --mode=skip-build
    node_modules/.bin/webpack --mode development --config web/webpack.config.ts   # -> web/.webpack

(about 8 min for the install and 5 for the build on two busy cores). A registry mirror that lacks
a few of the lockfile's versions needs them changed in the package.json files first, as ours did:
``@lichtblick/tsconfig`` 1.1.2 -> 1.0.0 (and ``"ignoreDeprecations": "6.0"``, ``"rootDir":
"${configDir}"`` added to its ``base.json`` for TypeScript 6), ``@lichtblick/rosbag2-web`` 1.0.5 ->
1.0.0, ``flatbuffers_reflection`` 1.3.0 -> 0.0.7, ``@lichtblick/eslint-plugin`` left out. We also left
``ForkTsCheckerWebpackPlugin`` out of ``packages/suite-base/webpack.ts`` (type checking, not needed
for the build, and slow). Then:

    python benchmarks/foxglove_screenshot.py --viewer ../lichtblick/web/.webpack
    python benchmarks/foxglove_screenshot.py --viewer DIR --input DRIVE --frames 0:20 --frame 10 \
        --shot /tmp/kitti.png   # a KITTI drive: never committed
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import threading
import time
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "graphs" / "paper_mcap.yaml"
SHOT = ROOT / "docs" / "img" / "foxglove_synthetic.png"
#: the console lines that are the viewer's own business, not the file's (fonts, extensions, telemetry)
BENIGN = re.compile(r"extension|font|analytics|sentry|DevTools|React Router|favicon", re.I)


def layout(image_topic: str, annotations: str, scene: str, timings: str, sync: bool = True) -> dict:
    """The viewer's layout: the Image panel above, the 3D panel and the timings below."""
    camera = {
        "distance": 40.0,
        "perspective": True,
        "phi": 36.0,
        "target": [0.0, 0.0, 0.0],
        "targetOffset": [21.0, 0.0, 0.0],
        "targetOrientation": [0.0, 0.0, 0.0, 1.0],
        "thetaOffset": 90.0,
        "fovy": 45.0,
        "near": 0.5,
        "far": 5000.0,
    }
    grid = {
        "visible": True,
        "frameLocked": True,
        "label": "Grid (5 m)",
        "instanceId": "grid",
        "layerId": "foxglove.Grid",
        "size": 50,
        "divisions": 10,
        "lineWidth": 1,
        "color": "#7f7f7f",
        "position": [25, 0, 0],
        "rotation": [0, 0, 0],
        "order": 1,
    }
    return {
        "configById": {
            "Image!lanes": {
                "imageMode": {
                    "imageTopic": image_topic,
                    "annotations": {annotations: {"visible": True}},
                    "synchronize": sync,
                },
            },
            "3D!road": {
                "cameraState": camera,
                "followMode": "follow-none",
                "followTf": "road",
                "scene": {},
                "transforms": {},
                "topics": {scene: {"visible": True}},
                "layers": {"grid": grid},
            },
            "RawMessages!timings": {"topicPath": timings, "diffEnabled": False, "expansion": "all"},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "first": "Image!lanes",
            "second": {
                "first": "3D!road",
                "second": "RawMessages!timings",
                "direction": "row",
                "splitPercentage": 62,
            },
            "direction": "column",
            "splitPercentage": 52,
        },
    }


class Handler(SimpleHTTPRequestHandler):
    """Static files under one folder plus ``/data/<name>`` for the named files, with byte ranges."""

    extensions_map = {
        **SimpleHTTPRequestHandler.extensions_map,
        ".wasm": "application/wasm",
        ".js": "text/javascript",
        ".mcap": "application/octet-stream",
        ".json": "application/json",
    }

    def __init__(self, *args, data: dict[str, Path], **kwargs):
        self.data = data
        super().__init__(*args, **kwargs)

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass

    def end_headers(self):
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Access-Control-Allow-Origin", "*")
        self.send_header("Access-Control-Expose-Headers", "Accept-Ranges, Content-Range, Content-Length")
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "credentialless")
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def translate_path(self, path):
        name = path.split("?", 1)[0]
        if name.startswith("/data/"):
            target = self.data.get(name[len("/data/") :])
            return str(target) if target else "/nonexistent"
        return super().translate_path(path)

    def send_head(self):
        rng = self.headers.get("Range")
        path = Path(self.translate_path(self.path))
        m = re.fullmatch(r"bytes=(\d+)-(\d*)", rng or "")
        if not m or not path.is_file():
            return super().send_head()
        size = path.stat().st_size
        start = int(m.group(1))
        end = min(int(m.group(2)) if m.group(2) else size - 1, size - 1)
        if start > end:
            self.send_error(416)
            return None
        fh = open(path, "rb")  # noqa: SIM115 - closed by copyfile's caller
        fh.seek(start)
        self.send_response(206)
        self.send_header("Content-Type", self.guess_type(str(path)))
        self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Content-Length", str(end - start + 1))
        self.end_headers()
        self._left = end - start + 1
        return fh

    def copyfile(self, source, outputfile):
        left = getattr(self, "_left", None)
        try:
            if left is None:
                super().copyfile(source, outputfile)
                return
            while left > 0:
                chunk = source.read(min(left, 1 << 16))
                if not chunk:
                    break
                outputfile.write(chunk)
                left -= len(chunk)
        except (BrokenPipeError, ConnectionResetError):  # the viewer cancels its size probe
            pass


def write_mcap(input_path: str | None, frames: str | None, out: Path) -> Path:
    """Run graphs/paper_mcap.yaml into ``out``; the MCAP file it wrote."""
    cmd = [sys.executable, "-m", "lanegraph", "run", str(GRAPH), "--out", str(out)]
    if input_path:
        cmd += ["--input", input_path]
    if frames:
        cmd += ["--frames", frames]
    print("writing the MCAP file:", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)
    return out / "lanes.mcap"


def frame_time(mcap: Path, frame: int) -> tuple[str, int]:
    """The log time of the ``frame``-th image (as the viewer's ``time`` parameter) and the frame count."""
    from mcap.reader import make_reader

    with open(mcap, "rb") as fh:
        times = [m.log_time for _, _, m in make_reader(fh).iter_messages(topics=["/camera/left/image"])]
    if not times:
        raise SystemExit(f"{mcap}: no message on /camera/left/image")
    t = times[min(frame, len(times) - 1)]
    return f"{t // 1_000_000_000}.{t % 1_000_000_000:09d}", len(times)


#: the text of the leaf elements left of x and below y (the sidebar's open tab), top to bottom
SIDEBAR_TEXT = """([x, y]) => {
  const out = [];
  for (const el of document.querySelectorAll("body *")) {
    if (el.children.length) continue;
    const r = el.getBoundingClientRect();
    const t = el.textContent.trim();
    if (t && r.width > 0 && r.right <= x && r.top >= y && r.bottom <= innerHeight - 90) out.push(t);
  }
  return out;
}"""


def sidebar_text(page, tab: str) -> str:
    """Open the left sidebar's ``tab`` and return its text, one line ("" when there is no such tab)."""
    tabs = page.get_by_role("tab", name=tab)
    if tabs.count() == 0:
        return ""
    tabs.first.click()
    page.wait_for_timeout(800)
    bar = page.get_by_role("tablist").first.bounding_box()
    texts = (
        page.evaluate(SIDEBAR_TEXT, [bar["x"] + bar["width"] + 30, bar["y"] + bar["height"]]) if bar else []
    )
    return " | ".join(texts)


def shoot(args, mcap: Path) -> int:
    from PIL import Image
    from playwright.sync_api import sync_playwright

    viewer = Path(args.viewer).resolve()
    if not (viewer / "index.html").is_file():
        raise SystemExit(
            f"--viewer {viewer}: no index.html (build the viewer first: see this script's docstring)"
        )
    tmp = Path(tempfile.mkdtemp(prefix="lg_fox_"))
    (tmp / "layout.json").write_text(
        json.dumps(layout("/camera/left/image", "/lanes/annotations", "/lanes/scene", "/lanegraph/timings"))
    )
    data = {"lanes.mcap": mcap.resolve(), "lanegraph.json": tmp / "layout.json"}
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(Handler, directory=str(viewer), data=data))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    stamp, n = frame_time(mcap, args.frame)
    url = (
        f"{base}/?ds=remote-file&ds.url={base}/data/lanes.mcap"
        f"&layoutUrl={base}/data/lanegraph.json&time={stamp}"
    )
    print(f"{mcap}: {n} frame(s); showing frame {min(args.frame, n - 1)} at t = {stamp} s", flush=True)
    print("opening", url, flush=True)
    console: list[str] = []
    refused: list[str] = []
    width, height = args.size
    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=args.chromium,
            args=["--use-gl=angle", "--use-angle=swiftshader", "--ignore-gpu-blocklist"],
        )
        page = browser.new_page(viewport={"width": width, "height": height}, color_scheme=args.theme)

        def route(r):
            if r.request.url.startswith(base) or r.request.url.startswith(("data:", "blob:")):
                r.continue_()
            else:
                refused.append(r.request.url)
                r.abort()

        page.route("**/*", route)
        page.on("console", lambda m: console.append(f"[{m.type}] {m.text}"))
        page.on("pageerror", lambda e: console.append(f"[pageerror] {e}"))
        page.goto(url)
        print(f"waiting {args.wait:.0f} s for the viewer to load the file and draw ...", flush=True)
        deadline = time.monotonic() + args.wait
        while time.monotonic() < deadline:
            page.wait_for_timeout(1000)
        alerts = sidebar_text(page, "Alerts")
        topics = sidebar_text(page, "Topics")  # left open: the topics and schemas the viewer read
        page.wait_for_timeout(1500)
        raw = tmp / "shot.png"
        page.screenshot(path=str(raw))
        browser.close()
    server.shutdown()
    img = (
        Image.open(raw)
        .convert("RGB")
        .quantize(args.colors, Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    )
    Path(args.shot).parent.mkdir(parents=True, exist_ok=True)
    img.save(args.shot, optimize=True)
    print(f"{args.shot}: {Path(args.shot).stat().st_size / 1024:.0f} KB, {width}x{height}")
    print("the viewer's Alerts tab:", alerts or "(not found)")
    print("the viewer's Topics tab:", topics or "(not found)")
    print(f"the viewer's console ({len(console)} line(s)):")
    for line in console:
        print("   ", line[:400])
    if refused:
        print(f"refused {len(refused)} request(s) outside 127.0.0.1: {sorted(set(refused))[:10]}")
    ours = [
        line
        for line in console
        if line.startswith(("[error]", "[pageerror]"))
        and not BENIGN.search(line)
        and re.search(r"lanes|camera|lanegraph|mcap|schema|annotation|message", line, re.I)
    ]
    if ours:
        print(f"{len(ours)} error line(s) that name the file or its messages: see above")
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--viewer", required=True, help="the viewer's web build: the folder holding index.html")
    ap.add_argument(
        "--mcap", help="an MCAP file written by io.write_mcap (default: run graphs/paper_mcap.yaml)"
    )
    ap.add_argument("--input", help="lanegraph run's --input (default: the synthetic scene)")
    ap.add_argument("--frames", help="lanegraph run's --frames")
    ap.add_argument("--frame", type=int, default=5, help="the frame shown (index in the file)")
    ap.add_argument("--shot", default=str(SHOT), help="the PNG written")
    ap.add_argument("--size", type=lambda s: tuple(int(v) for v in s.split("x")), default=(1400, 860))
    ap.add_argument("--theme", choices=("light", "dark"), default="light")
    ap.add_argument("--colors", type=int, default=256, help="palette size of the PNG")
    ap.add_argument("--wait", type=float, default=25.0, help="seconds to let the viewer load before the shot")
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    args = ap.parse_args(argv)
    if args.mcap:
        return shoot(args, Path(args.mcap))
    with tempfile.TemporaryDirectory(prefix="lg_fox_run_") as out:
        return shoot(args, write_mcap(args.input, args.frames, Path(out) / "run"))


if __name__ == "__main__":
    sys.exit(main())
