// What every stage of a build knows once the inputs are scanned: the options,
// the scan's statistics and the decisions that follow from them alone (the
// root box, the leaves' precision, the normals' orientation rules, which
// attributes are stored and how). Any process that holds the same options and
// statistics derives the same context, so the stages can run in different
// processes (stages.h) and still write the same bytes.
#pragma once

#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "block_codec.h"
#include "level_attributes.h"
#include "normals.h"
#include "octree_builder.h"
#include "sampler.h"
#include "texture_field.h"

namespace surfcast {

// Bits of the stored intensity (chooseAttributes): a 12-bit code by default,
// the value itself (step 1) where --attributes asks for intensity.
inline constexpr int kIntensityBits = 12;
// The bits of a set's intensity codes: 16 where it stores values (step 1), else 12.
inline int intensityCodeBits(double step) { return step == 1 ? 16 : kIntensityBits; }

// Where the build's time goes, summed over threads (BuildSummary::stepSeconds).
enum Step { kStepNormals, kStepOctree, kStepAttributes, kStepTextures, kStepEncode, kStepCount };
inline constexpr const char* kStepNames[kStepCount] = {"normals", "octree", "neighbours+h+weights", "textures", "encode"};
using StepTimes = std::atomic<uint64_t>[kStepCount];  // nanoseconds per Step

// Adds the wall time of a scope to a step's counter.
class ScopedTimer {
public:
    explicit ScopedTimer(std::atomic<uint64_t>& ns) : ns_(ns), start_(std::chrono::steady_clock::now()) {}
    ~ScopedTimer() {
        ns_ += uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start_).count());
    }

private:
    std::atomic<uint64_t>& ns_;
    std::chrono::steady_clock::time_point start_;
};

// The options as every stage reads them: threads resolved (0: all cores) and
// handed to the decoders, the scalar fields --attributes names added to those
// the readers decode, and a mesh store (MeshStore) shared by the passes.
BuildOptions normalizeOptions(BuildOptions options);

class BuildContext {
public:
    // Derives the decisions from the scan, and the textured meshes' texture
    // fields (--texture-filter ewa and optimal) from the meshes (read from
    // options.inputs.meshes, or their files). `options`: normalizeOptions'.
    // `report`: warn about attributes asked for and not stored (once per
    // build: the stages after the plan derive the same context quietly).
    // `set`: an update in place keeps that context's root box (its kept
    // blocks are positioned in it), and the inputs must lie inside it; with
    // `keepLayout` also its leaf step, its stored attributes and their
    // quantization (what every block was written with: an update that removes
    // points, whose values the set's layout still holds exactly), and the
    // provenance attribute where the inputs need it and the set has none.
    static Result<std::shared_ptr<const BuildContext>> derive(const BuildOptions& options, InputStats stats, bool report = true,
                                                              const BuildContext* set = nullptr, bool keepLayout = false);

    // `c` with its root cube replaced (an update that grows a set past its
    // root: the old root becomes a node of the new one).
    static std::shared_ptr<const BuildContext> rerooted(const BuildContext& c, const Vec3d& rootMin, double rootEdge);
    // `c` with the layout a set's tileset.json records (an update in place:
    // its root cube, which attributes it stores and their quantization),
    // whatever the statistics derive; a scalar field keeps its type's whole
    // width, so values the update adds within the type are not clipped.
    static std::shared_ptr<const BuildContext> withLayoutOf(const BuildContext& c, const TilesetInfo& set);

    const BuildOptions& options() const { return opt_; }
    const InputStats& stats() const { return stats_; }
    int threads() const { return threads_; }
    const Vec3d& rootMin() const { return rootMin_; }
    double rootEdge() const { return rootEdge_; }
    double edge(int level) const { return std::ldexp(rootEdge_, -level); }
    Vec3d nodeMinRel(const NodeKey& k) const {
        const double e = edge(k.level);
        return {k.x * e, k.y * e, k.z * e};
    }
    const NormalContext& normals() const { return normals_; }
    std::span<const uint16_t> sourceIds() const { return sourceIds_; }
    // Per source (InputStats::sources): the input it belongs to (the built-in
    // scene's scans are input 0, then the paths in order), the provenance value.
    std::span<const uint32_t> inputOfSource() const { return inputOfSource_; }
    // The inputs' names as tileset.json lists them (docs/FORMAT.md, "Provenance").
    const std::vector<std::string>& inputNames() const { return inputNames_; }

    // Stored attributes.
    bool stores(int lidar) const { return store_[lidar]; }
    bool storesOpacity() const { return storeOpacity_; }
    const std::vector<ScalarQuantization>& scalars() const { return stored_; }
    ScalarTable emptyTable() const;
    // Leaves keep every input point, exact duplicate positions too (TilesetInfo::duplicatesKept).
    bool keepsDuplicates() const { return duplicatesKept_; }
    // The quantized intensity a surfel stores.
    uint16_t storedIntensity(uint16_t intensity) const;

    // Textured meshes: the field of a surfel's orientation rule, or null.
    const TextureField* textureOf(const Surfel& s) const {
        return s.source < textureFields_.size() ? textureFields_[s.source].get() : nullptr;
    }
    std::span<const std::shared_ptr<const TextureField>> textureFields() const { return textureFields_; }
    bool anyTexture() const;
    // Some textured mesh's colours are fitted by least squares (--texture-filter optimal).
    bool fitting() const;
    uint64_t textureBytes() const { return textureBytes_; }

    // Working memory per chunk point (kBytesPerChunkPoint and what the stored
    // fields and the texture fit add).
    uint64_t bytesPerChunkPoint() const;

    // The grid a resampled node is sampled on (kLevelReduction), given the
    // surfels of its children.
    SampleGrid nodeGrid(const NodeKey& k, std::span<const Surfel> below) const;
    // Quantization bits of a node's positions: `cell` is the cell it was
    // sampled on, 0 for leaves (input points).
    int positionBits(const NodeKey& key, double cell) const;
    LevelParams levelParams(int level, double fallbackSpacing, int threads) const;

    // The tile set's description (TilesetInfo) but for what only the writer
    // and the finished tree know (nodes, levels, surfels, bytes).
    TilesetInfo tilesetInfo() const;
    // The summary's fields the context decides: colour bits, normal source,
    // attributes stored, texture filter.
    void describe(BuildSummary* summary) const;

private:
    BuildContext() = default;
    void chooseRootBox();
    Status chooseOrientationRules();
    Status chooseAttributes();
    void chooseLasSource();
    TilesetStatistics statistics() const;

    BuildOptions opt_;
    bool report_ = true;
    InputStats stats_;
    int threads_ = 1;
    Vec3d rootMin_;
    double rootEdge_ = 1;
    double leafStep_ = 0;  // quantization step at the leaves; 0: unknown precision
    NormalContext normals_;
    std::vector<uint16_t> sourceIds_;  // per input: its orientation rule, Surfel::source
    std::vector<uint32_t> inputOfSource_;
    std::vector<std::string> inputNames_;
    std::string normalSource_, textureFilter_;
    bool store_[kLidarCount] = {};  // per kLidarAttributes: stored
    bool storeOpacity_ = false;     // some surfel is translucent: "opacity" is stored
    std::vector<ScalarQuantization> stored_;  // scalar fields stored, in block order
    std::vector<std::string> attributeNames_;  // LiDAR attributes, opacity and scalar fields stored
    int intensityOffset_ = 0, intensityStep_ = 1;  // stored intensity = (value - offset) / step
    std::vector<ConstantAttribute> constants_;  // dimensions of one value, in no block
    std::vector<std::string> leftOut_;           // dimensions the inputs carry and the set does not keep
    LasSourceInfo las_;                          // what the LAS inputs' headers agree on
    bool duplicatesKept_ = false;
    // Per orientation rule: the texture of the textured mesh that alone has it
    // (--texture-filter ewa or optimal), else null.
    std::vector<std::shared_ptr<const TextureField>> textureFields_;
    uint64_t textureBytes_ = 0;  // what textureFields_ hold (TextureField::bytes)
};

}  // namespace surfcast
