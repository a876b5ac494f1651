#!/usr/bin/env python3
"""Writes blocks.json: Draco blocks both readers must decode or reject alike
(tests/block_codec_test.cpp, web/test/format.test.mjs).

The good blocks are the one node of a 150-point default scene that
surfcast-build writes (Draco's own encoder) in each codec, `draco` and
`draco-columns`, and of 100 points with a 32-bit scalar (two columns); each bad case changes one field of a header (docs/FORMAT.md,
"blocks.bin": the offsets of Draco 1.5's bitstream 2.x), or cuts a blob short,
or puts one where another belongs, so that it reaches the check it is about.
Header checks come before decoding, so a bad case of the one-blob codec keeps
only the bytes its check reads. `error` is text both readers' messages contain.

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


def build(binary, out, codec, inputs=("--default-scene", "--scene-points", "150")):
    """The one block of a set (by default of a 150-point default scene), and its tileset.json."""
    subprocess.run([binary, "-q", *inputs, "--codec", codec, "-o", out], check=True, stdout=subprocess.DEVNULL)
    info = json.load(open(os.path.join(out, "tileset.json")))
    assert info["nodes"] == 1, "one node: the whole blocks.bin is its block"
    assert info["blocks"]["codec"] == codec
    return open(os.path.join(out, "blocks.bin"), "rb").read(), info


def main():
    binary = sys.argv[1] if len(sys.argv) > 1 else "build/bin/surfcast-build"
    with tempfile.TemporaryDirectory() as tmp:
        block, info = build(binary, os.path.join(tmp, "draco"), "draco")
        split, split_info = build(binary, os.path.join(tmp, "columns"), "draco-columns")
        # 100 points on a plane with a 32-bit scalar "stamp" over [0, 2^32).
        ply = os.path.join(tmp, "stamped.ply")
        with open(ply, "w") as f:
            f.write("ply\nformat ascii 1.0\nelement vertex 100\nproperty float x\nproperty float y\nproperty float z\n"
                    "property uint stamp\nend_header\n")
            for i in range(100):
                f.write(f"{i % 10} {i // 10} 0 {(i * 2654435761) % 2**32 if i else 2**32 - 1}\n")
        wide, wide_info = build(binary, os.path.join(tmp, "wide"), "draco-columns", [ply, "--attributes", "stamp"])
    assert split_info["attributes"] == info["attributes"], "the two codecs' sets list the same attributes"
    stamp = [a for a in wide_info["attributes"] if a["name"] == "stamp"]
    assert stamp and stamp[0]["type"] == "uint32", "stamp is a 32-bit scalar"
    wide_names = [a["name"] for a in wide_info["attributes"]]
    wide_points = struct.unpack_from("<i", wide, 4 + 11)[0]
    wide_expect = {"points": wide_points, "color_bits": wide_info["color_bits"], "radii": "radius" in wide_names,
                   "edge_weights": False, "weights": False, "extra": ["stamp"], "extra_bits": [32]}
    points = struct.unpack_from("<i", block, 11)[0]
    names = [a["name"] for a in info["attributes"]]
    # What the node's record and tileset.json tell a reader to expect.
    expect = {"codec": "draco-columns", "points": points, "color_bits": info["color_bits"], "normals": "normal" in names,
              "weights": "weight" in names, "radii": "radius" in names, "edge_weights": "edge_weight" in names}
    draco = {"codec": "draco"}
    attributes = block[16]  # a varint below 128: one byte

    def patched(at, fmt, value, keep=64, source=None):
        b = bytearray((block if source is None else source)[:keep])
        struct.pack_into(fmt, b, at, value)
        return bytes(b)

    # Four attributes of four 8-byte components: 48 bytes a point to decode.
    huge = bytearray(block[:16]) + bytes([attributes])
    struct.pack_into("<i", huge, 11, 4_194_304)
    for i in range(attributes):
        huge += bytes([0, 8, 4, 0, i])  # attribute type, data type uint64, 4 components, normalized, unique id
    # draco-columns: u32 the positions blob's bytes, the positions blob, the columns blob.
    kd = struct.unpack_from("<I", split, 0)[0]
    positions, columns = split[4:4 + kd], split[4 + kd:]
    assert positions[:5] == b"DRACO" and positions[8] == 1 and columns[:5] == b"DRACO" and columns[8] == 0
    assert struct.unpack_from("<i", positions, 11)[0] == points == struct.unpack_from("<i", columns, 11)[0]

    def columns_case(positions_blob, columns_blob):
        return struct.pack("<I", len(positions_blob)) + positions_blob + columns_blob

    def patched_columns(at, fmt, value):
        b = bytearray(columns)
        struct.pack_into(fmt, b, at, value)
        return columns_case(positions, bytes(b))

    cases = [
        ("draco: good: the node's block", block, draco, {"count": points}),
        ("draco: a block that is not Draco", b"PLY" + block[3:64], draco, "the block is not Draco"),
        ("draco: shorter than a Draco header", block[:16], draco, "the block is not Draco"),
        ("draco: bitstream version 3", patched(5, "<B", 3), draco, "bitstream version 3"),
        ("draco: a mesh, not a point cloud", patched(7, "<B", 1), draco, "not a point cloud"),
        ("draco: sequential coding, not kd-tree", patched(8, "<B", 0), draco, "not kd-tree coded"),
        ("draco: metadata", patched(9, "<H", 0x8000), draco, "carries metadata"),
        ("draco: a negative point count", patched(11, "<i", -1), draco, "negative point count"),
        ("draco: more points than the record", patched(11, "<i", points + 1), draco, f"declares {points + 1} points"),
        ("draco: two attribute decoders", patched(15, "<B", 2), draco, "2 attribute decoders"),
        ("draco: another attribute count than tileset.json's", block, {**draco, "radii": not expect["radii"]},
         "attributes; the tile set declares"),
        ("draco: cut in its attribute descriptors", block[:19], draco, "ends in its attribute descriptors"),
        ("draco: an attribute of 5 components", patched(19, "<B", 5), draco, "has 5 components"),
        ("draco: an attribute of data type 12", patched(18, "<B", 12), draco, "of type 12"),
        ("draco: 4,194,304 points of 48 bytes each to decode", bytes(huge), {**draco, "points": 4_194_304}, "MiB to decode"),
        ("draco: the body cut short", block[:len(block) // 2], draco, "Draco decoding failed"),
        ("good: the node's block", split, {}, {"count": points}),
        ("shorter than the positions blob's length", split[:3], {}, "ends before its positions blob's length"),
        ("a positions blob past the block's end", struct.pack("<I", len(split)) + split[4:], {}, "runs past its end"),
        ("positions not Draco", columns_case(b"PLY" + positions[3:], columns), {}, "the positions blob is not Draco"),
        ("positions sequentially coded", columns_case(patched(8, "<B", 0, len(positions), positions), columns), {},
         "the positions blob is not kd-tree coded"),
        ("positions of more points than the record", columns_case(patched(11, "<i", points + 1, len(positions), positions), columns),
         {}, f"the positions blob declares {points + 1} points"),
        ("the whole block's attributes in the positions blob", columns_case(block, b""), {}, "the positions blob has"),
        ("no columns blob", columns_case(positions, b""), {}, "the columns blob is not Draco"),
        ("columns kd-tree coded", patched_columns(8, "<B", 1), {}, "the columns blob is not sequentially coded"),
        ("columns of more points than the record", patched_columns(11, "<i", points + 1), {},
         f"the columns blob declares {points + 1} points"),
        ("another column count than tileset.json's", split, {"radii": not expect["radii"]},
         "the columns blob has"),
        ("columns cut short", columns_case(positions, columns[:len(columns) // 2]), {}, "Draco decoding failed"),
        ("good: a 32-bit scalar in two columns", wide, wide_expect, {"count": wide_points}),
        ("a 32-bit scalar taken for one column", wide, {**wide_expect, "extra_bits": [16]}, "the columns blob has"),
        ("a LiDAR attribute declared 32-bit", wide, {**wide_expect, "extra": ["intensity"]}, "has an unexpected type"),
        ("a 16-bit column where a class belongs", wide,
         {**wide_expect, "extra": ["classification", "user_data"], "extra_bits": [8, 8]}, "has an unexpected type"),
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
