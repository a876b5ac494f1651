// Opening inputs by format, and the first pass over them: counts, bounds and
// what each input's colours really hold.
#pragma once

#include <climits>
#include <cmath>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "block_codec.h"
#include "default_scene.h"
#include "input_point.h"
#include "tile_source.h"
#include "mesh_reader.h"
#include "surfel.h"

namespace surfcast {

// Points decoded ahead of the visitor, at most (part of kBaselineBytes).
inline constexpr size_t kPrefetchBytes = 16u << 20;

// One input's points held in memory (InputOptions::captured).
struct CapturedInput {
    InputDescription description;
    std::vector<InputPoint> points;
    std::vector<double> scalars;  // description.scalars.size() per point
    uint64_t skipped = 0;
};

struct InputOptions {
    std::vector<std::string> paths;
    // Reads the first path from record `firstBegin` and the last one up to
    // record `lastEnd` (0: to its end): a part of a LAS/LAZ file cut by
    // inputPart (stages.h), at its cuts (las_reader.h). Other formats are read whole.
    uint64_t firstBegin = 0, lastEnd = 0;
    bool defaultScene = false;   // add the built-in scene
    SceneOptions scene;
    std::string columns;         // text layout; empty: detect
    MeshSampling mesh;
    std::shared_ptr<MeshStore> meshes;  // where every pass finds the meshes (null: each reads them anew)
    bool verticesOnly = false;   // treat a mesh file as its vertices
    // How inputs at http(s) URLs are reached (--header, --token-file, ...):
    // never stored in a plan or a record, as it may hold a token.
    HttpOptions http;
    int threads = 1;             // decoder threads (LAZ chunks)
    ScalarSelection scalars;     // scalar fields readers decode (none by default)
    bool readAlpha = false;      // PCD: take rgba's alpha byte as opacity (often junk, so off)
    double opacity = 1;          // multiplies every point's opacity (--opacity), in [0, 1]
    // Where set: the inputs' points as read once already (captureInputs),
    // one per input in their order, visited from memory instead of the files
    // (the scene and paths still say which inputs they are).
    std::shared_ptr<const std::vector<CapturedInput>> captured;
    // LAZ files read as their chunk starts (openLasChunkStarts): a preview's sample.
    bool chunkStarts = false;
};

// A sample of the inputs in memory (a preview's: surfcast-build --preview):
// every stride-th point of each input, counted from its first.
struct CapturedInputs {
    std::shared_ptr<const std::vector<CapturedInput>> inputs;
    uint32_t stride = 1;
};
// Reads every input once, keeping every stride-th point of each; where more
// than `most` points would be held, the stride doubles (and what is held
// thins to it) as often as needed, so the sample stays within `most`
// whatever the stride guessed. With options.chunkStarts a LAZ file's chunk
// starts are each kept (but for that thinning), and the stride is at least
// what they stand for: the file's points over those held.
Result<CapturedInputs> captureInputs(const InputOptions& options, uint32_t stride, uint64_t most);

// A point's stored opacity: its own alpha times `opacity`, rounded to 8 bits.
inline uint8_t pointAlpha(uint8_t alpha, double opacity) { return opacity == 1 ? alpha : uint8_t(std::lround(alpha * opacity)); }

// A short name of the coordinate system InputDescription::crs holds, for
// messages: a WKT's own name, or the EPSG code of GeoTIFF keys 3072
// (projected) or 2048 (geographic).
std::string crsName(const std::string& crs);
// What two coordinate systems are compared by: the EPSG code where the text
// gives one (GeoTIFF keys 3072 or 2048, the WKT's closing AUTHORITY or ID),
// so that a WKT and GeoTIFF keys of one code agree; else the text itself.
std::string crsIdentity(const std::string& crs);

// The input files that `args` name, in order: a file as itself, a tile set's
// folder as its tileset.json (set_reader.h), another folder as every file
// under it with an extension some reader takes (recursively, sorted by path;
// tile sets within it are not inputs), and "@LIST" as the paths in the text file LIST, one per line
// (blank lines and lines starting with '#' skipped; relative paths are taken
// relative to LIST's folder).
Result<std::vector<std::string>> expandInputPaths(const std::vector<std::string>& args);

// Visits every input in order with a fresh reader, each closed before the
// visitor gets the next. Threads read the files ahead:
// small files are decoded whole while the visitor works on earlier ones (at
// most kPrefetchBytes of points and 64 files wait), so the open files,
// decoders and buffers stay bounded however many inputs there are.
Status forEachInput(const InputOptions& options, const std::function<Status(size_t index, PointReader& reader)>& visit);

// What the first pass learns of each input (one entry per reader).
struct SourceStats {
    InputDescription description;
    uint64_t points = 0, skipped = 0;
    Box3d bounds;
    uint16_t colorMax = 0;      // largest raw colour channel value
    bool colors8Bit = true;     // every channel value is exactly representable in 8 bits
    bool colorsTimes256 = true; // every channel value is a multiple of 256 (8-bit values shifted)
    double colorScale = 1;      // multiplier to the 16-bit range (LAS files storing 0..255 get 257)
};

// What the first pass learns of the LiDAR attributes, over the inputs that
// carry each one: an attribute is stored only where it varies.
struct AttributeStats {
    uint64_t intensityPoints = 0, classifiedPoints = 0, returnPoints = 0;
    std::vector<uint64_t> intensityHistogram = std::vector<uint64_t>(65536);  // points per value
    std::vector<uint64_t> classCounts = std::vector<uint64_t>(256);          // points per class
    std::vector<uint64_t> returnsHistogram = std::vector<uint64_t>(256);     // points per packed returns byte
    uint64_t translucentPoints = 0;  // points whose stored opacity (pointAlpha) is under 255
};

// What the first pass learns of one scalar field (input_point.h), over the
// inputs that carry it (matched by name; the first input's kind and resolution hold).
struct ScalarStats {
    ScalarField field;
    uint64_t points = 0;  // with a valid (non-NaN) value
    double min = HUGE_VAL, max = -HUGE_VAL;
    // The exponent of the finest bit any value sets (v = m · 2^e with m an
    // odd integer: the least e); every value is a multiple of 2^finestBit.
    int finestBit = INT_MAX;
};

// The least e with v = m · 2^e for an integer m (INT_MAX for 0).
int finestBitOf(double v);

// How a stored scalar field maps to the integers blocks carry:
// q = round((v - offset) / step), clamped to [0, 2^bits - 1]. A point without
// a valid value (NaN, or an input without the field) gets 0. A field exact
// in more than 32 bits is two of them (docs/FORMAT.md, "Scalar attributes"):
// with N = round((v - offset) / (step / 2^lowBits)), this one holds N >> lowBits
// and the next, "<name>:low" (lowPart; offset 0), N's lowBits lowest bits.
struct ScalarQuantization {
    std::string name;
    bool categorical = false;
    double offset = 0, step = 1;
    int bits = 1;
    int lowBits = 0;
    bool lowPart = false;
    // The set's provenance (docs/FORMAT.md, "Provenance"): each point's input,
    // which forEachBatch fills in, not a field of the inputs.
    bool provenance = false;
};


struct InputStats {
    std::vector<SourceStats> sources;
    uint64_t points = 0, skipped = 0;
    Box3d bounds;
    bool anyColors = false;
    int colorBits = 0;          // 0 (no colour), 8 or 16: what the tile set stores
    AttributeStats attributes;
    std::vector<ScalarStats> scalars;  // in the order the inputs first offer them
    uint64_t largestMeshBytes = 0;     // the most one read of a mesh took (MeshStore::largestBytes), for the budget
};

// Pass 1. `progress` receives point counts as they are read.
Result<InputStats> scanInputs(const InputOptions& options, const std::function<void(uint64_t)>& progress);
// The statistics of consecutive runs of inputs (scanInputs of each), in
// order: the same as scanInputs of all of them at once. continues[p]: part p
// starts within the input the parts before it ended in (a file cut between
// parts), whose sources become one.
InputStats mergeInputStats(std::vector<InputStats> parts, const std::vector<bool>& continues);

// Every accepted point as a Surfel (position minus `origin`, colour scaled to
// 16 bits, LiDAR attributes as read, Surfel::source = sourceIds[input] + the
// point's scan where its input has several), in
// batches, with the `stored` scalar fields quantized: stored.size() per point
// (a provenance field: inputOf[source], the input each source belongs to).
using BatchConsumer = std::function<Status(std::span<Surfel>, std::span<const uint32_t> scalars)>;
Status forEachBatch(const InputOptions& options, const InputStats& stats, const Vec3d& origin,
                    std::span<const uint16_t> sourceIds, std::span<const ScalarQuantization> stored,
                    const BatchConsumer& consume, std::span<const uint32_t> inputOf = {});

}  // namespace surfcast
