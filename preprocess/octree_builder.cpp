#include "octree_builder.h"

#include <algorithm>
#include <atomic>
#include <cassert>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>
#include <unistd.h>

#include "block_codec.h"
#include "chunker.h"
#include "cones.h"
#include "level_attributes.h"
#include "normals.h"
#include "progress.h"
#include "sampler.h"
#include "texture_field.h"
#include "tileset_writer.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// Leaves of inputs whose precision is unknown (doubles, text) are quantized to
// this fraction of the leaf's cell size.
constexpr double kUnknownPrecisionFraction = 256;
// Float32 coordinates: 24 significant bits.
constexpr double kFloat32Epsilon = 0x1.0p-24;
// A default scan origin farther from the data than this many data extents is ignored.
constexpr double kFarOrigin = 10;
// Data whose height is under this fraction of its width is terrain: normals up.
constexpr double kFlatRatio = 0.25;

double distanceToBox(const Vec3d& p, const Box3d& b) {
    Vec3d d;
    for (int a = 0; a < 3; ++a) d[a] = std::max({b.min[a] - p[a], 0.0, p[a] - b.max[a]});
    return length(d);
}

// Adds the wall time of a scope to a counter: where the build's time goes,
// summed over worker threads.
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

// Sorts points along a Morton curve over the cube [lo, lo + edge)³ (points
// outside are clamped to it). It made FLANN's normals queries 1.4x faster on a
// real scan; with the grid search (which sorts its own copy) it measured
// neither faster nor slower, and it is kept for the normals' writes and the
// subtree partition, which then walk memory in runs.
void sortMorton(std::vector<Surfel>& points, const Vec3d& lo, double edge) {
    const double scale = double((1 << 21) - 1) / edge;
    std::vector<std::pair<uint64_t, uint32_t>> keys(points.size());
    for (size_t i = 0; i < points.size(); ++i) {
        uint32_t c[3];
        for (int a = 0; a < 3; ++a) c[a] = uint32_t(std::clamp((points[i].position[a] - lo[a]) * scale, 0.0, double((1 << 21) - 1)));
        keys[i] = {mortonCode(c[0], c[1], c[2]), uint32_t(i)};
    }
    std::sort(keys.begin(), keys.end());
    std::vector<Surfel> sorted(points.size());
    for (size_t i = 0; i < keys.size(); ++i) sorted[i] = points[keys[i].second];
    points.swap(sorted);
}

// Surfels of one least-squares solve at most (--texture-filter optimal): a
// larger node is solved in runs of this many, each with its halo.
constexpr uint32_t kFitGroupSurfels = 8192;

// Bits of the stored intensity (chooseAttributes).
constexpr int kIntensityBits = 12;
// Most bits of a stored scalar field (Draco's integer attributes are 32-bit).
constexpr int kMaxScalarBits = 32;
// Bits of a stored floating-point scalar field (ScalarField::resolution 0).
constexpr int kFloatScalarBits = 24;

enum Step { kStepNormals, kStepOctree, kStepAttributes, kStepTextures, kStepEncode, kStepCount };
const char* const kStepNames[kStepCount] = {"normals", "octree", "neighbours+h+weights", "textures", "encode"};

struct BuiltNode {
    NodeKey key;
    std::vector<Surfel> surfels;
    uint8_t childMask = 0;
    bool inputPoints = false;
    double cell = 0;  // the cell of the grid a resampled node was sampled on (Builder::nodeGrid); 0 for leaves
    LevelNode level;
};

class Builder {
public:
    explicit Builder(const BuildOptions& o) : opt_(o), progress_(o.progress) {
        threads_ = o.threads > 0 ? o.threads : int(std::max(1u, std::thread::hardware_concurrency()));
        opt_.inputs.threads = threads_;
        // Scalar fields are decoded only when asked for by name.
        if (opt_.attributes)
            for (const std::string& name : *opt_.attributes)
                if (lidarIndex(name) < 0 && !opt_.inputs.scalars.wants(name)) opt_.inputs.scalars.names.push_back(name);
    }

    Result<BuildSummary> run();

private:
    Status scan();
    void chooseRootBox();
    Status chooseOrientationRules();
    Status chooseAttributes();
    TilesetStatistics statistics() const;
    Status planAndDistribute();
    Status buildChunks();
    Status buildChunk(const Chunk& chunk, int innerThreads);
    BuiltNode* buildSubtree(std::vector<Surfel>& pts, size_t b, size_t e, const NodeKey& key,
                            std::vector<std::unique_ptr<BuiltNode>>& nodes, ScalarTable& scalars);
    Status buildUpperLevels();
    // The colours of one level's surfels from textured meshes
    // (--texture-filter ewa or optimal), once the level's h (and radii) are
    // known; `halo`: the level's surfels beyond these nodes (other chunks).
    void filterLevelTextures(std::span<BuiltNode* const> nodes, std::span<const Surfel> halo, int threads);
    Status emit(BuiltNode& node, const ScalarTable& scalars);
    uint64_t bytesPerChunkPoint() const {
        return kBytesPerChunkPoint + kBytesPerChunkScalar * stored_.size() + (fitting() ? kFitBytesPerChunkPoint : 0);
    }
    // Some textured mesh's colours are fitted by least squares (--texture-filter optimal).
    bool fitting() const {
        return opt_.textureFilter == BuildOptions::TextureFilter::Optimal &&
               std::any_of(textureFields_.begin(), textureFields_.end(), [](const auto& f) { return f != nullptr; });
    }
    ScalarTable emptyTable() const {
        ScalarTable t;
        for (const ScalarQuantization& q : stored_) t.categorical.push_back(q.categorical);
        return t;
    }
    int positionBits(const BuiltNode& node) const;
    double edge(int level) const { return std::ldexp(rootEdge_, -level); }
    Vec3d nodeMinRel(const NodeKey& k) const {
        double e = edge(k.level);
        return {k.x * e, k.y * e, k.z * e};
    }
    SampleGrid nodeGrid(const NodeKey& k, std::span<const Surfel> below) const;
    std::vector<Surfel> resampleHalo(const std::vector<Surfel>& halo, const Chunk& chunk, double margin, int level,
                                     std::span<BuiltNode* const> members) const;
    // The largest cell any of `nodes` was sampled on: the fallback h of a node
    // with no neighbours at all.
    double largestCell(int level, std::span<BuiltNode* const> nodes) const {
        double cell = edge(level) / opt_.grid;
        for (const BuiltNode* n : nodes) cell = std::max(cell, n->cell);
        return cell;
    }
    LevelParams levelParams(double fallbackSpacing, int threads) const {
        LevelParams p;
        p.spacingK = opt_.spacingK;
        p.fetchK = opt_.fetchK;
        p.cutoff = opt_.cutoff;
        p.kernelScale = opt_.kernelScale;
        p.radii = opt_.radii;
        p.fallbackSpacing = fallbackSpacing;
        p.weights = opt_.weights;
        p.threads = threads;
        return p;
    }
    void phaseDone(const std::string& name) { summary_.phaseSeconds.push_back({name, progress_.end()}); }

    BuildOptions opt_;
    int threads_ = 1;
    bool store_[kLidarCount] = {};  // per kLidarAttributes: stored
    bool storeOpacity_ = false;     // some surfel is translucent: "opacity" is stored
    std::vector<ScalarQuantization> stored_;  // scalar fields stored, in block order
    int intensityOffset_ = 0, intensityStep_ = 1;  // stored intensity = (value - offset) / step
    Progress progress_;
    InputStats stats_;
    Vec3d rootMin_;
    double rootEdge_ = 1;
    double leafStep_ = 0;  // quantization step at the leaves; 0: unknown precision
    NormalContext normals_;
    std::vector<uint16_t> sourceIds_;  // per input: its orientation rule, Surfel::source
    // Per orientation rule: the texture of the textured mesh that alone has it
    // (--texture-filter ewa or optimal), else null.
    std::vector<std::shared_ptr<const TextureField>> textureFields_;
    uint64_t textureBytes_ = 0;  // what textureFields_ hold (TextureField::bytes), through the whole build
    std::string chunkDir_;
    ChunkLayout layout_;
    std::unique_ptr<TilesetWriter> writer_;
    std::mutex mutex_;  // guards retained_ and summary_ counters
    std::map<NodeKey, std::unique_ptr<BuiltNode>> retained_;  // chunk roots, for the levels above
    ScalarTable upperScalars_;  // rows of retained_ and the levels above them
    BuildSummary summary_;
    std::atomic<uint64_t> stepNs_[kStepCount] = {};
};

Status Builder::scan() {
    progress_.begin("scan", 0);
    auto stats = scanInputs(opt_.inputs, [&](uint64_t n) { progress_.advance(n); });
    if (!stats) return stats.status();
    phaseDone("scan");
    stats_ = std::move(*stats);
    if (stats_.points == 0)
        return Status::error("the inputs hold no valid points (" + std::to_string(stats_.skipped) + " skipped as NaN/Inf)");
    chooseRootBox();
    SC_TRY(chooseOrientationRules());
    SC_TRY(chooseAttributes());
    upperScalars_ = emptyTable();
    summary_.colorBits = stats_.colorBits;
    return {};
}

TilesetStatistics Builder::statistics() const {
    TilesetStatistics st;
    st.elevationMin = stats_.bounds.min.z;
    st.elevationMax = stats_.bounds.max.z;
    const AttributeStats& a = stats_.attributes;
    if (store_[kLidarIntensity]) {
        st.intensity = true;
        // The value below which a fraction p of the points lie (the lowest such).
        auto percentile = [&](double p) {
            const uint64_t rank = uint64_t(std::ceil(p * double(a.intensityPoints)));
            uint64_t seen = 0;
            for (size_t v = 0; v < a.intensityHistogram.size(); ++v)
                if ((seen += a.intensityHistogram[v]) >= std::max<uint64_t>(rank, 1)) return double(v);
            return 65535.0;
        };
        st.intensityMin = percentile(0);
        st.intensityMax = percentile(1);
        st.intensityP2 = percentile(0.02);
        st.intensityP98 = percentile(0.98);
    }
    if (store_[kLidarClassification])
        for (int c = 0; c < 256; ++c)
            if (a.classCounts[size_t(c)]) st.classCounts.push_back({c, a.classCounts[size_t(c)]});
    return st;
}

// Which LiDAR attributes the set stores (BuildOptions::attributes), and how
// the intensity is quantized.
Status Builder::chooseAttributes() {
    const AttributeStats& a = stats_.attributes;
    auto distinct = [](const std::vector<uint64_t>& histogram, auto key) {
        std::set<int> values;
        for (size_t v = 0; v < histogram.size(); ++v)
            if (histogram[v]) values.insert(key(int(v)));
        return values.size();
    };
    auto self = [](int v) { return v; };
    const bool carried[kLidarCount] = {a.intensityPoints > 0, a.classifiedPoints > 0, a.returnPoints > 0, a.returnPoints > 0};
    // The return number and the number of returns go together (one means
    // little without the other): both are stored where either varies.
    const size_t values[kLidarCount] = {distinct(a.intensityHistogram, self), distinct(a.classCounts, self),
                                        distinct(a.returnsHistogram, self), distinct(a.returnsHistogram, self)};
    for (int i = 0; i < kLidarCount; ++i) store_[i] = carried[i] && (opt_.attributes || values[i] > 1);
    if (opt_.attributes) {
        for (const std::string& name : *opt_.attributes) {
            int i = lidarIndex(name);
            if (i >= 0 && !carried[i]) std::fprintf(stderr, "warning: --attributes %s: no input carries it; not stored\n", name.c_str());
            auto isField = [&](const ScalarStats& f) { return f.field.name == name; };
            if (i < 0 && std::none_of(stats_.scalars.begin(), stats_.scalars.end(), isField))
                return Status::error("--attributes: no input has an attribute '" + name +
                                     "' (LAS/LAZ: intensity, classification, return_number, number_of_returns, scan_angle, "
                                     "user_data, point_source_id, gps_time, nir and the Extra Bytes dimensions; PLY and PCD: "
                                     "their property names)");
        }
        for (int i = 0; i < kLidarCount; ++i)
            store_[i] = store_[i] && std::find(opt_.attributes->begin(), opt_.attributes->end(), kLidarAttributes[i]) !=
                                         opt_.attributes->end();
    }
    // One of the return pair asked for brings the other.
    store_[kLidarReturnNumber] = store_[kLidarNumberOfReturns] = store_[kLidarReturnNumber] || store_[kLidarNumberOfReturns];
    for (int i = 0; i < kLidarCount; ++i)
        if (store_[i]) summary_.attributes.push_back(kLidarAttributes[i]);
    // Opacity only where some point is translucent: an opaque set carries none.
    storeOpacity_ = a.translucentPoints > 0;
    if (storeOpacity_) summary_.attributes.push_back(kOpacityAttribute);
    // Scalar fields (selected by name or with "all": every one found that
    // varies is stored): exact at the file's own resolution where it has one
    // and the range fits 32 bits; floating ones in the power-of-two step that
    // splits the set's range into at most 2^24 (float32's precision).
    for (const ScalarStats& f : stats_.scalars) {
        // A constant field carries no information per point; stored, it still
        // costs Draco's kd-tree coder: seven constant fields beside the usual
        // attributes doubled the bytes of a scan (bench/BENCHMARKS.md).
        if (!(f.max > f.min)) {
            std::fprintf(stderr, "warning: --attributes %s: %s across the set; not stored\n", f.field.name.c_str(),
                         f.points ? ("constant (" + std::to_string(f.min) + ")").c_str() : "no valid value");
            continue;
        }
        ScalarQuantization q;
        q.name = f.field.name;
        q.categorical = f.field.categorical;
        const double lo = f.min, range = f.max - f.min;
        const double maxSteps = std::ldexp(1.0, kMaxScalarBits) - 1;
        const double floatSteps = std::ldexp(1.0, kFloatScalarBits) - 1;
        q.offset = lo;
        q.step = f.field.resolution > 0 ? f.field.resolution : std::exp2(std::ceil(std::log2(range / floatSteps)));
        while (range / q.step > maxSteps) q.step *= 2;
        q.bits = std::max(1, int(std::ceil(std::log2(std::round(range / q.step) + 1))));
        stored_.push_back(q);
        summary_.attributes.push_back(q.name);
    }
    // Intensity as (value - min) / step with the smallest power-of-two step
    // that fits the set's range in kIntensityBits: exact for ranges up to 4096
    // values (Megaplot, autzen, lone-star); a 16-bit range keeps 1/4096 of it,
    // finer than any display maps it (docs/FORMAT.md).
    if (store_[kLidarIntensity]) {
        const TilesetStatistics st = statistics();
        intensityOffset_ = int(st.intensityMin);
        intensityStep_ = 1;
        while ((st.intensityMax - st.intensityMin) / intensityStep_ >= double(1 << kIntensityBits)) intensityStep_ *= 2;
    }
    return {};
}

// The cubic root box around the points' bounds, and the leaves' quantization step.
void Builder::chooseRootBox() {
    // A hair larger than the bounds, so the maximum lies inside.
    const Box3d& b = stats_.bounds;
    double extent = std::max({b.max.x - b.min.x, b.max.y - b.min.y, b.max.z - b.min.z});
    double magnitude = std::max({std::fabs(b.min.x), std::fabs(b.min.y), std::fabs(b.min.z), std::fabs(b.max.x),
                                 std::fabs(b.max.y), std::fabs(b.max.z), 1.0});
    // Identical points have no extent: give them a box a million times their
    // coordinates' resolution.
    rootEdge_ = std::max(extent * (1 + 1e-6), magnitude * 1e-9);
    Vec3d centre = (b.min + b.max) * 0.5;
    rootMin_ = centre - Vec3d{rootEdge_, rootEdge_, rootEdge_} * 0.5;

    bool unknown = false;
    double step = HUGE_VAL;
    for (const SourceStats& s : stats_.sources) {
        const InputDescription& d = s.description;
        double mag = std::max({std::fabs(s.bounds.min.x), std::fabs(s.bounds.min.y), std::fabs(s.bounds.min.z),
                               std::fabs(s.bounds.max.x), std::fabs(s.bounds.max.y), std::fabs(s.bounds.max.z)});
        if (d.precision > 0) step = std::min(step, d.precision);
        else if (d.float32Coordinates) step = std::min(step, mag * kFloat32Epsilon);
        else unknown = true;
    }
    leafStep_ = unknown || !(step > 0) || !std::isfinite(step) ? 0 : step;
}

// The normal-orientation policy of each input (normals.h), deduplicated: inputs
// that orient alike share a rule, so Surfel::source stays 16-bit however many
// inputs there are.
Status Builder::chooseOrientationRules() {
    const Box3d& b = stats_.bounds;
    normals_.centre = (b.min + b.max) * 0.5 - rootMin_;
    normals_.k = opt_.normalK;
    normals_.rules.clear();
    sourceIds_.clear();
    std::map<std::tuple<bool, double, double, double, bool, long>, uint16_t> ruleIds;
    std::vector<std::string> sources;
    for (const SourceStats& s : stats_.sources) {
        const InputDescription& d = s.description;
        OrientationRule rule;
        const Box3d& sb = s.bounds;
        double sourceExtent = std::max({sb.max.x - sb.min.x, sb.max.y - sb.min.y, sb.max.z - sb.min.z});
        // A default scan origin (PCD's 0,0,0) far from the data is no origin.
        bool originUsable = d.scanOrigin && !(d.scanOriginIsDefault && distanceToBox(*d.scanOrigin, sb) > kFarOrigin * sourceExtent);
        if (originUsable) rule.scanOrigin = *d.scanOrigin - rootMin_;
        // Airborne LiDAR, and any data much flatter than wide (terrain), face up.
        bool flat = sb.max.z - sb.min.z < kFlatRatio * std::max(sb.max.x - sb.min.x, sb.max.y - sb.min.y);
        rule.up = d.airborne || (!originUsable && flat);
        Vec3d o = rule.scanOrigin.value_or(Vec3d{});
        // A textured mesh has a rule of its own: its surfels find their texture by it.
        const bool ownRule = d.textured && opt_.textureFilter != BuildOptions::TextureFilter::Nearest;
        auto [it, added] = ruleIds.try_emplace({rule.scanOrigin.has_value(), o.x, o.y, o.z, rule.up,
                                                ownRule ? long(&s - stats_.sources.data()) : -1L},
                                               uint16_t(normals_.rules.size()));
        if (added) {
            if (normals_.rules.size() > 0xFFFF)
                return Status::error(d.path + ": more than 65,536 distinct scan origins among the inputs");
            normals_.rules.push_back(rule);
        }
        sourceIds_.push_back(it->second);
        std::string name = d.hasNormals ? "input" : orientationName(rule);
        if (std::find(sources.begin(), sources.end(), name) == sources.end()) sources.push_back(name);
    }
    for (size_t i = 0; i < sources.size(); ++i) summary_.normalSource += (i ? "+" : "") + sources[i];
    // The textured meshes' fields, from the meshes the scan read (whose
    // textures they share).
    textureFields_.assign(normals_.rules.size(), nullptr);
    for (size_t i = 0; i < stats_.sources.size(); ++i) {
        const InputDescription& d = stats_.sources[i].description;
        if (!d.textured) continue;
        summary_.textureFilter = textureFilterName(opt_.textureFilter);
        if (opt_.textureFilter == BuildOptions::TextureFilter::Nearest) continue;
        auto mesh = readMeshTriangles(d.path, true, opt_.inputs.mesh, opt_.inputs.meshes.get());
        if (!mesh) return mesh.status();
        textureFields_[sourceIds_[i]] = std::make_shared<const TextureField>(*mesh, rootMin_);
        textureBytes_ += textureFields_[sourceIds_[i]]->bytes();
    }
    return {};
}

Status Builder::planAndDistribute() {
    // The chunk size depends on the budget alone, never on the thread count,
    // so the same inputs and options give the same chunks and the same bytes.
    // Memory outside the chunks (docs/ARCHITECTURE.md, "Memory"): the
    // texture fields, held through the build; while the inputs are read
    // again, the meshes the store keeps and the largest mesh, read anew
    // where the store dropped it; while chunks are built, the solves of the
    // optimal texture filter.
    MeshStore& meshes = *opt_.inputs.meshes;
    const uint64_t largestMesh = meshes.largestBytes();
    const uint64_t fitBytes = fitting() ? kChunksAtOnce * kFitSolvesPerChunk * kFitBytesPerSolve : 0;
    const uint64_t minChunks = kChunksAtOnce * bytesPerChunkPoint() * opt_.capacity * kMinChunkLeaves;
    const uint64_t minBytes = kBaselineBytes + textureBytes_ + std::max(largestMesh, fitBytes + minChunks);
    if (opt_.memoryBytes < minBytes) {
        auto mib = [](uint64_t bytes) { return std::to_string((bytes + (1 << 20) - 1) >> 20) + " MiB"; };
        std::string why = "--memory " + std::to_string(opt_.memoryBytes >> 20) + " MiB is too small: at least " + mib(minBytes) +
                          " are needed with capacity " + std::to_string(opt_.capacity);
        if (textureBytes_ > 0) why += "; the textured meshes' textures, mip levels and triangles take " + mib(textureBytes_);
        if (largestMesh > 0) why += "; the largest mesh takes " + mib(largestMesh) + " while it is read";
        if (fitBytes > 0) why += "; the optimal texture filter's solves take " + mib(fitBytes);
        return Status::error(why);
    }
    meshes.setCapacity(opt_.memoryBytes - kBaselineBytes - textureBytes_ - largestMesh);
    uint64_t maxChunkPoints = (opt_.memoryBytes - kBaselineBytes - textureBytes_ - fitBytes) / (kChunksAtOnce * bytesPerChunkPoint());

    if (stats_.points <= maxChunkPoints) {
        layout_ = ChunkLayout::single(rootEdge_, opt_.grid);
    } else {
        progress_.begin("count", stats_.points);
        std::vector<uint32_t> counts(size_t(1) << (3 * kCountLevel), 0);
        SC_TRY(forEachBatch(opt_.inputs, stats_, rootMin_, sourceIds_, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
            for (const Surfel& s : batch) counts[ChunkLayout::cellIndex(s.position, rootEdge_)]++;
            progress_.advance(batch.size());
            return Status{};
        }));
        phaseDone("count");
        layout_ = ChunkLayout::fromCounts(counts, maxChunkPoints, rootEdge_, opt_.grid);
    }

    progress_.begin("distribute", stats_.points);
    ChunkWriter chunkWriter(layout_, chunkDir_, stored_.size());
    uint64_t seen = 0;
    SC_TRY(forEachBatch(opt_.inputs, stats_, rootMin_, sourceIds_, stored_, [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
        seen += batch.size();
        progress_.advance(batch.size());
        return chunkWriter.add(batch, scalars);
    }));
    SC_TRY(chunkWriter.finish());
    meshes.setCapacity(0);  // the fields keep the textures; nothing reads the meshes again
    summary_.meshReads = meshes.reads();
    summary_.textureBytes = textureBytes_;
    phaseDone("distribute");
    if (seen != stats_.points)
        return Status::error("the inputs changed while being read: " + std::to_string(stats_.points) + " points, then " +
                             std::to_string(seen));
    summary_.chunks = layout_.chunks().size();
    return {};
}

BuiltNode* Builder::buildSubtree(std::vector<Surfel>& pts, size_t b, size_t e, const NodeKey& key,
                                 std::vector<std::unique_ptr<BuiltNode>>& nodes, ScalarTable& scalars) {
    auto node = std::make_unique<BuiltNode>();
    node->key = key;
    auto first = pts.begin() + long(b), last = pts.begin() + long(e);
    bool identical = std::all_of(first, last, [&](const Surfel& s) { return s.position == first->position; });
    if (e - b <= opt_.capacity || key.level >= kMaxLevel || identical) {
        // Leaf: the input points themselves, exact duplicates merged.
        node->inputPoints = true;
        node->surfels.assign(first, last);
        auto& v = node->surfels;
        // Of exact duplicates, the one kept has the lowest class, then intensity,
        // returns, colour and scalar fields in order (docs/FORMAT.md): the same
        // whatever the input order.
        const size_t fields = scalars.fields();
        std::sort(v.begin(), v.end(), [&](const Surfel& a, const Surfel& c) {
            const auto ka = std::tie(a.position.x, a.position.y, a.position.z, a.classification, a.intensity, a.returns,
                                     a.color[0], a.color[1], a.color[2]);
            const auto kc = std::tie(c.position.x, c.position.y, c.position.z, c.classification, c.intensity, c.returns,
                                     c.color[0], c.color[1], c.color[2]);
            if (ka != kc || fields == 0) return ka < kc;
            return std::lexicographical_compare(scalars.row(a.row), scalars.row(a.row) + fields, scalars.row(c.row),
                                                scalars.row(c.row) + fields);
        });
        size_t out = 0;
        for (size_t i = 0; i < v.size(); ++i) {
            if (out > 0 && v[out - 1].position == v[i].position) v[out - 1].count += v[i].count;
            else v[out++] = v[i];
        }
        v.resize(out);
    } else {
        // Partition the range into the 8 children (child index bits: x, y, z).
        Vec3d mid = nodeMinRel(key) + Vec3d{1, 1, 1} * (edge(key.level) * 0.5);
        size_t bounds[9];
        bounds[0] = b;
        bounds[8] = e;
        auto split = [&](size_t lo, size_t hi, int axis) {
            return size_t(std::partition(pts.begin() + long(lo), pts.begin() + long(hi),
                                         [&](const Surfel& s) { return s.position[axis] < mid[axis]; }) -
                          pts.begin());
        };
        bounds[4] = split(b, e, 0);
        bounds[2] = split(bounds[0], bounds[4], 1);
        bounds[6] = split(bounds[4], bounds[8], 1);
        for (int i = 0; i < 8; i += 2) bounds[i + 1] = split(bounds[i], bounds[i + 2], 2);
        std::vector<Surfel> gathered;
        for (int c = 0; c < 8; ++c) {
            if (bounds[c] == bounds[c + 1]) continue;
            BuiltNode* child = buildSubtree(pts, bounds[c], bounds[c + 1], key.child(c), nodes, scalars);
            node->childMask |= uint8_t(1u << c);
            gathered.insert(gathered.end(), child->surfels.begin(), child->surfels.end());
        }
        const SampleGrid grid = nodeGrid(key, gathered);
        node->cell = grid.cellSize;
        node->surfels = resample(gathered, grid, true, &scalars);
    }
    nodes.push_back(std::move(node));
    return nodes.back().get();
}

SampleGrid Builder::nodeGrid(const NodeKey& k, std::span<const Surfel> below) const {
    const size_t target = std::max<size_t>(1, below.size() / kLevelReduction);
    // Step j has floor(G / kGridCoarsening^j) cells per axis (one at least), so
    // its cells tile the node and line up with those of the level's other
    // nodes on the same step.
    auto grid = [&](int j) {
        const uint32_t cells = uint32_t(std::max(1.0, std::floor(opt_.grid * std::pow(kGridCoarsening, -j) + 1e-9)));
        return SampleGrid{nodeMinRel(k), edge(k.level) / cells, cells};
    };
    int j = 0;
    for (SampleGrid g = grid(0); g.cells > 1 && occupiedCells(below, g) > target; g = grid(++j)) {
    }
    return grid(j);
}

std::vector<Surfel> Builder::resampleHalo(const std::vector<Surfel>& halo, const Chunk& chunk, double margin, int level,
                                          std::span<BuiltNode* const> members) const {
    // Each halo point stands in for a neighbouring chunk's surfels near the
    // level's node that holds the point clamped into the chunk, and is
    // resampled on that node's cell (the level's G³ cell where that node is a
    // leaf, absent or not coarsened).
    const double e = edge(level), base = e / opt_.grid;
    const Vec3d chunkLo = nodeMinRel(chunk.key);
    const double chunkEdge = edge(chunk.key.level);
    auto sample = [&](std::span<const Surfel> points, double cell) {
        SampleGrid g;
        for (int a = 0; a < 3; ++a) g.origin[a] = std::floor((chunkLo[a] - margin) / cell) * cell;  // aligned with the level's cells
        g.cellSize = cell;
        const double cells = std::ceil((chunkEdge + 2 * margin) / cell) + 2;
        if (cells >= kMaxGridCells)
            return std::vector<Surfel>(points.begin(), points.end());  // finer than any grid can address: the points themselves
        g.cells = uint32_t(cells);
        return resample(points, g, false);
    };
    std::map<NodeKey, double> cellOf;
    for (const BuiltNode* n : members)
        if (n->cell > 0 && n->cell != base) cellOf[n->key] = n->cell;
    if (cellOf.empty()) return sample(halo, base);

    const int below = level - chunk.key.level;
    const uint32_t span = 1u << below;  // the level's nodes per axis of the chunk
    std::map<double, std::vector<Surfel>> byCell;
    for (const Surfel& s : halo) {
        NodeKey k{uint8_t(level), 0, 0, 0};
        uint32_t* axes[3] = {&k.x, &k.y, &k.z};
        const uint32_t first[3] = {chunk.key.x, chunk.key.y, chunk.key.z};
        for (int a = 0; a < 3; ++a)
            *axes[a] = (first[a] << below) +
                       uint32_t(std::clamp(std::floor((s.position[a] - chunkLo[a]) / e), 0.0, double(span - 1)));
        const auto it = cellOf.find(k);
        byCell[it == cellOf.end() ? base : it->second].push_back(s);
    }
    std::vector<Surfel> out;
    for (auto& [cell, points] : byCell) {
        std::vector<Surfel> sampled = sample(points, cell);
        out.insert(out.end(), sampled.begin(), sampled.end());
    }
    return out;
}

Status Builder::buildChunk(const Chunk& chunk, int innerThreads) {
    auto pts = readChunkFile(chunk.file, chunk.points);
    if (!pts) return pts.status();
    auto halo = readChunkFile(chunk.haloFile, chunk.haloPoints);
    if (!halo) return halo.status();
    ScalarTable scalars = emptyTable();
    if (!stored_.empty()) {
        auto values = readChunkScalars(chunk.scalarFile, chunk.points * stored_.size());
        if (!values) return values.status();
        scalars.values = std::move(*values);
    }
    for (size_t i = 0; i < pts->size(); ++i) (*pts)[i].row = uint32_t(i);
    std::error_code ec;
    fs::remove(chunk.file, ec);
    fs::remove(chunk.haloFile, ec);
    fs::remove(chunk.scalarFile, ec);
    if (pts->empty()) return {};

    const double margin = layout_.margin(int(&chunk - layout_.chunks().data()));
    NormalContext ctx = normals_;
    ctx.threads = innerThreads;
    {
        ScopedTimer t(stepNs_[kStepNormals]);
        const Vec3d lo = nodeMinRel(chunk.key) - Vec3d{margin, margin, margin};
        sortMorton(*pts, lo, edge(chunk.key.level) + 2 * margin);
        sortMorton(*halo, lo, edge(chunk.key.level) + 2 * margin);
        estimateNormals(*pts, *halo, ctx);
    }
    std::vector<std::unique_ptr<BuiltNode>> nodes;
    BuiltNode* root = nullptr;
    {
        ScopedTimer t(stepNs_[kStepOctree]);
        root = buildSubtree(*pts, 0, pts->size(), chunk.key, nodes, scalars);
        std::vector<Surfel>().swap(*pts);
    }

    // Per level: h, radii and weights, with the halo resampled on the level's grid.
    std::map<int, std::vector<BuiltNode*>> levels;
    for (auto& n : nodes) {
        n->level.surfels = n->surfels;
        levels[n->key.level].push_back(n.get());
    }
    for (auto& [level, built] : levels) {
        std::vector<LevelNode*> members;
        for (BuiltNode* n : built) members.push_back(&n->level);
        std::vector<Surfel> haloLevel;
        {
            ScopedTimer t(stepNs_[kStepAttributes]);
            haloLevel = resampleHalo(*halo, chunk, margin, level, built);
            computeLevelAttributes(members, haloLevel, levelParams(largestCell(level, built), innerThreads));
        }
        filterLevelTextures(built, haloLevel, innerThreads);
    }
    for (auto& n : nodes)
        if (n.get() != root) SC_TRY(emit(*n, scalars));
    bool isRoot = chunk.key == NodeKey{};
    if (isRoot) return emit(*root, scalars);
    // The chunk root is emitted now and kept for the levels above, its scalar
    // rows moved to their table.
    SC_TRY(emit(*root, scalars));
    std::lock_guard lock(mutex_);
    if (!stored_.empty())
        for (Surfel& s : root->surfels) s.row = upperScalars_.append(scalars.row(s.row));
    for (auto& n : nodes)
        if (n.get() == root) retained_[root->key] = std::move(n);
    return {};
}

Status Builder::buildChunks() {
    std::vector<size_t> order(layout_.chunks().size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    // Largest first: the long poles start early.
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return layout_.chunks()[a].points > layout_.chunks()[b].points; });
    // At most kChunksAtOnce chunks are in memory at once (the budget is split
    // that many ways); more threads work inside each chunk.
    int workers = int(std::min({size_t(threads_), size_t(kChunksAtOnce), order.size()}));
    int inner = std::max(1, threads_ / workers);
    progress_.begin("build", stats_.points);
    std::atomic<size_t> next{0};
    std::mutex errorMutex;
    Status firstError;
    auto work = [&] {
        while (true) {
            size_t i = next++;
            if (i >= order.size()) return;
            {
                std::lock_guard lock(errorMutex);
                if (!firstError.ok()) return;
            }
            const Chunk& c = layout_.chunks()[order[i]];
            Status st = buildChunk(c, inner);
            progress_.advance(c.points);
            if (!st.ok()) {
                std::lock_guard lock(errorMutex);
                if (firstError.ok()) firstError = st;
            }
        }
    };
    std::vector<std::thread> pool;
    for (int w = 1; w < workers; ++w) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
    phaseDone("build");
    return firstError;
}

Status Builder::buildUpperLevels() {
    if (retained_.empty()) return {};
    int deepest = 0;
    for (auto& [key, node] : retained_) deepest = std::max(deepest, int(key.level));
    progress_.begin("upper", uint64_t(deepest), "levels");
    std::map<NodeKey, std::unique_ptr<BuiltNode>> below;  // nodes of level L+1 still needed
    for (int level = deepest - 1; level >= 0; --level) {
        // Children: chunk roots and upper nodes of level+1.
        for (auto it = retained_.begin(); it != retained_.end();) {
            if (it->first.level == level + 1) {
                below[it->first] = std::move(it->second);
                it = retained_.erase(it);
            } else {
                ++it;
            }
        }
        std::map<NodeKey, std::unique_ptr<BuiltNode>> current;
        std::map<NodeKey, std::vector<Surfel>> gathered;
        for (auto& [key, child] : below) {
            NodeKey parent = key.parent();
            auto& p = current[parent];
            if (!p) {
                p = std::make_unique<BuiltNode>();
                p->key = parent;
            }
            p->childMask |= uint8_t(1u << key.childIndex());
            auto& g = gathered[parent];
            g.insert(g.end(), child->surfels.begin(), child->surfels.end());
        }
        below.clear();
        std::vector<LevelNode*> members;
        for (auto& [key, node] : current) {
            const SampleGrid grid = nodeGrid(key, gathered[key]);
            node->cell = grid.cellSize;
            node->surfels = resample(gathered[key], grid, true, &upperScalars_);
            node->level.surfels = node->surfels;
            members.push_back(&node->level);
        }
        gathered.clear();
        std::vector<Surfel> neighbours;  // chunk roots on this level
        for (auto& [key, node] : retained_)
            if (key.level == level) neighbours.insert(neighbours.end(), node->surfels.begin(), node->surfels.end());
        std::vector<BuiltNode*> built;
        for (auto& [key, node] : current) built.push_back(node.get());
        computeLevelAttributes(members, neighbours, levelParams(largestCell(level, built), threads_));
        filterLevelTextures(built, neighbours, threads_);
        for (auto& [key, node] : current) SC_TRY(emit(*node, upperScalars_));
        below = std::move(current);
        progress_.advance(1);
    }
    phaseDone("upper");
    return {};
}

void Builder::filterLevelTextures(std::span<BuiltNode* const> nodes, std::span<const Surfel> halo, int threads) {
    if (nodes.empty() || std::none_of(textureFields_.begin(), textureFields_.end(), [](const auto& f) { return f != nullptr; }))
        return;
    ScopedTimer t(stepNs_[kStepTextures]);
    auto fieldOf = [&](const Surfel& s) { return s.source < textureFields_.size() ? textureFields_[s.source].get() : nullptr; };
    auto sigmaOf = [&](const BuiltNode& node, size_t i) {
        return opt_.kernelScale * (node.level.radii.empty() ? node.level.h : node.level.radii[i]);
    };
    auto store = [](Surfel& s, const Vec3f& c) {
        for (int k = 0; k < 3; ++k) s.color[k] = uint16_t(std::lround(std::clamp(c[k], 0.f, 1.f) * 255.f) * 257);
    };
    // The view-independent EWA coefficients: the result for ewa, the
    // starting guess for optimal.
    for (BuiltNode* node : nodes) {
        std::vector<Surfel>& v = node->surfels;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 256)
        for (size_t i = 0; i < v.size(); ++i) {
            const TextureField* field = fieldOf(v[i]);
            Vec3f c;
            if (field && field->filter(v[i].position, v[i].normal, sigmaOf(*node, i), &c)) store(v[i], c);
        }
    }
    if (opt_.textureFilter != BuildOptions::TextureFilter::Optimal) return;

    // The least-squares coefficients, one group per node, each textured
    // mesh on its own. Halo surfels (other chunks) have no h of their own
    // and take the level's median.
    std::vector<float> hs;
    for (BuiltNode* node : nodes) hs.push_back(node->level.h);
    std::nth_element(hs.begin(), hs.begin() + long(hs.size() / 2), hs.end());
    const double haloSigma = opt_.kernelScale * hs[hs.size() / 2];
    FitParams params;
    params.cutoff = opt_.cutoff;
    params.zt = kDefaultZt;
    params.threads = std::min(threads, kFitSolvesPerChunk);
    for (size_t f = 0; f < textureFields_.size(); ++f) {
        const TextureField* field = textureFields_[f].get();
        if (!field) continue;
        std::vector<FitSurfel> fit;
        std::vector<std::pair<uint32_t, uint32_t>> groups;
        std::vector<std::pair<BuiltNode*, size_t>> from;  // the surfel each fitted one came from
        auto toFit = [](const Surfel& s, double sigma) {
            const double k = 1.0 / 65535;
            return FitSurfel{s.position, s.normal, sigma, Vec3f{float(s.color[0] * k), float(s.color[1] * k), float(s.color[2] * k)}};
        };
        for (BuiltNode* node : nodes) {
            const uint32_t begin = uint32_t(fit.size());
            for (size_t i = 0; i < node->surfels.size(); ++i)
                if (fieldOf(node->surfels[i]) == field) {
                    fit.push_back(toFit(node->surfels[i], sigmaOf(*node, i)));
                    from.push_back({node, i});
                }
            // Runs of a node's surfels (which lie in grid or Morton order) of
            // at most kFitGroupSurfels each, so that a solve's memory is bounded.
            const uint32_t n = uint32_t(fit.size()) - begin, parts = (n + kFitGroupSurfels - 1) / kFitGroupSurfels;
            for (uint32_t k = 0; k < parts; ++k) groups.push_back({begin + uint32_t(uint64_t(n) * k / parts), begin + uint32_t(uint64_t(n) * (k + 1) / parts)});
        }
        if (groups.empty()) continue;
        for (const Surfel& s : halo)
            if (fieldOf(s) == field) fit.push_back(toFit(s, haloSigma));
        FitReport report = field->fitOptimal(fit, groups, params);
        for (size_t i = 0; i < from.size(); ++i) store(from[i].first->surfels[from[i].second], fit[i].color);
        std::lock_guard lock(mutex_);
        summary_.textureFit.add(report);
    }
}

int Builder::positionBits(const BuiltNode& node) const {
    assert(node.inputPoints || node.cell > 0);
    double e = edge(node.key.level), cell = node.inputPoints ? e / opt_.grid : node.cell;
    double step = !node.inputPoints ? cell / opt_.positionFraction
                  : leafStep_ > 0   ? leafStep_
                                    : cell / kUnknownPrecisionFraction;
    int bits = int(std::ceil(std::log2(e / step) - 1e-9));
    return std::clamp(bits, 1, kMaxPositionBits);
}

Status Builder::emit(BuiltNode& node, const ScalarTable& scalars) {
    const size_t n = node.surfels.size();
    const int bits = positionBits(node);
    const double maxQ = double((uint64_t(1) << bits) - 1);
    const double step = edge(node.key.level) / maxQ;
    const Vec3d lo = nodeMinRel(node.key);
    BlockData block;
    block.positions.resize(3 * n);
    block.normals.resize(3 * n);
    if (stats_.colorBits) block.colors.resize(3 * n);
    if (store_[kLidarIntensity]) block.intensity.resize(n);
    if (store_[kLidarClassification]) block.classification.resize(n);
    if (store_[kLidarReturnNumber]) block.returnNumber.resize(n);
    if (store_[kLidarNumberOfReturns]) block.numberOfReturns.resize(n);
    if (storeOpacity_) block.opacity.resize(n);
    for (size_t f = 0; f < stored_.size(); ++f) {
        ScalarAttribute& a = block.scalars.emplace_back();
        a.bits = stored_[f].bits;
        a.values.resize(n);
        for (size_t i = 0; i < n; ++i) a.values[i] = scalars.row(node.surfels[i].row)[f];
    }
    for (size_t i = 0; i < n; ++i) {
        const Surfel& s = node.surfels[i];
        for (int a = 0; a < 3; ++a) {
            block.positions[3 * i + a] = uint32_t(std::clamp(std::round((s.position[a] - lo[a]) / step), 0.0, maxQ));
            block.normals[3 * i + a] = s.normal[a];
        }
        if (stats_.colorBits)
            for (int c = 0; c < 3; ++c) block.colors[3 * i + c] = stats_.colorBits == 8 ? uint16_t(s.color[c] >> 8) : s.color[c];
        if (!block.intensity.empty())
            // Clamped: an input without intensity (beside ones with it) reads as 0,
            // below the range of those that carry it.
            block.intensity[i] = uint16_t(std::clamp(std::lround(double(s.intensity - intensityOffset_) / intensityStep_), 0l,
                                                     long(1 << kIntensityBits) - 1));
        if (!block.classification.empty()) block.classification[i] = s.classification;
        if (!block.returnNumber.empty()) block.returnNumber[i] = s.returns & 15;
        if (!block.numberOfReturns.empty()) block.numberOfReturns[i] = s.returns >> 4;
        if (!block.opacity.empty()) block.opacity[i] = s.alpha;
    }
    block.weights = node.level.weights;
    block.radii = node.level.radii;
    BlockCodecOptions codec;
    codec.positionBits = bits;
    codec.normalBits = opt_.normalBits;
    codec.colorBits = stats_.colorBits ? stats_.colorBits : 8;
    auto blob = [&] {
        ScopedTimer t(stepNs_[kStepEncode]);
        return encodeBlock(block, codec);
    }();
    if (!blob) return Status::error("node " + node.key.name() + ": " + blob.status().message());

    NormalCone cone = computeCone(node.surfels);
    NodeRecord r;
    r.key = node.key;
    r.childMask = node.childMask;
    r.flags = uint16_t((cone.full ? kFlagConeFull : 0) | (block.radii.empty() ? 0 : kFlagHasRadius) |
                       (node.inputPoints ? kFlagInputPoints : 0));
    r.surfelCount = uint32_t(n);
    r.spacing = node.level.h;
    r.coneAxis = cone.axis;
    r.coneCosHalfAngle = cone.cosHalfAngle;
    r.positionBits = uint8_t(bits);
    SC_TRY(writer_->addNode(r, *blob));

    std::lock_guard lock(mutex_);
    size_t L = node.key.level;
    if (summary_.nodesPerLevel.size() <= L) {
        summary_.nodesPerLevel.resize(L + 1);
        summary_.surfelsPerLevel.resize(L + 1);
    }
    summary_.nodesPerLevel[L]++;
    summary_.surfelsPerLevel[L] += n;
    summary_.surfels += n;
    return {};
}

Result<BuildSummary> Builder::run() {
    auto start = std::chrono::steady_clock::now();
    // Meshes are read once: the scan keeps them for the passes after it,
    // within half the budget until planAndDistribute knows what else it holds.
    if (!opt_.inputs.meshes) opt_.inputs.meshes = std::make_shared<MeshStore>((opt_.memoryBytes - std::min(opt_.memoryBytes, kBaselineBytes)) / 2);
    SC_TRY(scan());
    auto writer = TilesetWriter::create(opt_.output);
    if (!writer) return writer.status();
    writer_ = std::move(*writer);
    fs::path partial(writer_->partialDir());
    chunkDir_ = (partial.parent_path() / (partial.filename().string() + "-chunks")).string();
    std::error_code ec;
    fs::create_directories(chunkDir_, ec);
    if (ec) return Status::error(chunkDir_ + ": cannot create the temporary chunk folder (" + ec.message() + ")");
    struct RemoveDir {
        std::string path;
        ~RemoveDir() { std::error_code e; fs::remove_all(path, e); }
    } chunkDirGuard{chunkDir_};

    SC_TRY(planAndDistribute());
    SC_TRY(buildChunks());
    SC_TRY(buildUpperLevels());

    progress_.begin("write", 0);
    TilesetInfo info;
    info.generator = "surfcast-build 0.1.0";
    info.inputPoints = stats_.points;
    info.surfels = summary_.surfels;
    info.levels = int(summary_.nodesPerLevel.size());
    info.grid = opt_.grid;
    info.pageDepth = opt_.pageDepth;
    info.rootMin = rootMin_;
    info.rootEdge = rootEdge_;
    info.bounds = stats_.bounds;
    info.colorBits = stats_.colorBits;
    info.attributes.push_back({"position", "uint32", 3, 0});
    info.attributes.push_back({"normal", "float32", 3, opt_.normalBits});
    if (stats_.colorBits) info.attributes.push_back({"color", stats_.colorBits == 8 ? "uint8" : "uint16", 3, 0});
    if (opt_.weights) info.attributes.push_back({"weight", "float32", 1, BlockCodecOptions{}.weightBits});
    info.attributes.push_back({"radius", "float32", 1, BlockCodecOptions{}.radiusBits});  // only in nodes flagged kFlagHasRadius
    const char* const types[kLidarCount] = {"uint16", "uint8", "uint8", "uint8"};
    for (int i = 0; i < kLidarCount; ++i)
        if (store_[i])
            info.attributes.push_back({kLidarAttributes[i], types[i], 1, 0, i == kLidarIntensity ? "continuous" : "categorical",
                                       i == kLidarIntensity ? double(intensityStep_) : 1.0,
                                       i == kLidarIntensity ? double(intensityOffset_) : 0.0});
    if (storeOpacity_) info.attributes.push_back({kOpacityAttribute, "uint8", 1, 0, "continuous", 1.0 / 255, 0.0});
    for (const ScalarQuantization& q : stored_)
        info.attributes.push_back({q.name, scalarType(q.bits), 1, 0, q.categorical ? "categorical" : "continuous", q.step, q.offset});
    info.statistics = statistics();
    info.normalSource = summary_.normalSource;
    info.weights = opt_.weights ? "analytic" : "none";
    info.textureFilter = summary_.textureFilter;
    info.kernelScale = opt_.kernelScale;
    SC_TRY(writer_->finish(info));
    phaseDone("write");

    summary_.inputPoints = stats_.points;
    summary_.skippedPoints = stats_.skipped;
    summary_.nodes = info.nodes;
    summary_.levels = info.levels;
    summary_.hierarchyBytes = info.hierarchyBytes;
    summary_.blocksBytes = info.blocksBytes;
    summary_.totalSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    summary_.peakRss = peakRssBytes();
    for (int i = 0; i < kStepCount; ++i) summary_.stepSeconds.push_back({kStepNames[i], double(stepNs_[i]) * 1e-9});
    return summary_;
}

}  // namespace

Result<BuildSummary> buildTileset(const BuildOptions& options) {
    Builder builder(options);
    return builder.run();
}

}  // namespace surfcast
