// The tile-set build: inputs → chunks on disk → a subtree per chunk → the
// levels above the chunks → tile set, as the stages of stages.h, here in one
// process. Follows DESIGN.md decisions 2-4: every
// level is a complete resampling on its node's grid (G³, or coarser where that
// keeps more than a quarter of the surfels below: kLevelReduction), leaves hold
// the input points, a node splits above `capacity` surfels, and each node gets
// h, a visibility cone and analytic normalization weights.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "inputs.h"
#include "level_attributes.h"
#include "tileset_format.h"
#include "status.h"
#include "texture_field.h"

namespace surfcast {

struct BuildOptions {
    InputOptions inputs;
    std::string output;
    int grid = 128;                     // G: cells per axis of a node's finest sampling grid
    uint32_t pageDepth = kDefaultPageDepth;  // levels per hierarchy page (docs/FORMAT.md)
    uint32_t capacity = 20000;          // surfels above which a node splits
    uint64_t memoryBytes = 2ull << 30;  // peak RSS budget
    int threads = 0;                    // 0: all cores
    int normalK = 16;                   // neighbours for PCA normals
    int spacingK = 8;                   // k of the k-th-neighbour spacing h
    int fetchK = 24;                    // neighbours fetched per d_k query (room to skip those facing away)
    double cutoff = 1.0;                // kernel cutoff c the weights assume
    double kernelScale = kDefaultKernelScale;  // k of V^r = (k h)^2 I the weights assume
    double positionFraction = 8;        // resampled levels: quantization step = cell size / this
    bool weights = false;               // store analytic per-surfel normalization weights (ewa-surfel reads them)
    bool radii = true;                  // store a per-surfel radius in irregularly sampled nodes
    double isolation = kDefaultIsolation;  // isolated surfels drawn at their level's spacing (level_attributes.h); 0: off
    // > 0: statistical outlier removal. An input point leaves the set where
    // its d_k (--spacing-k) exceeds the mean over its chunk's points by this
    // many standard deviations, and twice the mean (chunk_stage.cpp,
    // removeOutliers). 0: off, every point kept.
    double removeOutliers = 0;
    BlockCodec blockCodec = BlockCodec::DracoColumns;  // how blocks are coded (bench/BENCHMARKS.md, "Block coding")
    int normalBits = 8;                 // BlockCodecOptions::normalBits (bench/BENCHMARKS.md, "Block coding")
    // Attributes to store, each where some input carries it: names from
    // kLidarAttributes, and scalar fields (input_point.h) by name, which
    // inputs.scalars must select too. Unset: all of kLidarAttributes, each only
    // where it varies across the set ("model no more than a scene needs"), and
    // no scalar field.
    std::optional<std::vector<std::string>> attributes;
    bool progress = true;
    // The command line the set's build record keeps (docs/FORMAT.md,
    // "Updates in place"): options as surfcast-build parses them, -o and the
    // inputs. Empty: the set keeps no record and cannot be updated.
    std::vector<std::string> commandLine;
    // A preview of the build: its inputs sampled every `preview`-th point
    // (InputOptions::stride), marked so in tileset.json; 0: a build.
    uint32_t preview = 0;
    // Refinement while building (refine.h): where set, versions published to
    // `output` as the chunks are built, the chunks not built yet made from
    // about `points` of the input points (standInStride), at least `interval`
    // seconds apart (0: after every chunk) and rarer where publishing is slow
    // (kRefineCostFactor).
    struct Refine {
        uint64_t points = 200'000;
        double interval = 2;
    };
    std::optional<Refine> refine;
    // Colours of textured meshes' surfels (Zwicker et al. 2001, §5), on every
    // level: the texture filtered with each surfel's own kernel (ewa,
    // view-independent EWA), or the least-squares coefficients of eq. 10-11
    // for the renderer's normalized kernels (optimal); both texture_field.h.
    // Or the texture at the surfel's centre on the leaves and the resampled
    // averages above (nearest).
    enum class TextureFilter { Nearest, Ewa, Optimal } textureFilter = TextureFilter::Optimal;
};

struct BuildSummary {
    uint64_t inputPoints = 0, skippedPoints = 0, surfels = 0, nodes = 0;
    uint64_t removedOutliers = 0;  // input points --remove-outliers took out
    int levels = 0;
    size_t chunks = 0;
    std::vector<uint64_t> nodesPerLevel, surfelsPerLevel;
    uint64_t hierarchyBytes = 0, blocksBytes = 0;
    std::vector<std::pair<std::string, double>> phaseSeconds;
    std::vector<std::pair<std::string, double>> stepSeconds;  // inside build/upper, summed over threads
    double totalSeconds = 0;  // the whole build; 0 where it ran in stages (the merge's summary lists its own phases)
    uint64_t peakRss = 0;
    std::string normalSource;
    int colorBits = 0;
    std::vector<std::string> attributes;  // LiDAR attributes, opacity and scalar fields stored
    std::string textureFilter;            // textureFilterName() where a textured mesh was read, else empty
    FitReport textureFit;                 // the optimal filter's solves
    uint64_t textureBytes = 0;            // the texture fields held through the build (TextureField::bytes)
    uint64_t meshReads = 0;               // meshes read from their files (each once, unless the budget dropped one)

    std::string text() const;
};

// The whole build in this process (stages.h, one after another).
Result<BuildSummary> buildTileset(const BuildOptions& options);

// "nearest", "ewa" or "optimal": the --texture-filter and tileset.json spelling.
const char* textureFilterName(BuildOptions::TextureFilter filter);

// Bytes of working memory per point while a chunk is built (points, halo,
// kd-trees, sort keys, resampled levels), measured on the default scene (320
// with 48-byte surfels; 360 for the 56-byte ones that carry the LiDAR
// attributes, each surfel byte held about five times over; 400 for the
// 64-byte ones with opacity); the chunk size follows from the budget with it.
inline constexpr uint64_t kBytesPerChunkPoint = 400;
// And per stored scalar field: its value for the point and for the resampled
// surfels above it (about 1/3 per point at most: kLevelReduction), and the chunk file's buffer.
inline constexpr uint64_t kBytesPerChunkScalar = 12;
// Memory the build needs whatever the chunk size: code, libraries, counting
// grid (16 MiB), file buffers, upper levels.
inline constexpr uint64_t kBaselineBytes = 48ull << 20;
// Chunks built at the same time, each with its share of the budget. Fixed, not
// the thread count: the chunk layout, and so the output, must not depend on it.
inline constexpr uint64_t kChunksAtOnce = 2;
// Working memory of one least-squares solve of --texture-filter optimal (a
// run of at most 8192 surfels and its halo: matrices, triplets, CG vectors):
// 22.6 MB at most on the dragon, with slack (bench/BENCHMARKS.md, "Memory
// outside the chunks").
inline constexpr uint64_t kFitBytesPerSolve = 32ull << 20;
// Solves a chunk runs at once, whatever the thread count: their memory is a
// fixed part of the budget, and the chunk layout does not depend on threads.
inline constexpr int kFitSolvesPerChunk = 2;
// And per chunk point while optimal textures are fitted: the level's fit
// copies (position, normal, sigma, colour), its grid and back-references.
inline constexpr uint64_t kFitBytesPerChunkPoint = 112;
// A resampled node holds at most 1/kLevelReduction of the surfels below it
// (one at least): where its G³ grid keeps more, it is sampled on the grid of
// floor(G / kGridCoarsening^j) cells per axis for the smallest j that keeps
// few enough (BuildContext::nodeGrid). A quarter is what a surface keeps when its
// spacing doubles; summed over the tree, a set holds at most 4/3 surfels per
// input point plus 4/3 per node above fewer than four (DESIGN.md decision 3
// asks for at least a half, about 4/3 per point on surfaces). The rule and its
// step were chosen by measurement: bench/BENCHMARKS.md, "Surfels per input point".
inline constexpr size_t kLevelReduction = 4;
inline constexpr double kGridCoarsening = 1.189207115002721;  // 2^(1/4): a surface's cells halve every two steps
// A chunk holds at least this many full leaves (capacity points each), so
// that its subtree has levels to resample: the smallest budget follows from it.
inline constexpr uint64_t kMinChunkLeaves = 4;

}  // namespace surfcast
