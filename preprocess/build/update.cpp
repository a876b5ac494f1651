// An update in place (update.h): the chunk layout of all the inputs, the
// chunks the added points reach rebuilt from the set's own leaves and the new
// points, the others kept as they are, and the levels above the chunks anew.
#include "update.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <set>

#include "built_node.h"
#include "tileset_reader.h"
#include "tileset_writer.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// What the kept blocks were written with must not change: the root cube (the
// nodes' boxes), the colour depth and every attribute's layout and scale.
Status sameLayout(const TilesetInfo& set, const TilesetInfo& updated, const std::string& where) {
    auto differs = [&](const std::string& what) {
        return Status::error(where + ": the added inputs change " + what +
                             ", which the set's blocks were written with; build the set anew from all its inputs");
    };
    if (!(set.rootMin == updated.rootMin) || set.rootEdge != updated.rootEdge) return differs("the root cube");
    if (set.colorBits != updated.colorBits)
        return differs("the colour depth (" + std::to_string(set.colorBits) + " to " + std::to_string(updated.colorBits) + " bits)");
    if (set.weights != updated.weights || set.kernelScale != updated.kernelScale) return differs("the weights");
    for (size_t i = 0; i < std::max(set.attributes.size(), updated.attributes.size()); ++i) {
        if (i >= set.attributes.size()) return differs("the attributes (" + updated.attributes[i].name + " would be added)");
        if (i >= updated.attributes.size() || !(set.attributes[i] == updated.attributes[i]))
            return differs("how attribute '" + set.attributes[i].name + "' is stored");
    }
    return {};
}

// A decoded block's surfels as the builder holds them (positions relative to
// the root minimum, colours in 16 bits, LiDAR values as read, the stored
// scalar fields as rows of `table`), with orientation rule `source`.
void appendSurfels(const BuildContext& c, const TilesetReader& set, const NodeRecord& node, const BlockData& block, uint16_t source,
                   std::vector<Surfel>* out, ScalarTable* table) {
    const TilesetInfo& info = set.info();
    const Vec3d origin = c.rootMin();
    const AttributeInfo* intensity = info.attribute(kLidarAttributes[kLidarIntensity]);
    for (size_t i = 0; i < block.size(); ++i) {
        Surfel s;
        s.position = set.position(node, block, i) - origin;
        s.normal = Vec3f{block.normals[3 * i], block.normals[3 * i + 1], block.normals[3 * i + 2]};
        if (!block.colors.empty())
            for (int k = 0; k < 3; ++k) s.color[k] = info.colorBits == 8 ? uint16_t(block.colors[3 * i + k] * 257) : block.colors[3 * i + k];
        s.source = source;
        // The stored intensity is (value - offset) / scale: its value again
        // stores as the same integer.
        if (!block.intensity.empty() && intensity)
            s.intensity = uint16_t(std::lround(block.intensity[i] * intensity->scale + intensity->offset));
        if (!block.classification.empty()) s.classification = block.classification[i];
        s.returns = uint8_t((block.returnNumber.empty() ? 0 : block.returnNumber[i] & 15) |
                            (block.numberOfReturns.empty() ? 0 : block.numberOfReturns[i] << 4));
        if (!block.opacity.empty()) s.alpha = block.opacity[i];
        if (table) {
            std::vector<uint32_t> row(table->fields());
            for (size_t f = 0; f < row.size() && f < block.scalars.size(); ++f) row[f] = block.scalars[f].values[i];
            s.row = table->append(row.data());
        }
        out->push_back(s);
    }
}

Result<BlockData> decode(const TilesetReader& set, const NodeRecord& node) {
    auto bytes = set.readBlockBytes(node);
    if (!bytes) return bytes.status();
    BlockExpectation e = set.expectation(node);
    e.scalars = true;
    auto block = decodeBlock(bytes->data(), bytes->size(), e);
    if (!block) return Status::error(set.describe() + ": node " + node.key.name() + ": " + block.status().message());
    return block;
}

bool inside(const NodeKey& key, const NodeKey& chunk) {
    const int below = int(key.level) - int(chunk.level);
    return below >= 0 && (key.x >> below) == chunk.x && (key.y >> below) == chunk.y && (key.z >> below) == chunk.z;
}

}  // namespace

Result<BuildSummary> updateTileset(const BuildOptions& options, size_t added, const std::string& set, const BuildPlan& record,
                                   const std::vector<std::string>& commandLine) {
    const auto start = std::chrono::steady_clock::now();
    const BuildOptions opt = normalizeOptions(options);
    Progress progress(opt.progress);
    BuildSummary summary;
    auto reader = TilesetReader::open(set);
    if (!reader) return reader.status();
    const TilesetInfo& info = reader->info();
    if (!info.textureFilter.empty())
        return Status::error(set + ": built from textured meshes, whose texture fields an update does not rebuild yet; build it anew");
    if (info.weights == "captured")
        return Status::error(set + ": its weights were captured by rendering; an update cannot keep them; build it anew");

    // The set's context, from its record; the record must be this set's.
    BuildOptions setOptions = opt;
    setOptions.inputs.paths.resize(opt.inputs.paths.size() - added);
    auto old = BuildContext::derive(setOptions, record.stats, false);
    if (!old) return old.status();
    SC_TRY(sameLayout(info, (*old)->tilesetInfo(), set + "/" + buildRecordFile(info.hierarchyFile) + " (not this set's record)"));

    // The added inputs: scanned, then the context of them all, in the set's root cube.
    InputOptions addedInputs = opt.inputs;
    addedInputs.defaultScene = false;
    addedInputs.paths.assign(opt.inputs.paths.end() - long(added), opt.inputs.paths.end());
    progress.begin("scan", 0);
    auto scanned = scanInputs(addedInputs, [&](uint64_t n) { progress.advance(n); });
    if (!scanned) return scanned.status();
    summary.phaseSeconds.push_back({"scan", progress.end()});
    const size_t oldSources = record.stats.sources.size();
    const uint64_t addedPoints = scanned->points;
    if (addedPoints == 0) return Status::error("the added inputs hold no valid points");
    InputStats merged = mergeInputStats({record.stats, std::move(*scanned)}, {false, false});
    auto derived = BuildContext::derive(opt, std::move(merged), true, old->get());
    if (!derived) return derived.status();
    const BuildContext& c = **derived;
    c.describe(&summary);
    SC_TRY(sameLayout(info, c.tilesetInfo(), set));
    const auto oldRules = (*old)->sourceIds();
    if (!std::equal(oldRules.begin(), oldRules.end(), c.sourceIds().begin()))
        return Status::error(set + ": the added inputs change how the set's normals are oriented; build it anew from all its inputs");
    // Without provenance the kept points' inputs are unknown: every input
    // must orient its normals by the same rule, which is then theirs.
    if (std::any_of(oldRules.begin(), oldRules.end(), [&](uint16_t r) { return r != oldRules[0]; }))
        return Status::error(set + ": its inputs orient their normals by different rules, which an update cannot tell apart yet; build it anew");
    const uint16_t keptRule = oldRules.empty() ? 0 : oldRules[0];

    // The plan of all the inputs: one part, the counts summed.
    BuildPlan plan;
    plan.stats = c.stats();
    InputPart all;
    all.first = 0;
    all.last = (opt.inputs.defaultScene ? 1 : 0) + opt.inputs.paths.size();
    all.sources = c.stats().sources.size();
    all.points = c.stats().points;
    plan.parts = {all};
    auto most = chunkPoints(c);
    if (!most) return most.status();
    plan.maxChunkPoints = *most;
    if (plan.maxChunkPoints != record.maxChunkPoints)
        return Status::error(set + ": the added points outgrow the set's single chunk; build it anew from all its inputs");
    InputPart addedPart;
    addedPart.first = all.last - added;
    addedPart.last = all.last;
    addedPart.firstSource = oldSources;
    addedPart.sources = c.stats().sources.size() - oldSources;
    addedPart.points = addedPoints;
    if (plan.maxChunkPoints > 0) {
        progress.begin("count", addedPoints);
        auto counts = countStage(c, addedPart, progress);
        if (!counts) return counts.status();
        summary.phaseSeconds.push_back({"count", progress.end()});
        plan.counts = addCounts({record.counts, *counts});
    }
    ChunkLayout layout = plan.layout(c);
    const ChunkLayout before = record.layout(**old);

    // The chunks to build: those the added points or their halos reach, and
    // those the set did not have.
    std::set<NodeKey> oldChunks;
    for (const Chunk& ch : before.chunks()) oldChunks.insert(ch.key);
    std::vector<bool> touched(layout.chunks().size(), false);
    for (size_t i = 0; i < touched.size(); ++i) touched[i] = !oldChunks.count(layout.chunks()[i].key);
    std::vector<int> halo;
    SC_TRY(forEachPartBatch(c, addedPart, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
        for (const Surfel& s : batch) {
            touched[size_t(layout.chunkOf(s.position))] = true;
            layout.haloChunksOf(s.position, &halo);
            for (int h : halo) touched[size_t(h)] = true;
        }
        return Status{};
    }));

    auto writer = TilesetWriter::update(set, info);
    if (!writer) return writer.status();
    const WorkFolder work{(*writer)->partialDir() + "/work"};
    std::error_code ec;
    fs::create_directories(work.chunks(0), ec);
    if (ec) return Status::error(work.dir + ": cannot create (" + ec.message() + ")");

    // Their points: the set's leaves that reach a rebuilt chunk or its halo,
    // and the added points.
    std::vector<Box3d> rebuilt;
    for (size_t i = 0; i < touched.size(); ++i)
        if (touched[i]) {
            const Chunk& ch = layout.chunks()[i];
            const double m = layout.margin(int(i)), e = c.edge(ch.key.level);
            Box3d b;
            b.min = c.nodeMinRel(ch.key) - Vec3d{m, m, m};
            b.max = c.nodeMinRel(ch.key) + Vec3d{e + m, e + m, e + m};
            rebuilt.push_back(b);
        }
    progress.begin("distribute", 0);
    {
        ChunkWriter chunkWriter(layout, work.chunks(0), c.scalars().size());
        for (const NodeRecord& n : reader->nodes()) {
            if (!(n.flags & kFlagInputPoints)) continue;
            const Vec3d lo = c.nodeMinRel(n.key);
            const double e = c.edge(n.key.level);
            const bool reaches = std::any_of(rebuilt.begin(), rebuilt.end(), [&](const Box3d& b) {
                for (int a = 0; a < 3; ++a)
                    if (lo[a] > b.max[a] || lo[a] + e < b.min[a]) return false;
                return true;
            });
            if (!reaches) continue;
            auto block = decode(*reader, n);
            if (!block) return block.status();
            std::vector<Surfel> points;
            ScalarTable table = c.emptyTable();
            appendSurfels(c, *reader, n, *block, keptRule, &points, &table);
            SC_TRY(chunkWriter.add(points, table.values));
            progress.advance(points.size());
        }
        SC_TRY(forEachPartBatch(c, addedPart, c.scalars(), [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
            progress.advance(batch.size());
            return chunkWriter.add(batch, scalars);
        }));
        SC_TRY(chunkWriter.finish());
    }
    summary.phaseSeconds.push_back({"distribute", progress.end()});
    std::vector<size_t> build;
    uint64_t buildPoints = 0;
    for (size_t i = 0; i < layout.chunks().size(); ++i) {
        Chunk& ch = layout.chunks()[i];
        ch.points = ch.written.points;
        ch.haloPoints = ch.written.haloPoints;
        ch.pieces = {ch.written};
        if (touched[i]) build.push_back(i), buildPoints += ch.points;
    }
    summary.chunks = build.size();
    progress.begin("build", buildPoints);
    SC_TRY(buildChunks(c, plan, layout, build, work, progress));
    summary.phaseSeconds.push_back({"build", progress.end()});

    // The kept chunks: their nodes as the set holds them, their roots decoded
    // for the levels above.
    std::map<size_t, ChunkOutput> kept;
    for (size_t i = 0; i < layout.chunks().size(); ++i)
        if (!touched[i]) kept[i].plan = plan.id;
    for (const NodeRecord& n : reader->nodes()) {
        for (auto& [i, out] : kept) {
            const NodeKey& key = layout.chunks()[i].key;
            if (!inside(n.key, key)) continue;
            out.records.push_back(n);
            if (n.key == key && !(key == NodeKey{})) {
                auto block = decode(*reader, n);
                if (!block) return block.status();
                out.root = std::make_unique<BuiltNode>();
                out.root->key = key;
                out.rootScalars = c.emptyTable();
                appendSurfels(c, *reader, n, *block, keptRule, &out.root->surfels, &out.rootScalars);
            }
            break;
        }
    }
    BuildPlan copy = plan;
    const std::string recordPath = (*writer)->partialDir() + "/build.record";
    SC_TRY(writePlan(recordPath, copy, commandLine));
    (*writer)->setBuildRecord(recordPath);
    SC_TRY(mergeStage(c, plan, layout, work, **writer, progress, &summary, &kept));
    summary.inputPoints = c.stats().points;
    summary.skippedPoints = c.stats().skipped;
    summary.totalSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    summary.peakRss = peakRssBytes();
    return summary;
}

}  // namespace surfcast
