// Refinement while building (surfcast-build --preview): as a build's chunks
// are built, versions of the set are published to its output, each holding
// the chunks built so far at full detail and the others as stand-ins: the same
// chunks built from every Nth input point, which the distribute pass writes
// beside the chunks' own files (distributeStage's standInStride). Each version
// is an ordinary set in the build's own layout, marked a preview with the
// share of its points at full detail (docs/FORMAT.md, "preview"), so a
// follower keeps a built chunk's nodes from one version to the next. The
// build's own merge then replaces the last version; nothing here changes the
// build's own files, so its bytes are those of a build without previews.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "set_lock.h"
#include "stages.h"

namespace surfcast {

// A version is published at most once per kRefineCostFactor times the time
// the last one took to publish, so that publishing takes at most about
// 1 / kRefineCostFactor of the build (bench/BENCHMARKS.md, "Previews").
inline constexpr double kRefineCostFactor = 20;

// The stand-ins' stride: every Nth of `points` input points, about `wanted`
// in all; 0 (no versions) where N would be under kMinStandInStride: the
// stand-ins would cost a good part of the build itself, which is small.
inline constexpr uint64_t kMinStandInStride = 8;
inline uint32_t standInStride(uint64_t points, uint64_t wanted) {
    const uint64_t n = points / std::max<uint64_t>(1, wanted);
    return n < kMinStandInStride ? 0 : uint32_t(std::min<uint64_t>(n, UINT32_MAX));
}

// Builds the stand-ins of `layout`'s chunks (from the parts' stand-in files)
// into work.standIns(), but those built there already.
Status buildStandIns(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work);

// Publishes a version to the plan's output: the chunks `built` from the work
// folder, the others' stand-ins (buildStandIns), marked a preview of `stride`.
// `lock` then holds the version's folder (taken before it is swapped in: the
// output stays locked from one version to the next). Fails, writing nothing,
// where the output holds a set that is not a preview: versions never replace
// a finished set.
Status publishRefinement(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                         std::vector<bool> built, uint32_t stride, SetLock* lock);

// A build in one process: publishes versions as its chunks are built.
class Refiner {
public:
    // Builds the stand-ins and publishes them as the first version.
    // `layout`: readDistribution's; `stride`: distributeStage's.
    static Result<std::unique_ptr<Refiner>> create(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout,
                                                   const WorkFolder& work, uint32_t stride, double interval);

    // Chunk `index` is built (its files are in the work folder): publishes a
    // version where one is due. Called from the chunks' threads; publishes one
    // at a time, on the calling thread, never after the last chunk (the build's
    // merge comes next). A version that fails is a warning: the build goes on.
    void chunkBuilt(size_t index);

private:
    Refiner(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work, uint32_t stride,
            double interval);

    const BuildContext& context_;
    const BuildPlan& plan_;
    const ChunkLayout& layout_;
    const WorkFolder& work_;
    const uint32_t stride_;
    const double interval_;
    std::mutex mutex_;  // guards what follows
    SetLock lock_;      // the last version's folder
    std::vector<bool> built_;
    size_t builtChunks_ = 0;
    bool publishing_ = false;
    std::chrono::steady_clock::time_point lastEnd_;
    double lastSeconds_ = 0;
};

}  // namespace surfcast
