#include "tileset_writer.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>

#include "byte_io.h"
#include "crc32.h"
#include "folder_publish.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// The blobs as nodes arrive, before finish() lays them out in hierarchy order.
constexpr char kUnorderedBlocks[] = "blocks.unordered";

}  // namespace

Result<std::unique_ptr<TilesetWriter>> TilesetWriter::create(const std::string& output) {
    // A Surfcast set has a hierarchy.bin beside its tileset.json; a 3D Tiles
    // export (surfcast-export) has a tileset.json alone, and is not replaced.
    auto folder = PublishedFolder::create(output, "tileset.json", [](const std::string& out) {
        std::error_code ec;
        return fs::exists(fs::path(out) / "tileset.json", ec) && fs::exists(fs::path(out) / "hierarchy.bin", ec);
    }, "a tile set");
    if (!folder) return folder.status();
    std::unique_ptr<TilesetWriter> w(new TilesetWriter);
    w->folder_ = std::move(*folder);
    w->partial_ = w->folder_->path();
    w->blocks_ = std::fopen((w->partial_ + "/" + kUnorderedBlocks).c_str(), "w+b");
    if (!w->blocks_) return Status::error(w->partial_ + "/" + kUnorderedBlocks + ": cannot create");
    return w;
}

TilesetWriter::~TilesetWriter() {
    if (blocks_) std::fclose(blocks_);
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
    SC_TRY(writeFileSynced(partial_ + "/hierarchy.bin", hierarchy.data(), hierarchy.size()));
    std::string json = writeTilesetJson(info);
    SC_TRY(writeFileSynced(partial_ + "/tileset.json", json.data(), json.size()));
    return folder_->publish();
}

}  // namespace surfcast
