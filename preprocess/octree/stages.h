// The build as stages with files between them in a work folder, so that each
// can run as its own process on any machine that sees the inputs and the
// folder (docs/ARCHITECTURE.md, "Stages"):
//
//   scan P/N    part P of the inputs: bounds, counts, attributes → scan/P.bin
//   count P/N   part P's points on the counting grid             → count/P.bin
//   plan        the parts reduced, the chunk layout cut           → plan.bin
//   distribute P  part P's points to its chunk files, and to the halos of
//               the chunks whose margin holds them                → chunks/P/
//   chunk I     chunk I's subtree: normals, the octree, h, cones, weights,
//               textures, Draco blocks                            → nodes/I.*
//   merge       the levels above the chunks, then the tile set    → the output
//
// and, for viewers while it builds (refine.h): preview, a sample's set at the
// output before the scan; distribute --stand-ins N, every Nth point aside;
// refine, a version of the chunks built so far and the others' stand-ins.
//
// Parts are runs of the inputs' records of about equal bytes (inputPart), so
// the scan, count and distribute passes run in parallel over inputs, and over
// one big LAS or LAZ file; a chunk reads the parts' files in part order, which
// is input and record order. buildTileset
// (octree_builder.h) runs the same stages in one process, in the parts of
// readParts on threads, so a build writes the same bytes whatever its parts. The
// work folder's files are internal: each names its format and version (a new
// layout takes a new magic), the job or plan that made it, and a stage checks
// what it reads (sizes, counts, a CRC over each file, the job or plan) and
// names the file where it fails.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "build_context.h"
#include "work_files.h"
#include "chunker.h"
#include "progress.h"
#include "tileset_writer.h"

namespace surfcast {

struct WorkFolder {
    std::string dir;

    std::string scan(size_t part) const { return dir + "/scan/" + std::to_string(part) + ".bin"; }
    std::string count(size_t part) const { return dir + "/count/" + std::to_string(part) + ".bin"; }
    std::string plan() const { return dir + "/plan.bin"; }
    std::string chunks() const { return dir + "/chunks"; }  // the distribute stage's output, a folder per part
    std::string chunks(size_t part) const { return chunks() + "/" + std::to_string(part); }
    std::string distribution(size_t part) const { return chunks(part) + "/distribution.bin"; }
    std::string nodes(size_t chunk) const { return dir + "/nodes/" + std::to_string(chunk) + ".nodes"; }
    std::string blocks(size_t chunk) const { return dir + "/nodes/" + std::to_string(chunk) + ".blocks"; }
    std::string update() const { return dir + "/update.bin"; }  // a staged update's own record (update.h)
    // Refinement while building (refine.h): a part's stand-ins' chunk files
    // beside its own (in `partFolder`, chunks(part)), and the stand-ins'
    // chunks' outputs under the work folder.
    static std::string standIns(const std::string& partFolder) { return partFolder + "/stand-ins"; }
    WorkFolder standIns() const { return {dir + "/stand-ins"}; }
};

// A run of consecutive inputs' records, from record `begin` of input `first`
// up to record `end` of input `last`, not included (`end` 0: up to input
// `last`, which it does not read). Inputs are the built-in scene (index 0,
// where given), then the paths in order. A LAS or LAZ file with a part
// boundary inside it is read in parts, cut at its cuts (las_reader.h);
// every other input, the scene included, is read whole by one part.
// `sources`: the part's readers (the scene has several), from `firstSource`
// on in InputStats::sources, where a part that starts within a file (begin
// > 0) and reads any of it shares that file's one source with the last part
// before it that read some; `points`: the points it reads.
struct InputPart {
    size_t first = 0, last = 0;
    uint64_t begin = 0, end = 0;
    size_t firstSource = 0, sources = 0;
    uint64_t points = 0;

    bool empty() const { return first == last && begin == end; }
    size_t readEnd() const { return empty() ? first : last + (end > 0); }  // one past the last input it reads
    bool continuesSource() const { return begin > 0 && sources > 0; }
};
// Part `part` of `parts`: runs of about equal bytes (file sizes; the scene
// at 32 bytes a point, a tile set at its blocks.bin's), so that a file's records belong to the part their
// byte position falls in (the whole of an uncut input to the part of its
// middle byte). Parts may outnumber the inputs: some are then empty.
InputPart inputPart(const InputOptions& inputs, size_t part, size_t parts);
// The options reading only `part`'s inputs.
InputOptions partInputs(const InputOptions& inputs, const InputPart& part);
// forEachBatch over `part`'s points (none for an empty part), with its
// sources' statistics and ids, and the `stored` scalar fields.
Status forEachPartBatch(const BuildContext& context, const InputPart& part, std::span<const ScalarQuantization> stored,
                        const BatchConsumer& consume);

// What the plan learns: with the options, all that the later stages need.
struct BuildPlan {
    // Which plan this is: the CRC of plan.bin's payload (0 in one process).
    // The distribute and chunk stages stamp their files with it, and the
    // stages after them refuse files of another plan.
    uint32_t id = 0;
    InputStats stats;
    std::vector<InputPart> parts;
    uint64_t maxChunkPoints = 0;  // 0: every point in one chunk
    // Counting-grid cells (ChunkLayout::cellIndex) that hold points, by index.
    std::vector<std::pair<uint32_t, uint32_t>> counts;

    ChunkLayout layout(const BuildContext& context) const;
};

// Scan: part `part` of `parts` of the inputs (`progress` gets its points).
Result<InputStats> scanStage(const BuildOptions& options, const InputPart& part, Progress& progress);
// `job` identifies the build the part belongs to (a hash of its command line):
// reading a part of another job fails, naming the file.
Status writeScan(const std::string& path, const InputStats& stats, const InputPart& part, uint32_t job);
Result<InputStats> readScan(const std::string& path, InputPart* part, uint32_t job);

// The most points a chunk may hold (0: one chunk takes every point), from the
// budget and what the scan found (docs/ARCHITECTURE.md, "Memory").
Result<uint64_t> chunkPoints(const BuildContext& context);

// Count: part `part`'s points on the counting grid, occupied cells by index.
// `adjust` moves each batch's points first where given (an update's: update.cpp).
Result<std::vector<std::pair<uint32_t, uint32_t>>> countStage(const BuildContext& context, const InputPart& part, Progress& progress,
                                                              const std::function<Status(std::span<Surfel>)>& adjust = {});
Status writeCount(const std::string& path, const std::vector<std::pair<uint32_t, uint32_t>>& counts, uint32_t job);
Result<std::vector<std::pair<uint32_t, uint32_t>>> readCount(const std::string& path, uint32_t job);
// Sums sparse counts (each sorted by cell) into one, sorted by cell.
std::vector<std::pair<uint32_t, uint32_t>> addCounts(const std::vector<std::vector<std::pair<uint32_t, uint32_t>>>& parts);

// The statistics of parts scanned apart (scanStage of each, in order, each
// part's `sources` set to its scan's), reduced to those of one scan of every
// input: each part's firstSource is set. A part whose inputs do not follow on
// from the part before fails, named by name(p).
Result<InputStats> reduceScans(std::vector<InputStats> scans, std::vector<InputPart>& parts,
                               const std::function<std::string(size_t)>& name);
// Runs f(0) .. f(n - 1), each on a thread of its own; the first failure.
Status forEachPartInParallel(size_t n, const std::function<Status(size_t)>& f);

// Plan in one process: scan and count the inputs in `parts` parts (inputPart),
// each on a thread of its own. `context` receives the decisions derived from
// the scan; `summary` the phases' times.
Result<BuildPlan> planStage(const BuildOptions& options, size_t parts, Progress& progress, std::shared_ptr<const BuildContext>* context,
                            BuildSummary* summary);
// Every input as one part, of the sources and points of `stats`.
InputPart wholeInputs(const InputOptions& inputs, const InputStats& stats);
// plan.bin: the plan and `args`, the command line that made it (the staged
// CLI's later stages read their options from it). Sets plan.id.
Status writePlan(const std::string& path, BuildPlan& plan, std::span<const std::string> args);
// The id writePlan gives `plan` with `args`.
uint32_t planId(const BuildPlan& plan, std::span<const std::string> args);
// `buildRecord`: the file is a set's build record (update.h), which may be
// one of an earlier format (SCPLAN04 and 05: plan_stage.cpp).
Result<BuildPlan> readPlan(const std::string& path, std::vector<std::string>* args, bool buildRecord = false);
// The set's build record (update.h), handed to `writer`: `plan` (a copy:
// writePlan sets its id, and the chunks were built to the plan's) with
// `commandLine`, written as dir/build.record.
Status keepBuildRecord(TilesetWriter& writer, const std::string& dir, BuildPlan plan, std::span<const std::string> commandLine);

// The parts a build in one process reads its inputs in, in parallel: one per
// thread where the input is one local LAS file, which parts cut by record
// ranges; one otherwise (a LAZ file's decoder decodes its chunks on every
// thread already: bench/BENCHMARKS.md, "Reading one file in parallel").
size_t readParts(const BuildOptions& options);
// Distribute: writes part `part`'s points to its chunk files and
// distribution.bin (each chunk's point and halo counts from this part).
// `standInStride` > 0: also every standInStride-th point of the part, counted
// from its first, to the same files and a distribution.bin of their own in
// WorkFolder::standIns(work.chunks(part)) (refine.h); the part's own files
// are the same bytes either way.
Status distributeStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, size_t part,
                       const WorkFolder& work, Progress& progress, BuildSummary* summary, uint32_t standInStride = 0);
// Distribute every part of `plan` at once, a thread each (forEachPartInParallel).
Status distributeParts(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                       Progress& progress, BuildSummary* summary, uint32_t standInStride = 0);
// distribution.bin at `path`: each chunk's point and halo counts as
// `layout`'s chunks were written, for `plan`.
Status writeDistribution(const std::string& path, const BuildPlan& plan, const ChunkLayout& layout);
// Each chunk's files of every part, with their counts, from distribution.bin
// (`standIns`: the stand-ins', distributeStage's standInStride).
Status readDistribution(const WorkFolder& work, const BuildPlan& plan, ChunkLayout& layout, bool standIns = false);

// An update's rule for the nodes it builds again: true where the set's node
// of the built node's key stays, record and block, since nothing the update
// changed reaches it (Update's rule). Given the built node's key, children and
// surfel count, before it is encoded: a kept node is never encoded, and its
// record in a chunk's output carries no block (blockSize 0). Called from
// several chunks' threads at once.
using KeepNode = std::function<bool(const NodeRecord& built)>;

// Chunk: builds chunk `index` of `layout` (its pieces from readDistribution)
// on `threads` threads and writes its nodes' blocks and records, and its root
// (the merge's input), to work.blocks(index) and work.nodes(index); each is
// written beside its path and renamed into place, the .nodes file last, which
// marks the chunk done. `removeInputs`: delete the chunk's files once read (a
// build in one process; a staged build keeps them, so that a chunk task can
// run again).
// `keep`: an update's rule (KeepNode).
Status chunkStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, size_t index, const WorkFolder& work,
                  int threads, bool removeInputs, const KeepNode& keep = {});

// Merge: reads every chunk's output (checking each block's CRC as it copies
// it), builds the levels above the chunks and finishes `writer`. Fills the
// summary's counts, steps, texture fit and phases "upper" and "write".
// `kept`: an update's chunks taken as the set holds them (ChunkOutput's
// records, placed in the set's block files, and its root decoded), by chunk
// index; the writer keeps their blocks in place (TilesetWriter::update).
// `keep`: an update's rule (KeepNode), for the levels above the chunks too;
// the chunks' nodes it kept take the set's nodes of their keys.
// `refinement`: a version of a build in progress (refine.h).
struct Refinement;
Status mergeStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                  TilesetWriter& writer, Progress& progress, BuildSummary* summary,
                  std::map<size_t, ChunkOutput>* kept = nullptr, const KeepNode& keep = {}, const Refinement* refinement = nullptr);

// A merge of a build in progress (refine.h): the chunks not `built` yet are
// taken from their stand-ins in `standIns` (built to the same plan), and the
// set is marked a preview of `stride` with `done` of its points at full detail.
struct Refinement {
    const WorkFolder* standIns = nullptr;
    std::vector<bool> built;  // by chunk index
    uint32_t stride = 1;
    double done = 0;
};

// Builds the chunks `which` of `layout` (chunkStage, removing their inputs),
// largest first, kChunksAtOnce at a time; `progress` advances by their points.
// `built`, where given, is called with each chunk's index once it is built,
// on the thread that built it.
Status buildChunks(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, std::vector<size_t> which,
                   const WorkFolder& work, Progress& progress, const KeepNode& keep = {},
                   const std::function<void(size_t)>& built = {});

}  // namespace surfcast
