// A tile set's points back out as LAZ: the input points its leaves hold
// (docs/FORMAT.md: leaves are the input points, exact duplicates merged),
// those inside a box and of the classes asked for, with the value (never the
// stored code) of every dimension the set keeps, stored or constant: colour,
// the LiDAR attributes, the LAS fields (las_reader.h) and the Extra Bytes
// dimensions, other inputs' scalar fields as float64 extra bytes; and the
// inputs' header fields the set kept (LasSourceInfo). LAS 1.4, compressed by
// the `laz` crate (preprocess/readers/laz_ffi), written as a stream:
// surfcast-export writes it to a file, surfcast-serve sends it as it is
// produced. Or COPC, to a file.
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "tileset_reader.h"

namespace surfcast {

struct PointFilter {
    std::optional<Box3d> box;  // world coordinates, bounds included; none: every point
    std::vector<uint8_t> classes;  // ASPRS classes kept; empty: every class
};

// "2,6,9" (boxes: parseBox in camera.h): errors name the text.
Result<std::vector<uint8_t>> parseClasses(const std::string& text);

// What an export writes: the points it keeps and bounds that hold them (for
// a whole set, from the hierarchy and tileset.json's bounds grown by half the
// coarsest leaf step; else the points' own, from a first pass that decodes
// each leaf the filter reaches), and the LAS layout (point format; the scale
// and offset are the set's, the same for every box).
struct LazExportPlan {
    std::vector<size_t> nodes;  // indices into set.nodes(): leaves the filter reaches, in hierarchy order
    uint64_t points = 0;
    uint64_t pointsByReturn[15] = {};  // of the points kept, by return number 1-15
    Box3d bounds;
    Vec3d scale{0.001, 0.001, 0.001};  // per axis, as LAS stores it
    Vec3d offset;
    // The inputs' own point format where they agree on one that holds what
    // the set keeps, else LAS 1.4's 6-10 (COPC: 6-8) by colour, NIR and wave
    // packets; the record's bytes, with the Extra Bytes VLR's descriptors.
    int pointFormat = 6;
    size_t recordBytes = 30;
    std::vector<std::vector<uint8_t>> extraBytes;
    // The dimensions the records carry values of (stored or constant), and
    // those the inputs had that the set or the point format left out.
    std::vector<std::string> dimensions, leftOut;
};

// The most points the filter can keep, from the hierarchy alone (the
// surfels of the leaves its box reaches): a cheap refusal of an export over
// a limit before any block is decoded.
uint64_t exportPointsAtMost(const TilesetReader& set, const PointFilter& filter);

// `stop`, where given, is asked before each leaf is decoded: true ends the
// export with an error (a server whose client left, or that is stopping).
using StopExport = std::function<bool()>;
Result<LazExportPlan> planLazExport(const TilesetReader& set, const PointFilter& filter, const StopExport& stop = {});

// The LAZ file's bytes, in order, to `out` (which may fail the export).
// Decodes the plan's leaves again; fails if they no longer give its points.
Status writeLazExport(const TilesetReader& set, const PointFilter& filter, const LazExportPlan& plan,
                      const std::function<Status(const uint8_t*, size_t)>& out, const StopExport& stop = {});

// COPC 1.0 (copc.io) into `f` (a new file, seekable: the header is written
// last): the same points and records as writeLazExport, in an octree on the
// set's own root cube, each node one LAZ chunk. Leaves are walked depth
// first, decoded once; a point goes to the shallowest node above its leaf
// whose cell (128 per axis) it falls in is still empty, else to its leaf, so
// every node above the leaves holds an even sample of what lies under it (and
// at least one point where anything does, which readers descending only
// through non-empty nodes need), and only the nodes above the current leaf
// wait in memory (each a 256 KiB cell mask and its records). The hierarchy is
// one page, an EVLR after the chunk table.
struct CopcReport {
    uint64_t points = 0;
    size_t nodes = 0;
    int pointFormat = 6;
    std::vector<std::string> dimensions, leftOut;  // as LazExportPlan's
};
Result<CopcReport> writeCopcExport(const TilesetReader& set, const PointFilter& filter, std::FILE* f, const StopExport& stop = {});

}  // namespace surfcast
