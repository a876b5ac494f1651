// An update in place (update.h): the chunk layout of all the inputs, the
// chunks the added points reach rebuilt from the set's own leaves and the new
// points, the others kept as they are, and the levels above the chunks anew.
#include "update.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <filesystem>
#include <set>
#include <unordered_set>

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

// Whether the set's layout holds what an update adds: the attributes a fresh
// build of all the inputs would store (`all`) are the set's (but provenance,
// which a set of one input gains: see updateTileset), with its colour depth,
// and the added values fit the set's quantization of each.
Status holds(const TilesetInfo& set, const TilesetInfo& all, const InputStats& added, const std::string& where) {
    auto refuse = [&](const std::string& what) {
        return Status::error(where + ": the added inputs " + what + ", which the set's blocks were not written for; build the set "
                             "anew from all its inputs");
    };
    if (set.colorBits != all.colorBits)
        return refuse("change the colour depth (" + std::to_string(set.colorBits) + " to " + std::to_string(all.colorBits) + " bits)");
    for (const AttributeInfo& a : all.attributes)
        if (!set.attribute(a.name) && a.name != kProvenanceAttribute) return refuse("bring attribute '" + a.name + "'");
    auto span = [](const AttributeInfo& a, int bits) { return a.offset + a.scale * (std::ldexp(1.0, bits) - 1); };
    auto typeBits = [](const AttributeInfo& a) { return a.type == "uint8" ? 8 : a.type == "uint16" ? 16 : 32; };
    if (const AttributeInfo* a = set.attribute(kLidarAttributes[kLidarIntensity]); a && added.attributes.intensityPoints > 0) {
        const auto& h = added.attributes.intensityHistogram;
        const auto lo = std::find_if(h.begin(), h.end(), [](uint64_t n) { return n > 0; }) - h.begin();
        const auto hi = h.rend() - std::find_if(h.rbegin(), h.rend(), [](uint64_t n) { return n > 0; }) - 1;
        // As BuildContext::chooseAttributes takes a range: (hi - offset) / step under 2^12.
        const double top = a->offset + a->scale * std::ldexp(1.0, kIntensityBits) - 1;
        if (double(lo) < a->offset || double(hi) > top)
            return refuse("hold intensities " + std::to_string(lo) + "-" + std::to_string(hi) + " beyond the set's " +
                          std::to_string(int(a->offset)) + "-" + std::to_string(int(top)));
    }
    for (const ScalarStats& f : added.scalars) {
        const AttributeInfo* a = set.attribute(f.field.name);
        if (!a || f.points == 0) continue;
        if (f.min < a->offset - 0.5 * a->scale || f.max > span(*a, typeBits(*a)) + 0.5 * a->scale)
            return refuse("hold values of '" + f.field.name + "' beyond what the set stores");
    }
    if (const AttributeInfo* a = set.attribute(kProvenanceAttribute); a && all.inputs.size() > (uint64_t(1) << typeBits(*a)))
        return refuse("bring the inputs past " + std::to_string(uint64_t(1) << typeBits(*a)) + ", what the input attribute holds");
    return {};
}

// A decoded block's surfels as the builder holds them (positions relative to
// the root minimum, colours in 16 bits, LiDAR values as read, the stored
// scalar fields as rows of `table`), with orientation rules `rules`.
void appendSurfels(const BuildContext& c, const TilesetReader& set, const NodeRecord& node, const BlockData& block,
                   const std::vector<uint16_t>& rules, std::vector<Surfel>* out, ScalarTable* table) {
    const TilesetInfo& info = set.info();
    const Vec3d origin = c.rootMin();
    const AttributeInfo* intensity = info.attribute(kLidarAttributes[kLidarIntensity]);
    // A position is held inside its node's box, [k e, (k + 1) e) relative to
    // `origin`, so that it goes to its own chunk (a kept neighbour would drop
    // it) and quantizes as before: one quantized to the node's upper face lies
    // in the neighbour's box, and one on its lower face can round below it
    // on the way from world coordinates. k e is exact (the root is aligned
    // with the set's, `origin` a whole number of node edges from its minimum),
    // as the chunks' cells, whole fractions of it, are.
    const double e = nodeEdge(info, node.key.level);
    Vec3d lo = nodeMin(info, node.key) - origin;
    for (int a = 0; a < 3; ++a) lo[a] = std::round(lo[a] / e) * e;
    for (size_t i = 0; i < block.size(); ++i) {
        Surfel s;
        s.position = set.position(node, block, i) - origin;
        for (int a = 0; a < 3; ++a) s.position[a] = std::clamp(s.position[a], lo[a], std::nextafter(lo[a] + e, lo[a]));
        s.normal = Vec3f{block.normals[3 * i], block.normals[3 * i + 1], block.normals[3 * i + 2]};
        if (!block.colors.empty())
            for (int k = 0; k < 3; ++k) s.color[k] = info.colorBits == 8 ? uint16_t(block.colors[3 * i + k] * 257) : block.colors[3 * i + k];
        s.source = rules[i];
        s.fromSet = node.flags & kFlagInputPoints;
        // The stored intensity is (value - offset) / scale: its value again
        // stores as the same integer (the top step's value can pass 65535,
        // which the clamp of storedIntensity also maps to the top).
        if (!block.intensity.empty() && intensity)
            s.intensity = uint16_t(std::clamp(std::lround(block.intensity[i] * intensity->scale + intensity->offset), 0l, 65535l));
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

// A set grown past its root cube: the old root becomes the node at `levels`
// below the new root at `offset` (in old-root edges), so every old node keeps
// its box, and so its block (positions are relative to the node).
struct Growth {
    int levels = 0;
    uint32_t offset[3] = {};
    Vec3d rootMin;
    double rootEdge = 0;

    NodeKey key(NodeKey k) const {
        const int l = k.level;
        k.level = uint8_t(l + levels);
        k.x += offset[0] << l, k.y += offset[1] << l, k.z += offset[2] << l;
        return k;
    }
    // A counting-grid cell (ChunkLayout::cellIndex) of the old root in the new one.
    uint32_t cell(uint32_t index) const {
        if (levels == 0) return index;
        const uint32_t n = 1u << kCountLevel, mask = n - 1;
        const uint32_t c[3] = {index >> (2 * kCountLevel), (index >> kCountLevel) & mask, index & mask};
        uint32_t out[3];
        for (int a = 0; a < 3; ++a) out[a] = ((offset[a] << kCountLevel) + c[a]) >> levels;
        return (out[0] << (2 * kCountLevel)) | (out[1] << kCountLevel) | out[2];
    }
};

// The smallest cube of 2^levels old root edges, aligned with the old root,
// that holds `bounds` (levels 0: the old root holds them).
Result<Growth> growRoot(const TilesetInfo& set, const Box3d& bounds) {
    Growth g;
    for (g.levels = 0; g.levels + set.levels <= kMaxLevel; ++g.levels) {
        const double edge = std::ldexp(set.rootEdge, g.levels);
        bool fits = true;
        for (int a = 0; a < 3 && fits; ++a) {
            const double lo = std::min(bounds.min[a], set.rootMin[a]);
            const double steps = std::ceil((set.rootMin[a] - lo) / set.rootEdge);
            g.offset[a] = uint32_t(steps);
            g.rootMin[a] = set.rootMin[a] - steps * set.rootEdge;
            fits = steps <= std::ldexp(1.0, g.levels) - 1 && bounds.max[a] < g.rootMin[a] + edge;
        }
        if (fits) {
            g.rootEdge = edge;
            if (g.levels == 0) g.rootMin = set.rootMin;
            return g;
        }
    }
    return Status::error("the added inputs lie too far from the set: its root would grow past level " + std::to_string(kMaxLevel) +
                         "; build it anew from all its inputs");
}

bool inside(const NodeKey& key, const NodeKey& chunk) {
    const int below = int(key.level) - int(chunk.level);
    return below >= 0 && (key.x >> below) == chunk.x && (key.y >> below) == chunk.y && (key.z >> below) == chunk.z;
}


// The statistics without the removed inputs' points (`gone`, decoded from
// the set): their sources keep their places with no points, the set's bounds
// are the other sources' again, and the histograms lose the points' values
// (exact, but for intensities stored in steps wider than 1 and duplicates the
// build merged, whose one surviving point had one input's provenance).
void removeFromStats(InputStats& stats, std::span<const uint32_t> inputOfSource, const std::vector<uint32_t>& removed,
                     const std::vector<Surfel>& gone) {
    stats.bounds = Box3d{};
    for (size_t i = 0; i < stats.sources.size(); ++i) {
        SourceStats& src = stats.sources[i];
        // Sources past the set's own are the ones this update adds, never removed.
        if (i < inputOfSource.size() && std::find(removed.begin(), removed.end(), inputOfSource[i]) != removed.end()) {
            stats.points -= std::min(stats.points, src.points);
            stats.skipped -= std::min(stats.skipped, src.skipped);
            src.points = src.skipped = 0;  // its bounds stay: its orientation rule must not change
        } else if (src.points > 0) {
            stats.bounds.extend(src.bounds);
        }
    }
    AttributeStats& a = stats.attributes;
    auto less = [](std::vector<uint64_t>& h, size_t v) {
        if (v < h.size() && h[v] > 0) --h[v];
    };
    for (const Surfel& s : gone) {
        if (a.intensityPoints) less(a.intensityHistogram, s.intensity), --a.intensityPoints;
        if (a.classifiedPoints) less(a.classCounts, s.classification), --a.classifiedPoints;
        if (a.returnPoints) less(a.returnsHistogram, s.returns), --a.returnPoints;
        if (s.alpha < 255 && a.translucentPoints) --a.translucentPoints;
    }
}

}  // namespace

Result<BuildSummary> updateTileset(const BuildOptions& options, const UpdateRequest& request, const std::string& set,
                                   const BuildPlan& record, const std::vector<std::string>& commandLine) {
    const auto start = std::chrono::steady_clock::now();
    const BuildOptions opt = normalizeOptions(options);
    const size_t added = request.added;
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
    auto derivedOld = BuildContext::derive(setOptions, record.stats, false);
    if (!derivedOld) return derivedOld.status();
    // Its layout is the set's own (what its blocks were written with), which
    // the record's statistics need not derive again after an update.
    const std::shared_ptr<const BuildContext> setContext = BuildContext::withLayoutOf(**derivedOld, info);
    const auto* old = &setContext;
    const std::string recordName = set + "/" + buildRecordFile(info.hierarchyFile);
    SC_TRY(sameLayout(info, (*old)->tilesetInfo(), recordName + " (not this set's record)"));
    if ((*derivedOld)->stats().colorBits != info.colorBits || (info.inputs.size() > 1 && (*derivedOld)->inputNames() != info.inputs))
        return Status::error(recordName + ": its inputs are not the set's (not this set's record)");
    const auto oldRules = (*old)->sourceIds();
    const auto oldInputs = (*old)->inputOfSource();
    // A set of one input keeps no provenance: its one input is all of it.
    if (!request.removed.empty() && !info.attribute(kProvenanceAttribute))
        return Status::error(set + ": a set of one input, whose points carry no input to remove; build the set anew from the "
                             "inputs it should hold");
    for (uint32_t k : request.removed) {
        uint64_t points = 0;
        for (size_t i = 0; i < oldInputs.size(); ++i) points += oldInputs[i] == k ? record.stats.sources[i].points : 0;
        if (points == 0) return Status::error(set + ": input " + std::to_string(k) + " has no points in the set (removed before?)");
    }
    // A kept point's orientation rule is its input's (its first scan's: an
    // input of several scans, an E57 file, has a rule per scan, which the set
    // does not keep per point).
    for (const SourceStats& src : record.stats.sources)
        if (src.description.scanOrigins.size() > 1)
            return Status::error(set + ": " + src.description.path +
                                 " holds several scans, whose points' scans the set does not keep; build it anew");
    auto ruleOf = [&](const BlockData& block) {
        std::vector<uint16_t> rules(block.size(), oldRules.empty() ? 0 : oldRules[0]);
        const ScalarAttribute* input = nullptr;
        for (const ScalarAttribute& a : block.scalars)
            if (a.name == kProvenanceAttribute) input = &a;
        if (input)
            for (size_t i = 0; i < rules.size(); ++i)
                for (size_t src = 0; src < oldInputs.size(); ++src)
                    if (oldInputs[src] == input->values[i]) {
                        rules[i] = oldRules[src];
                        break;
                    }
        return rules;
    };
    auto inputsOf = [&](const BlockData& block) {
        std::vector<uint32_t> of(block.size(), 0);
        for (const ScalarAttribute& a : block.scalars)
            if (a.name == kProvenanceAttribute) of = a.values;
        return of;
    };

    // The added inputs: scanned; all of them together must keep the set's
    // layout, in its root cube or in one grown around it.
    std::shared_ptr<const BuildContext> root = *old;  // the set's layout in the updated set's root cube
    TilesetInfo rootInfo = info;
    Growth grow;
    // A set of one input stores no provenance (docs/FORMAT.md): the first
    // update that makes it one of several builds every chunk again, so that
    // every block gains the attribute (its old blocks stay for readers that
    // opened it, dead bytes until --compact).
    // (The set's points then take provenance 0, its one input's, from the
    // zero-filled last field of appendSurfels' rows.)
    bool addsProvenance = false;
    InputStats stats = record.stats;
    const size_t oldSources = record.stats.sources.size();
    uint64_t addedPoints = 0;
    if (added > 0) {
        InputOptions addedInputs = opt.inputs;
        addedInputs.defaultScene = false;
        addedInputs.paths.assign(opt.inputs.paths.end() - long(added), opt.inputs.paths.end());
        progress.begin("scan", 0);
        auto scanned = scanInputs(addedInputs, [&](uint64_t n) { progress.advance(n); });
        if (!scanned) return scanned.status();
        summary.phaseSeconds.push_back({"scan", progress.end()});
        addedPoints = scanned->points;
        if (addedPoints == 0) return Status::error("the added inputs hold no valid points");
        for (const SourceStats& src : scanned->sources)
            if (src.description.scanOrigins.size() > 1)
                return Status::error(src.description.path + ": holds several scans, whose points' scans a set does not keep for "
                                     "later updates; build the set anew from all its inputs");
        const InputStats addedStats = *scanned;
        stats = mergeInputStats({std::move(stats), std::move(*scanned)}, {false, false});
        auto grown = growRoot(info, stats.bounds);
        if (!grown) return grown.status();
        grow = *grown;
        if (grow.levels > 0) {
            root = BuildContext::rerooted(**old, grow.rootMin, grow.rootEdge);
            rootInfo.rootMin = grow.rootMin;
            rootInfo.rootEdge = grow.rootEdge;
        }
        auto all = BuildContext::derive(opt, stats, true, root.get());  // what a fresh build of them all stores
        if (!all) return all.status();
        SC_TRY(holds(rootInfo, (*all)->tilesetInfo(), addedStats, set));
        addsProvenance = !info.attribute(kProvenanceAttribute) && (*all)->tilesetInfo().attribute(kProvenanceAttribute);
        if (!std::equal(oldRules.begin(), oldRules.end(), (*all)->sourceIds().begin()))
            return Status::error(set + ": the added inputs change how the set's normals are oriented; build it anew from all its inputs");
    }

    // The removed inputs' points: in the leaves their sources' bounds reach.
    std::vector<Box3d> removedBoxes;
    for (size_t i = 0; i < oldInputs.size(); ++i)
        if (std::find(request.removed.begin(), request.removed.end(), oldInputs[i]) != request.removed.end())
            removedBoxes.push_back(record.stats.sources[i].bounds);
    auto reaches = [&](const NodeRecord& n, const std::vector<Box3d>& boxes, const Vec3d& shift) {
        const Vec3d lo = nodeMin(info, n.key) - shift;
        const double e = nodeEdge(info, n.key.level);
        return std::any_of(boxes.begin(), boxes.end(), [&](const Box3d& b) {
            for (int a = 0; a < 3; ++a)
                if (lo[a] > b.max[a] || lo[a] + e < b.min[a]) return false;
            return true;
        });
    };
    std::vector<Surfel> gone;  // the removed points, relative to the root
    if (!request.removed.empty()) {
        progress.begin("find removed", 0);
        for (const NodeRecord& n : reader->nodes()) {
            if (!(n.flags & kFlagInputPoints) || !reaches(n, removedBoxes, Vec3d{})) continue;
            auto block = decode(*reader, n);
            if (!block) return block.status();
            std::vector<Surfel> points;
            appendSurfels(*root, *reader, n, *block, ruleOf(*block), &points, nullptr);
            const std::vector<uint32_t> of = inputsOf(*block);
            for (size_t i = 0; i < points.size(); ++i)
                if (std::find(request.removed.begin(), request.removed.end(), of[i]) != request.removed.end()) gone.push_back(points[i]);
            progress.advance(points.size());
        }
        summary.phaseSeconds.push_back({"find removed", progress.end()});
        removeFromStats(stats, oldInputs, request.removed, gone);
    }

    // The context of what the set will hold, in the set's layout.
    auto derived = BuildContext::derive(opt, std::move(stats), false, root.get(), true);
    if (!derived) return derived.status();
    const BuildContext& c = **derived;
    c.describe(&summary);

    // The plan of all the inputs: one part, the counts changed by the points.
    BuildPlan plan;
    plan.stats = c.stats();
    InputPart all;
    all.last = (opt.inputs.defaultScene ? 1 : 0) + opt.inputs.paths.size();
    all.sources = c.stats().sources.size();
    all.points = c.stats().points;
    plan.parts = {all};
    auto most = chunkPoints(c);
    if (!most) return most.status();
    plan.maxChunkPoints = *most;
    // (Where every chunk is built again, only the chunks' size may change:
    // provenance takes memory per point.)
    if ((plan.maxChunkPoints == 0) != (record.maxChunkPoints == 0) || (!addsProvenance && plan.maxChunkPoints != record.maxChunkPoints))
        return Status::error(set + ": the update changes whether the set's points fit one chunk; build it anew from all its inputs");
    InputPart addedPart;
    addedPart.first = all.last - added;
    addedPart.last = all.last;
    addedPart.firstSource = oldSources;
    addedPart.sources = c.stats().sources.size() - oldSources;
    addedPart.points = addedPoints;
    if (plan.maxChunkPoints > 0) {
        std::map<uint32_t, int64_t> cells;
        for (auto [cell, n] : record.counts) cells[grow.cell(cell)] += n;
        if (added > 0) {
            progress.begin("count", addedPoints);
            auto counts = countStage(c, addedPart, progress);
            if (!counts) return counts.status();
            summary.phaseSeconds.push_back({"count", progress.end()});
            for (auto [cell, n] : *counts) cells[cell] += n;
        }
        for (const Surfel& s : gone) cells[uint32_t(ChunkLayout::cellIndex(s.position, c.rootEdge()))]--;
        for (auto [cell, n] : cells)
            if (n > 0) plan.counts.push_back({cell, uint32_t(std::min<int64_t>(n, UINT32_MAX))});
    }
    ChunkLayout layout = plan.layout(c);
    const ChunkLayout before = record.layout(**old);

    // The chunks to build: those the added or removed points or their halos
    // reach, and those the set did not have (every chunk where the set gains
    // provenance).
    std::set<NodeKey> oldChunks;
    for (const Chunk& ch : before.chunks()) oldChunks.insert(grow.key(ch.key));
    std::vector<bool> touched(layout.chunks().size(), false);
    for (size_t i = 0; i < touched.size(); ++i) touched[i] = addsProvenance || !oldChunks.count(layout.chunks()[i].key);
    std::vector<int> halo;
    auto touch = [&](std::span<const Surfel> points) {
        for (const Surfel& s : points) {
            const int own = layout.chunkOf(s.position);
            if (own >= 0) touched[size_t(own)] = true;
            layout.haloChunksOf(s.position, &halo);
            for (int h : halo) touched[size_t(h)] = true;
        }
    };
    touch(gone);
    // A removed point's cell may be empty now, and so in no chunk: the chunk
    // that held it is rebuilt where the layout keeps it.
    std::map<NodeKey, size_t> chunkIndex;
    for (size_t i = 0; i < layout.chunks().size(); ++i) chunkIndex[layout.chunks()[i].key] = i;
    for (const Surfel& s : gone)
        if (const int was = before.chunkOf(s.position + (c.rootMin() - (*old)->rootMin())); was >= 0)
            if (auto it = chunkIndex.find(grow.key(before.chunks()[size_t(was)].key)); it != chunkIndex.end()) touched[it->second] = true;
    if (added > 0)
        SC_TRY(forEachPartBatch(c, addedPart, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
            touch(batch);
            return Status{};
        }));

    // The set's nodes under the keys of the updated set's root.
    std::vector<NodeRecord> nodes = reader->nodes();
    for (NodeRecord& n : nodes) n.key = grow.key(n.key);
    auto writer = TilesetWriter::update(set, info, nodes);
    if (!writer) return writer.status();
    const WorkFolder work{(*writer)->partialDir() + "/work"};
    std::error_code ec;
    fs::create_directories(work.chunks(0), ec);
    if (ec) return Status::error(work.dir + ": cannot create (" + ec.message() + ")");

    // Their points: the set's leaves that reach a rebuilt chunk or its halo,
    // but the removed inputs' points, and the added points.
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
    // Normals the build estimated are estimated again near the added and
    // removed points, whose neighbourhoods changed (within one chunk-root cell
    // of the finest rebuilt chunk: a normal's 16 neighbours lie far closer);
    // elsewhere a point keeps its normal, and so its node its bytes.
    double nearCell = c.rootEdge();
    for (size_t i = 0; i < touched.size(); ++i)
        if (touched[i]) nearCell = std::min(nearCell, layout.margin(int(i)) / kHaloCells);
    // Cells of that size holding a changed point, and the box they span: the
    // box spares the 27 look-ups for the many decoded points far from the
    // change (they were 16 % of an update's time: bench/BENCHMARKS.md,
    // "Updates in place").
    std::unordered_set<uint64_t> changedCells;
    using Cell = std::array<int64_t, 3>;
    Cell cellsMin{INT64_MAX, INT64_MAX, INT64_MAX}, cellsMax{INT64_MIN, INT64_MIN, INT64_MIN};
    auto cellOf = [&](const Vec3d& p) {
        return Cell{int64_t(std::floor(p.x / nearCell)), int64_t(std::floor(p.y / nearCell)), int64_t(std::floor(p.z / nearCell))};
    };
    auto cellKey = [](const Cell& c) {
        return (uint64_t(c[0]) & 0x1FFFFF) << 42 | (uint64_t(c[1]) & 0x1FFFFF) << 21 | (uint64_t(c[2]) & 0x1FFFFF);
    };
    auto changed = [&](const Vec3d& p) {
        const Cell c = cellOf(p);
        changedCells.insert(cellKey(c));
        for (int a = 0; a < 3; ++a) cellsMin[a] = std::min(cellsMin[a], c[a]), cellsMax[a] = std::max(cellsMax[a], c[a]);
    };
    for (const Surfel& s : gone) changed(s.position);
    if (added > 0)
        SC_TRY(forEachPartBatch(c, addedPart, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
            for (const Surfel& s : batch) changed(s.position);
            return Status{};
        }));
    auto nearChange = [&](const Vec3d& p) {
        const Cell c = cellOf(p);
        for (int a = 0; a < 3; ++a)
            if (c[a] < cellsMin[a] - 1 || c[a] > cellsMax[a] + 1) return false;
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy)
                for (int64_t dz = -1; dz <= 1; ++dz)
                    if (changedCells.count(cellKey({c[0] + dx, c[1] + dy, c[2] + dz}))) return true;
        return false;
    };
    std::vector<bool> estimated;  // per input: its normals were estimated
    for (size_t i = 0; i < oldInputs.size(); ++i) {
        if (estimated.size() <= oldInputs[i]) estimated.resize(oldInputs[i] + 1, false);
        if (!record.stats.sources[i].description.hasNormals) estimated[oldInputs[i]] = true;
    }

    progress.begin("distribute", 0);
    {
        ChunkWriter chunkWriter(layout, work.chunks(0), c.scalars().size());
        for (const NodeRecord& n : reader->nodes()) {
            if (!(n.flags & kFlagInputPoints) || !reaches(n, rebuilt, c.rootMin())) continue;
            auto block = decode(*reader, n);
            if (!block) return block.status();
            std::vector<Surfel> points;
            ScalarTable table = c.emptyTable();
            appendSurfels(c, *reader, n, *block, ruleOf(*block), &points, &table);
            const std::vector<uint32_t> of = inputsOf(*block);
            for (size_t i = 0; i < points.size(); ++i)
                if (of[i] < estimated.size() && estimated[of[i]] && (addsProvenance || nearChange(points[i].position)))
                    points[i].normal = Vec3f{};  // (every chunk built again: every normal, as a fresh build estimates them)
            if (!request.removed.empty()) {
                size_t kept = 0;
                const size_t fields = table.fields();
                for (size_t i = 0; i < points.size(); ++i) {
                    if (std::find(request.removed.begin(), request.removed.end(), of[i]) != request.removed.end()) continue;
                    std::copy_n(table.values.begin() + long(i * fields), fields, table.values.begin() + long(kept * fields));
                    points[kept++] = points[i];
                }
                points.resize(kept);
                table.values.resize(kept * fields);
            }
            SC_TRY(chunkWriter.add(points, table.values));
            progress.advance(points.size());
        }
        if (added > 0)
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
    for (size_t j = 0; j < nodes.size(); ++j) {
        const NodeRecord& n = nodes[j];
        for (auto& [i, out] : kept) {
            const NodeKey& key = layout.chunks()[i].key;
            if (!inside(n.key, key)) continue;
            out.records.push_back(n);
            if (n.key == key && !(key == NodeKey{})) {
                auto block = decode(*reader, reader->nodes()[j]);
                if (!block) return block.status();
                out.root = std::make_unique<BuiltNode>();
                out.root->key = key;
                out.rootScalars = c.emptyTable();
                appendSurfels(c, *reader, reader->nodes()[j], *block, ruleOf(*block), &out.root->surfels, &out.rootScalars);
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
