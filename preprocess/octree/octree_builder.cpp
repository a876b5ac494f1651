// A build in one process: the stages of stages.h one after another, the chunks
// kChunksAtOnce at a time, with the work folder beside the partial output.
#include "octree_builder.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <thread>

#include "refine.h"
#include "stages.h"

namespace fs = std::filesystem;

namespace surfcast {

// Largest first (the long poles start early), at most kChunksAtOnce at a time
// (the budget is split that many ways); more threads work inside each chunk.
Status buildChunks(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, std::vector<size_t> order,
                   const WorkFolder& work, Progress& progress, const KeepNode& keep, const std::function<void(size_t)>& built) {
    if (order.empty()) return {};
    const std::vector<Chunk>& chunks = layout.chunks();
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return chunks[a].points > chunks[b].points; });
    const int threads = context.threads();
    const int workers = int(std::min({size_t(threads), size_t(kChunksAtOnce), order.size()}));
    const int inner = std::max(1, threads / workers);
    std::atomic<size_t> next{0};
    std::mutex errorMutex;
    Status firstError;
    auto work1 = [&] {
        while (true) {
            const size_t i = next++;
            if (i >= order.size()) return;
            {
                std::lock_guard lock(errorMutex);
                if (!firstError.ok()) return;
            }
            Status st = chunkStage(context, plan, layout, order[i], work, inner, true, keep);
            progress.advance(chunks[order[i]].points);
            if (st.ok() && built) built(order[i]);
            if (!st.ok()) {
                std::lock_guard lock(errorMutex);
                if (firstError.ok()) firstError = st;
            }
        }
    };
    std::vector<std::thread> pool;
    for (int w = 1; w < workers; ++w) pool.emplace_back(work1);
    work1();
    for (auto& t : pool) t.join();
    return firstError;
}

Result<BuildSummary> buildTileset(const BuildOptions& options) {
    const auto start = std::chrono::steady_clock::now();
    Progress progress(options.progress);
    BuildSummary summary;
    std::shared_ptr<const BuildContext> context;
    auto plan = planStage(options, readParts(normalizeOptions(options)), progress, &context, &summary);
    if (!plan) return plan.status();
    const BuildContext& c = *context;
    c.describe(&summary);

    auto writer = TilesetWriter::create(options.output);
    if (!writer) return writer.status();
    const fs::path partial((*writer)->partialDir());
    const WorkFolder work{(partial.parent_path() / (partial.filename().string() + "-work")).string()};
    std::error_code ec;
    fs::create_directories(work.dir, ec);
    if (ec) return Status::error(work.dir + ": cannot create the temporary work folder (" + ec.message() + ")");
    struct RemoveDir {
        std::string path;
        ~RemoveDir() {
            std::error_code e;
            fs::remove_all(path, e);
        }
    } workGuard{work.dir};

    ChunkLayout layout = plan->layout(c);
    // Versions of the build in progress (refine.h), where there is more than
    // one chunk to refine: a failure to start them is a warning.
    const uint32_t stride = options.refine && layout.chunks().size() > 1 ? standInStride(c.stats().points, options.refine->points) : 0;
    const bool refining = stride > 0;
    SC_TRY(distributeParts(c, *plan, layout, work, progress, &summary, stride));
    SC_TRY(readDistribution(work, *plan, layout));
    summary.chunks = layout.chunks().size();
    std::unique_ptr<Refiner> refiner;
    if (refining) {
        const auto begun = std::chrono::steady_clock::now();
        auto created = Refiner::create(c, *plan, layout, work, stride, options.refine->interval);
        summary.phaseSeconds.push_back({"stand-ins", std::chrono::duration<double>(std::chrono::steady_clock::now() - begun).count()});
        if (created) refiner = std::move(*created);
        else std::fprintf(stderr, "surfcast-build: no versions while building: %s\n", created.status().message().c_str());
    }
    progress.begin("build", c.stats().points);
    std::vector<size_t> all(layout.chunks().size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = i;
    SC_TRY(buildChunks(c, *plan, layout, std::move(all), work, progress, {},
                       refiner ? std::function<void(size_t)>([&](size_t i) { refiner->chunkBuilt(i); }) : nullptr));
    summary.phaseSeconds.push_back({"build", progress.end()});
    if (!options.commandLine.empty()) {
        // The record names the inputs as one part, whatever parts they were
        // read in: the same record, and so the same set, whatever the threads.
        BuildPlan record = *plan;
        record.parts = {wholeInputs(c.options().inputs, c.stats())};
        SC_TRY(keepBuildRecord(**writer, work.dir, std::move(record), options.commandLine));
    }
    SC_TRY(mergeStage(c, *plan, layout, work, **writer, progress, &summary));

    summary.inputPoints = c.stats().points;
    summary.skippedPoints = c.stats().skipped;
    summary.totalSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    summary.peakRss = peakRssBytes();
    return summary;
}

}  // namespace surfcast
