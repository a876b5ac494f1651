#include "tileset_writer.h"

#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>

#include "byte_io.h"
#include "crc32.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// The blobs as nodes arrive, before finish() lays them out in hierarchy order.
constexpr char kUnorderedBlocks[] = "blocks.unordered";

Status writeFileSynced(const fs::path& path, const void* data, size_t size) {
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0) return Status::error(path.string() + ": cannot create (" + std::strerror(errno) + ")");
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        ssize_t w = ::write(fd, p, size);
        if (w < 0) {
            if (errno == EINTR) continue;
            ::close(fd);
            return Status::error(path.string() + ": write failed (" + std::strerror(errno) + ")");
        }
        p += w;
        size -= size_t(w);
    }
    bool ok = ::fsync(fd) == 0;
    ok = ::close(fd) == 0 && ok;
    if (!ok) return Status::error(path.string() + ": could not be flushed to disk");
    return {};
}

// Removes the hidden folders that writers into `out` left when they were
// killed (".NAME.partial-PID", ".NAME.partial-PID-work" and
// ".NAME.old-PID" of a process that no longer runs). An old set that the non-exchanging fallback had moved aside
// goes back into place if nothing took its place.
void removeLeftovers(const fs::path& out) {
    const std::string name = out.filename().string();
    std::error_code ec;
    std::vector<std::pair<fs::path, bool>> stale;  // path, is an old set
    for (const auto& entry : fs::directory_iterator(out.parent_path(), ec))
        for (const char* kind : {".partial-", ".old-"}) {
            const std::string prefix = "." + name + kind, file = entry.path().filename().string();
            if (file.rfind(prefix, 0) != 0) continue;
            char* end = nullptr;
            const long pid = std::strtol(file.c_str() + prefix.size(), &end, 10);
            // ".NAME.partial-PID" and what the process keeps beside it (the
            // build's ".NAME.partial-PID-work").
            if ((*end != '\0' && *end != '-') || pid <= 0 || pid == ::getpid()) continue;
            if (::kill(pid_t(pid), 0) == 0 || errno != ESRCH) continue;  // still running (or not ours to judge)
            stale.push_back({entry.path(), kind[1] == 'o' && *end == '\0'});
        }
    for (const auto& [path, old] : stale) {
        if (old && !fs::exists(out, ec) && fs::exists(path / "tileset.json", ec)) {
            fs::rename(path, out, ec);
            if (!ec) continue;
        }
        fs::remove_all(path, ec);
    }
}

}  // namespace

Result<std::unique_ptr<TilesetWriter>> TilesetWriter::create(const std::string& output) {
    fs::path out = fs::absolute(output).lexically_normal();
    if (out.filename().empty()) out = out.parent_path();
    std::error_code ec;
    if (fs::is_directory(out.parent_path(), ec)) removeLeftovers(out);
    if (fs::exists(out, ec) && !(fs::is_directory(out) && (fs::is_empty(out) || fs::exists(out / "tileset.json"))))
        return Status::error(out.string() + ": exists and is not a tile set; refusing to replace it");
    fs::create_directories(out.parent_path(), ec);
    std::unique_ptr<TilesetWriter> w(new TilesetWriter);
    w->output_ = out.string();
    w->partial_ = (out.parent_path() / ("." + out.filename().string() + ".partial-" + std::to_string(::getpid()))).string();
    fs::remove_all(w->partial_, ec);
    if (!fs::create_directory(w->partial_, ec))
        return Status::error(w->partial_ + ": cannot create (" + ec.message() + ")");
    w->blocks_ = std::fopen((w->partial_ + "/" + kUnorderedBlocks).c_str(), "w+b");
    if (!w->blocks_) return Status::error(w->partial_ + "/" + kUnorderedBlocks + ": cannot create");
    return w;
}

TilesetWriter::~TilesetWriter() {
    if (blocks_) std::fclose(blocks_);
    if (!finished_) {
        std::error_code ec;
        fs::remove_all(partial_, ec);
    }
}

Status TilesetWriter::addNode(NodeRecord record, const std::vector<uint8_t>& blob) {
    uint32_t crc = crc32(blob.data(), blob.size());
    std::lock_guard lock(mutex_);
    if (std::fwrite(blob.data(), 1, blob.size(), blocks_) != blob.size())
        return Status::error(partial_ + "/" + kUnorderedBlocks + ": write failed (disk full?)");
    record.blockOffset = ownBytes_;
    record.blockSize = uint32_t(blob.size());
    record.blockCrc = crc;
    ownBytes_ += blob.size();
    blocksBytes_ += blob.size();
    records_.push_back(record);
    sources_.push_back(kOwnBlocks);
    return {};
}

Status TilesetWriter::addPlacedNodes(const std::string& blocks, uint64_t bytes, const std::vector<NodeRecord>& records) {
    std::error_code ec;
    const uintmax_t size = fs::file_size(blocks, ec);
    if (ec || size != bytes)
        return Status::error(blocks + ": " + (ec ? "cannot read (" + ec.message() + ")" : "holds " + std::to_string(size) + " bytes, not " + std::to_string(bytes)));
    std::lock_guard lock(mutex_);
    placed_.push_back(blocks);
    for (const NodeRecord& r : records) {
        records_.push_back(r);
        sources_.push_back(uint32_t(placed_.size() - 1));
        blocksBytes_ += r.blockSize;
    }
    return {};
}

Status TilesetWriter::finish(TilesetInfo& info) {
    // blocks.bin: the blobs copied in hierarchy order from where they arrived
    // (addNode's file, or addPlacedNodes' files).
    if (std::fflush(blocks_) != 0) return Status::error(partial_ + "/" + kUnorderedBlocks + ": write failed (disk full?)");
    std::map<NodeKey, size_t> index;
    for (size_t i = 0; i < records_.size(); ++i) index[records_[i].key] = i;
    const fs::path ordered = fs::path(partial_) / "blocks.bin";
    std::FILE* out = std::fopen(ordered.c_str(), "wb");
    if (!out) return Status::error(ordered.string() + ": cannot create (" + std::strerror(errno) + ")");
    // Placed blobs are read from their files, a few open at a time.
    std::map<uint32_t, int> open;
    auto closeAll = [&] {
        for (auto [source, fd] : open) ::close(fd);
        open.clear();
    };
    std::vector<uint8_t> blob;
    uint64_t offset = 0;
    bool ok = true;
    Status failed;
    for (const NodeKey& key : hierarchyOrder(records_, info.pageDepth)) {
        const size_t i = index.at(key);
        NodeRecord& r = records_[i];
        blob.resize(r.blockSize);
        int fd = ::fileno(blocks_);
        if (sources_[i] != kOwnBlocks) {
            auto it = open.find(sources_[i]);
            if (it == open.end()) {
                if (open.size() >= 64) closeAll();
                const int opened = ::open(placed_[sources_[i]].c_str(), O_RDONLY | O_CLOEXEC);
                if (opened < 0) {
                    failed = Status::error(placed_[sources_[i]] + ": cannot open (" + std::strerror(errno) + ")");
                    break;
                }
                it = open.emplace(sources_[i], opened).first;
            }
            fd = it->second;
        }
        if (::pread(fd, blob.data(), blob.size(), off_t(r.blockOffset)) != ssize_t(blob.size())) {
            const std::string from = sources_[i] == kOwnBlocks ? partial_ + "/" + kUnorderedBlocks : placed_[sources_[i]];
            failed = Status::error(from + ": cannot read the block of node " + key.name() + " at byte " + std::to_string(r.blockOffset));
            break;
        }
        if (sources_[i] != kOwnBlocks && crc32(blob.data(), blob.size()) != r.blockCrc) {
            failed = Status::error(placed_[sources_[i]] + ": the block of node " + key.name() + " at byte " +
                                   std::to_string(r.blockOffset) + " fails its CRC (corrupt)");
            break;
        }
        ok = std::fwrite(blob.data(), 1, blob.size(), out) == blob.size();
        if (!ok) break;
        r.blockOffset = offset;
        offset += r.blockSize;
    }
    closeAll();
    if (!failed.ok()) {
        std::fclose(out);
        return failed;
    }
    ok = ok && std::fflush(out) == 0 && ::fsync(::fileno(out)) == 0;
    ok = std::fclose(out) == 0 && ok;
    std::fclose(blocks_);
    blocks_ = nullptr;
    if (!ok) return Status::error(ordered.string() + ": could not be written and flushed to disk (disk full?)");
    std::error_code ec;
    fs::remove(fs::path(partial_) / kUnorderedBlocks, ec);

    std::vector<uint8_t> hierarchy = writeHierarchy(records_, info.pageDepth);
    info.nodes = records_.size();
    info.hierarchyBytes = hierarchy.size();
    info.hierarchyCrc = crc32(hierarchy.data(), hierarchy.size());
    info.hierarchyPages = le::get<uint32_t>(hierarchy.data() + 12);  // page count, header byte 12
    info.blocksBytes = blocksBytes_;
    SC_TRY(writeFileSynced(fs::path(partial_) / "hierarchy.bin", hierarchy.data(), hierarchy.size()));
    std::string json = writeTilesetJson(info);
    SC_TRY(writeFileSynced(fs::path(partial_) / "tileset.json", json.data(), json.size()));

    // Exchange the folders in one step where the file system can; else move
    // the old set (if any) aside and the new one in.
    if (::renameat2(AT_FDCWD, partial_.c_str(), AT_FDCWD, output_.c_str(), RENAME_EXCHANGE) == 0) {
        finished_ = true;
        // Now the old set: it stops reading as one first, then goes.
        fs::remove(fs::path(partial_) / "tileset.json", ec);
        fs::remove_all(partial_, ec);
        return {};
    }
    fs::path old = fs::path(partial_).parent_path() / ("." + fs::path(output_).filename().string() + ".old-" + std::to_string(::getpid()));
    bool hadOld = fs::exists(output_, ec);
    if (hadOld) {
        fs::rename(output_, old, ec);
        if (ec) return Status::error(output_ + ": cannot move the previous tile set aside (" + ec.message() + ")");
    }
    fs::rename(partial_, output_, ec);
    if (ec) {
        if (hadOld) fs::rename(old, output_, ec);
        return Status::error(output_ + ": cannot move the new tile set into place");
    }
    finished_ = true;
    if (hadOld) fs::remove_all(old, ec);
    return {};
}

}  // namespace surfcast
