// The build as four stages with files between them in a work folder, so that
// each can run as its own process on any machine that sees the inputs and the
// folder (docs/ARCHITECTURE.md, "Stages"):
//
//   plan        scan the inputs (bounds, counts, attributes), count points on
//               the counting grid and cut the chunk layout      → plan.bin
//   distribute  every point to its chunk's file, and to the halos of the
//               chunks whose margin holds it                    → chunks/
//   chunk I     chunk I's subtree: normals, the octree, h, cones, weights,
//               textures, Draco blocks                          → nodes/I.*
//   merge       the levels above the chunks, then the tile set  → the output
//
// buildTileset (octree_builder.h) runs the same stages in one process, so a
// build staged across processes writes the same bytes. The work folder's
// files are internal: each names its format and version, and a stage checks
// what it reads (sizes, counts, a CRC over each chunk's output) and names the
// file where it fails.
#pragma once

#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "build_context.h"
#include "chunker.h"
#include "progress.h"
#include "tileset_writer.h"

namespace surfcast {

struct WorkFolder {
    std::string dir;

    std::string plan() const { return dir + "/plan.bin"; }
    std::string chunks() const { return dir + "/chunks"; }          // the distribute stage's output
    std::string distribution() const { return dir + "/chunks/distribution.bin"; }
    std::string nodes(size_t chunk) const { return dir + "/nodes/" + std::to_string(chunk) + ".nodes"; }
    std::string blocks(size_t chunk) const { return dir + "/nodes/" + std::to_string(chunk) + ".blocks"; }
};

// What the plan stage learns: with the options, all that the later stages need.
struct BuildPlan {
    InputStats stats;
    uint64_t maxChunkPoints = 0;  // 0: every point in one chunk
    // Counting-grid cells (ChunkLayout::cellIndex) that hold points, by index.
    std::vector<std::pair<uint32_t, uint32_t>> counts;

    ChunkLayout layout(const BuildContext& context) const;
};

// Plan: the scan and the count. `context` receives the decisions derived
// from the scan; `summary` the phases' times.
Result<BuildPlan> planStage(const BuildOptions& options, Progress& progress, std::shared_ptr<const BuildContext>* context,
                            BuildSummary* summary);
// plan.bin: the plan and `args`, the command line that made it (the staged
// CLI's later stages read their options from it).
Status writePlan(const std::string& path, const BuildPlan& plan, std::span<const std::string> args);
Result<BuildPlan> readPlan(const std::string& path, std::vector<std::string>* args);

// Distribute: writes the chunk files and distribution.bin (each chunk's point
// and halo counts), and fills them into `layout`.
Status distributeStage(const BuildContext& context, ChunkLayout& layout, const WorkFolder& work, Progress& progress,
                       BuildSummary* summary);
// The chunk files' names and counts, from distribution.bin.
Status readDistribution(const WorkFolder& work, ChunkLayout& layout);

// Chunk: builds chunk `index` of `layout` on `threads` threads and writes its
// nodes' blocks and records, and its root (the merge's input), to
// work.blocks(index) and work.nodes(index); the .nodes file, written last and
// renamed into place, marks the chunk done. `removeInputs`: delete the
// chunk's files once read (a build in one process; a staged build keeps them,
// so that a chunk task can run again).
Status chunkStage(const BuildContext& context, const ChunkLayout& layout, size_t index, const WorkFolder& work, int threads,
                  bool removeInputs);

// Merge: reads every chunk's output (checking each block's CRC as it copies
// it), builds the levels above the chunks and finishes `writer`. Fills the
// summary's counts, steps, texture fit and phases "upper" and "write".
Status mergeStage(const BuildContext& context, const ChunkLayout& layout, const WorkFolder& work, TilesetWriter& writer,
                  Progress& progress, BuildSummary* summary);

}  // namespace surfcast
