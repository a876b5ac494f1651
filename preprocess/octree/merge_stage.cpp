// The merge stage (stages.h): the chunks' outputs into the writer, the levels
// above the chunk roots, and the tile set.
#include <map>
#include <set>

#include "built_node.h"
#include "stages.h"
#include "work_files.h"

namespace surfcast {

Status mergeStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                  TilesetWriter& writer, Progress& progress, BuildSummary* summary, std::map<size_t, ChunkOutput>* kept,
                  const KeepNode& keep, const Refinement* refinement) {
    StepTimes steps = {};
    auto count = [&](const NodeRecord& r) {
        const size_t level = r.key.level;
        if (summary->nodesPerLevel.size() <= level) {
            summary->nodesPerLevel.resize(level + 1);
            summary->surfelsPerLevel.resize(level + 1);
        }
        summary->nodesPerLevel[level]++;
        summary->surfelsPerLevel[level] += r.surfelCount;
        summary->surfels += r.surfelCount;
    };

    // The chunks' nodes, and their roots for the levels above.
    std::map<NodeKey, std::unique_ptr<BuiltNode>> retained;
    ScalarTable upperScalars = context.emptyTable();  // rows of retained and the levels above them
    std::set<NodeKey> seen;
    for (size_t i = 0; i < layout.chunks().size(); ++i) {
        const bool isKept = kept && kept->count(i);
        const WorkFolder& from = refinement && !refinement->built.at(i) ? *refinement->standIns : work;
        auto out = isKept ? Result<ChunkOutput>(std::move(kept->at(i))) : readChunkOutput(from.nodes(i), context.emptyTable());
        if (!out) return out.status();
        if (!isKept && out->plan != plan.id)
            return Status::error(from.nodes(i) + ": built for another plan (build chunk " + std::to_string(i) + " again)");
        // Every node lies in its chunk, once.
        const NodeKey& chunkKey = layout.chunks()[i].key;
        for (const NodeRecord& r : out->records) {
            const int below = int(r.key.level) - int(chunkKey.level);
            const bool inside = below >= 0 && below <= kMaxLevel && (r.key.x >> below) == chunkKey.x &&
                                (r.key.y >> below) == chunkKey.y && (r.key.z >> below) == chunkKey.z;
            if (!inside || !seen.insert(r.key).second)
                return Status::error(from.nodes(i) + ": node " + r.key.name() + " is not chunk " + std::to_string(i) + "'s, or repeats");
        }
        if (isKept) {
            SC_TRY(writer.addKeptNodes(out->records));
        } else {
            // Nodes the rule kept (no block) take the set's.
            std::vector<NodeRecord> placed, same;
            for (const NodeRecord& r : out->records)
                if (r.blockSize > 0) placed.push_back(r);
                else if (keep && keep(r)) same.push_back(r);
                else return Status::error(from.nodes(i) + ": node " + r.key.name() + " has no block");
            SC_TRY(writer.addPlacedNodes(from.blocks(i), out->blocksBytes, placed));
            SC_TRY(writer.keepCurrentNodes(same));
        }
        for (const NodeRecord& r : out->records) count(r);
        for (int s = 0; s < kStepCount; ++s) steps[s] += out->stepNs[s];
        summary->textureFit.add(out->fits);
        summary->removedOutliers += out->removedOutliers;
        if (out->root) {
            if (!(out->root->key == layout.chunks()[i].key))
                return Status::error(from.nodes(i) + ": its root is not chunk " + std::to_string(i) + "'s node");
            for (Surfel& s : out->root->surfels) s.row = upperScalars.append(out->rootScalars.row(s.row));
            retained[out->root->key] = std::move(out->root);
        }
    }

    // Level by level up from the deepest chunk root: each node resampled from
    // its children (chunk roots and upper nodes of the level below).
    if (!retained.empty()) {
        int deepest = 0;
        for (auto& [key, node] : retained) deepest = std::max(deepest, int(key.level));
        progress.begin("upper", uint64_t(deepest), "levels");
        std::map<NodeKey, std::unique_ptr<BuiltNode>> below;  // nodes of level L+1 still needed
        for (int level = deepest - 1; level >= 0; --level) {
            for (auto it = retained.begin(); it != retained.end();) {
                if (it->first.level == level + 1) {
                    below[it->first] = std::move(it->second);
                    it = retained.erase(it);
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
            // As in a chunk, nodes the rule keeps get no values and no block:
            // they are neighbours of the others, with the chunk roots.
            std::vector<LevelNode*> members;
            std::vector<BuiltNode*> built, valued;
            std::vector<Surfel> neighbours;  // chunk roots on this level, and the kept nodes
            std::vector<NodeRecord> same;
            for (auto& [key, node] : current) {
                const SampleGrid grid = context.nodeGrid(key, gathered[key]);
                node->cell = grid.cellSize;
                node->surfels = resample(gathered[key], grid, true, &upperScalars);
                node->level.surfels = node->surfels;
                node->level.cell = node->cell;
                built.push_back(node.get());
                if (const NodeRecord r = keptRecord(*node); keep && keep(r)) {
                    same.push_back(r);
                    neighbours.insert(neighbours.end(), node->surfels.begin(), node->surfels.end());
                } else {
                    valued.push_back(node.get());
                    members.push_back(&node->level);
                }
            }
            gathered.clear();
            for (auto& [key, node] : retained)
                if (key.level == level) neighbours.insert(neighbours.end(), node->surfels.begin(), node->surfels.end());
            if (!members.empty())
                computeLevelAttributes(members, neighbours, context.levelParams(level, largestCell(context, level, built), context.threads()));
            summary->textureFit.add(filterLevelTextures(context, valued, neighbours, context.threads(), steps));
            SC_TRY(writer.keepCurrentNodes(same));
            for (const NodeRecord& r : same) count(r);
            for (BuiltNode* node : valued) {
                auto encoded = encodeNode(context, *node, upperScalars, steps);
                if (!encoded) return encoded.status();
                count(encoded->record);
                SC_TRY(writer.addNode(encoded->record, encoded->blob));
            }
            below = std::move(current);
            progress.advance(1);
        }
        summary->phaseSeconds.push_back({"upper", progress.end()});
    }

    progress.begin("write", 0);
    TilesetInfo info = context.tilesetInfo();
    if (refinement) {
        info.previewStride = refinement->stride;
        info.previewDone = refinement->done;
    }
    info.surfels = summary->surfels;
    info.levels = int(summary->nodesPerLevel.size());
    SC_TRY(writer.finish(info));
    summary->phaseSeconds.push_back({"write", progress.end()});
    summary->nodes = info.nodes;
    summary->levels = info.levels;
    summary->hierarchyBytes = info.hierarchyBytes;
    summary->blocksBytes = info.blocksBytes;
    for (int s = 0; s < kStepCount; ++s) summary->stepSeconds.push_back({kStepNames[s], double(steps[s]) * 1e-9});
    return {};
}

}  // namespace surfcast
