#!/usr/bin/env python3
"""Writes blocks.json: Draco blocks both readers must decode or reject alike
(tests/block_codec_test.cpp, web/test/format.test.mjs).

The good block is the one node of a 150-point default scene that
surfcast-build writes (Draco's own encoder); each bad case changes one field
of its header (docs/FORMAT.md, "blocks.bin": the offsets of Draco 1.5's
bitstream 2.x), or cuts it short, so that it reaches the check it is about.
Header checks come before decoding, so a bad case keeps only the bytes its
check reads. `error` is text both readers' messages contain.

Run it again after changing a case:
    python3 tests/conformance/make_block_cases.py build/bin/surfcast-build
"""
import json
import os
import struct
import subprocess
import sys
import tempfile
import zlib


def main():
    build = sys.argv[1] if len(sys.argv) > 1 else "build/bin/surfcast-build"
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "set")
        subprocess.run([build, "-q", "--default-scene", "--scene-points", "150", "-o", out], check=True,
                       stdout=subprocess.DEVNULL)
        info = json.load(open(os.path.join(out, "tileset.json")))
        block = open(os.path.join(out, "blocks.bin"), "rb").read()
    assert info["nodes"] == 1, "one node: the whole blocks.bin is its block"
    points = struct.unpack_from("<i", block, 11)[0]
    names = [a["name"] for a in info["attributes"]]
    # What the node's record and tileset.json tell a reader to expect.
    expect = {"points": points, "color_bits": info["color_bits"], "normals": "normal" in names,
              "weights": "weight" in names, "radii": "radius" in names, "edge_weights": "edge_weight" in names}
    attributes = block[16]  # a varint below 128: one byte

    def patched(at, fmt, value, keep=64):
        b = bytearray(block[:keep])
        struct.pack_into(fmt, b, at, value)
        return bytes(b)

    # Four attributes of four 8-byte components: 48 bytes a point to decode.
    huge = bytearray(block[:16]) + bytes([attributes])
    struct.pack_into("<i", huge, 11, 4_194_304)
    for i in range(attributes):
        huge += bytes([0, 8, 4, 0, i])  # attribute type, data type uint64, 4 components, normalized, unique id
    cases = [
        ("good: the node's block", block, {}, {"count": points}),
        ("a block that is not Draco", b"PLY" + block[3:64], {}, "not a Draco block"),
        ("shorter than a Draco header", block[:16], {}, "not a Draco block"),
        ("bitstream version 3", patched(5, "<B", 3), {}, "bitstream version 3"),
        ("a mesh, not a point cloud", patched(7, "<B", 1), {}, "not a point cloud"),
        ("sequential coding, not kd-tree", patched(8, "<B", 0), {}, "not kd-tree coded"),
        ("metadata", patched(9, "<H", 0x8000), {}, "carries metadata"),
        ("a negative point count", patched(11, "<i", -1), {}, "negative point count"),
        ("more points than the record", patched(11, "<i", points + 1), {}, f"declares {points + 1} points"),
        ("two attribute decoders", patched(15, "<B", 2), {}, "2 attribute decoders"),
        ("another attribute count than tileset.json's", block, {"radii": not expect["radii"]}, "attributes; the tile set declares"),
        ("cut in its attribute descriptors", block[:19], {}, "ends in its attribute descriptors"),
        ("an attribute of 5 components", patched(19, "<B", 5), {}, "has 5 components"),
        ("an attribute of data type 12", patched(18, "<B", 12), {}, "of type 12"),
        ("4,194,304 points of 48 bytes each to decode", bytes(huge), {"points": 4_194_304}, "MiB to decode"),
        ("the body cut short", block[:len(block) // 2], {}, "Draco decoding failed"),
    ]
    result = {
        "about": [
            "Draco blocks both readers must decode or reject alike: common/block_codec.cpp's decodeBlock",
            "(tests/block_codec_test.cpp) and web/src/block_decode.ts's decodeBlock with draco3d (web/test/format.test.mjs).",
            "Written by make_block_cases.py beside this file from a block surfcast-build wrote. `expect` is what the node's",
            "record and tileset.json say (a case's own `expect` overrides fields of it). The bytes are in hex; `crc` is",
            "their CRC-32, as the record would hold it. A good case gives the surfels decoded, a bad one its error's text.",
        ],
        "expect": expect,
        "cases": [],
    }
    for name, data, override, outcome in cases:
        case = {"name": name, "block": data.hex(), "crc": zlib.crc32(data)}
        if override:
            case["expect"] = override
        case.update(outcome if isinstance(outcome, dict) else {"error": outcome})
        result["cases"].append(case)
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "blocks.json")
    with open(path, "w") as f:
        json.dump(result, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
