// Refinement while building (surfcast-build --preview): as a build's chunks
// are built, versions of the set are published to its output, each holding
// the chunks built so far at full detail and the others as stand-ins: the same
// chunks built from the preview's sample (every stride-th point). Each version
// is an ordinary set in the build's own layout, marked a preview with the
// share of its points at full detail (docs/FORMAT.md, "preview"), so a
// follower keeps a built chunk's nodes from one version to the next. The
// build's own merge then replaces the last version; nothing here touches the
// build's files, so its bytes are those of a build without previews.
#pragma once

#include <chrono>
#include <memory>
#include <mutex>
#include <vector>

#include "stages.h"

namespace surfcast {

// A version is published at most once per kRefineCostFactor times the time
// the last one took to publish, so that publishing takes at most about
// 1 / kRefineCostFactor of the build (bench/BENCHMARKS.md, "Previews").
inline constexpr double kRefineCostFactor = 20;

class Refiner {
public:
    // Distributes the sample to `layout`'s chunks and builds each chunk's
    // stand-in, in a folder inside the work folder. `layout`: readDistribution's.
    static Result<std::unique_ptr<Refiner>> create(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout,
                                                   const WorkFolder& work, const BuildOptions::Refine& options);

    // Chunk `index` is built (its files are in the work folder): publishes a
    // version where one is due. Called from the chunks' threads; publishes one
    // at a time, on the calling thread, never after the last chunk (the build's
    // merge comes next). A version that fails is a warning: the build goes on.
    void chunkBuilt(size_t index);

    size_t versions() const { return versions_; }  // published so far

private:
    Refiner(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
            const BuildOptions::Refine& options);
    Status buildStandIns();
    Status publish(Refinement refinement);

    const BuildContext& context_;
    const BuildPlan& plan_;
    const ChunkLayout& layout_;
    const WorkFolder& work_;
    WorkFolder standIns_;
    BuildOptions::Refine options_;
    std::mutex mutex_;  // guards what follows
    std::vector<bool> built_;
    uint64_t builtPoints_ = 0;
    size_t builtChunks_ = 0, versions_ = 0;
    bool publishing_ = false;
    std::chrono::steady_clock::time_point lastEnd_;
    double lastSeconds_ = 0;
};

}  // namespace surfcast
