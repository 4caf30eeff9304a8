"""PNG decoding for the pair sources: OpenCV's pixels, in less than half its CPU time.

A stereo camera's PNG is 8-bit grey or RGB, one zlib stream over filtered rows. Inflating that
stream is most of the work, and OpenCV's libpng does it with zlib: ISA-L's inflate (the ``isal``
package, which releases the GIL) does it 2.3x faster. The rows' filters (none, sub, up, average,
Paeth: PNG specification, section 9) are then undone by one numba kernel, which also writes the
result as OpenCV gives it: BGR for an RGB image, and for ``IMREAD_GRAYSCALE`` of an RGB image
libpng's own conversion, ``(9797 R + 19234 G + 3737 B) >> 15`` (``png_set_rgb_to_gray`` with
OpenCV's weights 0.299 and 0.587 in 1/32768, truncated; identical to ``cv2.imread`` over all
2^24 colours).

Only files whose pixels this decodes exactly as OpenCV does take this path: the signature, an
IHDR chunk of 8-bit grey or RGB, not interlaced; IDAT chunks in one run; no chunk but IHDR, IDAT,
IEND and the ancillary chunks OpenCV's pixels do not depend on (text, time, physical size); every
chunk's CRC right; nothing after IEND; the zlib stream complete (its Adler-32 checked) and of
exactly the image's size, every row's filter type 0-4. Anything else (a palette, 16 bits, alpha,
``tRNS``, gamma or colour-space chunks, a damaged or truncated file) gives ``None``: the caller
decodes the file with OpenCV, which reads those too or reports what is wrong. The inflated stream
is capped at the image's size plus one byte, so a stream that would inflate to more (a deflate
bomb) stops there and is left to OpenCV.
"""

from __future__ import annotations

import struct

import numpy as np

from lanegraph import jit

try:  # ISA-L's inflate; the standard library's zlib gives the same bytes, more slowly
    from isal.isal_zlib import crc32 as _crc32
    from isal.isal_zlib import decompressobj as _decompressobj
except ImportError:  # pragma: no cover - isal is a dependency; a platform without its wheels
    from zlib import crc32 as _crc32
    from zlib import decompressobj as _decompressobj

SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: ancillary chunks that do not change the pixels OpenCV returns
NEUTRAL_CHUNKS = frozenset({b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})
#: colour type -> channels: grey, RGB
CHANNELS = {0: 1, 2: 3}
#: ``_unfilter_kernel``'s output modes: the rows as stored (grey), BGR from RGB, grey from RGB
AS_STORED, BGR, GRAY_FROM_RGB = 0, 1, 2
#: libpng's RGB-to-grey weights as OpenCV sets them (0.299, 0.587: 1/32768 units, truncated)
GRAY_WEIGHTS = (9797, 19234, 3737)
#: deflate's largest ratio of inflated to compressed size (258 bytes from about two bits)
MAX_DEFLATE_RATIO = 1032


def decode_png(data: bytes, gray: bool = False) -> np.ndarray | None:
    """``data`` (a PNG file's bytes) decoded as ``cv2.imdecode`` with ``IMREAD_GRAYSCALE`` when
    ``gray``, else ``IMREAD_UNCHANGED``, gives it (grey: ``(H, W)``; RGB: ``(H, W, 3)`` BGR, or
    ``(H, W)`` grey when ``gray``), or ``None`` when the file is not one this decodes exactly
    (see the module's text: the caller then uses OpenCV)."""
    parsed = _parse(data)
    if parsed is None:
        return None
    width, height, channels, stream = parsed
    size = (width * channels + 1) * height
    if size > MAX_DEFLATE_RATIO * len(stream):  # a header that claims more than the stream can hold
        return None
    inflater = _decompressobj()
    try:
        raw = inflater.decompress(stream, size + 1)  # at most one byte more than the image
    except Exception:  # noqa: BLE001 - isal raises IsalError, zlib zlib.error: a damaged stream
        return None
    if len(raw) != size or not inflater.eof or inflater.unused_data:
        return None
    raw = np.frombuffer(raw, np.uint8)
    if channels == 1:
        mode, out = AS_STORED, np.empty((height, width), np.uint8)
    elif gray:
        mode, out = GRAY_FROM_RGB, np.empty((height, width), np.uint8)
    else:
        mode, out = BGR, np.empty((height, width, 3), np.uint8)
    bad_row = _unfilter_kernel(raw, height, width, channels, mode, out.reshape(height, -1))
    return out if bad_row < 0 else None


def _parse(data: bytes) -> tuple[int, int, int, bytes] | None:
    """``(width, height, channels, zlib stream)`` of a PNG this module decodes, else ``None``."""
    n_data = len(data)
    if n_data < 8 or data[:8] != SIGNATURE:
        return None
    view = memoryview(data)
    pos, header, idat, idat_ended = 8, None, [], False
    while True:
        if pos + 12 > n_data:
            return None
        length, kind = struct.unpack_from(">I4s", data, pos)
        end = pos + 12 + length
        if length > 0x7FFFFFFF or end > n_data:
            return None
        body = view[pos + 8 : pos + 8 + length]
        if _crc32(body, _crc32(kind)) != struct.unpack_from(">I", data, end - 4)[0]:
            return None
        if header is None:
            if kind != b"IHDR" or length != 13:
                return None
            width, height, depth, colour, compression, filtering, interlace = struct.unpack_from(
                ">IIBBBBB", data, pos + 8
            )
            if (
                not (width and height)
                or depth != 8
                or colour not in CHANNELS
                or compression
                or filtering
                or interlace
            ):
                return None
            header = (width, height, CHANNELS[colour])
        elif kind == b"IDAT":
            if idat_ended:
                return None
            idat.append(body)
        elif kind == b"IEND":
            if length or end != n_data or not idat:
                return None
            return (*header, b"".join(idat))
        elif kind in NEUTRAL_CHUNKS:
            idat_ended = bool(idat)
        else:
            return None
        pos = end


@jit
def _unfilter_kernel(raw, height, width, channels, mode, out):
    """Undo the filter of each of ``height`` rows of ``raw`` (the inflated stream: a filter-type
    byte, then ``width * channels`` bytes, per row) into ``out`` (2-D, C-contiguous uint8):
    ``AS_STORED`` the bytes as they are (``out`` is ``(H, W * channels)``), ``BGR`` RGB written as
    BGR (``(H, 3 W)``), ``GRAY_FROM_RGB`` libpng's grey of RGB (``(H, W)``). Returns -1, or the
    first row whose filter type is not 0-4 (``out`` is then incomplete)."""
    n = width * channels
    stride = n + 1
    prev = np.empty(n, np.uint8)  # the row above, unfiltered (zeros above the first row)
    cur = np.empty(n, np.uint8)
    for i in range(n):
        prev[i] = 0
    wr, wg, wb = GRAY_WEIGHTS
    for r in range(height):
        src = raw[r * stride + 1 : (r + 1) * stride]
        kind = raw[r * stride]
        if kind == 0:
            for i in range(n):
                cur[i] = src[i]
        elif kind == 1 and channels == 3:  # sub: the byte one pixel to the left, carried in registers
            a0 = a1 = a2 = 0
            for x in range(width):
                a0 = (src[3 * x] + a0) & 255
                a1 = (src[3 * x + 1] + a1) & 255
                a2 = (src[3 * x + 2] + a2) & 255
                cur[3 * x] = a0
                cur[3 * x + 1] = a1
                cur[3 * x + 2] = a2
        elif kind == 1:
            a0 = 0
            for i in range(n):
                a0 = (src[i] + a0) & 255
                cur[i] = a0
        elif kind == 2:  # up: the byte above
            for i in range(n):
                cur[i] = (src[i] + prev[i]) & 255
        elif kind == 3:  # average of left and above, rounded down
            for i in range(channels):
                cur[i] = (src[i] + (prev[i] >> 1)) & 255
            for i in range(channels, n):
                cur[i] = (src[i] + ((np.int32(cur[i - channels]) + np.int32(prev[i])) >> 1)) & 255
        elif kind == 4:  # Paeth: left, above or upper left, whichever is nearest to left + above - upper left
            for i in range(channels):
                cur[i] = (src[i] + prev[i]) & 255  # left and upper left are 0: the predictor is above
            for i in range(channels, n):
                a = np.int32(cur[i - channels])
                b = np.int32(prev[i])
                c = np.int32(prev[i - channels])
                pa = abs(b - c)  # |p - a| with p = a + b - c
                pb = abs(a - c)
                pc = abs(a + b - c - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (src[i] + pred) & 255
        else:
            return r
        row = out[r]
        if mode == AS_STORED:
            for i in range(n):
                row[i] = cur[i]
        elif mode == BGR:
            for x in range(width):
                row[3 * x] = cur[3 * x + 2]
                row[3 * x + 1] = cur[3 * x + 1]
                row[3 * x + 2] = cur[3 * x]
        else:
            for x in range(width):
                row[x] = (
                    wr * np.int32(cur[3 * x]) + wg * np.int32(cur[3 * x + 1]) + wb * np.int32(cur[3 * x + 2])
                ) >> 15
        prev, cur = cur, prev
    return -1
