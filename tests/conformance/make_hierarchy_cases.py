#!/usr/bin/env python3
"""Writes hierarchy.json: hierarchy.bin files both readers must accept or
reject alike (tests/tileset_format_test.cpp, web/test/format.test.mjs).

The bytes are encoded here from docs/FORMAT.md ("hierarchy.bin"), by neither
reader's code. Each bad case changes one thing of a good file and keeps every
other check passing (CRCs fixed where the case is not about a CRC), so that it
reaches the check it is about; `error` is text both readers' messages contain.

Run it again after changing a case: python3 tests/conformance/make_hierarchy_cases.py
"""
import json
import os
import struct
import zlib

CHILDREN_IN_PAGE = 4
NO_PAGE = 0xFFFFFFFF


def record(level, x, y, z, mask=0, flags=0, block=(0, 0), surfels=100, spacing=0.5, bits=16, child_page=NO_PAGE):
    offset, size = block
    return struct.pack("<BBHIIIQIIIf3ffB3xI", level, mask, flags, x, y, z, offset, size, 0, surfels, spacing,
                       0.0, 0.0, 1.0, -1.0, bits, child_page)


def hierarchy(pages, nodes, version=2, record_size=64, page_depth=2, table_crc=None, entries=None):
    """pages: each a list of 64-byte records; entries overrides (offset, records, crc) per page."""
    count = len(pages)
    offset = 32 + 16 * count
    table, body = b"", b""
    for i, page in enumerate(pages):
        data = b"".join(page)
        entry = (offset, len(page), zlib.crc32(data))
        if entries and i in entries:
            entry = tuple(e if e is not None else d for e, d in zip(entries[i], entry))
        table += struct.pack("<QII", *entry)
        body += data
        offset += len(data)
    crc = zlib.crc32(table) if table_crc is None else table_crc
    return b"SCHY" + struct.pack("<IIIIIII", version, record_size, count, page_depth, nodes, crc, 0) + table + body


# The good file: page depth 2. Page 0 holds the root (children 0 and 7) and
# level 1; node 1-1-1-1's children (0 and 7) are in page 1, which starts with
# a copy of it. Five nodes, blocks of 100 bytes each in a blocks.bin of 500.
BLOCKS = 500
def good_pages(child_flags=CHILDREN_IN_PAGE, child_page=1, page1_root=(1, 1, 1, 1), extra=()):
    page0 = [record(0, 0, 0, 0, mask=0x81, block=(0, 100)),
             record(1, 0, 0, 0, block=(100, 100)),
             record(1, 1, 1, 1, mask=0x81, flags=child_flags, block=(200, 100), child_page=child_page)] + list(extra)
    page1 = [record(*page1_root, mask=0x81, block=(200, 100)),
             record(2, 2, 2, 2, block=(300, 100)),
             record(2, 3, 3, 3, block=(400, 100))]
    return [page0, page1]

GOOD_KEYS = ["0-0-0-0", "1-0-0-0", "1-1-1-1", "2-2-2-2", "2-3-3-3"]


def with_record(pages, page, index, **fields):
    """pages with one record replaced by one built from the good one's fields changed."""
    old = struct.unpack("<BBHIIIQIIIf3ffB3xI", pages[page][index])
    names = ["level", "mask", "flags", "x", "y", "z", "offset", "size", "crc", "surfels", "spacing", "ax", "ay", "az",
             "cos", "bits", "child_page"]
    values = dict(zip(names, old))
    values.update(fields)
    pages = [list(p) for p in pages]
    pages[page][index] = struct.pack("<BBHIIIQIIIf3ffB3xI", *(values[n] for n in names))
    return pages


def swapped(pages, page, i, j):
    """pages with records i and j of `page` trading places."""
    pages = [list(p) for p in pages]
    pages[page][i], pages[page][j] = pages[page][j], pages[page][i]
    return pages


def chain(depth):
    """One page holding a chain of nodes 0-0-0-0, 1-0-0-0, ... down to level `depth`."""
    page = [record(level, 0, 0, 0, mask=1 if level < depth else 0, block=(0, 0)) for level in range(depth + 1)]
    return hierarchy([page], depth + 1, page_depth=32)


def main():
    good = hierarchy(good_pages(), 5)
    cases = [
        ("good: two pages, five nodes", good, GOOD_KEYS),
        ("good: version 1 header", hierarchy(good_pages(), 5, version=1), GOOD_KEYS),
        ("good: a chain down to level 20, the deepest", chain(20), [f"{level}-0-0-0" for level in range(21)]),
        ("shorter than the header", good[:20], "shorter than the 32-byte header"),
        ("bad magic", b"SCHX" + good[4:], "bad magic"),
        ("version 3", hierarchy(good_pages(), 5, version=3), "unsupported version 3"),
        ("record size 60", hierarchy(good_pages(), 5, record_size=60), "record size"),
        ("page table past the end", good[:12] + struct.pack("<I", 1000) + good[16:], "page table runs past the end"),
        ("page table CRC", hierarchy(good_pages(), 5, table_crc=12345), "page table CRC mismatch"),
        ("page past the end of the file", hierarchy(good_pages(), 5, entries={1: (10_000, None, None)}),
         "page 1 at byte 10000: out of the file's bounds"),
        ("page of no records", hierarchy(good_pages(), 5, entries={1: (None, 0, None)}), "out of the file's bounds"),
        ("page CRC", hierarchy(good_pages(), 5, entries={1: (None, None, 7)}), "CRC mismatch"),
        ("page 1's first record is not the node that points to it",
         hierarchy(good_pages(page1_root=(1, 1, 1, 0)), 5), "page root does not match"),
        ("a node at level 21", chain(21), "level beyond 20"),
        ("a block past the end of blocks.bin", hierarchy(with_record(good_pages(), 1, 2, offset=450), 5),
         "points past the end of blocks.bin"),
        ("0 position bits", hierarchy(with_record(good_pages(), 0, 1, bits=0), 5), "0 position bits"),
        ("31 position bits", hierarchy(with_record(good_pages(), 1, 1, bits=31), 5), "31 position bits"),
        ("spacing 0", hierarchy(with_record(good_pages(), 0, 1, spacing=0.0), 5), "spacing"),
        ("spacing NaN", hierarchy(with_record(good_pages(), 1, 2, spacing=float("nan")), 5), "spacing"),
        ("spacing infinite", hierarchy(with_record(good_pages(), 0, 0, spacing=float("inf")), 5), "spacing"),
        ("more surfels than a node may hold", hierarchy(with_record(good_pages(), 1, 1, surfels=4_194_305), 5),
         "declares 4194305 surfels"),
        ("a child page that is not later", hierarchy(good_pages(child_page=0), 5), "bad child page 0"),
        ("a child page past the table", hierarchy(good_pages(child_page=2), 5), "bad child page 2"),
        ("children out of order", hierarchy(swapped(good_pages(), 0, 1, 2), 5), "children of node 0-0-0-0 out of order"),
        ("a record no parent reaches", hierarchy(good_pages(extra=[record(1, 0, 1, 0, block=(0, 100))]), 6),
         "records not reachable from the page root"),
    ]
    out = {
        "about": [
            "hierarchy.bin files both readers must accept or reject alike (docs/FORMAT.md, 'hierarchy.bin'):",
            "written by make_hierarchy_cases.py beside this file, from the format's text and not either reader's code.",
            "A reader checks the header and page table, then each page as traversal reaches it: page 0 from the root 0-0-0-0,",
            "each later page from the record that points to it (flag CHILDREN_IN_PAGE). blocks_bytes is blocks.bin's size.",
            "The bytes are in hex. A good case lists the nodes read, in file order (page roots once); a bad one the text its error must contain.",
        ],
        "blocks_bytes": BLOCKS,
        "cases": [],
    }
    for name, data, outcome in cases:
        case = {"name": name, "hierarchy": data.hex()}
        case.update({"nodes": outcome} if isinstance(outcome, list) else {"error": outcome})
        out["cases"].append(case)
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "hierarchy.json")
    with open(path, "w") as f:
        json.dump(out, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
