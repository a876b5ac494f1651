// The distribute stage (stages.h): every point to its chunk's file and the
// halos that hold it, and distribution.bin, which the chunk stage reads its
// files' counts from.
#include <filesystem>

#include "stages.h"
#include "work_files.h"

namespace surfcast {

namespace {
constexpr char kDistributionMagic[9] = "SCDIST01";

void nameChunkFiles(const WorkFolder& work, ChunkLayout& layout) {
    for (size_t i = 0; i < layout.chunks().size(); ++i) {
        Chunk& c = layout.chunks()[i];
        const std::string base = work.chunks() + "/chunk-" + std::to_string(i);
        c.file = base + ".bin";
        c.haloFile = base + ".halo";
        c.scalarFile = base + ".scalars";
    }
}
}  // namespace

Status distributeStage(const BuildContext& context, ChunkLayout& layout, const WorkFolder& work, Progress& progress,
                       BuildSummary* summary) {
    const BuildOptions& opt = context.options();
    std::error_code ec;
    std::filesystem::create_directories(work.chunks(), ec);
    if (ec) return Status::error(work.chunks() + ": cannot create (" + ec.message() + ")");
    for (Chunk& c : layout.chunks()) c.points = c.haloPoints = 0;  // ChunkWriter counts them, and names the files as nameChunkFiles does
    MeshStore& meshes = *opt.inputs.meshes;
    progress.begin("distribute", context.stats().points);
    ChunkWriter chunkWriter(layout, work.chunks(), context.scalars().size());
    uint64_t seen = 0;
    SC_TRY(forEachBatch(opt.inputs, context.stats(), context.rootMin(), context.sourceIds(), context.scalars(),
                        [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
        seen += batch.size();
        progress.advance(batch.size());
        return chunkWriter.add(batch, scalars);
    }));
    SC_TRY(chunkWriter.finish());
    meshes.setCapacity(0);  // the fields keep the textures; nothing reads the meshes again
    summary->meshReads = meshes.reads();
    summary->phaseSeconds.push_back({"distribute", progress.end()});
    if (seen != context.stats().points)
        return Status::error("the inputs changed while being read: " + std::to_string(context.stats().points) + " points, then " +
                             std::to_string(seen));
    ByteWriter w;
    w.put(uint64_t(layout.chunks().size()));
    for (const Chunk& c : layout.chunks()) w.put(c.points), w.put(c.haloPoints);
    return writeWorkFile(work.distribution(), kDistributionMagic, w);
}

Status readDistribution(const WorkFolder& work, ChunkLayout& layout) {
    auto bytes = readWorkFile(work.distribution(), kDistributionMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    if (r.getCount(16) != layout.chunks().size() || !r.ok())
        return Status::error(work.distribution() + ": does not match the plan's " + std::to_string(layout.chunks().size()) + " chunks");
    for (Chunk& c : layout.chunks()) {
        c.points = r.get<uint64_t>();
        c.haloPoints = r.get<uint64_t>();
    }
    nameChunkFiles(work, layout);
    return {};
}

}  // namespace surfcast
