// The plan's stages (stages.h): the scan and the count, by parts of the
// inputs, the memory budget's chunk size, and plan.bin.
#include <algorithm>
#include <cassert>
#include <filesystem>
#include <map>
#include <thread>
#include <tuple>

#include "crc32.h"
#include "input_file.h"
#include "las_reader.h"
#include "set_reader.h"
#include "stages.h"
#include "work_files.h"

namespace surfcast {

namespace {

// A format change bumps its magic, here and in scripts/surfcast-dask, which
// judges work files whole by them (dask_test fails where the two differ).
constexpr char kPlanMagic[9] = "SCPLAN07";
constexpr char kScanMagic[9] = "SCSCAN07";
// A set's build record of an earlier format, still read for updates: 06
// without the LAS headers' fields, the fields not decoded and the scalars'
// finest bits, 05 without the inputs' lattices (InputDescription::latticeScale)
// either, 04 without their coordinate systems either.
constexpr int kPlanVersion = 7;
constexpr int kOldestRecordVersion = 4;
constexpr char kCountMagic[9] = "SCCOUNT2";

std::string mib(uint64_t bytes) { return std::to_string((bytes + (1 << 20) - 1) >> 20) + " MiB"; }

}  // namespace

// What is left of the budget once the texture fields, and the optimal texture
// filter's solves, are paid for, split between the chunks built at once. The
// chunk size depends on the budget alone, never on the thread count, so the
// same inputs and options give the same chunks and the same bytes.
Result<uint64_t> chunkPoints(const BuildContext& c) {
    const BuildOptions& opt = c.options();
    const uint64_t largestMesh = c.stats().largestMeshBytes;
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
    const uint64_t most = (opt.memoryBytes - kBaselineBytes - c.textureBytes() - fitBytes) / (kChunksAtOnce * c.bytesPerChunkPoint());
    return c.stats().points <= most ? 0 : most;
}

namespace {

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

// A LAS input's header fields and the names of the fields a reader skipped.
void putLas(ByteWriter& w, const InputDescription& d) {
    w.put(uint64_t(d.otherScalars.size()));
    for (const std::string& name : d.otherScalars) w.putString(name);
    const LasSourceInfo& l = d.las;
    w.put(uint8_t(l.present));
    for (int v : {l.pointFormat, l.gpsTimeType, l.creationDay, l.creationYear}) w.put(int32_t(v));
    w.putString(l.systemIdentifier);
    w.putString(l.generatingSoftware);
    w.put(uint64_t(l.crsVlrs.size()));
    for (const auto& [record, payload] : l.crsVlrs) w.put(record), w.putString(std::string(payload.begin(), payload.end()));
    w.put(uint64_t(l.extraBytes.size()));
    for (const std::vector<uint8_t>& e : l.extraBytes) w.putString(std::string(e.begin(), e.end()));
}
void getLas(ByteReader& r, InputDescription& d) {
    d.otherScalars.resize(r.getCount(8));
    for (std::string& name : d.otherScalars) name = r.getString();
    LasSourceInfo& l = d.las;
    l.present = r.get<uint8_t>() != 0;
    for (int* v : {&l.pointFormat, &l.gpsTimeType, &l.creationDay, &l.creationYear}) *v = r.get<int32_t>();
    l.systemIdentifier = r.getString();
    l.generatingSoftware = r.getString();
    l.crsVlrs.resize(r.getCount(10));
    for (auto& [record, payload] : l.crsVlrs) {
        record = r.get<uint16_t>();
        const std::string bytes = r.getString();
        payload.assign(bytes.begin(), bytes.end());
    }
    l.extraBytes.resize(r.getCount(8));
    for (std::vector<uint8_t>& e : l.extraBytes) {
        const std::string bytes = r.getString();
        e.assign(bytes.begin(), bytes.end());
    }
    if (l.present) l.scale = d.latticeScale, l.offset = d.latticeOffset;
}

void putStats(ByteWriter& w, const InputStats& s) {
    w.put(uint64_t(s.sources.size()));
    for (const SourceStats& src : s.sources) {
        const InputDescription& d = src.description;
        w.putString(d.path);
        w.putString(d.format);
        w.putString(d.crs);
        w.put(d.declaredPoints);
        for (bool b : {d.hasNormals, d.hasColors, d.textured, d.hasIntensity, d.hasClassification, d.hasReturns,
                       d.float32Coordinates, d.scanOriginIsDefault, d.airborne})
            w.put(uint8_t(b));
        w.put(int32_t(d.colorBits));
        w.put(d.precision);
        for (int a = 0; a < 3; ++a) w.put(d.latticeScale[a]), w.put(d.latticeOffset[a]);
        w.put(uint64_t(d.scanOrigins.size()));
        for (const std::optional<Vec3d>& origin : d.scanOrigins) {
            w.put(uint8_t(origin.has_value()));
            for (int a = 0; a < 3; ++a) w.put(origin.value_or(Vec3d{})[a]);
        }
        w.put(uint64_t(d.scalars.size()));
        for (const ScalarField& f : d.scalars) putField(w, f);
        putLas(w, d);
        w.put(src.points);
        w.put(src.skipped);
        putBox(w, src.bounds);
        w.put(src.colorMax);
        w.put(uint8_t(src.colors8Bit));
        w.put(uint8_t(src.colorsTimes256));
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
        w.put(int32_t(f.finestBit));
    }
    w.put(s.largestMeshBytes);
}

bool getStats(ByteReader& r, InputStats& s, int version = kPlanVersion) {
    s.sources.resize(r.getCount(64));
    for (SourceStats& src : s.sources) {
        InputDescription& d = src.description;
        d.path = r.getString();
        d.format = r.getString();
        if (version >= 5) d.crs = r.getString();
        d.declaredPoints = r.get<uint64_t>();
        for (bool* b : {&d.hasNormals, &d.hasColors, &d.textured, &d.hasIntensity, &d.hasClassification, &d.hasReturns,
                        &d.float32Coordinates, &d.scanOriginIsDefault, &d.airborne})
            *b = r.get<uint8_t>() != 0;
        d.colorBits = r.get<int32_t>();
        d.precision = r.get<double>();
        if (version >= 6)
            for (int a = 0; a < 3; ++a) d.latticeScale[a] = r.get<double>(), d.latticeOffset[a] = r.get<double>();
        d.scanOrigins.resize(r.getCount(25));
        for (std::optional<Vec3d>& origin : d.scanOrigins) {
            const bool has = r.get<uint8_t>() != 0;
            Vec3d o;
            for (int a = 0; a < 3; ++a) o[a] = r.get<double>();
            if (has) origin = o;
        }
        d.scalars.resize(r.getCount(13));
        for (ScalarField& f : d.scalars) f = getField(r);
        if (version >= 7) getLas(r, d);
        src.points = r.get<uint64_t>();
        src.skipped = r.get<uint64_t>();
        src.bounds = getBox(r);
        src.colorMax = r.get<uint16_t>();
        src.colors8Bit = r.get<uint8_t>() != 0;
        if (version >= 7) src.colorsTimes256 = r.get<uint8_t>() != 0;
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
        return false;
    s.scalars.resize(r.getCount(37));
    for (ScalarStats& f : s.scalars) {
        f.field = getField(r);
        f.points = r.get<uint64_t>();
        f.min = r.get<double>();
        f.max = r.get<double>();
        if (version >= 7) f.finestBit = r.get<int32_t>();
    }
    s.largestMeshBytes = r.get<uint64_t>();
    return r.ok();
}

void putPart(ByteWriter& w, const InputPart& p) {
    for (uint64_t v : {uint64_t(p.first), uint64_t(p.last), p.begin, p.end, uint64_t(p.firstSource), uint64_t(p.sources), p.points})
        w.put(v);
}
InputPart getPart(ByteReader& r) {
    InputPart p;
    p.first = size_t(r.get<uint64_t>());
    p.last = size_t(r.get<uint64_t>());
    p.begin = r.get<uint64_t>();
    p.end = r.get<uint64_t>();
    p.firstSource = size_t(r.get<uint64_t>());
    p.sources = size_t(r.get<uint64_t>());
    p.points = r.get<uint64_t>();
    return p;
}

void putCounts(ByteWriter& w, const std::vector<std::pair<uint32_t, uint32_t>>& counts) {
    w.put(uint64_t(counts.size()));
    for (auto [cell, n] : counts) w.put(cell), w.put(n);
}
bool getCounts(ByteReader& r, std::vector<std::pair<uint32_t, uint32_t>>& counts) {
    counts.resize(r.getCount(8));
    uint32_t previous = 0;
    for (size_t i = 0; i < counts.size(); ++i) {
        auto& [cell, n] = counts[i];
        cell = r.get<uint32_t>();
        n = r.get<uint32_t>();
        if (cell >= (1u << (3 * kCountLevel)) || (i > 0 && cell <= previous)) return false;
        previous = cell;
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

InputPart inputPart(const InputOptions& inputs, size_t part, size_t parts) {
    const size_t scene = inputs.defaultScene ? 1 : 0;
    InputPart p;
    if (parts == 1) {  // every input whole: no size asked for (a URL's is a request)
        p.last = scene + inputs.paths.size();
        return p;
    }
    std::vector<double> weight;
    if (scene) weight.push_back(32.0 * double(inputs.scene.targetPoints));
    for (const std::string& path : inputs.paths) {
        // A URL's asks its host; a tile set weighs as its blocks.bin (set_reader.h;
        // an updated set's other block files left out: the weight only balances parts).
        auto bytes = inputFileSize(isSetInput(path) ? (std::filesystem::path(path).parent_path() / "blocks.bin").string() : path, inputs.http);
        weight.push_back(bytes ? double(*bytes) + 1 : 1.0);  // unreadable: its reader names the error
    }
    double total = 0;
    for (double w : weight) total += w;
    auto owner = [&](double at) { return std::min(parts - 1, size_t(at / total * double(parts))); };
    // The part runs from the first record owned by `part` or a later part to
    // the first owned by a later part. Owners never decrease along the inputs.
    const size_t n = weight.size();
    std::pair<size_t, uint64_t> start{n, 0}, stop{n, 0};
    auto visit = [&](size_t input, uint64_t record, size_t by) {
        if (start.first == n && by >= part) start = {input, record};
        if (stop.first == n && by > part) stop = {input, record};
    };
    double before = 0;
    for (size_t i = 0; i < n && stop.first == n; before += weight[i++]) {
        std::vector<RecordCut> cuts;
        // Only a file that a part boundary falls within is opened for its cuts.
        if (i >= scene && owner(before) != owner(before + weight[i]))
            if (auto found = lasCuts(inputs.paths[i - scene], inputs.http)) cuts = std::move(*found);
        if (cuts.empty()) visit(i, 0, owner(before + weight[i] / 2));
        for (const RecordCut& c : cuts) visit(i, c.record, owner(before + double(c.byte)));
    }
    std::tie(p.first, p.begin) = start;
    std::tie(p.last, p.end) = stop;
    return p;
}

InputOptions partInputs(const InputOptions& inputs, const InputPart& part) {
    InputOptions o = inputs;
    const size_t scene = inputs.defaultScene ? 1 : 0;
    o.defaultScene = inputs.defaultScene && part.first == 0 && part.readEnd() > 0;
    o.paths.assign(inputs.paths.begin() + long(std::max(part.first, scene) - scene),
                   inputs.paths.begin() + long(std::max(part.readEnd(), scene) - scene));
    o.firstBegin = part.first >= scene ? part.begin : 0;
    o.lastEnd = part.end;
    return o;
}

Result<InputStats> scanStage(const BuildOptions& options, const InputPart& part, Progress& progress) {
    const BuildOptions opt = normalizeOptions(options);
    const InputOptions inputs = partInputs(opt.inputs, part);
    InputStats stats;
    if (inputs.defaultScene || !inputs.paths.empty()) {
        auto scanned = scanInputs(inputs, [&](uint64_t n) { progress.advance(n); });
        if (!scanned) return scanned.status();
        stats = std::move(*scanned);
    }
    stats.largestMeshBytes = opt.inputs.meshes->largestBytes();
    return stats;
}

Status writeScan(const std::string& path, const InputStats& stats, const InputPart& part, uint32_t job) {
    ByteWriter w;
    w.put(job);
    putPart(w, part);
    putStats(w, stats);
    return writeWorkFile(path, kScanMagic, w);
}

Result<InputStats> readScan(const std::string& path, InputPart* part, uint32_t job) {
    auto bytes = readWorkFile(path, kScanMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    if (r.get<uint32_t>() != job) {
        std::error_code ec;
        std::filesystem::remove(path, ec);  // so that the part is scanned again, not refused for good
        return Status::error(path + ": scanned for another build (other inputs or options); removed, scan the part again");
    }
    *part = getPart(r);
    InputStats stats;
    if (!getStats(r, stats) || r.left() != 0) return Status::error(path + ": malformed scan");
    return stats;
}

Status forEachPartBatch(const BuildContext& c, const InputPart& part, std::span<const ScalarQuantization> stored,
                        const BatchConsumer& consume) {
    const InputOptions inputs = partInputs(c.options().inputs, part);
    if (!inputs.defaultScene && inputs.paths.empty()) return {};
    InputStats stats;  // the part's sources, as forEachBatch indexes them
    stats.sources.assign(c.stats().sources.begin() + long(part.firstSource),
                         c.stats().sources.begin() + long(part.firstSource + part.sources));
    return forEachBatch(inputs, stats, c.rootMin(), c.sourceIds().subspan(part.firstSource, part.sources), stored, consume,
                        c.inputOfSource().subspan(part.firstSource, part.sources));
}

Result<std::vector<std::pair<uint32_t, uint32_t>>> countStage(const BuildContext& c, const InputPart& part, Progress& progress,
                                                              const std::function<Status(std::span<Surfel>)>& adjust) {
    std::vector<std::pair<uint32_t, uint32_t>> occupied;
    std::vector<uint32_t> counts(size_t(1) << (3 * kCountLevel), 0);
    SC_TRY(forEachPartBatch(c, part, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
        if (adjust) SC_TRY(adjust(batch));
        for (const Surfel& s : batch) counts[ChunkLayout::cellIndex(s.position, c.rootEdge())]++;
        progress.advance(batch.size());
        return Status{};
    }));
    for (size_t i = 0; i < counts.size(); ++i)
        if (counts[i]) occupied.push_back({uint32_t(i), counts[i]});
    return occupied;
}

Status writeCount(const std::string& path, const std::vector<std::pair<uint32_t, uint32_t>>& counts, uint32_t job) {
    ByteWriter w;
    w.put(job);
    putCounts(w, counts);
    return writeWorkFile(path, kCountMagic, w);
}

Result<std::vector<std::pair<uint32_t, uint32_t>>> readCount(const std::string& path, uint32_t job) {
    auto bytes = readWorkFile(path, kCountMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    if (r.get<uint32_t>() != job) {
        std::error_code ec;
        std::filesystem::remove(path, ec);
        return Status::error(path + ": counted for another build (other inputs or options); removed, count the part again");
    }
    std::vector<std::pair<uint32_t, uint32_t>> counts;
    if (!getCounts(r, counts) || r.left() != 0) return Status::error(path + ": malformed counts");
    return counts;
}

std::vector<std::pair<uint32_t, uint32_t>> addCounts(const std::vector<std::vector<std::pair<uint32_t, uint32_t>>>& parts) {
    std::map<uint32_t, uint64_t> sum;
    for (const auto& part : parts)
        for (auto [cell, n] : part) sum[cell] += n;
    std::vector<std::pair<uint32_t, uint32_t>> out;
    for (auto [cell, n] : sum) out.push_back({cell, uint32_t(std::min<uint64_t>(n, UINT32_MAX))});
    return out;
}

Result<InputStats> reduceScans(std::vector<InputStats> scans, std::vector<InputPart>& parts,
                               const std::function<std::string(size_t)>& name) {
    assert(scans.size() == parts.size());
    std::vector<bool> continues;
    size_t sources = 0;
    for (size_t p = 0; p < parts.size(); ++p) {
        InputPart& part = parts[p];
        const bool follows = p == 0 ? part.first == 0 && part.begin == 0 : part.first == parts[p - 1].last && part.begin == parts[p - 1].end;
        if (!follows || part.sources != scans[p].sources.size() || (part.continuesSource() && sources == 0))
            return Status::error(name(p) + ": its inputs do not follow on from the previous part's (scanned with another number of parts?)");
        // A part that starts within a file shares its source with the part before.
        part.firstSource = part.continuesSource() ? sources - 1 : sources;
        sources = part.firstSource + part.sources;
        continues.push_back(part.continuesSource());
    }
    return mergeInputStats(std::move(scans), continues);
}

Status forEachPartInParallel(size_t n, const std::function<Status(size_t)>& f) {
    if (n == 1) return f(0);
    std::vector<Status> results(n);
    std::vector<std::thread> threads;
    for (size_t p = 0; p < n; ++p) threads.emplace_back([&, p] { results[p] = f(p); });
    for (std::thread& t : threads) t.join();
    for (const Status& st : results) SC_TRY(st);
    return {};
}

size_t readParts(const BuildOptions& options) {
    const InputOptions& in = options.inputs;
    // (A preview's captured sample is read whole, whatever the part.)
    if (options.threads <= 1 || in.defaultScene || in.captured || in.paths.size() != 1) return 1;
    const std::string& path = in.paths[0];
    std::string ext = std::filesystem::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
    return isRemoteInput(path) || isSetInput(path) || ext != ".las" ? 1 : size_t(options.threads);
}

InputPart wholeInputs(const InputOptions& inputs, const InputStats& stats) {
    InputPart all = inputPart(inputs, 0, 1);
    all.sources = stats.sources.size();
    all.points = stats.points;
    return all;
}

Result<BuildPlan> planStage(const BuildOptions& options, size_t parts, Progress& progress, std::shared_ptr<const BuildContext>* context,
                            BuildSummary* summary) {
    const BuildOptions opt = normalizeOptions(options);
    BuildPlan plan;
    plan.parts.resize(std::max<size_t>(parts, 1));
    for (size_t p = 0; p < plan.parts.size(); ++p) plan.parts[p] = inputPart(opt.inputs, p, plan.parts.size());
    std::vector<InputStats> scans(plan.parts.size());
    progress.begin("scan", 0);
    SC_TRY(forEachPartInParallel(plan.parts.size(), [&](size_t p) {
        auto scanned = scanStage(opt, plan.parts[p], progress);
        if (!scanned) return scanned.status();
        plan.parts[p].sources = scanned->sources.size();
        plan.parts[p].points = scanned->points;
        scans[p] = std::move(*scanned);
        return Status{};
    }));
    auto stats = reduceScans(std::move(scans), plan.parts, [](size_t p) { return "scan part " + std::to_string(p); });
    if (!stats) return stats.status();
    summary->phaseSeconds.push_back({"scan", progress.end()});
    auto derived = BuildContext::derive(opt, std::move(*stats));
    if (!derived) return derived.status();
    const BuildContext& c = **derived;
    *context = *derived;

    plan.stats = c.stats();
    auto most = chunkPoints(c);
    if (!most) return most.status();
    MeshStore& meshes = *opt.inputs.meshes;
    meshes.setCapacity(opt.memoryBytes - kBaselineBytes - c.textureBytes() - c.stats().largestMeshBytes);
    plan.maxChunkPoints = *most;
    if (plan.maxChunkPoints > 0) {
        progress.begin("count", c.stats().points);
        std::vector<std::vector<std::pair<uint32_t, uint32_t>>> counts(plan.parts.size());
        SC_TRY(forEachPartInParallel(plan.parts.size(), [&](size_t p) {
            auto counted = countStage(c, plan.parts[p], progress);
            if (!counted) return counted.status();
            counts[p] = std::move(*counted);
            return Status{};
        }));
        summary->phaseSeconds.push_back({"count", progress.end()});
        plan.counts = addCounts(counts);
    }
    return plan;
}

namespace {
ByteWriter planPayload(const BuildPlan& plan, std::span<const std::string> args) {
    ByteWriter w;
    w.put(uint64_t(args.size()));
    for (const std::string& a : args) w.putString(a);
    putStats(w, plan.stats);
    w.put(uint64_t(plan.parts.size()));
    for (const InputPart& p : plan.parts) putPart(w, p);
    w.put(plan.maxChunkPoints);
    putCounts(w, plan.counts);
    return w;
}
}  // namespace

uint32_t planId(const BuildPlan& plan, std::span<const std::string> args) {
    ByteWriter w = planPayload(plan, args);
    return crc32(w.bytes().data(), w.bytes().size());
}

Status writePlan(const std::string& path, BuildPlan& plan, std::span<const std::string> args) {
    ByteWriter w = planPayload(plan, args);
    plan.id = crc32(w.bytes().data(), w.bytes().size());
    return writeWorkFile(path, kPlanMagic, w);
}

Status keepBuildRecord(TilesetWriter& writer, const std::string& dir, BuildPlan plan, std::span<const std::string> commandLine) {
    const std::string path = dir + "/build.record";
    SC_TRY(writePlan(path, plan, commandLine));
    writer.setBuildRecord(path);
    return {};
}

Result<BuildPlan> readPlan(const std::string& path, std::vector<std::string>* args, bool buildRecord) {
    auto bytes = readWorkFile(path, kPlanMagic);
    int version = kPlanVersion;
    while (!bytes && buildRecord && version > kOldestRecordVersion) {
        char magic[9] = "SCPLAN00";
        magic[7] = char('0' + --version);
        bytes = readWorkFile(path, magic);
    }
    if (!bytes) return readWorkFile(path, kPlanMagic).status();
    ByteReader r(*bytes);
    const Status corrupt = Status::error(path + ": malformed plan");
    BuildPlan plan;
    plan.id = crc32(bytes->data(), bytes->size());
    args->resize(r.getCount(4));
    for (std::string& arg : *args) arg = r.getString();
    if (!getStats(r, plan.stats, version)) return corrupt;
    plan.parts.resize(r.getCount(32));
    for (InputPart& p : plan.parts) p = getPart(r);
    plan.maxChunkPoints = r.get<uint64_t>();
    if (!getCounts(r, plan.counts) || !r.ok() || r.left() != 0 || plan.parts.empty()) return corrupt;
    // Parts tile the inputs' records and the sources in order.
    size_t source = 0;
    for (size_t i = 0; i < plan.parts.size(); ++i) {
        const InputPart& p = plan.parts[i];
        const bool follows = i == 0 ? p.first == 0 && p.begin == 0 : p.first == plan.parts[i - 1].last && p.begin == plan.parts[i - 1].end;
        if (p.continuesSource() && source == 0) return corrupt;
        const size_t expected = p.continuesSource() ? source - 1 : source;
        if (!follows || p.firstSource != expected || p.sources > plan.stats.sources.size() - expected) return corrupt;
        source = expected + p.sources;
    }
    if (source != plan.stats.sources.size() || plan.parts.back().end != 0) return corrupt;
    return plan;
}

}  // namespace surfcast
