// Updates in place (docs/FORMAT.md, "Updates in place"): scans added to or
// removed from a published set, rebuilding only the chunks the added or
// removed points reach (their own points and their halos) and the levels
// above the chunks. Every other node
// keeps its block, its byte range and so its ETag; the new blocks go into a
// block file of their own and the new hierarchy is switched in with tileset.json.
#pragma once

#include <string>
#include <vector>

#include "octree_builder.h"
#include "stages.h"

namespace surfcast {

// What an update changes: inputs added (the last `added` of the options'
// paths, after the set's own) and inputs removed (their indices: the built-in
// scene 0 where the set has it, then the set's paths in order), whose points
// the provenance attribute names (docs/FORMAT.md, "Provenance").
struct UpdateRequest {
    size_t added = 0;
    std::vector<uint32_t> removed;
    // The set's s3:// URL, where the set folder an update is given is a local
    // copy of its tileset.json and build record (set_publisher.h): the blocks
    // are read from the store, and the update writes its version to the
    // folder, for the caller to publish. Empty: the folder is the set.
    std::string store;
};

// `options`: the set's build options (from its build record) with the added
// inputs after its own, `threads` and `progress` as the update asks; `set`:
// the set's folder; `record`: the set's build record; `commandLine`: the one
// the updated set's record keeps. A removed input keeps its place, with no
// points, so that the other points' provenance stays. Fails, leaving the set
// as it was, where the added points change a decision the kept blocks depend
// on (the colour depth, an attribute's quantization) or where the set was
// built with textured meshes, captured weights or a file of several scans.
// Points beyond the root cube grow it (the old root a node of the new one).
// A set of one input given a second builds every chunk again, as its blocks
// then gain the provenance attribute.
Result<BuildSummary> updateTileset(const BuildOptions& options, const UpdateRequest& request, const std::string& set,
                                   const BuildPlan& record, const std::vector<std::string>& commandLine);

// The update in stages (stages.h), each its own process, for a driver that
// runs the chunks' builds as tasks (scripts/surfcast-dask), with the same
// bytes as updateTileset:
//   update-plan   updatePlanStage: all that precedes the chunks' builds, into
//                 `work` (update.bin, plan.bin, the chunk files)
//   chunk I       chunkStage, with updateContext's context and rule, for the
//                 chunks `build` names
//   update-merge  updateMergeStage: the levels above the chunks, and the switch
// The later stages take `options` from plan.bin's command line (-o names the
// set) and fail, naming the set and the work folder, where the set changed
// after the plan (another update ran): a plan holds for the version of the
// set it was made on. updateApplied tells a stage run again after the switch
// that the set already holds the update (its build record is plan.bin).
struct StagedUpdate {
    BuildPlan plan;                    // as plan.bin holds it
    ChunkLayout layout;                // its chunks, as distributed
    std::vector<uint64_t> chunkPoints;  // per chunk of the layout: the points distributed to it
    std::vector<size_t> build;         // the chunks to build
};
Result<StagedUpdate> updatePlanStage(const BuildOptions& options, const UpdateRequest& request, const std::string& set,
                                     const BuildPlan& record, const std::vector<std::string>& commandLine, const WorkFolder& work);
Result<bool> updateApplied(const BuildOptions& options, const WorkFolder& work);
Result<std::shared_ptr<const BuildContext>> updateContext(const BuildOptions& options, const BuildPlan& plan, const WorkFolder& work,
                                                          std::vector<size_t>* build, KeepNode* keep);
// `commandLine`: plan.bin's, which the set's build record keeps.
Result<BuildSummary> updateMergeStage(const BuildOptions& options, const BuildPlan& plan, const std::vector<std::string>& commandLine,
                                      const WorkFolder& work);

}  // namespace surfcast
