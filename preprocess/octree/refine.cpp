#include "refine.h"

#include <cstdio>
#include <filesystem>

namespace surfcast {

Refiner::Refiner(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                 const BuildOptions::Refine& options)
    : context_(context), plan_(plan), layout_(layout), work_(work), standIns_{work.dir + "/stand-ins"}, options_(options),
      built_(layout.chunks().size(), false), lastEnd_(std::chrono::steady_clock::now()) {}

Result<std::unique_ptr<Refiner>> Refiner::create(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout,
                                                 const WorkFolder& work, const BuildOptions::Refine& options) {
    std::unique_ptr<Refiner> r(new Refiner(context, plan, layout, work, options));
    SC_TRY(r->buildStandIns());
    return r;
}

// The sample read as the build reads its inputs (forEachPartBatch of every
// input), to the layout's chunks and halos, then each chunk built from it.
Status Refiner::buildStandIns() {
    ChunkLayout layout = layout_;
    std::error_code ec;
    std::filesystem::create_directories(standIns_.chunks(0), ec);
    if (ec) return Status::error(standIns_.chunks(0) + ": cannot create (" + ec.message() + ")");
    {
        ChunkWriter writer(layout, standIns_.chunks(0), context_.scalars().size());
        InputOptions inputs = context_.options().inputs;
        inputs.firstBegin = inputs.lastEnd = 0;
        inputs.captured = options_.sample.inputs;
        SC_TRY(forEachBatch(inputs, context_.stats(), context_.rootMin(), context_.sourceIds(), context_.scalars(),
                            [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) { return writer.add(batch, scalars); },
                            context_.inputOfSource()));
        SC_TRY(writer.finish());
    }
    for (Chunk& c : layout.chunks()) {
        c.points = c.written.points;
        c.haloPoints = c.written.haloPoints;
        c.pieces = {c.written};
    }
    for (size_t i = 0; i < layout.chunks().size(); ++i)
        SC_TRY(chunkStage(context_, plan_, layout, i, standIns_, context_.threads(), true));
    return {};
}

void Refiner::chunkBuilt(size_t index) {
    Refinement version;
    {
        std::lock_guard lock(mutex_);
        built_.at(index) = true;
        builtPoints_ += layout_.chunks()[index].points;
        ++builtChunks_;
        const double since = std::chrono::duration<double>(std::chrono::steady_clock::now() - lastEnd_).count();
        const bool due = options_.interval == 0 || (since >= options_.interval && since >= kRefineCostFactor * lastSeconds_);
        if (publishing_ || builtChunks_ == built_.size() || !due) return;
        publishing_ = true;
        version = {&standIns_, built_, options_.sample.stride,
                   std::min(double(builtPoints_) / double(std::max<uint64_t>(1, context_.stats().points)), 0.999)};
    }
    const auto start = std::chrono::steady_clock::now();
    const double done = version.done;
    const Status st = publish(std::move(version));
    const auto end = std::chrono::steady_clock::now();
    if (!st.ok()) std::fprintf(stderr, "surfcast-build: a version of the build in progress failed: %s\n", st.message().c_str());
    std::lock_guard lock(mutex_);
    publishing_ = false;
    lastEnd_ = end;
    lastSeconds_ = std::chrono::duration<double>(end - start).count();
    if (st.ok()) {
        ++versions_;
        if (context_.options().progress)
            std::fprintf(stderr, "preview: %s, %.0f %% at full detail, published in %.2f s\n", context_.options().output.c_str(),
                         100 * done, lastSeconds_);
    }
}

Status Refiner::publish(Refinement refinement) {
    auto writer = TilesetWriter::create(context_.options().output, "refine");
    if (!writer) return writer.status();
    Progress quiet(false);
    BuildSummary summary;
    return mergeStage(context_, plan_, layout_, work_, **writer, quiet, &summary, nullptr, {}, &refinement);
}

}  // namespace surfcast
