#include "work_files.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <unistd.h>

#include "crc32.h"

namespace surfcast {

std::string partialName(const std::string& path) {
    char host[256] = {};
    if (::gethostname(host, sizeof host - 1) != 0) host[0] = '\0';
    return path + ".partial-" + host + "-" + std::to_string(::getpid());
}

Status writeWorkFile(const std::string& path, const char (&magic)[9], ByteWriter& payload) {
    std::vector<uint8_t>& bytes = payload.bytes();
    bytes.insert(bytes.begin(), magic, magic + 8);
    const uint32_t crc = crc32(bytes.data(), bytes.size());
    payload.put(crc);
    const std::string partial = partialName(path);
    std::FILE* f = std::fopen(partial.c_str(), "wb");
    if (!f) return Status::error(partial + ": cannot create (" + std::strerror(errno) + ")");
    bool ok = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size() && std::fflush(f) == 0 && ::fsync(::fileno(f)) == 0;
    ok = std::fclose(f) == 0 && ok;
    std::error_code ec;
    if (ok) std::filesystem::rename(partial, path, ec);
    if (!ok || ec) {
        std::filesystem::remove(partial, ec);
        return Status::error(path + ": could not be written (disk full?)");
    }
    return {};
}

Result<std::vector<uint8_t>> readWorkFile(const std::string& path, const char (&magic)[9]) {
    std::error_code ec;
    const uintmax_t size = std::filesystem::file_size(path, ec);
    if (ec) return Status::error(path + ": cannot read (" + ec.message() + ")");
    if (size < 12) return Status::error(path + ": truncated (" + std::to_string(size) + " bytes)");
    std::vector<uint8_t> bytes(size);
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return Status::error(path + ": cannot open (" + std::strerror(errno) + ")");
    const bool read = std::fread(bytes.data(), 1, bytes.size(), f) == bytes.size();
    std::fclose(f);
    if (!read) return Status::error(path + ": read failed");
    if (std::memcmp(bytes.data(), magic, 8) != 0)
        return Status::error(path + ": not a " + std::string(magic, 8) + " file of this version (wrong magic)");
    const uint32_t stored = le::get<uint32_t>(bytes.data() + size - 4);
    if (crc32(bytes.data(), size - 4) != stored) return Status::error(path + ": checksum mismatch (corrupt or truncated)");
    return std::vector<uint8_t>(bytes.begin() + 8, bytes.end() - 4);
}

}  // namespace surfcast

namespace surfcast {

namespace {
constexpr char kChunkMagic[9] = "SCNODES4";  // 4: the outliers removed
}

Status writeChunkOutput(const std::string& path, const ChunkOutput& out) {
    ByteWriter w;
    w.put(out.plan);
    w.put(uint64_t(out.records.size()));
    for (const NodeRecord& r : out.records) {
        uint8_t bytes[kRecordSize];
        encodeRecord(r, bytes);
        w.putBytes(bytes, kRecordSize);
    }
    w.put(out.blocksBytes);
    for (uint64_t ns : out.stepNs) w.put(ns);
    w.put(uint64_t(out.fits.groups));
    w.put(uint64_t(out.fits.unknowns));
    w.put(uint64_t(out.fits.samples));
    w.put(out.fits.iterations);
    w.put(int32_t(out.fits.maxIterations));
    w.put(out.fits.maxResidual);
    w.put(out.removedOutliers);
    w.put(uint8_t(out.root != nullptr));
    if (out.root) {
        const BuiltNode& root = *out.root;
        w.put(root.key.level);
        w.put(root.key.x);
        w.put(root.key.y);
        w.put(root.key.z);
        w.put(uint64_t(root.surfels.size()));
        for (const Surfel& s : root.surfels) w.putBytes(&s, sizeof s);
        w.put(uint64_t(out.rootScalars.values.size()));
        for (uint32_t v : out.rootScalars.values) w.put(v);
    }
    return writeWorkFile(path, kChunkMagic, w);
}

Result<ChunkOutput> readChunkOutput(const std::string& path, const ScalarTable& empty) {
    auto bytes = readWorkFile(path, kChunkMagic);
    if (!bytes) return bytes.status();
    ByteReader r(*bytes);
    const Status corrupt = Status::error(path + ": malformed chunk output");
    ChunkOutput out;
    out.plan = r.get<uint32_t>();
    out.records.resize(r.getCount(kRecordSize));
    for (NodeRecord& rec : out.records) {
        uint8_t b[kRecordSize];
        r.getBytes(b, kRecordSize);
        rec = decodeRecord(b);
    }
    out.blocksBytes = r.get<uint64_t>();
    for (uint64_t& ns : out.stepNs) ns = r.get<uint64_t>();
    out.fits.groups = r.get<uint64_t>();
    out.fits.unknowns = r.get<uint64_t>();
    out.fits.samples = r.get<uint64_t>();
    out.fits.iterations = r.get<uint64_t>();
    out.fits.maxIterations = r.get<int32_t>();
    out.fits.maxResidual = r.get<double>();
    out.removedOutliers = r.get<uint64_t>();
    if (r.get<uint8_t>()) {
        out.root = std::make_unique<BuiltNode>();
        BuiltNode& root = *out.root;
        root.key.level = r.get<uint8_t>();
        root.key.x = r.get<uint32_t>();
        root.key.y = r.get<uint32_t>();
        root.key.z = r.get<uint32_t>();
        root.surfels.resize(r.getCount(sizeof(Surfel)));
        for (Surfel& s : root.surfels) r.getBytes(&s, sizeof s);
        out.rootScalars = empty;
        out.rootScalars.values.resize(r.getCount(4));
        for (uint32_t& v : out.rootScalars.values) v = r.get<uint32_t>();
        if (out.rootScalars.values.size() != root.surfels.size() * empty.fields()) return corrupt;
        for (size_t i = 0; i < root.surfels.size(); ++i)
            if (root.surfels[i].row != i) return corrupt;
        if (root.key.level > kMaxLevel) return corrupt;
    }
    for (const NodeRecord& rec : out.records)
        if (rec.blockOffset > out.blocksBytes || rec.blockSize > out.blocksBytes - rec.blockOffset) return corrupt;
    if (!r.ok() || r.left() != 0) return corrupt;
    return out;
}

}  // namespace surfcast
