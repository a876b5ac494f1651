// The plan stage (stages.h): the scan, the memory budget's chunk size, the
// count, and plan.bin.
#include <algorithm>

#include "stages.h"
#include "work_files.h"

namespace surfcast {

namespace {

constexpr char kPlanMagic[9] = "SCPLAN01";

std::string mib(uint64_t bytes) { return std::to_string((bytes + (1 << 20) - 1) >> 20) + " MiB"; }

// The most points a chunk may hold, given the budget (docs/ARCHITECTURE.md,
// "Memory"): what is left once the texture fields, and the optimal texture
// filter's solves, are paid for, split between the chunks built at once.
// The chunk size depends on the budget alone, never on the thread count, so
// the same inputs and options give the same chunks and the same bytes.
Result<uint64_t> maxChunkPoints(const BuildContext& c) {
    const BuildOptions& opt = c.options();
    MeshStore& meshes = *opt.inputs.meshes;
    const uint64_t largestMesh = meshes.largestBytes();
    const uint64_t fitBytes = c.fitting() ? kChunksAtOnce * kFitSolvesPerChunk * kFitBytesPerSolve : 0;
    const uint64_t minChunks = kChunksAtOnce * c.bytesPerChunkPoint() * opt.capacity * kMinChunkLeaves;
    const uint64_t minBytes = kBaselineBytes + c.textureBytes() + std::max(largestMesh, fitBytes + minChunks);
    if (opt.memoryBytes < minBytes) {
        std::string why = "--memory " + std::to_string(opt.memoryBytes >> 20) + " MiB is too small: at least " + mib(minBytes) +
                          " are needed with capacity " + std::to_string(opt.capacity);
        if (c.textureBytes() > 0) why += "; the textured meshes' textures, mip levels and triangles take " + mib(c.textureBytes());
        if (largestMesh > 0) why += "; the largest mesh takes " + mib(largestMesh) + " while it is read";
        if (fitBytes > 0) why += "; the optimal texture filter's solves take " + mib(fitBytes);
        return Status::error(why);
    }
    return (opt.memoryBytes - kBaselineBytes - c.textureBytes() - fitBytes) / (kChunksAtOnce * c.bytesPerChunkPoint());
}

void putBox(ByteWriter& w, const Box3d& b) {
    for (int a = 0; a < 3; ++a) w.put(b.min[a]);
    for (int a = 0; a < 3; ++a) w.put(b.max[a]);
}
Box3d getBox(ByteReader& r) {
    Box3d b;
    for (int a = 0; a < 3; ++a) b.min[a] = r.get<double>();
    for (int a = 0; a < 3; ++a) b.max[a] = r.get<double>();
    return b;
}
void putField(ByteWriter& w, const ScalarField& f) {
    w.putString(f.name);
    w.put(uint8_t(f.categorical));
    w.put(f.resolution);
}
ScalarField getField(ByteReader& r) {
    ScalarField f;
    f.name = r.getString();
    f.categorical = r.get<uint8_t>() != 0;
    f.resolution = r.get<double>();
    return f;
}
// Histograms are sparse: (value, count) pairs of the values that occur.
void putHistogram(ByteWriter& w, const std::vector<uint64_t>& h) {
    w.put(uint64_t(std::count_if(h.begin(), h.end(), [](uint64_t n) { return n > 0; })));
    for (size_t v = 0; v < h.size(); ++v)
        if (h[v]) w.put(uint32_t(v)), w.put(h[v]);
}
bool getHistogram(ByteReader& r, std::vector<uint64_t>& h) {
    const uint64_t n = r.getCount(12);
    for (uint64_t i = 0; i < n && r.ok(); ++i) {
        const uint32_t v = r.get<uint32_t>();
        if (v >= h.size()) return false;
        h[v] = r.get<uint64_t>();
    }
    return r.ok();
}

}  // namespace

ChunkLayout BuildPlan::layout(const BuildContext& context) const {
    const int grid = context.options().grid;
    if (maxChunkPoints == 0) return ChunkLayout::single(context.rootEdge(), grid);
    std::vector<uint32_t> grid3(size_t(1) << (3 * kCountLevel), 0);
    for (auto [cell, n] : counts) grid3[cell] = n;
    return ChunkLayout::fromCounts(grid3, maxChunkPoints, context.rootEdge(), grid);
}

Result<BuildPlan> planStage(const BuildOptions& options, Progress& progress, std::shared_ptr<const BuildContext>* context,
                            BuildSummary* summary) {
    const BuildOptions opt = normalizeOptions(options);
    progress.begin("scan", 0);
    auto stats = scanInputs(opt.inputs, [&](uint64_t n) { progress.advance(n); });
    if (!stats) return stats.status();
    summary->phaseSeconds.push_back({"scan", progress.end()});
    auto derived = BuildContext::derive(opt, std::move(*stats));
    if (!derived) return derived.status();
    const BuildContext& c = **derived;
    *context = *derived;

    BuildPlan plan;
    plan.stats = c.stats();
    auto maxPoints = maxChunkPoints(c);
    if (!maxPoints) return maxPoints.status();
    MeshStore& meshes = *opt.inputs.meshes;
    meshes.setCapacity(opt.memoryBytes - kBaselineBytes - c.textureBytes() - meshes.largestBytes());
    if (c.stats().points > *maxPoints) {
        plan.maxChunkPoints = *maxPoints;
        progress.begin("count", c.stats().points);
        std::vector<uint32_t> counts(size_t(1) << (3 * kCountLevel), 0);
        SC_TRY(forEachBatch(opt.inputs, c.stats(), c.rootMin(), c.sourceIds(), {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
            for (const Surfel& s : batch) counts[ChunkLayout::cellIndex(s.position, c.rootEdge())]++;
            progress.advance(batch.size());
            return Status{};
        }));
        summary->phaseSeconds.push_back({"count", progress.end()});
        for (size_t i = 0; i < counts.size(); ++i)
            if (counts[i]) plan.counts.push_back({uint32_t(i), counts[i]});
    }
    return plan;
}

Status writePlan(const std::string& path, const BuildPlan& plan, std::span<const std::string> args) {
    ByteWriter w;
    w.put(uint64_t(args.size()));
    for (const std::string& a : args) w.putString(a);
    const InputStats& s = plan.stats;
    w.put(uint64_t(s.sources.size()));
    for (const SourceStats& src : s.sources) {
        const InputDescription& d = src.description;
        w.putString(d.path);
        w.putString(d.format);
        w.put(d.declaredPoints);
        for (bool b : {d.hasNormals, d.hasColors, d.textured, d.hasIntensity, d.hasClassification, d.hasReturns,
                       d.float32Coordinates, d.scanOrigin.has_value(), d.scanOriginIsDefault, d.airborne})
            w.put(uint8_t(b));
        w.put(int32_t(d.colorBits));
        w.put(d.precision);
        const Vec3d origin = d.scanOrigin.value_or(Vec3d{});
        for (int a = 0; a < 3; ++a) w.put(origin[a]);
        w.put(uint64_t(d.scalars.size()));
        for (const ScalarField& f : d.scalars) putField(w, f);
        w.put(src.points);
        w.put(src.skipped);
        putBox(w, src.bounds);
        w.put(src.colorMax);
        w.put(uint8_t(src.colors8Bit));
        w.put(src.colorScale);
    }
    w.put(s.points);
    w.put(s.skipped);
    putBox(w, s.bounds);
    w.put(uint8_t(s.anyColors));
    w.put(int32_t(s.colorBits));
    const AttributeStats& a = s.attributes;
    w.put(a.intensityPoints);
    w.put(a.classifiedPoints);
    w.put(a.returnPoints);
    w.put(a.translucentPoints);
    putHistogram(w, a.intensityHistogram);
    putHistogram(w, a.classCounts);
    putHistogram(w, a.returnsHistogram);
    w.put(uint64_t(s.scalars.size()));
    for (const ScalarStats& f : s.scalars) {
        putField(w, f.field);
        w.put(f.points);
        w.put(f.min);
        w.put(f.max);
    }
    w.put(plan.maxChunkPoints);
    w.put(uint64_t(plan.counts.size()));
    for (auto [cell, n] : plan.counts) w.put(cell), w.put(n);
    return writeWorkFile(path, kPlanMagic, w);
}

Result<BuildPlan> readPlan(const std::string& path, std::vector<std::string>* args) {
    auto bytes = readWorkFile(path, kPlanMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    const Status corrupt = Status::error(path + ": malformed plan");
    args->resize(r.getCount(4));
    for (std::string& arg : *args) arg = r.getString();
    BuildPlan plan;
    InputStats& s = plan.stats;
    s.sources.resize(r.getCount(64));
    for (SourceStats& src : s.sources) {
        InputDescription& d = src.description;
        d.path = r.getString();
        d.format = r.getString();
        d.declaredPoints = r.get<uint64_t>();
        bool hasOrigin = false;
        for (bool* b : {&d.hasNormals, &d.hasColors, &d.textured, &d.hasIntensity, &d.hasClassification, &d.hasReturns,
                        &d.float32Coordinates, &hasOrigin, &d.scanOriginIsDefault, &d.airborne})
            *b = r.get<uint8_t>() != 0;
        d.colorBits = r.get<int32_t>();
        d.precision = r.get<double>();
        Vec3d origin;
        for (int a = 0; a < 3; ++a) origin[a] = r.get<double>();
        if (hasOrigin) d.scanOrigin = origin;
        d.scalars.resize(r.getCount(13));
        for (ScalarField& f : d.scalars) f = getField(r);
        src.points = r.get<uint64_t>();
        src.skipped = r.get<uint64_t>();
        src.bounds = getBox(r);
        src.colorMax = r.get<uint16_t>();
        src.colors8Bit = r.get<uint8_t>() != 0;
        src.colorScale = r.get<double>();
    }
    s.points = r.get<uint64_t>();
    s.skipped = r.get<uint64_t>();
    s.bounds = getBox(r);
    s.anyColors = r.get<uint8_t>() != 0;
    s.colorBits = r.get<int32_t>();
    AttributeStats& a = s.attributes;
    a.intensityPoints = r.get<uint64_t>();
    a.classifiedPoints = r.get<uint64_t>();
    a.returnPoints = r.get<uint64_t>();
    a.translucentPoints = r.get<uint64_t>();
    if (!getHistogram(r, a.intensityHistogram) || !getHistogram(r, a.classCounts) || !getHistogram(r, a.returnsHistogram))
        return corrupt;
    s.scalars.resize(r.getCount(37));
    for (ScalarStats& f : s.scalars) {
        f.field = getField(r);
        f.points = r.get<uint64_t>();
        f.min = r.get<double>();
        f.max = r.get<double>();
    }
    plan.maxChunkPoints = r.get<uint64_t>();
    plan.counts.resize(r.getCount(8));
    for (auto& [cell, n] : plan.counts) {
        cell = r.get<uint32_t>();
        n = r.get<uint32_t>();
        if (cell >= (1u << (3 * kCountLevel))) return corrupt;
    }
    if (!r.ok() || r.left() != 0) return corrupt;
    return plan;
}

}  // namespace surfcast
