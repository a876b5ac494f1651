#!/usr/bin/env python3
"""Writes small seed inputs for the fuzz targets from ../shared/data, from
tile sets built by surfcast-build (nothing here is copied into the repository)
and from the format's conformance cases (tests/conformance: every tileset.json
and block case, good and bad, for fuzz_tileset and fuzz_block).

Usage: make_seeds.py DATA_DIR SETS_DIR OUT_DIR
  DATA_DIR  ../shared/data (PROVENANCE.md lists the scans)
  SETS_DIR  a folder of tile sets (fuzz/run.sh builds them)
  OUT_DIR   gets one folder per target: read_ply, read_las, read_laz, read_e57, read_pcd,
            read_xyz, read_obj, read_gltf, read_glb, tileset, block (client_response, http_request
            and range seeds are committed in fuzz/seeds)
Needs laspy with lazrs (scripts/test-venv.sh installs them into build/test-venv).
"""
import os
import re
import base64
import json
import struct
import sys
import zlib

import laspy
import numpy as np

KEEP = 64  # points per seed: enough to pass every header check, small to mutate


def out(path, data):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "wb") as f:
        f.write(data)


def ply_seeds(data, dst):
    for name in sorted(os.listdir(data)):
        if not name.endswith(".ply"):
            continue
        raw = open(os.path.join(data, name), "rb").read()
        end = raw.index(b"end_header") + len(b"end_header")
        end = raw.index(b"\n", end) + 1
        header, body = raw[:end].decode("latin-1"), raw[end:]
        if "format ascii" in header:
            lines = body.split(b"\n")
            count = int(re.search(r"element vertex (\d+)", header).group(1))
            verts = lines[:KEEP]
            faces = [l for l in lines[count:count + 2000] if l and all(int(i) < KEEP for i in l.split()[1:])][:KEEP]
            h = re.sub(r"element vertex \d+", "element vertex %d" % len(verts), header)
            h = re.sub(r"element face \d+", "element face %d" % len(faces), h)
            out(os.path.join(dst, name), h.encode() + b"\n".join(verts + faces) + b"\n")
            out(os.path.join(dst, "points-" + name), re.sub(r"element face \d+", "element face 0", h).encode()
                + b"\n".join(verts) + b"\n")
    # Binary, both byte orders, with colour, normals, alpha and a label.
    for order, fmt in (("<", "binary_little_endian"), (">", "binary_big_endian")):
        header = ("ply\nformat %s 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                  "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\n"
                  "property uchar blue\nproperty uchar alpha\nproperty ushort intensity\nproperty int label\n"
                  "element face 2\nproperty list uchar int vertex_indices\nend_header\n" % fmt).encode()
        body = b""
        for i, (x, y) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
            body += struct.pack(order + "6f4BHi", x, y, 0, 0, 0, 1, 200, 100, 50, 255, 1000 * i, i % 3)
        body += struct.pack(order + "B3i", 3, 0, 1, 2) + struct.pack(order + "B3i", 3, 1, 3, 2)
        out(os.path.join(dst, "quad-%s.ply" % fmt), header + body)


def las_seeds(data, las_dst, laz_dst):
    os.makedirs(las_dst, exist_ok=True)
    os.makedirs(laz_dst, exist_ok=True)
    for name in sorted(os.listdir(data)):
        if not (name.endswith(".las") or name.endswith(".laz")):
            continue
        src = laspy.read(os.path.join(data, name))
        # A fresh header of the same format and version: laspy cannot write
        # a COPC file's VLRs back.
        header = laspy.LasHeader(point_format=src.header.point_format, version=src.header.version)
        header.scales, header.offsets = src.header.scales, src.header.offsets
        small = laspy.LasData(header)
        small.points = laspy.ScaleAwarePointRecord(src.points.array[:KEEP].copy(), header.point_format,
                                                   header.scales, header.offsets)
        stem = name.split(".")[0]
        small.write(os.path.join(las_dst, stem + ".las"))
        small.write(os.path.join(laz_dst, stem + ".laz"), do_compress=True)
    # LAS 1.4 format 6 with Extra Bytes: a scaled int and a float.
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([laspy.ExtraBytesParams("amplitude", "int16", scales=np.array([0.1]), offsets=np.array([0.0])),
                           laspy.ExtraBytesParams("deviation", "float32")])
    las = laspy.LasData(header)
    n = 16
    las.x = np.arange(n, dtype=float)
    las.y = np.arange(n, dtype=float) * 2
    las.z = np.zeros(n)
    las.intensity = np.arange(n, dtype=np.uint16) * 100
    las.classification = np.arange(n, dtype=np.uint8) % 4
    las.amplitude = np.arange(n) * 1.5
    las.deviation = np.arange(n, dtype=np.float32) / 3
    las.write(os.path.join(las_dst, "extra-bytes.las"))
    las.write(os.path.join(laz_dst, "extra-bytes.laz"), do_compress=True)


def lzf_literal(data):
    """LZF stream of literal runs only (control byte n < 32: n + 1 literal bytes)."""
    outb = bytearray()
    for i in range(0, len(data), 32):
        chunk = data[i:i + 32]
        outb.append(len(chunk) - 1)
        outb += chunk
    return bytes(outb)


def e57_seeds(data, dst):
    """The shared E57 files under 64 KiB, as their pages' payloads: the
    target (fuzz/read_e57.cpp) writes the checksums back."""
    folder = os.path.join(data, "e57")
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if not name.endswith(".e57") or os.path.getsize(path) > 65536:
            continue
        with open(path, "rb") as f:
            raw = f.read()
        payload = b"".join(raw[k:k + 1020] for k in range(0, len(raw), 1024))
        out(os.path.join(dst, name), payload)


def pcd_seeds(data, dst):
    for name in sorted(os.listdir(data)):
        if not name.endswith(".pcd"):
            continue
        raw = open(os.path.join(data, name), "rb").read()
        end = raw.index(b"\n", raw.index(b"DATA")) + 1
        header = raw[:end].decode("latin-1")
        sizes = [int(s) for s in re.search(r"SIZE ([\d ]+)", header).group(1).split()]
        counts = [int(s) for s in re.search(r"COUNT ([\d ]+)", header).group(1).split()] if "COUNT" in header else [1] * len(sizes)
        stride = sum(s * c for s, c in zip(sizes, counts))
        h = re.sub(r"WIDTH \d+", "WIDTH %d" % KEEP, header)
        h = re.sub(r"HEIGHT \d+", "HEIGHT 1", h)
        h = re.sub(r"POINTS \d+", "POINTS %d" % KEEP, h)
        if "binary_compressed" in header:
            # Decompressing LZF here is not needed: seed with the first points of
            # an uncompressed twin, column by column, compressed as literals.
            continue
        if "DATA binary" in header:
            rows = raw[end:end + KEEP * stride]
            out(os.path.join(dst, name), h.encode() + rows)
            # The same points as binary_compressed (PCL's column-major layout).
            cols = b"".join(b"".join(rows[r * stride + off:r * stride + off + s * c] for r in range(KEEP))
                            for off, s, c in _columns(sizes, counts))
            hc = h.replace("DATA binary", "DATA binary_compressed")
            comp = lzf_literal(cols)
            out(os.path.join(dst, "compressed-" + name), hc.encode() + struct.pack("<II", len(comp), len(cols)) + comp)
        else:
            lines = raw[end:].split(b"\n")[:KEEP]
            out(os.path.join(dst, name), h.encode() + b"\n".join(lines) + b"\n")
    out(os.path.join(dst, "ascii-intensity.pcd"),
        b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity label\nSIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n"
        b"WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n0 0 0 1 2\n1 0 0 5 2\n0 1 nan 3 6\n")


def _columns(sizes, counts):
    off = 0
    for s, c in zip(sizes, counts):
        yield off, s, c
        off += s * c


def text_seeds(data, dst):
    src = laspy.read(os.path.join(data, "autzen_trim.las"))
    rows = ["%.3f %.3f %.3f %d %d %d" % (x, y, z, r >> 8, g >> 8, b >> 8)
            for x, y, z, r, g, b in zip(src.x[:KEEP], src.y[:KEEP], src.z[:KEEP], src.red[:KEEP], src.green[:KEEP],
                                        src.blue[:KEEP])]
    out(os.path.join(dst, "autzen.xyz"), ("\n".join(rows) + "\n").encode())
    out(os.path.join(dst, "header.xyz"), ("x,y,z,red,green,blue\n" + "\n".join(r.replace(" ", ",") for r in rows[:8])
                                          + "\n").encode())


def obj_seeds(data, dst):
    lines = open(os.path.join(data, "fg_spkMgDragon", "fg_spkMgDragon.obj"), encoding="latin-1").read().split("\n")
    verts = [l for l in lines if l.startswith("v ")][:KEEP]
    texs = [l for l in lines if l.startswith("vt ")][:KEEP]
    norms = [l for l in lines if l.startswith("vn ")][:KEEP]
    faces = []
    for l in lines:
        if l.startswith("f "):
            idx = [int(p.split("/")[0]) for p in l.split()[1:]]
            if max(idx) <= KEEP:
                faces.append(re.sub(r"/\d*(/\d*)?", "", l))
    out(os.path.join(dst, "dragon.obj"), ("\n".join(verts + texs + norms + faces[:KEEP]) + "\n").encode())
    out(os.path.join(dst, "quad.obj"), b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2//1 4//1 3//1\n")


def png(width, height, rgb_of):
    """A small RGB PNG (filter 0 rows) of texels rgb_of(i, j)."""
    raw = b"".join(b"\0" + bytes(c for i in range(width) for c in rgb_of(i, j)) for j in range(height))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def gltf_seeds(gltf_dst, glb_dst):
    """A textured quad (indexed, with a node transform and baseColorFactor) and
    an untextured one, as .gltf with a data-URI buffer and image, and as .glb."""
    geometry = struct.pack("<12f", 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0) + struct.pack("<8f", 0, 1, 1, 1, 1, 0, 0, 0) \
        + struct.pack("<6H", 0, 1, 2, 0, 2, 3)
    image = png(4, 4, lambda i, j: (60 * i, 60 * j, 90))

    def scene(buffer, image_entry, image_view):
        views = [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                 {"buffer": 0, "byteOffset": 80, "byteLength": 12}] + image_view
        return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
                "nodes": [{"mesh": 0, "translation": [1, 0, 0], "scale": [2, 2, 2], "children": [1]},
                          {"mesh": 1, "rotation": [0, 0, 0.7071068, 0.7071068]}],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]},
                           {"primitives": [{"attributes": {"POSITION": 0}, "material": 1}]}],
                "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "baseColorFactor": [1, 0.5, 1, 1]}},
                              {"pbrMetallicRoughness": {"baseColorFactor": [0, 1, 0, 1]}}],
                "textures": [{"source": 0}], "images": [image_entry], "buffers": [buffer], "bufferViews": views,
                "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                               "min": [0, 0, 0], "max": [1, 1, 0]},
                              {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                              {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]}
    uri = "data:application/octet-stream;base64," + base64.b64encode(geometry).decode()
    text = scene({"uri": uri, "byteLength": len(geometry)},
                 {"uri": "data:image/png;base64," + base64.b64encode(image).decode()}, [])
    out(os.path.join(gltf_dst, "quads.gltf"), json.dumps(text).encode())
    binary = geometry + image
    binary += b"\0" * (-len(binary) % 4)
    doc = json.dumps(scene({"byteLength": len(binary)}, {"bufferView": 3, "mimeType": "image/png"},
                           [{"buffer": 0, "byteOffset": 92, "byteLength": len(image)}])).encode()
    doc += b" " * (-len(doc) % 4)
    glb = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(doc) + 8 + len(binary)) + struct.pack("<I4s", len(doc), b"JSON") + doc \
        + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    out(os.path.join(glb_dst, "quads.glb"), glb)


def set_seeds(sets, tileset_dst, block_dst):
    for name in sorted(os.listdir(sets)):
        d = os.path.join(sets, name)
        if not os.path.exists(os.path.join(d, "tileset.json")):
            continue
        js = open(os.path.join(d, "tileset.json"), "rb").read()
        hier = open(os.path.join(d, "hierarchy.bin"), "rb").read()
        blocks = open(os.path.join(d, "blocks.bin"), "rb").read()
        # fuzz_tileset reads blocks.bin's first bytes after the hierarchy: as
        # many as run.sh's -max_len leaves (the first records' blocks).
        out(os.path.join(tileset_dst, name), js + b"\0" + hier + blocks[:max(0, 65536 - len(js) - 1 - len(hier))])
        # The first records of page 0: each block with the flags its set declares.
        pages = struct.unpack_from("<I", hier, 12)[0]
        page0 = struct.unpack_from("<Q", hier, 32)[0]
        count = struct.unpack_from("<I", hier, 40)[0]
        meta = js.decode()
        color = 0 if '"color_bits": 0' in meta or '"color_bits":0' in meta else 1
        for i in range(min(count, 4)):
            rec = page0 + 64 * i
            off, size = struct.unpack_from("<QI", hier, rec + 16)
            flags = struct.unpack_from("<H", hier, rec + 2)[0]
            f = color | 4 | 8 | (16 if flags & 2 else 0) | (32 if flags & 16 else 0)
            f |= 64 if "classification" in meta else 0
            count = struct.unpack_from("<I", hier, rec + 32)[0]
            columns = 0x8000 if '"draco-columns"' in meta else 0
            if count < 32768:  # the target takes the record's count as 15 bits, the codec as the 16th
                out(os.path.join(block_dst, "%s-%d" % (name, i)), bytes([f]) + struct.pack("<H", count | columns) +
                    blocks[off:off + size])
        del pages


def conformance_seeds(tileset_dst, block_dst):
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "conformance")
    corpus = json.load(open(os.path.join(here, "tileset_json.json")))

    def walk(doc, pointer):
        path = [p.replace("~1", "/").replace("~0", "~") for p in pointer.split("/")[1:]]
        for p in path[:-1]:
            doc = doc[int(p)] if isinstance(doc, list) else doc[p]
        return doc, (int(path[-1]) if isinstance(doc, list) else path[-1])

    for i, case in enumerate(corpus["cases"]):
        if "text" in case:
            text = case["text"]
        else:
            doc = json.loads(json.dumps(corpus["good"]))
            for pointer, value in case.get("set", {}).items():
                parent, key = walk(doc, pointer)
                parent[key] = value
            for pointer in case.get("remove", []):
                parent, key = walk(doc, pointer)
                del parent[key]
            text = json.dumps(doc, indent=2)
        # fuzz_tileset's input: tileset.json, a NUL, then hierarchy.bin (none here).
        out(os.path.join(tileset_dst, "conformance-%02d" % i), text.encode() + b"\0")
    blocks = json.load(open(os.path.join(here, "blocks.json")))
    for i, case in enumerate(blocks["cases"]):
        e = dict(blocks["expect"], **case.get("expect", {}))
        f = (1 if e["color_bits"] == 8 else 2 if e["color_bits"] == 16 else 0) | (4 if e["normals"] else 0) | \
            (8 if e["weights"] else 0) | (16 if e["radii"] else 0) | (32 if e["edge_weights"] else 0)
        if e["points"] < 32768:  # the target takes the record's count as 15 bits, the codec as the 16th
            columns = 0x8000 if e["codec"] == "draco-columns" else 0
            out(os.path.join(block_dst, "conformance-%02d" % i), bytes([f]) + struct.pack("<H", e["points"] | columns) +
                bytes.fromhex(case["block"]))


def main():
    data, sets, dst = sys.argv[1:4]
    conformance_seeds(os.path.join(dst, "tileset"), os.path.join(dst, "block"))
    ply_seeds(data, os.path.join(dst, "read_ply"))
    las_seeds(data, os.path.join(dst, "read_las"), os.path.join(dst, "read_laz"))
    e57_seeds(data, os.path.join(dst, "read_e57"))
    pcd_seeds(data, os.path.join(dst, "read_pcd"))
    text_seeds(data, os.path.join(dst, "read_xyz"))
    obj_seeds(data, os.path.join(dst, "read_obj"))
    gltf_seeds(os.path.join(dst, "read_gltf"), os.path.join(dst, "read_glb"))
    set_seeds(sets, os.path.join(dst, "tileset"), os.path.join(dst, "block"))


if __name__ == "__main__":
    main()
