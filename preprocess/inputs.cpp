#include "inputs.h"

#include <algorithm>
#include <filesystem>

#include "byte_stream.h"
#include "las_reader.h"
#include "pcd_reader.h"
#include "ply_reader.h"
#include "text_reader.h"

namespace surfcast {

namespace {

constexpr size_t kBatchPoints = 1 << 16;


Result<std::unique_ptr<PointReader>> openOne(const std::string& path, const InputOptions& options) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) return Status::error(path + ": no such file");
    std::string ext = lowerExtension(path);
    char magic[4] = {};
    {
        auto in = ByteStream::open(path);
        if (!in) return in.status();
        if (in->fileSize() == 0) return Status::error(path + ": empty file");
        in->readBytes(magic, std::min<uint64_t>(4, in->fileSize()));
    }
    if (ext == ".ply" || std::string(magic, 3) == "ply") {
        if (!options.verticesOnly) {
            auto in = ByteStream::open(path);
            if (!in) return in.status();
            auto header = parsePlyHeader(*in);
            if (!header) return header.status();
            if (plyHasFaces(*header)) return openMeshReader(path, options.mesh);
        }
        return openPlyReader(path);
    }
    if (ext == ".pcd" || std::string(magic, 4) == "# .P" || std::string(magic, 4) == "VERS") return openPcdReader(path);
    if (ext == ".las" || ext == ".laz" || std::string(magic, 4) == "LASF") return openLasReader(path, options.threads);
    if (isMeshExtension(path)) return openMeshReader(path, options.mesh);
    if (ext == ".xyz" || ext == ".txt" || ext == ".pts" || ext == ".csv" || ext == ".asc")
        return openTextReader(path, options.columns);
    return Status::error(path + ": unknown input format '" + ext + "' (PLY, LAS, LAZ, PCD, XYZ/TXT/PTS/CSV, OBJ, OFF, STL)");
}

uint16_t scaled(uint16_t raw, double scale) { return uint16_t(std::min(65535.0, raw * scale)); }

}  // namespace

Result<std::vector<std::unique_ptr<PointReader>>> openInputs(const InputOptions& options) {
    std::vector<std::unique_ptr<PointReader>> readers;
    if (options.defaultScene)
        for (auto& r : openDefaultScene(options.scene)) readers.push_back(std::move(r));
    for (const std::string& path : options.paths) {
        auto r = openOne(path, options);
        if (!r) return r.status();
        readers.push_back(std::move(*r));
    }
    if (readers.empty()) return Status::error("no inputs given");
    if (readers.size() > 65535) return Status::error("more than 65535 inputs");
    return readers;
}

Result<InputStats> scanInputs(const InputOptions& options, const std::function<void(uint64_t)>& progress) {
    auto readers = openInputs(options);
    if (!readers) return readers.status();
    InputStats stats;
    std::vector<InputPoint> batch(kBatchPoints);
    for (auto& reader : *readers) {
        SourceStats s;
        s.description = reader->description();
        while (true) {
            auto n = reader->read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) break;
            for (size_t i = 0; i < *n; ++i) {
                const InputPoint& p = batch[i];
                s.bounds.extend(p.position);
                for (int c = 0; c < 3; ++c) {
                    s.colorMax = std::max(s.colorMax, p.color[c]);
                    // 8-bit values scaled by 257 (v = c·257) or shifted by 8 (v = c·256).
                    uint16_t v = p.color[c];
                    if ((v >> 8) * 257 != v && (v & 0xFF) != 0) s.colors8Bit = false;
                }
            }
            s.points += *n;
            progress(*n);
        }
        s.skipped = reader->skipped();
        // LAS stores 16-bit colour, but many writers put 8-bit values in it.
        if (s.description.colorBits == 16 && s.colorMax <= 255) {
            s.colorScale = 257;
            s.colors8Bit = true;
        }
        if (s.description.declaredPoints && s.points + s.skipped != s.description.declaredPoints &&
            s.description.format != "mesh")
            return Status::error(s.description.path + ": header declares " + std::to_string(s.description.declaredPoints) +
                                 " points, the file holds " + std::to_string(s.points + s.skipped));
        stats.points += s.points;
        stats.skipped += s.skipped;
        stats.bounds.extend(s.bounds);
        if (s.description.hasColors) {
            stats.anyColors = true;
            stats.colorBits = std::max(stats.colorBits, s.colors8Bit ? 8 : 16);
        }
        stats.sources.push_back(std::move(s));
    }
    return stats;
}

Status forEachBatch(const InputOptions& options, const InputStats& stats, const Vec3d& origin,
                    const std::function<Status(std::span<Surfel>)>& consume) {
    auto readers = openInputs(options);
    if (!readers) return readers.status();
    std::vector<InputPoint> batch(kBatchPoints);
    std::vector<Surfel> surfels(kBatchPoints);
    for (size_t r = 0; r < readers->size(); ++r) {
        const SourceStats& src = stats.sources[r];
        while (true) {
            auto n = (*readers)[r]->read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) break;
            for (size_t i = 0; i < *n; ++i) {
                Surfel& s = surfels[i];
                s = Surfel{};
                s.position = batch[i].position - origin;
                s.normal = batch[i].normal;
                s.source = uint16_t(r);
                for (int c = 0; c < 3; ++c)
                    s.color[c] = src.description.hasColors ? scaled(batch[i].color[c], src.colorScale) : 65535;
            }
            SC_TRY(consume(std::span<Surfel>(surfels.data(), *n)));
        }
    }
    return {};
}

}  // namespace surfcast
