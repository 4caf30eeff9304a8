"""The pair sources' PNG decoder (``lanegraph_io._png``): OpenCV's pixels on every file it takes,
OpenCV's own decoding for every file it does not, and its numba kernel against a NumPy twin."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from lanegraph_io import _png
from lanegraph_io._png import decode_png
from lanegraph_io._sources import read_image

from lanegraph.errors import InputError

FLAGS = {False: cv2.IMREAD_UNCHANGED, True: cv2.IMREAD_GRAYSCALE}


def chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(body, zlib.crc32(kind)))


def paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def filter_rows(img: np.ndarray, kinds: list[int]) -> bytes:
    """The PNG filter of each row (``kinds[r]``, 0-4) applied to ``img`` (H x W x C, RGB order):
    the specification's forward filters, written plainly."""
    h = img.shape[0]
    ch = 1 if img.ndim == 2 else img.shape[2]
    rows = img.reshape(h, -1).astype(np.int64)
    out = bytearray()
    for r in range(h):
        cur = rows[r]
        up = rows[r - 1] if r else np.zeros_like(cur)
        left = np.concatenate([np.zeros(ch, np.int64), cur[:-ch]])
        upleft = np.concatenate([np.zeros(ch, np.int64), up[:-ch]])
        k = kinds[r]
        if k == 0:
            pred = np.zeros_like(cur)
        elif k == 1:
            pred = left
        elif k == 2:
            pred = up
        elif k == 3:
            pred = (left + up) // 2
        else:
            pred = np.array([paeth(a, b, c) for a, b, c in zip(left, up, upleft)], np.int64)
        out.append(k)
        out += ((cur - pred) % 256).astype(np.uint8).tobytes()
    return bytes(out)


def make_png(
    img: np.ndarray,
    kinds: list[int] | None = None,
    *,
    colour: int | None = None,
    extra: list[tuple[bytes, bytes]] = (),
    depth: int = 8,
    interlace: int = 0,
    idat_parts: int = 3,
    stream: bytes | None = None,
) -> bytes:
    """A PNG of ``img`` (RGB order) with the given row filters (random when None), the stream split
    over ``idat_parts`` IDAT chunks, and ``extra`` chunks before the first IDAT."""
    h, w = img.shape[:2]
    if colour is None:
        colour = 0 if img.ndim == 2 else 2
    if kinds is None:
        kinds = list(np.random.default_rng(h * w).integers(0, 5, h))
    if stream is None:
        stream = zlib.compress(filter_rows(img, kinds), 6)
    parts = np.array_split(np.frombuffer(stream, np.uint8), idat_parts)
    out = _png.SIGNATURE + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, interlace))
    for kind, body in extra:
        out += chunk(kind, body)
    for part in parts:
        out += chunk(b"IDAT", part.tobytes())
    return out + chunk(b"IEND", b"")


def opencv(data: bytes, gray: bool) -> np.ndarray | None:
    return cv2.imdecode(np.frombuffer(data, np.uint8), FLAGS[gray])


def unfilter_twin(raw: np.ndarray, height: int, width: int, channels: int, mode: int) -> np.ndarray:
    """The NumPy twin of ``_unfilter_kernel`` (one row at a time; sub, average and Paeth byte by byte)."""
    n = width * channels
    rows = raw.reshape(height, n + 1).astype(np.int64)
    prev = np.zeros(n, np.int64)
    done = np.zeros((height, n), np.uint8)
    for r in range(height):
        k, src = rows[r, 0], rows[r, 1:]
        cur = np.zeros(n, np.int64)
        if k in (0, 2):
            cur = (src + (prev if k == 2 else 0)) % 256
        else:
            for i in range(n):
                a = cur[i - channels] if i >= channels else 0
                c = prev[i - channels] if i >= channels else 0
                pred = a if k == 1 else ((a + prev[i]) // 2 if k == 3 else paeth(a, prev[i], c))
                cur[i] = (src[i] + pred) % 256
        done[r] = cur
        prev = cur
    if mode == _png.AS_STORED:
        return done
    rgb = done.reshape(height, width, 3).astype(np.int64)
    if mode == _png.BGR:
        return rgb[:, :, ::-1].reshape(height, n).astype(np.uint8)
    wr, wg, wb = _png.GRAY_WEIGHTS
    return ((wr * rgb[..., 0] + wg * rgb[..., 1] + wb * rgb[..., 2]) >> 15).astype(np.uint8)


@pytest.mark.parametrize("channels", [1, 3])
def test_the_kernel_matches_its_numpy_twin(channels):
    rng = np.random.default_rng(channels)
    height, width = 23, 17
    raw = rng.integers(0, 256, (height, width * channels + 1), np.uint8)
    raw[:, 0] = rng.integers(0, 5, height)
    raw[:5, 0] = [0, 1, 2, 3, 4]
    raw = raw.reshape(-1)
    modes = [_png.AS_STORED] if channels == 1 else [_png.AS_STORED, _png.BGR, _png.GRAY_FROM_RGB]
    for mode in modes:
        cols = width if mode == _png.GRAY_FROM_RGB else width * channels
        out = np.empty((height, cols), np.uint8)
        assert _png._unfilter_kernel(raw, height, width, channels, mode, out) == -1
        np.testing.assert_array_equal(out, unfilter_twin(raw, height, width, channels, mode))


def test_the_kernel_reports_the_first_row_with_an_unknown_filter():
    raw = np.zeros((4, 7), np.uint8)
    raw[2, 0] = 5
    out = np.empty((4, 6), np.uint8)
    assert _png._unfilter_kernel(raw.reshape(-1), 4, 2, 3, _png.BGR, out) == 2


@pytest.mark.parametrize("kinds", ["each", "mixed"])
@pytest.mark.parametrize("shape", [(31, 45), (31, 45, 3), (1, 1), (1, 1, 3), (2, 300, 3)])
def test_opencv_pixels_for_every_filter(shape, kinds):
    rng = np.random.default_rng(len(shape))
    img = rng.integers(0, 256, shape, np.uint8)
    img[: shape[0] // 2] //= 8  # smooth parts and noisy parts
    filters = [[k] * shape[0] for k in range(5)] if kinds == "each" else [None]
    for ks in filters:
        data = make_png(img, ks)
        for gray in (False, True):
            got = decode_png(data, gray)
            want = opencv(data, gray)
            assert got is not None and want is not None
            assert got.dtype == np.uint8 and got.flags.c_contiguous
            np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    "params",
    [[cv2.IMWRITE_PNG_COMPRESSION, 0], [cv2.IMWRITE_PNG_COMPRESSION, 1], [cv2.IMWRITE_PNG_COMPRESSION, 9]],
)
def test_opencv_pixels_for_files_opencv_wrote(params):
    rng = np.random.default_rng(7)
    base = cv2.GaussianBlur(rng.integers(0, 256, (60, 80, 3), np.uint8), (7, 7), 2)
    for img in (base, base[..., 1].copy()):
        ok, buf = cv2.imencode(".png", img, params)
        assert ok
        for gray in (False, True):
            got = decode_png(buf.tobytes(), gray)
            assert got is not None
            np.testing.assert_array_equal(got, opencv(buf.tobytes(), gray))


def test_libpngs_grey_of_every_colour():
    """``IMREAD_GRAYSCALE`` of an RGB file, over all 2^24 colours (a 4096 x 4096 image)."""
    v = np.arange(1 << 24, dtype=np.uint32)
    bgr = np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], 1).astype(np.uint8).reshape(4096, 4096, 3)
    ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    got = decode_png(buf.tobytes(), True)
    assert got is not None
    np.testing.assert_array_equal(got, opencv(buf.tobytes(), True))


def _rgb(h=9, w=11):
    return np.random.default_rng(3).integers(0, 256, (h, w, 3), np.uint8)


def _corrupt_crc(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 1]) + data[at + 1 :]


def _unfinished(raw: bytes) -> bytes:
    """A zlib stream of ``raw`` flushed but never finished (no last block, no Adler-32)."""
    z = zlib.compressobj()
    return z.compress(raw) + z.flush(zlib.Z_SYNC_FLUSH)


def _with_size(data: bytes, width: int, height: int) -> bytes:
    """``data`` with another size in its IHDR (and the chunk's CRC made right)."""
    body = struct.pack(">II", width, height) + data[24:29]
    return data[:8] + chunk(b"IHDR", body) + data[33:]


LEFT_TO_OPENCV = {
    "palette": lambda: make_png(_rgb()[..., 0] % 4, [0] * 9, colour=3, extra=[(b"PLTE", bytes(range(12)))]),
    "16 bits": lambda: cv2.imencode(".png", (_rgb()[..., 0].astype(np.uint16) * 257))[1].tobytes(),
    "alpha": lambda: cv2.imencode(".png", np.dstack([_rgb(), _rgb()[..., :1]]))[1].tobytes(),
    "interlaced": lambda: make_png(_rgb(), interlace=1),
    "transparency chunk": lambda: make_png(_rgb(), extra=[(b"tRNS", b"\0\1\0\2\0\3")]),
    "gamma chunk": lambda: make_png(_rgb(), extra=[(b"gAMA", struct.pack(">I", 45455))]),
    "a private chunk": lambda: make_png(_rgb(), extra=[(b"prVt", b"x")]),
    "a wrong CRC in IHDR": lambda: _corrupt_crc(make_png(_rgb()), 8 + 8 + 2),
    "a wrong CRC in IDAT": lambda: _corrupt_crc(make_png(_rgb(), idat_parts=1), 8 + 25 + 8 + 3),
    "truncated": lambda: make_png(_rgb())[:-30],
    "bytes after IEND": lambda: make_png(_rgb()) + b"junk",
    "a stream too short": lambda: make_png(_rgb(), stream=zlib.compress(filter_rows(_rgb(), [1] * 9)[:-5])),
    "a stream too long": lambda: make_png(
        _rgb(), stream=zlib.compress(filter_rows(_rgb(), [1] * 9) + b"\0" * 34)
    ),
    "data after the stream": lambda: make_png(
        _rgb(), stream=zlib.compress(filter_rows(_rgb(), [1] * 9)) + b"zz"
    ),
    "a stream without its end": lambda: make_png(_rgb(), stream=_unfinished(filter_rows(_rgb(), [0] * 9))),
    "an unknown row filter": lambda: make_png(
        _rgb(), stream=zlib.compress(bytes([5]) + filter_rows(_rgb(), [0] * 9)[1:])
    ),
    "a header claiming more than the stream can hold": lambda: _with_size(make_png(_rgb()), 100000, 100000),
    "no IDAT": lambda: make_png(_rgb())[:33] + chunk(b"IEND", b""),
    "not a PNG": lambda: b"GIF89a" + b"\0" * 40,
}


@pytest.mark.parametrize("case", sorted(LEFT_TO_OPENCV))
def test_files_it_cannot_decode_exactly_are_left_to_opencv(case, tmp_path):
    data = LEFT_TO_OPENCV[case]()
    for gray in (False, True):
        assert decode_png(data, gray) is None
    # the source then reads the file as OpenCV does, or reports it
    path = tmp_path / "000000.png"
    path.write_bytes(data)
    try:
        want = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error:  # above OpenCV's own pixel limit
        want = None
    if want is None or want.dtype != np.uint8:
        with pytest.raises(InputError):
            read_image(path, "000000")
    else:
        got = read_image(path, "000000")
        np.testing.assert_array_equal(got, want if want.ndim == 2 or want.shape[2] == 3 else want[..., :3])


def test_a_split_idat_run_is_left_to_opencv():
    good = make_png(_rgb(), idat_parts=2)
    first_idat = good.index(b"IDAT") - 4
    n = struct.unpack(">I", good[first_idat : first_idat + 4])[0]
    cut = first_idat + 12 + n
    data = good[:cut] + chunk(b"tEXt", b"k\0v") + good[cut:]
    assert decode_png(data) is None
    # a neutral chunk before the IDAT run is fine
    data = good[:first_idat] + chunk(b"tEXt", b"k\0v") + chunk(b"pHYs", bytes(9)) + good[first_idat:]
    np.testing.assert_array_equal(decode_png(data), opencv(data, False))


def test_without_isal_the_standard_zlib_gives_the_same(monkeypatch):
    data = make_png(_rgb(40, 50))
    fast = decode_png(data)
    monkeypatch.setattr(_png, "_decompressobj", zlib.decompressobj)
    monkeypatch.setattr(_png, "_crc32", zlib.crc32)
    np.testing.assert_array_equal(decode_png(data), fast)
    assert decode_png(_corrupt_crc(data, 20)) is None


def test_the_sources_read_pngs_with_it(tmp_path, monkeypatch):
    img = _rgb(20, 30)
    path = tmp_path / "000000.png"
    path.write_bytes(make_png(img[..., ::-1].copy()))
    calls = []
    real = _png.decode_png
    monkeypatch.setattr(
        "lanegraph_io._sources.decode_png", lambda data, gray: calls.append(gray) or real(data, gray)
    )
    np.testing.assert_array_equal(read_image(path, "000000"), img)
    np.testing.assert_array_equal(
        read_image(path, "000000", gray=True), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    )
    assert calls == [False, True]


def test_real_kitti_frames_decode_as_opencv_does(kitti_drive):
    odometry = kitti_drive.parents[2] / "kitti_odometry" / "seq2" / "image_0"
    files = sorted((kitti_drive / "image_02" / "data").glob("*.png"))[:2]
    files += (
        sorted((kitti_drive / "image_03" / "data").glob("*.png"))[:1] + sorted(odometry.glob("*.png"))[:2]
    )
    assert len(files) >= 3
    for path in files:
        for gray in (False, True):
            got = decode_png(path.read_bytes(), gray)
            assert got is not None, path
            np.testing.assert_array_equal(got, cv2.imread(str(path), FLAGS[gray]))
