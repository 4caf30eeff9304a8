"""``benchmarks/foxglove_screenshot.py``: its server answers the byte ranges the viewer's "Remote
file" source asks for and serves nothing but the viewer's folder and the files it names; its layout
shows our topics. The viewer itself (a local web build of Lichtblick) is never needed here except by
the last test, which runs only where ``LANEGRAPH_VIEWER`` names such a build."""

from __future__ import annotations

import importlib.util
import os
import threading
import urllib.error
import urllib.request
from functools import partial
from http.server import ThreadingHTTPServer
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "foxglove_screenshot", ROOT / "benchmarks" / "foxglove_screenshot.py"
)
fs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fs)


@pytest.fixture
def server(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text("<html></html>")
    blob = bytes(range(256)) * 40
    (tmp_path / "lanes.mcap").write_bytes(blob)
    (tmp_path / "secret.txt").write_text("not served")
    srv = ThreadingHTTPServer(
        ("127.0.0.1", 0),
        partial(fs.Handler, directory=str(site), data={"lanes.mcap": tmp_path / "lanes.mcap"}),
    )
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{srv.server_address[1]}", blob
    srv.shutdown()


def get(url, **headers):
    with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=10) as r:
        return r.status, dict(r.headers), r.read()


def test_the_server_answers_byte_ranges_of_the_named_file(server):
    base, blob = server
    status, headers, body = get(f"{base}/data/lanes.mcap")
    assert status == 200 and body == blob and headers["Accept-Ranges"] == "bytes"
    status, headers, body = get(f"{base}/data/lanes.mcap", Range="bytes=1000-1099")
    assert status == 206 and body == blob[1000:1100]
    assert headers["Content-Range"] == f"bytes 1000-1099/{len(blob)}" and headers["Content-Length"] == "100"
    status, _, body = get(f"{base}/data/lanes.mcap", Range=f"bytes={len(blob) - 10}-")  # open end
    assert status == 206 and body == blob[-10:]
    status, _, body = get(f"{base}/data/lanes.mcap", Range=f"bytes=10-{len(blob) + 500}")  # past the end
    assert status == 206 and body == blob[10:]


def test_the_server_serves_nothing_it_was_not_given(server):
    base, _ = server
    assert get(f"{base}/index.html")[0] == 200
    for path in ("/data/secret.txt", "/../secret.txt", "/%2e%2e/secret.txt", "/data/../../secret.txt"):
        with pytest.raises(urllib.error.HTTPError) as e:
            get(base + path)
        assert e.value.code == 404, path


def test_the_layout_shows_the_sinks_topics():
    from lanegraph_io._mcap_sink import TOPICS

    lay = fs.layout(TOPICS["image"], TOPICS["annotations"], TOPICS["scene"], TOPICS["timings"])
    panels = lay["configById"]
    image = panels["Image!lanes"]["imageMode"]
    assert image["imageTopic"] == "/camera/left/image" and image["synchronize"] is True
    assert image["annotations"] == {"/lanes/annotations": {"visible": True}}
    assert panels["3D!road"]["topics"] == {"/lanes/scene": {"visible": True}}
    assert panels["3D!road"]["followTf"] == "road"
    assert panels["RawMessages!timings"]["topicPath"] == "/lanegraph/timings"

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(lay["layout"])) == sorted(panels)


@pytest.mark.slow
@pytest.mark.skipif(
    not os.environ.get("LANEGRAPH_VIEWER"),
    reason="needs a local web build of Lichtblick named by LANEGRAPH_VIEWER (benchmarks/foxglove_screenshot.py)",
)
def test_the_viewer_opens_the_sinks_file_without_errors(tmp_path):
    pytest.importorskip("playwright", reason="playwright is not installed")
    pytest.importorskip("mcap", reason='the io extra is not installed: pip install -e ".[io]"')
    if not Path("/usr/bin/chromium").exists():
        pytest.skip("needs Chromium at /usr/bin/chromium")
    shot = tmp_path / "shot.png"
    rc = fs.main(
        ["--viewer", os.environ["LANEGRAPH_VIEWER"], "--frames", "0:3", "--frame", "1", "--shot", str(shot)]
    )
    assert rc == 0 and shot.stat().st_size > 10_000
