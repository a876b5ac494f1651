// The distribute stage (stages.h): one part's points to its chunk files and
// the halos that hold them, and its distribution.bin, which the chunk stage
// reads the files' counts from.
#include <fcntl.h>
#include <stdio.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <memory>

#include "stages.h"
#include "work_files.h"

namespace surfcast {

namespace {
constexpr char kDistributionMagic[9] = "SCDIST03";  // 03: Surfel::scanDk in the chunk files' records

// Part `part`'s points to its chunk files, in a folder of its own, and every
// `standInStride`-th of them to the stand-ins' files in its stand-ins/ (0: none).
Status distributePart(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& planned, size_t part,
                      const WorkFolder& work, Progress& progress, uint32_t standInStride) {
    const InputPart& inputs = plan.parts.at(part);
    // Written into a folder of this process's own and renamed into place
    // whole: a task run twice at once, or killed, never mixes its files with
    // another's.
    const std::string folder = partialName(work.chunks(part));
    std::error_code ec;
    std::filesystem::remove_all(folder, ec);
    std::filesystem::create_directories(folder, ec);
    if (ec) return Status::error(folder + ": cannot create (" + ec.message() + ")");
    struct RemoveDir {
        std::string path;
        ~RemoveDir() {
            std::error_code e;
            std::filesystem::remove_all(path, e);
        }
    } guard{folder};
    ChunkLayout layout = planned, standInLayout = planned;
    const uint64_t expected = inputs.points;
    ChunkWriter chunkWriter(layout, folder, context.scalars().size());
    std::unique_ptr<ChunkWriter> standIns;
    if (standInStride > 0) {
        std::filesystem::create_directories(WorkFolder::standIns(folder), ec);
        if (ec) return Status::error(WorkFolder::standIns(folder) + ": cannot create (" + ec.message() + ")");
        standIns = std::make_unique<ChunkWriter>(standInLayout, WorkFolder::standIns(folder), context.scalars().size());
    }
    uint64_t seen = 0;
    std::vector<Surfel> sample;
    std::vector<uint32_t> sampleScalars;
    const size_t fields = context.scalars().size();
    SC_TRY(forEachPartBatch(context, inputs, context.scalars(), [&](std::span<Surfel> batch, std::span<const uint32_t> scalars) {
        if (standIns) {
            sample.clear();
            sampleScalars.clear();
            for (uint64_t i = (standInStride - seen % standInStride) % standInStride; i < batch.size(); i += standInStride) {
                sample.push_back(batch[i]);
                sampleScalars.insert(sampleScalars.end(), scalars.begin() + long(i * fields), scalars.begin() + long((i + 1) * fields));
            }
            SC_TRY(standIns->add(sample, sampleScalars));
        }
        seen += batch.size();
        progress.advance(batch.size());
        return chunkWriter.add(batch, scalars);
    }));
    SC_TRY(chunkWriter.finish());
    if (seen != expected)
        return Status::error("the inputs changed while being read: " + std::to_string(expected) + " points, then " + std::to_string(seen));
    SC_TRY(writeDistribution(folder + "/distribution.bin", plan, layout));
    if (standIns) {
        SC_TRY(standIns->finish());
        SC_TRY(writeDistribution(WorkFolder::standIns(folder) + "/distribution.bin", plan, standInLayout));
    }
    // Into place in one step: exchanged with an earlier run's folder (whose
    // files then go with `folder`), or renamed where there is none. A chunk
    // stage reading the part meanwhile sees one folder or the other, whole.
    const std::string target = work.chunks(part);
    if (::renameat2(AT_FDCWD, folder.c_str(), AT_FDCWD, target.c_str(), RENAME_EXCHANGE) != 0 &&
        ::rename(folder.c_str(), target.c_str()) != 0 &&
        ::renameat2(AT_FDCWD, folder.c_str(), AT_FDCWD, target.c_str(), RENAME_EXCHANGE) != 0)
        return Status::error(target + ": cannot move the part's chunk files into place (" + std::strerror(errno) + ")");
    return {};
}

// The parts `which` at once, a thread each, as one phase.
Status distributeEach(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const std::vector<size_t>& which,
                      const WorkFolder& work, Progress& progress, BuildSummary* summary, uint32_t standInStride) {
    uint64_t points = 0;
    for (size_t part : which) points += plan.parts.at(part).points;
    progress.begin("distribute", points);
    SC_TRY(forEachPartInParallel(which.size(), [&](size_t i) { return distributePart(context, plan, layout, which[i], work, progress, standInStride); }));
    MeshStore& meshes = *context.options().inputs.meshes;
    meshes.setCapacity(0);  // the fields keep the textures; nothing reads the meshes again
    summary->meshReads = meshes.reads();  // the store's, since the scan: the build's in one process
    summary->phaseSeconds.push_back({"distribute", progress.end()});
    return {};
}

}  // namespace

Status distributeStage(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, size_t part,
                       const WorkFolder& work, Progress& progress, BuildSummary* summary, uint32_t standInStride) {
    return distributeEach(context, plan, layout, {part}, work, progress, summary, standInStride);
}

Status distributeParts(const BuildContext& context, const BuildPlan& plan, const ChunkLayout& layout, const WorkFolder& work,
                       Progress& progress, BuildSummary* summary, uint32_t standInStride) {
    std::vector<size_t> all(plan.parts.size());
    for (size_t p = 0; p < all.size(); ++p) all[p] = p;
    return distributeEach(context, plan, layout, all, work, progress, summary, standInStride);
}

Status writeDistribution(const std::string& path, const BuildPlan& plan, const ChunkLayout& layout) {
    ByteWriter w;
    w.put(plan.id);
    w.put(uint64_t(layout.chunks().size()));
    for (const Chunk& c : layout.chunks()) w.put(c.written.points), w.put(c.written.haloPoints);
    return writeWorkFile(path, kDistributionMagic, w);
}

Status readDistribution(const WorkFolder& work, const BuildPlan& plan, ChunkLayout& layout, bool standIns) {
    for (Chunk& c : layout.chunks()) {
        c.points = c.haloPoints = 0;
        c.pieces.clear();
    }
    for (size_t part = 0; part < plan.parts.size(); ++part) {
        const std::string folder = standIns ? WorkFolder::standIns(work.chunks(part)) : work.chunks(part);
        const std::string path = folder + "/distribution.bin";
        auto bytes = readWorkFile(path, kDistributionMagic);
        if (!bytes) return bytes.status();
        ByteReader r(*bytes);
        if (r.get<uint32_t>() != plan.id) return Status::error(path + ": written for another plan (distribute this part again)");
        if (r.getCount(16) != layout.chunks().size() || r.left() != 16 * layout.chunks().size())
            return Status::error(path + ": does not match the plan's " + std::to_string(layout.chunks().size()) + " chunks");
        for (size_t i = 0; i < layout.chunks().size(); ++i) {
            Chunk& c = layout.chunks()[i];
            ChunkPiece piece = ChunkWriter::files(folder, i);
            piece.points = r.get<uint64_t>();
            piece.haloPoints = r.get<uint64_t>();
            c.points += piece.points;
            c.haloPoints += piece.haloPoints;
            c.pieces.push_back(std::move(piece));
        }
    }
    return {};
}

}  // namespace surfcast
