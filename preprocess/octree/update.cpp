// An update in place (update.h): the chunk layout of all the inputs, the
// chunks the added points reach rebuilt from the set's own leaves and the new
// points, the others kept as they are, and the levels above the chunks anew.
#include "update.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <unordered_set>

#include "built_node.h"
#include "set_points.h"
#include "crc32.h"
#include "http_tile_source.h"
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
    // A wide field's low part is no attribute of its own: a set that stores
    // the field narrower (one built before fields went wide) takes the range
    // check below.
    auto lowPartOfStored = [&](const std::string& name) {
        return name.ends_with(kLowPartSuffix) && set.attribute(name.substr(0, name.size() - std::strlen(kLowPartSuffix)));
    };
    for (const AttributeInfo& a : all.attributes)
        if (!set.attribute(a.name) && a.name != kProvenanceAttribute && !lowPartOfStored(a.name))
            return refuse("bring attribute '" + a.name + "'");
    auto span = [](const AttributeInfo& a, int bits) { return a.offset + a.scale * (std::ldexp(1.0, bits) - 1); };
    auto typeBits = [](const AttributeInfo& a) { return a.type == "uint8" ? 8 : a.type == "uint16" ? 16 : 32; };
    if (const AttributeInfo* a = set.attribute(kLidarAttributes[kLidarIntensity]); a && added.attributes.intensityPoints > 0) {
        const auto& h = added.attributes.intensityHistogram;
        const auto lo = std::find_if(h.begin(), h.end(), [](uint64_t n) { return n > 0; }) - h.begin();
        const auto hi = h.rend() - std::find_if(h.rbegin(), h.rend(), [](uint64_t n) { return n > 0; }) - 1;
        // As BuildContext::chooseAttributes takes a range: (hi - offset) / step within the code's bits.
        const double top = a->offset + a->scale * std::ldexp(1.0, intensityCodeBits(a->scale)) - 1;
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

// Whether node `n`'s box, less `shift`, meets any of `boxes`.
bool reaches(const TilesetInfo& info, const NodeRecord& n, const std::vector<Box3d>& boxes, const Vec3d& shift) {
    const Vec3d lo = nodeMin(info, n.key) - shift;
    const double e = nodeEdge(info, n.key.level);
    return std::any_of(boxes.begin(), boxes.end(), [&](const Box3d& b) {
        for (int a = 0; a < 3; ++a)
            if (lo[a] > b.max[a] || lo[a] + e < b.min[a]) return false;
        return true;
    });
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

constexpr char kUpdateMagic[9] = "SCUPDT02";

Result<std::string> tilesetText(const std::string& set) {
    std::ifstream in(set + "/tileset.json", std::ios::binary);
    if (!in) return Status::error(set + ": not a tile set (no tileset.json)");
    return std::string{std::istreambuf_iterator<char>(in), {}};
}

// Which version of the set an update was planned on: the CRC-32 of its
// tileset.json, which every update writes anew (it names a new hierarchy).
Result<uint32_t> setVersion(const std::string& set) {
    auto json = tilesetText(set);
    if (!json) return json.status();
    return crc32(json->data(), json->size());
}

// The path of the set's current build record (named by its hierarchy's).
Result<std::string> buildRecordPath(const std::string& set) {
    auto json = tilesetText(set);
    if (!json) return json.status();
    auto info = readTilesetJson(*json, set + "/tileset.json");
    if (!info) return info.status();
    return set + "/" + buildRecordFile(info->hierarchyFile);
}

Result<BuildPlan> readBuildRecord(const std::string& set) {
    auto path = buildRecordPath(set);
    if (!path) return path.status();
    std::vector<std::string> args;
    return readPlan(*path, &args, true);
}

// An update's course: plan (all that precedes the chunks' builds), distribute
// and merge, one after another in one process (updateTileset), or as stages
// with the work folder between them, where resume takes up what plan decided
// (update.bin) from the set as it still is.
class Update {
public:
    // SetLeaves and the decoded blocks refer into the set's reader it holds.
    Update() = default;
    Update(const Update&) = delete;
    Update& operator=(const Update&) = delete;
    Status plan(const BuildOptions& options, const UpdateRequest& request, const std::string& set, const BuildPlan& record,
                Progress& progress, BuildSummary* summary);
    // The rebuilt chunks' points: the set's own near them and the added ones,
    // to work.chunks(0), whose distribution.bin names the plan's id.
    Status distribute(const WorkFolder& work, Progress& progress, BuildSummary* summary);
    Status write(const std::string& path) const;
    Status resume(const BuildOptions& options, BuildPlan plan, const WorkFolder& work);
    // The set's writer, its nodes under the keys of the updated set's root.
    Result<std::unique_ptr<TilesetWriter>> writer() const;
    // The levels above the chunks (the rebuilt ones read from `work`, the kept
    // ones as the set holds them), and the switch.
    Status merge(TilesetWriter& writer, const WorkFolder& work, Progress& progress, BuildSummary* summary) const;
    // The nodes built again that keep the set's (KeepNode); none where every
    // node may have changed.
    KeepNode keepRule() const;

    const BuildContext& context() const { return *context_; }
    const std::shared_ptr<const BuildContext>& sharedContext() const { return context_; }
    const BuildPlan& buildPlan() const { return plan_; }
    BuildPlan& buildPlan() { return plan_; }
    const ChunkLayout& layout() const { return layout_; }
    ChunkLayout& layout() { return layout_; }
    std::vector<size_t> rebuilt() const {
        std::vector<size_t> which;
        for (size_t i = 0; i < touched_.size(); ++i)
            if (touched_[i]) which.push_back(i);
        return which;
    }

private:
    // The set and its context, from its record; the record must be its own.
    // `store`: where the set's blocks are read where `set` is a folder of its
    // metadata only (UpdateRequest::store).
    Status open(const BuildOptions& options, size_t added, const std::string& set, const BuildPlan& record, const std::string& store = {});
    std::vector<uint16_t> rulesOf(const BlockData& block) const;
    // A block of the set as the builder holds it (appendSurfels), its leaves'
    // points on their inputs' lattices where latticeOf gives one.
    void decode(const BuildContext& c, const NodeRecord& n, const BlockData& block, std::vector<Surfel>* out, ScalarTable* table) const {
        std::vector<const Lattice*> lattices;
        if (n.flags & kFlagInputPoints)
            for (uint32_t input : inputsOf(block)) lattices.push_back(latticeOf(n, input));
        appendSurfels(c, *reader_, n, block, rulesOf(block), lattices, out, table);
    }
    // The added points, each batch snapped onto the set's leaves (SetLeaves):
    // every pass over them sees them where the chunks receive them.
    Status forEachAdded(std::span<const ScalarQuantization> stored, const BatchConsumer& consume) {
        return forEachPartBatch(*context_, addedPart_, stored, [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
            if (leaves_) SC_TRY(leaves_->snap(batch));
            return consume(batch, scalars);
        });
    }
    // The lattice that leaf n's points of `input` are taken back to: the
    // input's, where it has one and the leaf's step is below its scale on
    // every axis, so that the lattice point nearest a stored position is the
    // input's own (a leaf whose step is unknown or capped keeps them decoded).
    const Lattice* latticeOf(const NodeRecord& n, uint32_t input) const {
        if (input >= lattices_.size()) return nullptr;
        const Lattice& l = lattices_[input];
        const double step = positionStep(reader_->info(), n);
        return l.scale.x > step && l.scale.y > step && l.scale.z > step ? &l : nullptr;
    }

    BuildOptions opt_;
    UpdateRequest request_;
    std::string set_;
    std::string name_;  // the set as messages name it: its folder, or its store URL
    uint32_t version_ = 0;
    std::optional<TilesetReader> reader_;
    BuildPlan record_;
    std::shared_ptr<const BuildContext> old_;   // the set's, in its layout
    std::shared_ptr<const BuildContext> root_;  // the set's layout in the updated set's root cube
    std::shared_ptr<const BuildContext> context_;  // what the updated set holds, in the set's layout
    std::vector<uint16_t> oldRules_;
    std::vector<uint32_t> oldInputs_;
    std::vector<bool> estimated_;  // per old input: its normals were estimated (a source of it came without)
    Growth grow_;
    bool addsProvenance_ = false;
    InputPart addedPart_;
    // Per input of the set, its lattice where it is a file of one LAS/LAZ
    // source (else scale 0), so that the set's leaf points of it are its very
    // points again (latticeOf), which an added point repeating one meets
    // exactly, as in a fresh build. Added points are snapped onto the set's
    // points that stay decoded (SetLeaves).
    std::vector<Lattice> lattices_;
    std::optional<SetLeaves> leaves_;  // none where every leaf point is taken back
    std::vector<Surfel> gone_;  // the removed points, relative to the root
    BuildPlan plan_;
    ChunkLayout layout_;
    std::vector<bool> touched_;  // per chunk: built again
    // What no change reaches (keepRule): the box of the added and removed
    // points, and how far a node's values look (the widest halo margin of the
    // rebuilt chunks); none where every node may have changed.
    bool keepsFar_ = false;
    Box3d changed_;
    double reach_ = 0;
};

// Whether the box of the node of `key`, widened by the larger of `reach` and
// two node edges of its level, misses `changed` (keepRule).
bool unreached(const BuildContext& c, const Box3d& changed, double reach, const NodeKey& key) {
    if (changed.empty()) return true;
    const double r = std::max(reach, 2 * c.edge(key.level));
    const Vec3d lo = c.nodeMinRel(key) - Vec3d{r, r, r};
    const double e = c.edge(key.level) + 2 * r;
    for (int a = 0; a < 3; ++a)
        if (lo[a] > changed.max[a] || lo[a] + e < changed.min[a]) return true;
    return false;
}

// A node built again keeps the set's node of its key where its box, widened
// by the larger of reach_ and two node edges of its level, misses every
// added and removed point, and its children and surfel count agree: its
// points are the same, and so are the neighbours its values came from. A
// chunk's build looks no further than its halo; a node's weights take its
// neighbouring nodes' h, and d_k of a sparse surfel reaches a few of its
// cells, which two edges of the node hold. (The weights' search grid takes
// its cell from the whole level's h, which a change far away can move; that
// changes which sparse neighbours past a surfel's own reach count, and the
// rule keeps the node anyway.) Built again it would differ by being computed
// from decoded points (bench/BENCHMARKS.md, "Nodes the change cannot reach
// keep their blocks"). So a kept node is neither given values nor encoded
// (KeepNode). The rule holds what it needs (a stage's Update goes before its
// chunks are built); it is off where the root grows, so the set's keys are
// the updated set's.
KeepNode Update::keepRule() const {
    if (!keepsFar_) return {};
    auto current = std::make_shared<std::map<NodeKey, std::pair<uint8_t, uint32_t>>>();
    for (const NodeRecord& n : reader_->nodes()) (*current)[n.key] = {n.childMask, n.surfelCount};
    return [c = context_, changed = changed_, reach = reach_, current](const NodeRecord& built) {
        auto it = current->find(built.key);
        return it != current->end() && it->second == std::pair{built.childMask, built.surfelCount} &&
               unreached(*c, changed, reach, built.key);
    };
}

Status Update::open(const BuildOptions& options, size_t added, const std::string& set, const BuildPlan& record, const std::string& store) {
    opt_ = normalizeOptions(options);
    request_.added = added;
    set_ = set;
    name_ = store.empty() ? set : store;
    record_ = record;
    auto json = tilesetText(set);
    if (!json) return json.status();
    version_ = crc32(json->data(), json->size());
    auto reader = store.empty() ? TilesetReader::open(set) : openTileset(store);
    if (!reader) return reader.status();
    reader_ = std::move(*reader);
    const TilesetInfo& info = reader_->info();
    if (!store.empty()) {
        // The version whose metadata `set` holds, or the update stops.
        auto mirrored = readTilesetJson(*json, set + "/tileset.json");
        if (!mirrored) return mirrored.status();
        if (versionFiles(*mirrored) != versionFiles(info) || mirrored->hierarchyCrc != info.hierarchyCrc)
            return Status::error(store + ": changed while this update read it (another update wrote it); run the update again");
    }
    if (!info.textureFilter.empty())
        return Status::error(name_ + ": built from textured meshes, whose texture fields an update does not rebuild yet; build it anew");
    if (info.weights == "captured")
        return Status::error(name_ + ": its weights were captured by rendering; an update cannot keep them; build it anew");
    // The set's blocks keep their coding, whatever the defaults are now.
    opt_.blockCodec = info.blockCodec;
    opt_.normalBits = info.normalBits(opt_.normalBits);
    BuildOptions setOptions = opt_;
    setOptions.inputs.paths.resize(opt_.inputs.paths.size() - added);
    auto derivedOld = BuildContext::derive(setOptions, record.stats, false);
    if (!derivedOld) return derivedOld.status();
    // Its layout is the set's own (what its blocks were written with), which
    // the record's statistics need not derive again after an update.
    old_ = BuildContext::withLayoutOf(**derivedOld, info);
    root_ = old_;
    const std::string recordName = set + "/" + buildRecordFile(info.hierarchyFile);
    SC_TRY(sameLayout(info, old_->tilesetInfo(), recordName + " (not this set's record)"));
    if ((*derivedOld)->stats().colorBits != info.colorBits || (info.inputs.size() > 1 && (*derivedOld)->inputNames() != info.inputs))
        return Status::error(recordName + ": its inputs are not the set's (not this set's record)");
    oldRules_.assign(old_->sourceIds().begin(), old_->sourceIds().end());
    oldInputs_.assign(old_->inputOfSource().begin(), old_->inputOfSource().end());
    const size_t inputs = oldInputs_.empty() ? 0 : *std::max_element(oldInputs_.begin(), oldInputs_.end()) + 1;
    std::vector<int> sources(inputs, 0);
    lattices_.assign(inputs, Lattice{});
    estimated_.assign(inputs, false);
    for (size_t i = 0; i < oldInputs_.size(); ++i) {
        const InputDescription& d = record.stats.sources[i].description;
        if (!d.hasNormals) estimated_[oldInputs_[i]] = true;
        if (sources[oldInputs_[i]]++ == 0) lattices_[oldInputs_[i]] = {d.latticeScale, d.latticeOffset};
        else lattices_[oldInputs_[i]] = Lattice{};  // (several sources: the default scene)
    }
    return {};
}

// A kept point's orientation rule is its input's (its first scan's: a set
// keeps no scan per point, so an update refuses inputs of several scans).
std::vector<uint16_t> Update::rulesOf(const BlockData& block) const {
    std::vector<uint16_t> rules(block.size(), oldRules_.empty() ? 0 : oldRules_[0]);
    const ScalarAttribute* input = nullptr;
    for (const ScalarAttribute& a : block.scalars)
        if (a.name == kProvenanceAttribute) input = &a;
    if (input)
        for (size_t i = 0; i < rules.size(); ++i)
            for (size_t src = 0; src < oldInputs_.size(); ++src)
                if (oldInputs_[src] == input->values[i]) {
                    rules[i] = oldRules_[src];
                    break;
                }
    return rules;
}

Status Update::plan(const BuildOptions& options, const UpdateRequest& request, const std::string& set, const BuildPlan& record,
                    Progress& progress, BuildSummary* summary) {
    const size_t added = request.added;
    SC_TRY(open(options, added, set, record, request.store));
    request_ = request;
    const BuildOptions& opt = opt_;
    const TilesetInfo& info = reader_->info();
    // A set of one input keeps no provenance: its one input is all of it.
    if (!request.removed.empty() && !info.attribute(kProvenanceAttribute))
        return Status::error(name_ + ": a set of one input, whose points carry no input to remove; build the set anew from the "
                             "inputs it should hold");
    for (uint32_t k : request.removed) {
        uint64_t points = 0;
        for (size_t i = 0; i < oldInputs_.size(); ++i) points += oldInputs_[i] == k ? record.stats.sources[i].points : 0;
        if (points == 0) return Status::error(name_ + ": input " + std::to_string(k) + " has no points in the set (removed before?)");
    }
    for (const SourceStats& src : record.stats.sources)
        if (src.description.scanOrigins.size() > 1)
            return Status::error(name_ + ": " + src.description.path +
                                 " holds several scans, whose points' scans the set does not keep; build it anew");

    // The added inputs: scanned; all of them together must keep the set's
    // layout, in its root cube or in one grown around it.
    TilesetInfo rootInfo = info;
    // A set of one input stores no provenance (docs/FORMAT.md): the first
    // update that makes it one of several builds every chunk again, so that
    // every block gains the attribute (its old blocks stay for readers that
    // opened it, dead bytes until --compact).
    // (The set's points then take provenance 0, its one input's, from the
    // zero-filled last field of appendSurfels' rows.)
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
        summary->phaseSeconds.push_back({"scan", progress.end()});
        addedPoints = scanned->points;
        if (addedPoints == 0) return Status::error("the added inputs hold no valid points");
        for (const SourceStats& src : scanned->sources)
            if (src.description.scanOrigins.size() > 1)
                return Status::error(src.description.path + ": holds several scans, whose points' scans a set does not keep for "
                                     "later updates; build the set anew from all its inputs");
        // The added inputs declare the set's coordinate system, where both
        // declare one (the first of its inputs that does and stays).
        const SourceStats* declared = nullptr;
        for (size_t i = 0; i < record.stats.sources.size() && !declared; ++i) {
            const SourceStats& src = record.stats.sources[i];
            const bool removed = std::find(request.removed.begin(), request.removed.end(), oldInputs_[i]) != request.removed.end();
            if (!src.description.crs.empty() && src.points > 0 && !removed) declared = &src;
        }
        if (declared)
            for (const SourceStats& src : scanned->sources)
                if (!src.description.crs.empty() && crsIdentity(src.description.crs) != crsIdentity(declared->description.crs))
                    return Status::error(src.description.path + ": declares another coordinate system (" + crsName(src.description.crs) +
                                         ") than the set's inputs (" + crsName(declared->description.crs) +
                                         "); reproject it to theirs, or build the set anew from all its inputs");
        const InputStats addedStats = *scanned;
        stats = mergeInputStats({std::move(stats), std::move(*scanned)}, {false, false});
        auto grown = growRoot(info, stats.bounds);
        if (!grown) return grown.status();
        grow_ = *grown;
        if (grow_.levels > 0) {
            root_ = BuildContext::rerooted(*old_, grow_.rootMin, grow_.rootEdge);
            rootInfo.rootMin = grow_.rootMin;
            rootInfo.rootEdge = grow_.rootEdge;
        }
        auto all = BuildContext::derive(opt, stats, true, root_.get());  // what a fresh build of them all stores
        if (!all) return all.status();
        SC_TRY(holds(rootInfo, (*all)->tilesetInfo(), addedStats, set));
        addsProvenance_ = !info.attribute(kProvenanceAttribute) && (*all)->tilesetInfo().attribute(kProvenanceAttribute);
        if (!std::equal(oldRules_.begin(), oldRules_.end(), (*all)->sourceIds().begin()))
            return Status::error(name_ + ": the added inputs change how the set's normals are oriented; build it anew from all its inputs");
    }

    // The removed inputs' points: in the leaves their sources' bounds reach.
    std::vector<Box3d> removedBoxes;
    for (size_t i = 0; i < oldInputs_.size(); ++i)
        if (std::find(request.removed.begin(), request.removed.end(), oldInputs_[i]) != request.removed.end())
            removedBoxes.push_back(record.stats.sources[i].bounds);
    if (!request.removed.empty()) {
        progress.begin("find removed", 0);
        std::vector<NodeRecord> leaves;
        for (const NodeRecord& n : reader_->nodes())
            if ((n.flags & kFlagInputPoints) && reaches(info, n, removedBoxes, Vec3d{})) leaves.push_back(n);
        SC_TRY(reader_->forEachBlock(leaves, true, [&](const NodeRecord& n, BlockData& block) {
            std::vector<Surfel> points;
            decode(*root_, n, block, &points, nullptr);
            const std::vector<uint32_t> of = inputsOf(block);
            for (size_t i = 0; i < points.size(); ++i)
                if (std::find(request.removed.begin(), request.removed.end(), of[i]) != request.removed.end()) gone_.push_back(points[i]);
            progress.advance(points.size());
            return Status{};
        }));
        summary->phaseSeconds.push_back({"find removed", progress.end()});
        removeFromStats(stats, oldInputs_, request.removed, gone_);
    }

    // The context of what the set will hold, in the set's layout.
    auto derived = BuildContext::derive(opt, std::move(stats), false, root_.get(), true);
    if (!derived) return derived.status();
    context_ = *derived;
    const BuildContext& c = *context_;
    c.describe(summary);
    // (Where every leaf point is taken back, no added point is moved: every
    // input with points has a lattice whose scale passes every leaf's step.)
    double largestStep = 0, smallestScale = HUGE_VAL;
    for (const NodeRecord& n : reader_->nodes())
        if (n.flags & kFlagInputPoints) largestStep = std::max(largestStep, positionStep(info, n));
    for (size_t i = 0; i < oldInputs_.size(); ++i)
        if (record.stats.sources[i].points > 0) {
            const Vec3d& scale = lattices_[oldInputs_[i]].scale;
            smallestScale = std::min({smallestScale, scale.x, scale.y, scale.z});
        }
    if (largestStep >= smallestScale)
        leaves_.emplace(*reader_, c.rootMin(), [this](const NodeRecord& n, uint32_t input) { return !latticeOf(n, input); },
                        request.removed);

    // The plan of all the inputs: one part, the counts changed by the points.
    const InputPart all = wholeInputs(opt.inputs, c.stats());
    plan_.stats = c.stats();
    plan_.parts = {all};
    auto most = chunkPoints(c);
    if (!most) return most.status();
    plan_.maxChunkPoints = *most;
    // (Where every chunk is built again, only the chunks' size may change:
    // provenance takes memory per point.)
    if ((plan_.maxChunkPoints == 0) != (record.maxChunkPoints == 0) ||
        (!addsProvenance_ && plan_.maxChunkPoints != record.maxChunkPoints))
        return Status::error(name_ + ": the update changes whether the set's points fit one chunk; build it anew from all its inputs");
    addedPart_.first = all.last - added;
    addedPart_.last = all.last;
    addedPart_.firstSource = oldSources;
    addedPart_.sources = c.stats().sources.size() - oldSources;
    addedPart_.points = addedPoints;
    if (plan_.maxChunkPoints > 0) {
        std::map<uint32_t, int64_t> cells;
        for (auto [cell, n] : record.counts) cells[grow_.cell(cell)] += n;
        if (added > 0) {
            progress.begin("count", addedPoints);
            auto counts = countStage(c, addedPart_, progress, [&](std::span<Surfel> batch) { return leaves_ ? leaves_->snap(batch) : Status{}; });
            if (!counts) return counts.status();
            summary->phaseSeconds.push_back({"count", progress.end()});
            for (auto [cell, n] : *counts) cells[cell] += n;
        }
        for (const Surfel& s : gone_) cells[uint32_t(ChunkLayout::cellIndex(s.position, c.rootEdge()))]--;
        for (auto [cell, n] : cells)
            if (n > 0) plan_.counts.push_back({cell, uint32_t(std::min<int64_t>(n, UINT32_MAX))});
    }
    layout_ = plan_.layout(c);
    const ChunkLayout before = record.layout(*old_);

    // The chunks to build: those the added or removed points or their halos
    // reach, and those the set did not have (every chunk where the set gains
    // provenance).
    std::set<NodeKey> oldChunks;
    for (const Chunk& ch : before.chunks()) oldChunks.insert(grow_.key(ch.key));
    touched_.assign(layout_.chunks().size(), false);
    for (size_t i = 0; i < touched_.size(); ++i) touched_[i] = addsProvenance_ || !oldChunks.count(layout_.chunks()[i].key);
    std::vector<int> halo;
    auto touch = [&](std::span<const Surfel> points) {
        for (const Surfel& s : points) {
            const int own = layout_.chunkOf(s.position);
            if (own >= 0) touched_[size_t(own)] = true;
            layout_.haloChunksOf(s.position, &halo);
            for (int h : halo) touched_[size_t(h)] = true;
        }
    };
    touch(gone_);
    for (const Surfel& s : gone_) changed_.extend(s.position);
    // A removed point's cell may be empty now, and so in no chunk: the chunk
    // that held it is rebuilt where the layout keeps it.
    std::map<NodeKey, size_t> chunkIndex;
    for (size_t i = 0; i < layout_.chunks().size(); ++i) chunkIndex[layout_.chunks()[i].key] = i;
    for (const Surfel& s : gone_)
        if (const int was = before.chunkOf(s.position + (c.rootMin() - old_->rootMin())); was >= 0)
            if (auto it = chunkIndex.find(grow_.key(before.chunks()[size_t(was)].key)); it != chunkIndex.end()) touched_[it->second] = true;
    if (added > 0)
        SC_TRY(forEachAdded({}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
            touch(batch);
            for (const Surfel& s : batch) changed_.extend(s.position);
            return Status{};
        }));
    // Where the set gains provenance every block changes; where the root
    // grows, nodes move to deeper keys (the rule keeps to the simple case).
    keepsFar_ = !addsProvenance_ && grow_.levels == 0;
    for (size_t i = 0; i < touched_.size(); ++i)
        if (touched_[i]) reach_ = std::max(reach_, layout_.margin(int(i)));
    return {};
}

Status Update::distribute(const WorkFolder& work, Progress& progress, BuildSummary* summary) {
    const BuildContext& c = *context_;
    const TilesetInfo& info = reader_->info();
    const size_t added = request_.added;
    const std::vector<uint32_t>& removed = request_.removed;
    // Their points: the set's leaves that reach a rebuilt chunk or its halo,
    // but the removed inputs' points, and the added points.
    std::vector<Box3d> boxes;
    for (size_t i = 0; i < touched_.size(); ++i)
        if (touched_[i]) {
            const Chunk& ch = layout_.chunks()[i];
            const double m = layout_.margin(int(i)), e = c.edge(ch.key.level);
            Box3d b;
            b.min = c.nodeMinRel(ch.key) - Vec3d{m, m, m};
            b.max = c.nodeMinRel(ch.key) + Vec3d{e + m, e + m, e + m};
            boxes.push_back(b);
        }
    // Normals the build estimated are estimated again near the added and
    // removed points, whose neighbourhoods changed (within one chunk-root cell
    // of the finest rebuilt chunk: a normal's 16 neighbours lie far closer);
    // elsewhere a point keeps its normal, and so its node its bytes.
    double nearCell = c.rootEdge();
    for (size_t i = 0; i < touched_.size(); ++i)
        if (touched_[i]) nearCell = std::min(nearCell, layout_.margin(int(i)) / kHaloCells);
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
    auto cellKey = [](const Cell& cell) {
        return (uint64_t(cell[0]) & 0x1FFFFF) << 42 | (uint64_t(cell[1]) & 0x1FFFFF) << 21 | (uint64_t(cell[2]) & 0x1FFFFF);
    };
    auto changed = [&](const Vec3d& p) {
        const Cell cell = cellOf(p);
        changedCells.insert(cellKey(cell));
        for (int a = 0; a < 3; ++a) cellsMin[a] = std::min(cellsMin[a], cell[a]), cellsMax[a] = std::max(cellsMax[a], cell[a]);
    };
    for (const Surfel& s : gone_) changed(s.position);
    std::error_code ec;
    fs::create_directories(work.chunks(0), ec);
    if (ec) return Status::error(work.chunks(0) + ": cannot create (" + ec.message() + ")");
    progress.begin("distribute", 0);
    ChunkWriter chunkWriter(layout_, work.chunks(0), c.scalars().size());
    // The added points first: one pass both finds their cells and writes them.
    if (added > 0)
        SC_TRY(forEachAdded(c.scalars(), [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
            for (const Surfel& s : batch) changed(s.position);
            progress.advance(batch.size());
            return chunkWriter.add(batch, scalars);
        }));
    auto nearChange = [&](const Vec3d& p) {
        const Cell cell = cellOf(p);
        for (int a = 0; a < 3; ++a)
            if (cell[a] < cellsMin[a] - 1 || cell[a] > cellsMax[a] + 1) return false;
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy)
                for (int64_t dz = -1; dz <= 1; ++dz)
                    if (changedCells.count(cellKey({cell[0] + dx, cell[1] + dy, cell[2] + dz}))) return true;
        return false;
    };
    std::vector<NodeRecord> leaves;
    for (const NodeRecord& n : reader_->nodes())
        // (Every chunk built again where the set gains provenance: every leaf.)
        if ((n.flags & kFlagInputPoints) && (addsProvenance_ || reaches(info, n, boxes, c.rootMin()))) leaves.push_back(n);
    // Decoded on the threads, written in the leaves' order.
    struct Decoded {
        std::vector<Surfel> points;
        ScalarTable table;
    };
    std::vector<Decoded> decoded(leaves.size());
    auto prepare = [&](size_t leaf, const NodeRecord& n, BlockData& block) {
        std::vector<Surfel>& points = decoded[leaf].points;
        ScalarTable& table = decoded[leaf].table;
        table = c.emptyTable();
        decode(c, n, block, &points, &table);
        const std::vector<uint32_t> of = inputsOf(block);
        // Points of a leaf the change cannot reach (keepRule's box) are not
        // measured: they stay in it, which the update keeps, and their
        // isolation judges nothing. (A leaf that is built again all the same,
        // its decoded points merging otherwise or its chunk's nodes changed
        // above it, judges them at its level.)
        const bool isolating = c.normals().measure && !(keepsFar_ && unreached(c, changed_, reach_, n.key));
        for (size_t i = 0; i < points.size(); ++i) {
            if (of[i] >= estimated_.size() || !estimated_[of[i]]) continue;
            if (addsProvenance_ || nearChange(points[i].position))
                points[i].normal = Vec3f{};  // (every chunk built again: every normal, as a fresh build estimates them)
            else if (isolating)
                points[i].scanDk = kScanDkToMeasure;  // its normal kept, its isolation judged by its scan as a build's
        }
        if (!removed.empty()) {
            size_t kept = 0;
            const size_t fields = table.fields();
            for (size_t i = 0; i < points.size(); ++i) {
                if (std::find(removed.begin(), removed.end(), of[i]) != removed.end()) continue;
                std::copy_n(table.values.begin() + long(i * fields), fields, table.values.begin() + long(kept * fields));
                points[kept++] = points[i];
            }
            points.resize(kept);
            table.values.resize(kept * fields);
        }
        return Status{};
    };
    SC_TRY(reader_->forEachBlockInOrder(leaves, true, c.threads(), prepare, [&](size_t leaf) {
        Decoded d = std::move(decoded[leaf]);
        progress.advance(d.points.size());
        return chunkWriter.add(d.points, d.table.values);
    }));
    SC_TRY(chunkWriter.finish());
    summary->phaseSeconds.push_back({"distribute", progress.end()});
    for (Chunk& ch : layout_.chunks()) {
        ch.points = ch.written.points;
        ch.haloPoints = ch.written.haloPoints;
        ch.pieces = {ch.written};
    }
    summary->chunks = boxes.size();
    return writeDistribution(work.distribution(0), plan_, layout_);
}

// update.bin: the plan's id, the set's version, the added inputs' count, the
// growth of the root (levels and the old root's offset: the new root follows
// from the set), the chunks built again, and what keepRule needs (whether
// it applies, the changed points' box, the reach); the rest a stage derives
// again from the plan and the set.
Status Update::write(const std::string& path) const {
    ByteWriter w;
    w.put(plan_.id);
    w.put(version_);
    w.put(uint64_t(request_.added));
    w.put(uint32_t(grow_.levels));
    for (int a = 0; a < 3; ++a) w.put(grow_.offset[a]);
    const std::vector<size_t> which = rebuilt();
    w.put(uint64_t(which.size()));
    for (size_t i : which) w.put(uint64_t(i));
    w.put(uint8_t(keepsFar_));
    for (int a = 0; a < 3; ++a) w.put(changed_.min[a]), w.put(changed_.max[a]);
    w.put(reach_);
    return writeWorkFile(path, kUpdateMagic, w);
}

Status Update::resume(const BuildOptions& options, BuildPlan plan, const WorkFolder& work) {
    const std::string path = work.update();
    auto bytes = readWorkFile(path, kUpdateMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    const Status corrupt = Status::error(path + ": malformed update record");
    if (r.get<uint32_t>() != plan.id) return Status::error(path + ": written for another plan (plan the update again)");
    const uint32_t version = r.get<uint32_t>();
    const uint64_t added = r.get<uint64_t>();
    const uint32_t levels = r.get<uint32_t>();
    for (int a = 0; a < 3; ++a) grow_.offset[a] = r.get<uint32_t>();
    const uint64_t count = r.getCount(8);
    std::vector<uint64_t> which(count);
    for (uint64_t& i : which) i = r.get<uint64_t>();
    keepsFar_ = r.get<uint8_t>() != 0;
    for (int a = 0; a < 3; ++a) changed_.min[a] = r.get<double>(), changed_.max[a] = r.get<double>();
    reach_ = r.get<double>();
    if (!(reach_ >= 0 && reach_ < HUGE_VAL)) return corrupt;
    if (!r.ok() || r.left() != 0 || added > options.inputs.paths.size() || levels > uint32_t(kMaxLevel)) return corrupt;
    grow_.levels = int(levels);
    for (int a = 0; a < 3; ++a)
        if (grow_.offset[a] > (uint32_t(1) << levels) - 1) return corrupt;

    // The set must be the version planned on (checked before it is read).
    const std::string set = options.output;
    auto now = setVersion(set);
    if (!now) return now.status();
    if (*now != version)
        return Status::error(set + ": changed since this update was planned in " + work.dir +
                             " (another update or compaction ran); remove " + work.dir + " and run the update again");
    auto record = readBuildRecord(set);
    if (!record) return record.status();
    SC_TRY(open(options, size_t(added), set, *record));
    if (version_ != version) return Status::error(set + ": changed while this update read it; run the update again");
    // The grown root, as growRoot makes it from the set's.
    const TilesetInfo& info = reader_->info();
    grow_.rootEdge = std::ldexp(info.rootEdge, grow_.levels);
    for (int a = 0; a < 3; ++a) grow_.rootMin[a] = info.rootMin[a] - double(grow_.offset[a]) * info.rootEdge;
    if (grow_.levels > 0) root_ = BuildContext::rerooted(*old_, grow_.rootMin, grow_.rootEdge);
    auto derived = BuildContext::derive(opt_, plan.stats, false, root_.get(), true);
    if (!derived) return derived.status();
    context_ = *derived;
    plan_ = std::move(plan);
    layout_ = plan_.layout(*context_);
    touched_.assign(layout_.chunks().size(), false);
    for (uint64_t i : which) {
        if (i >= touched_.size()) return corrupt;
        touched_[i] = true;
    }
    return {};
}

Result<std::unique_ptr<TilesetWriter>> Update::writer() const {
    std::vector<NodeRecord> nodes = reader_->nodes();
    for (NodeRecord& n : nodes) n.key = grow_.key(n.key);
    return TilesetWriter::update(set_, reader_->info(), nodes,
                                 [this](const std::vector<NodeRecord>& n) { return reader_->readBlocksBytes(n); });
}

Status Update::merge(TilesetWriter& writer, const WorkFolder& work, Progress& progress, BuildSummary* summary) const {
    const BuildContext& c = *context_;
    // The kept chunks: their nodes as the set holds them, their roots decoded
    // for the levels above.
    std::map<size_t, ChunkOutput> kept;
    for (size_t i = 0; i < layout_.chunks().size(); ++i)
        if (!touched_[i]) kept[i].plan = plan_.id;
    const std::vector<NodeRecord>& nodes = reader_->nodes();
    std::vector<NodeRecord> roots;
    std::vector<ChunkOutput*> rootOf;
    for (const NodeRecord& n : nodes) {
        const NodeKey key = grow_.key(n.key);
        for (auto& [i, out] : kept) {
            const NodeKey& chunk = layout_.chunks()[i].key;
            if (!inside(key, chunk)) continue;
            NodeRecord moved = n;
            moved.key = key;
            out.records.push_back(moved);
            if (key == chunk && !(chunk == NodeKey{})) {
                roots.push_back(n);
                rootOf.push_back(&out);
            }
            break;
        }
    }
    auto decodeRoot = [&](size_t i, const NodeRecord& n, BlockData& block) {
        ChunkOutput& out = *rootOf[i];
        out.root = std::make_unique<BuiltNode>();
        out.root->key = grow_.key(n.key);
        out.rootScalars = c.emptyTable();
        decode(c, n, block, &out.root->surfels, &out.rootScalars);
        return Status{};
    };
    SC_TRY(reader_->forEachBlockInOrder(roots, true, c.threads(), decodeRoot, [](size_t) { return Status{}; }));
    return mergeStage(c, plan_, layout_, work, writer, progress, summary, &kept, keepRule());
}

}  // namespace

Result<BuildSummary> updateTileset(const BuildOptions& options, const UpdateRequest& request, const std::string& set,
                                   const BuildPlan& record, const std::vector<std::string>& commandLine) {
    const auto start = std::chrono::steady_clock::now();
    Progress progress(options.progress);
    BuildSummary summary;
    Update update;
    SC_TRY(update.plan(options, request, set, record, progress, &summary));
    auto writer = update.writer();
    if (!writer) return writer.status();
    const WorkFolder work{(*writer)->partialDir() + "/work"};
    SC_TRY(update.distribute(work, progress, &summary));
    const BuildContext& c = update.context();
    uint64_t buildPoints = 0;
    for (size_t i : update.rebuilt()) buildPoints += update.layout().chunks()[i].points;
    progress.begin("build", buildPoints);
    SC_TRY(buildChunks(c, update.buildPlan(), update.layout(), update.rebuilt(), work, progress, update.keepRule()));
    summary.phaseSeconds.push_back({"build", progress.end()});
    SC_TRY(keepBuildRecord(**writer, (*writer)->partialDir(), update.buildPlan(), commandLine));
    SC_TRY(update.merge(**writer, work, progress, &summary));
    summary.inputPoints = c.stats().points;
    summary.skippedPoints = c.stats().skipped;
    summary.totalSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    summary.peakRss = peakRssBytes();
    return summary;
}

Result<StagedUpdate> updatePlanStage(const BuildOptions& options, const UpdateRequest& request, const std::string& set,
                                     const BuildPlan& record, const std::vector<std::string>& commandLine, const WorkFolder& work) {
    Progress progress(options.progress);
    BuildSummary summary;
    Update update;
    SC_TRY(update.plan(options, request, set, record, progress, &summary));
    // A new plan: what an earlier one wrote goes. update.bin comes before
    // plan.bin, so that no stage takes the folder for a build's; plan.json,
    // what a driver schedules by, comes last (the caller writes it).
    std::error_code ec;
    for (const std::string& file : {work.dir + "/plan.json", work.update(), work.plan()}) fs::remove(file, ec);
    for (const char* folder : {"chunks", "nodes"}) fs::remove_all(work.dir + "/" + folder, ec);
    update.buildPlan().id = planId(update.buildPlan(), commandLine);  // the id the chunk files name
    SC_TRY(update.write(work.update()));
    SC_TRY(writePlan(work.plan(), update.buildPlan(), commandLine));
    SC_TRY(update.distribute(work, progress, &summary));
    StagedUpdate staged{update.buildPlan(), update.layout(), {}, update.rebuilt()};
    for (const Chunk& ch : update.layout().chunks()) staged.chunkPoints.push_back(ch.points);
    return staged;
}

Result<bool> updateApplied(const BuildOptions& options, const WorkFolder& work) {
    auto record = buildRecordPath(options.output);
    if (!record) return record.status();
    std::ifstream a(*record, std::ios::binary), b(work.plan(), std::ios::binary);
    if (!a || !b) return false;
    return std::string{std::istreambuf_iterator<char>(a), {}} == std::string{std::istreambuf_iterator<char>(b), {}};
}

Result<std::shared_ptr<const BuildContext>> updateContext(const BuildOptions& options, const BuildPlan& plan, const WorkFolder& work,
                                                          std::vector<size_t>* build, KeepNode* keep) {
    Update update;
    SC_TRY(update.resume(options, plan, work));
    *build = update.rebuilt();
    *keep = update.keepRule();
    return update.sharedContext();
}

Result<BuildSummary> updateMergeStage(const BuildOptions& options, const BuildPlan& plan, const std::vector<std::string>& commandLine,
                                      const WorkFolder& work) {
    Progress progress(options.progress);
    BuildSummary summary;
    Update update;
    SC_TRY(update.resume(options, plan, work));
    update.context().describe(&summary);
    SC_TRY(readDistribution(work, update.buildPlan(), update.layout()));
    summary.chunks = update.rebuilt().size();
    auto writer = update.writer();
    if (!writer) return writer.status();
    // The set keeps the plan as its build record (update.h): plan.bin's bytes.
    SC_TRY(keepBuildRecord(**writer, (*writer)->partialDir(), update.buildPlan(), commandLine));
    SC_TRY(update.merge(**writer, work, progress, &summary));
    summary.inputPoints = update.context().stats().points;
    summary.skippedPoints = update.context().stats().skipped;
    summary.peakRss = peakRssBytes();
    return summary;
}

}  // namespace surfcast
