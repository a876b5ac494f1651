#include "refine.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

namespace surfcast {

Status buildStandIns(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work) {
    ChunkLayout standIns = layout;
    SC_TRY(readDistribution(work, plan, standIns, true));
    std::error_code ec;
    for (size_t i = 0; i < standIns.chunks().size(); ++i)
        if (!std::filesystem::exists(work.standIns().nodes(i), ec))
            SC_TRY(chunkStage(context, plan, standIns, i, work.standIns(), context.threads(), false));
    return {};
}

Status publishRefinement(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                         std::vector<bool> built, uint32_t stride, SetLock* lock) {
    uint64_t points = 0;
    for (size_t i = 0; i < built.size(); ++i) points += built[i] ? layout.chunks().at(i).points : 0;
    const WorkFolder standIns = work.standIns();
    Refinement refinement{&standIns, std::move(built), stride,
                          std::min(double(points) / double(std::max<uint64_t>(1, context.stats().points)), 0.999)};
    const std::string& out = context.options().output;
    std::error_code ec;
    if (std::filesystem::exists(out + "/tileset.json", ec)) {
        std::ifstream in(out + "/tileset.json", std::ios::binary);
        auto there = readTilesetJson(std::string{std::istreambuf_iterator<char>(in), {}}, out + "/tileset.json");
        if (there && there->previewStride == 0) return Status::error(out + ": holds a set, which no version of a build replaces");
    }
    auto writer = TilesetWriter::create(out, "refine");
    if (!writer) return writer.status();
    SetLock next;
    SC_TRY(lockSet((*writer)->partialDir(), &next));
    Progress quiet(false);
    BuildSummary summary;
    SC_TRY(mergeStage(context, plan, layout, work, **writer, quiet, &summary, nullptr, {}, &refinement));
    std::swap(lock->fd, next.fd);
    if (context.options().progress)
        std::fprintf(stderr, "preview: %s, %.0f %% at full detail\n", context.options().output.c_str(), 100 * refinement.done);
    return {};
}

Refiner::Refiner(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work, uint32_t stride,
                 double interval)
    : context_(context), plan_(plan), layout_(layout), work_(work), stride_(stride), interval_(interval),
      built_(layout.chunks().size(), false), lastEnd_(std::chrono::steady_clock::now()) {}

Result<std::unique_ptr<Refiner>> Refiner::create(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout,
                                                 const WorkFolder& work, uint32_t stride, double interval) {
    SC_TRY(buildStandIns(context, plan, layout, work));
    std::unique_ptr<Refiner> r(new Refiner(context, plan, layout, work, stride, interval));
    // The stand-ins alone first: every point's region in the build's layout
    // (where the preview held a LAZ file's chunk starts only, far more).
    const auto start = std::chrono::steady_clock::now();
    if (Status st = publishRefinement(context, plan, layout, work, r->built_, stride, &r->lock_); !st.ok())
        std::fprintf(stderr, "surfcast-build: a version of the build in progress failed: %s\n", st.message().c_str());
    r->lastEnd_ = std::chrono::steady_clock::now();
    r->lastSeconds_ = std::chrono::duration<double>(r->lastEnd_ - start).count();
    return r;
}

void Refiner::chunkBuilt(size_t index) {
    std::vector<bool> built;
    {
        std::lock_guard lock(mutex_);
        built_.at(index) = true;
        ++builtChunks_;
        const double since = std::chrono::duration<double>(std::chrono::steady_clock::now() - lastEnd_).count();
        const bool due = interval_ == 0 || (since >= interval_ && since >= kRefineCostFactor * lastSeconds_);
        if (publishing_ || builtChunks_ == built_.size() || !due) return;
        publishing_ = true;
        built = built_;
    }
    const auto start = std::chrono::steady_clock::now();
    Status st;
    try {  // on a chunk's thread: a version is a convenience, never the build's end
        st = publishRefinement(context_, plan_, layout_, work_, std::move(built), stride_, &lock_);
    } catch (const std::exception& e) {
        st = Status::error(e.what());
    }
    const auto end = std::chrono::steady_clock::now();
    if (!st.ok()) std::fprintf(stderr, "surfcast-build: a version of the build in progress failed: %s\n", st.message().c_str());
    std::lock_guard lock(mutex_);
    publishing_ = false;
    lastEnd_ = end;
    lastSeconds_ = std::chrono::duration<double>(end - start).count();
}

}  // namespace surfcast
