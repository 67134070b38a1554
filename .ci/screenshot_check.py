#!/usr/bin/env python3
"""Checks a screenshot of the built-in page (.ci/check-browser.sh, step 2), standard library only.

Usage: screenshot_check.py SHOT.png [PREVIOUS.png]

SHOT must be a real 1280x900 picture (at least 50 colours) with a greyscale slice drawn in the views (at
least 2000 grey pixels sampled left of the side panel, below the header); with PREVIOUS, the views (left
part of the page, below the header) must differ from it in at least 50 pixels.

Exit 0: all holds. Exit 3: a well-formed screenshot that does not show it yet (blank, no slice, unchanged):
the caller takes another. Exit 1: not a plausible PNG of the page (fails at once).
"""
import struct
import sys
import zlib

NOT_YET = 3


def fail(msg):
    print("check-browser: FAIL: " + msg, file=sys.stderr)
    sys.exit(1)


def not_yet(msg):
    print("check-browser: " + msg, file=sys.stderr)
    sys.exit(NOT_YET)


def decode(path):
    """Width, height and rows of RGB(A) bytes of an 8-bit truecolour PNG (standard library only)."""
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        fail("%s is not a PNG (%d bytes)" % (path, len(data)))
    if len(data) < 10000:
        not_yet("%s is a nearly empty picture (%d bytes)" % (path, len(data)))
    pos, idat, head = 8, [], None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            head = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = head
    if depth != 8 or colour not in (2, 6) or interlace:
        fail("%s: unexpected PNG format (depth %d, colour type %d)" % (path, depth, colour))
    bpp = 3 if colour == 2 else 4
    raw = zlib.decompress(b"".join(idat))
    stride = width * bpp
    rows, prev = [], bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        if f == 1:
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 255
        elif f == 2:
            line = bytearray((a + b) & 255 for a, b in zip(line, prev))
        elif f == 3:
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 255
        elif f == 4:
            for i in range(stride):
                a = line[i - bpp] if i >= bpp else 0
                b = prev[i]
                c = prev[i - bpp] if i >= bpp else 0
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(line)
        prev = line
    return width, height, bpp, rows


def main():
    path = sys.argv[1]
    w, h, bpp, rows = decode(path)
    name = path.rsplit("/", 1)[-1]
    if (w, h) != (1280, 900):
        fail("%s is %dx%d, expected 1280x900" % (path, w, h))
    colours = set()
    grey = 0
    for y in range(0, h, 2):
        row = rows[y]
        for x in range(0, w * bpp, 2 * bpp):
            px = bytes(row[x:x + 3])
            colours.add(px)
            if px[0] == px[1] == px[2] and px[0] >= 40 and y > 80 and x < 905 * bpp:
                grey += 1
    if len(colours) < 50:
        not_yet("%s looks blank (%d colours)" % (name, len(colours)))
    if grey < 2000:
        not_yet("%s: no greyscale slice in the views yet (%d grey pixels sampled)" % (name, grey))
    print("check-browser: ok: %s: %dx%d, %d colours, %d greyscale slice pixels sampled" % (name, w, h, len(colours), grey))
    if len(sys.argv) > 2:
        _, _, _, before = decode(sys.argv[2])
        changed = sum(1 for y in range(90, 520) for x in range(0, 905 * bpp, bpp) if before[y][x:x + 3] != rows[y][x:x + 3])
        if changed < 50:
            not_yet("the views did not change between the two screenshots (%d pixels differ)" % changed)
        print("check-browser: ok: %d pixels of the views changed between the screenshots" % changed)


if __name__ == "__main__":
    main()
