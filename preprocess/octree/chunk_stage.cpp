// The chunk stage (stages.h): one chunk's subtree, from its point and halo
// files to its blocks, records and root in the work folder.
#include <algorithm>
#include <cerrno>
#include <cstring>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <unistd.h>

#include "built_node.h"
#include "crc32.h"
#include "stages.h"
#include "work_files.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

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

// Statistical outlier removal (BuildOptions::removeOutliers): removes the
// read points whose d_k (Surfel::scanDk) exceeds the mean over the chunk's
// measured read points by `sigmas` standard deviations, and twice the mean,
// with their entries of `flags`. (On a surface sampled evenly, a border
// point's k neighbours fill a half disc, a corner's a quarter: its d_k is √2
// and 2 times an inner point's. On a clean one the deviation is near 0, and
// without the second bound its borders would go.) A set's points an update
// decoded (Surfel::fromSet) are not judged again. Returns how many it removed.
uint64_t removeOutliers(std::vector<Surfel>& points, std::vector<uint8_t>& flags, double sigmas) {
    double sum = 0, sum2 = 0;
    size_t n = 0;
    for (const Surfel& s : points)
        if (!s.fromSet && s.scanDk >= 0) sum += s.scanDk, sum2 += double(s.scanDk) * s.scanDk, ++n;
    if (n < 2) return 0;
    const double mean = sum / double(n), sd = std::sqrt(std::max(0.0, sum2 / double(n) - mean * mean));
    const double limit = std::max(mean + sigmas * sd, 2 * mean);
    size_t kept = 0;
    for (size_t i = 0; i < points.size(); ++i) {
        if (!points[i].fromSet && points[i].scanDk > limit) continue;
        points[kept] = points[i], flags[kept] = flags[i], ++kept;
    }
    const uint64_t removed = points.size() - kept;
    points.resize(kept), flags.resize(kept);
    return removed;
}

BuiltNode* buildSubtree(const BuildContext& ctx, std::vector<Surfel>& pts, size_t b, size_t e, const NodeKey& key,
                        std::vector<std::unique_ptr<BuiltNode>>& nodes, ScalarTable& scalars) {
    auto node = std::make_unique<BuiltNode>();
    node->key = key;
    auto first = pts.begin() + long(b), last = pts.begin() + long(e);
    bool identical = std::all_of(first, last, [&](const Surfel& s) { return s.position == first->position; });
    if (e - b <= ctx.options().capacity || key.level >= kMaxLevel || identical) {
        // Leaf: the input points themselves, exact duplicates merged unless the set keeps them.
        node->inputPoints = true;
        node->surfels.assign(first, last);
        auto& v = node->surfels;
        // Of exact duplicates, the one kept has the lowest class, then stored
        // intensity, returns, stored colour and scalar fields in order
        // (docs/FORMAT.md): the same whatever the input order, and the same
        // for an update's decoded set points as for their raw values, so that
        // of a set's point and its repeat the lower input stays.
        const size_t fields = scalars.fields();
        const bool colors8 = ctx.stats().colorBits == 8;
        auto stored = [&](const Surfel& s) {
            const auto color = [&](int k) { return colors8 ? s.color[k] >> 8 : s.color[k]; };
            return std::make_tuple(s.classification, ctx.storedIntensity(s.intensity), s.returns, color(0), color(1), color(2));
        };
        std::sort(v.begin(), v.end(), [&](const Surfel& a, const Surfel& c) {
            // By position; exact duplicates by their stored values.
            for (int axis = 0; axis < 3; ++axis)
                if (a.position[axis] != c.position[axis]) return a.position[axis] < c.position[axis];
            const auto ka = stored(a), kc = stored(c);
            if (ka != kc) return ka < kc;
            if (fields > 0 && !std::equal(scalars.row(a.row), scalars.row(a.row) + fields, scalars.row(c.row)))
                return std::lexicographical_compare(scalars.row(a.row), scalars.row(a.row) + fields, scalars.row(c.row),
                                                    scalars.row(c.row) + fields);
            // A set that keeps every point keeps those two as well: by what
            // else they carry, so that their order is the input's in no case.
            if (!ctx.keepsDuplicates()) return false;
            return std::make_tuple(a.normal.x, a.normal.y, a.normal.z, a.alpha, a.source) <
                   std::make_tuple(c.normal.x, c.normal.y, c.normal.z, c.alpha, c.source);
        });
        // (A point of an update's set that took an added one in stands for a
        // set point still: another set point at its position stays apart.)
        // A set that keeps every point merges none (sorted all the same: the
        // same bytes whatever the input order).
        size_t out = ctx.keepsDuplicates() ? v.size() : 0;
        for (size_t i = out; i < v.size(); ++i) {
            Surfel& kept = v[out - (out > 0)];
            if (out > 0 && kept.position == v[i].position && !(kept.fromSet && v[i].fromSet)) {
                kept.count += v[i].count;
                kept.fromSet = kept.fromSet || v[i].fromSet;
            } else {
                v[out++] = v[i];
            }
        }
        v.resize(out);
    } else {
        // Partition the range into the 8 children (child index bits: x, y, z).
        Vec3d mid = ctx.nodeMinRel(key) + Vec3d{1, 1, 1} * (ctx.edge(key.level) * 0.5);
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
        for (int i = 0; i < 8; ++i) {
            if (bounds[i] == bounds[i + 1]) continue;
            BuiltNode* child = buildSubtree(ctx, pts, bounds[i], bounds[i + 1], key.child(i), nodes, scalars);
            node->childMask |= uint8_t(1u << i);
            gathered.insert(gathered.end(), child->surfels.begin(), child->surfels.end());
        }
        const SampleGrid grid = ctx.nodeGrid(key, gathered);
        node->cell = grid.cellSize;
        node->surfels = resample(gathered, grid, true, &scalars);
    }
    nodes.push_back(std::move(node));
    return nodes.back().get();
}

std::vector<Surfel> resampleHalo(const BuildContext& ctx, const std::vector<Surfel>& halo, const Chunk& chunk, double margin, int level,
                                 std::span<BuiltNode* const> members) {
    // Each halo point stands in for a neighbouring chunk's surfels near the
    // level's node that holds the point clamped into the chunk, and is
    // resampled on that node's cell (the level's G³ cell where that node is a
    // leaf, absent or not coarsened).
    const double e = ctx.edge(level), base = e / ctx.options().grid;
    const Vec3d chunkLo = ctx.nodeMinRel(chunk.key);
    const double chunkEdge = ctx.edge(chunk.key.level);
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

// A chunk's blocks file, appended to as its nodes are encoded beside its
// path and renamed into place when closed: two processes building the same
// chunk (a task retried while the first still runs) each write their own, and
// either's is the same bytes.
class BlockFile {
public:
    explicit BlockFile(std::string path)
        : path_(std::move(path)), partial_(partialName(path_)),
          file_(std::fopen(partial_.c_str(), "wb")) {}
    ~BlockFile() {
        if (file_) std::fclose(file_);
        std::error_code ec;
        fs::remove(partial_, ec);
    }
    Status add(EncodedNode node, std::vector<NodeRecord>* records) {
        if (!file_) return Status::error(partial_ + ": cannot create (" + std::strerror(errno) + ")");
        if (std::fwrite(node.blob.data(), 1, node.blob.size(), file_) != node.blob.size())
            return Status::error(path_ + ": write failed (disk full?)");
        node.record.blockOffset = bytes_;
        node.record.blockSize = uint32_t(node.blob.size());
        node.record.blockCrc = crc32(node.blob.data(), node.blob.size());
        bytes_ += node.blob.size();
        records->push_back(node.record);
        return {};
    }
    Status close() {
        bool ok = file_ && std::fflush(file_) == 0 && ::fsync(::fileno(file_)) == 0;
        ok = file_ && std::fclose(file_) == 0 && ok;
        file_ = nullptr;
        std::error_code ec;
        if (ok) fs::rename(partial_, path_, ec);
        return ok && !ec ? Status{} : Status::error(path_ + ": write failed (disk full?)");
    }
    uint64_t bytes() const { return bytes_; }

private:
    std::string path_, partial_;
    std::FILE* file_;
    uint64_t bytes_ = 0;
};

}  // namespace

Status chunkStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, size_t index, const WorkFolder& work,
                  int threads, bool removeInputs, const KeepNode& keep) {
    const Chunk& chunk = layout.chunks().at(index);
    StepTimes steps = {};
    FitReport fits;
    // Every part's points in part order: a build's in the inputs' order, an
    // update's added points before the set's. (Each file's size is checked
    // against its count before anything is allocated.)
    std::vector<Surfel> points, halo;
    ScalarTable scalars = context.emptyTable();
    for (const ChunkPiece& piece : chunk.pieces) {
        if (piece.points > UINT32_MAX) return Status::error(piece.file + ": more points than a chunk can hold");
        SC_TRY(appendChunkFile(piece.file, piece.points, &points));
        SC_TRY(appendChunkFile(piece.haloFile, piece.haloPoints, &halo));
        if (!context.scalars().empty())
            SC_TRY(appendChunkScalars(piece.scalarFile, piece.points * context.scalars().size(), &scalars.values));
    }
    for (size_t i = 0; i < points.size(); ++i) points[i].row = uint32_t(i);
    std::error_code ec;
    if (removeInputs)
        for (const ChunkPiece& piece : chunk.pieces) {
            fs::remove(piece.file, ec);
            fs::remove(piece.haloFile, ec);
            fs::remove(piece.scalarFile, ec);
        }
    // A chunk built again (a staged build's retried task) is not done until
    // its new records are in place.
    fs::remove(work.nodes(index), ec);
    fs::create_directories(fs::path(work.nodes(index)).parent_path(), ec);
    BlockFile blocks(work.blocks(index));
    std::vector<NodeRecord> records;
    std::unique_ptr<BuiltNode> retained;  // the chunk root, for the levels above (none for the root chunk)

    uint64_t removedOutliers = 0;
    if (!points.empty()) {
        const double margin = layout.margin(int(index));
        NormalContext normals = context.normals();
        normals.threads = threads;
        {
            ScopedTimer t(steps[kStepNormals]);
            const Vec3d lo = context.nodeMinRel(chunk.key) - Vec3d{margin, margin, margin};
            sortMorton(points, lo, context.edge(chunk.key.level) + 2 * margin);
            sortMorton(halo, lo, context.edge(chunk.key.level) + 2 * margin);
            // Outlier removal judges every read point by its d_k: those whose
            // normals came with them (flagged) are measured for it alone, and
            // forget it after, as isolation judges them at their level; where
            // isolation is off, every point forgets it.
            const double sigmas = context.options().removeOutliers;
            std::vector<uint8_t> judgedOnly;
            if (sigmas > 0) {
                normals.measure = true;
                judgedOnly.resize(points.size());
                for (size_t i = 0; i < points.size(); ++i)
                    if (!points[i].fromSet && points[i].normal != Vec3f{} && points[i].scanDk == -1)
                        points[i].scanDk = kScanDkToMeasure, judgedOnly[i] = 1;
            }
            estimateNormals(points, halo, normals);
            if (sigmas > 0) {
                removedOutliers = removeOutliers(points, judgedOnly, sigmas);
                const bool keepsMeasure = context.normals().measure;
                for (size_t i = 0; i < points.size(); ++i)
                    if (judgedOnly[i] || !keepsMeasure) points[i].scanDk = -1, points[i].scanSpread = 0;
            }
        }
        std::vector<std::unique_ptr<BuiltNode>> nodes;
        BuiltNode* root = nullptr;
        {
            ScopedTimer t(steps[kStepOctree]);
            root = buildSubtree(context, points, 0, points.size(), chunk.key, nodes, scalars);
            std::vector<Surfel>().swap(points);
        }

        // Nodes an update keeps (KeepNode) get no values and no block: at
        // their level they are neighbours of the others as the halo is.
        std::set<const BuiltNode*> kept;
        if (keep)
            for (auto& n : nodes)
                if (keep(keptRecord(*n))) kept.insert(n.get());
        // Per level: h, radii and weights, with the halo resampled on the level's grid.
        std::map<int, std::vector<BuiltNode*>> levels;
        for (auto& n : nodes) {
            n->level.surfels = n->surfels;
            n->level.cell = n->cell;
            levels[n->key.level].push_back(n.get());
        }
        for (auto& [level, built] : levels) {
            std::vector<BuiltNode*> valued;
            std::vector<LevelNode*> members;
            for (BuiltNode* n : built)
                if (!kept.count(n)) valued.push_back(n), members.push_back(&n->level);
            if (valued.empty()) continue;
            std::vector<Surfel> haloLevel;
            {
                ScopedTimer t(steps[kStepAttributes]);
                haloLevel = resampleHalo(context, halo, chunk, margin, level, built);
                for (BuiltNode* n : built)
                    if (kept.count(n)) haloLevel.insert(haloLevel.end(), n->surfels.begin(), n->surfels.end());
                computeLevelAttributes(members, haloLevel, context.levelParams(level, largestCell(context, level, built), threads));
            }
            fits.add(filterLevelTextures(context, valued, haloLevel, threads, steps));
        }
        for (auto& n : nodes) {
            if (kept.count(n.get())) {
                records.push_back(keptRecord(*n));
            } else {
                auto encoded = encodeNode(context, *n, scalars, steps);
                if (!encoded) return encoded.status();
                SC_TRY(blocks.add(std::move(*encoded), &records));
            }
            if (n.get() == root && !(chunk.key == NodeKey{})) retained = std::move(n);
        }
    }
    SC_TRY(blocks.close());

    ChunkOutput out;
    out.plan = plan.id;
    out.records = std::move(records);
    out.blocksBytes = blocks.bytes();
    for (int i = 0; i < kStepCount; ++i) out.stepNs[i] = steps[i];
    out.fits = fits;
    out.removedOutliers = removedOutliers;
    if (retained) {
        // Rows renumbered in surfel order, each with its scalar values.
        out.root = std::move(retained);
        out.rootScalars = context.emptyTable();
        for (size_t i = 0; i < out.root->surfels.size(); ++i) {
            Surfel& s = out.root->surfels[i];
            out.rootScalars.append(scalars.row(s.row));
            s.row = uint32_t(i);
        }
    }
    return writeChunkOutput(work.nodes(index), out);
}

}  // namespace surfcast
