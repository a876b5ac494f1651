#include "tileset_writer.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "byte_io.h"
#include "crc32.h"
#include "folder_publish.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// The blobs as nodes arrive, before finish() lays them out in hierarchy order.
constexpr char kUnorderedBlocks[] = "blocks.unordered";

}  // namespace

Result<std::unique_ptr<TilesetWriter>> TilesetWriter::create(const std::string& output, const std::string& tag) {
    // A Surfcast set has a hierarchy.bin beside its tileset.json; a 3D Tiles
    // export (surfcast-export) has a tileset.json alone, and is not replaced.
    auto folder = PublishedFolder::create(output, "tileset.json", [](const std::string& out) {
        std::error_code ec;
        if (!fs::exists(fs::path(out) / "tileset.json", ec)) return false;
        for (const auto& e : fs::directory_iterator(out, ec))  // hierarchy.bin, or an updated set's hierarchy-XXXXXXXX.bin
            if (validHierarchyFile(e.path().filename().string())) return true;
        return false;
    }, "a tile set", tag);
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
    std::error_code ec;
    if (!set_.empty()) fs::remove_all(partial_, ec);  // an update's own folder (a new set's: PublishedFolder's)
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

Status TilesetWriter::addKeptNodes(const std::vector<NodeRecord>& records) {
    std::lock_guard lock(mutex_);
    for (const NodeRecord& r : records) {
        if (set_.empty() || r.blockOffset > current_.blocksBytes || r.blockSize > current_.blocksBytes - r.blockOffset)
            return Status::error("node " + r.key.name() + ": kept, but its block is not in the set's block files");
        records_.push_back(r);
        sources_.push_back(kKept);
        blocksBytes_ += r.blockSize;
    }
    return {};
}

Status TilesetWriter::keepCurrentNodes(const std::vector<NodeRecord>& built) {
    std::vector<NodeRecord> records;
    for (const NodeRecord& b : built) {
        auto it = currentNodes_.find(b.key);
        if (it == currentNodes_.end() || it->second.childMask != b.childMask || it->second.surfelCount != b.surfelCount)
            return Status::error("node " + b.key.name() + ": kept, but the set has no node of its key, children and surfel count");
        records.push_back(it->second);
    }
    return addKeptNodes(records);
}

Result<std::unique_ptr<TilesetWriter>> TilesetWriter::update(const std::string& set, const TilesetInfo& current,
                                                            const std::vector<NodeRecord>& currentNodes, CurrentBlobs currentBlobs) {
    std::unique_ptr<TilesetWriter> w(new TilesetWriter);
    w->set_ = set;
    w->current_ = current;
    w->currentBlobs_ = std::move(currentBlobs);
    for (const NodeRecord& r : currentNodes) w->currentNodes_[r.key] = r;
    // A hidden folder inside the set for the new blobs and the build's work
    // (readers and surfcast-serve never open it); a killed update's is
    // cleared by the next one.
    w->partial_ = set + "/.update-" + std::to_string(::getpid());
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(set, ec))
        if (e.path().filename().string().rfind(".update-", 0) == 0) fs::remove_all(e.path(), ec);
    fs::create_directories(w->partial_, ec);
    if (ec) return Status::error(w->partial_ + ": cannot create (" + ec.message() + ")");
    w->blocks_ = std::fopen((w->partial_ + "/" + kUnorderedBlocks).c_str(), "w+b");
    if (!w->blocks_) return Status::error(w->partial_ + "/" + kUnorderedBlocks + ": cannot create");
    return w;
}

Status TilesetWriter::readBlob(size_t i, std::map<uint32_t, int>& open, std::vector<uint8_t>& blob) {
    const NodeRecord& r = records_[i];
    blob.resize(r.blockSize);
    int fd = ::fileno(blocks_);
    if (sources_[i] != kOwnBlocks) {
        auto it = open.find(sources_[i]);
        if (it == open.end()) {
            if (open.size() >= 64) {
                for (auto [source, opened] : open) ::close(opened);
                open.clear();
            }
            const int opened = ::open(placed_[sources_[i]].c_str(), O_RDONLY | O_CLOEXEC);
            if (opened < 0) return Status::error(placed_[sources_[i]] + ": cannot open (" + std::strerror(errno) + ")");
            it = open.emplace(sources_[i], opened).first;
        }
        fd = it->second;
    }
    const std::string from = sources_[i] == kOwnBlocks ? partial_ + "/" + kUnorderedBlocks : placed_[sources_[i]];
    if (::pread(fd, blob.data(), blob.size(), off_t(r.blockOffset)) != ssize_t(blob.size()))
        return Status::error(from + ": cannot read the block of node " + r.key.name() + " at byte " + std::to_string(r.blockOffset));
    if (sources_[i] != kOwnBlocks && crc32(blob.data(), blob.size()) != r.blockCrc)
        return Status::error(from + ": the block of node " + r.key.name() + " at byte " + std::to_string(r.blockOffset) +
                             " fails its CRC (corrupt)");
    return {};
}

Status TilesetWriter::finish(TilesetInfo& info) {
    if (std::fflush(blocks_) != 0) return Status::error(partial_ + "/" + kUnorderedBlocks + ": write failed (disk full?)");
    if (!set_.empty()) return finishUpdate(info);
    // blocks.bin: the blobs copied in hierarchy order from where they arrived
    // (addNode's file, or addPlacedNodes' files).
    std::map<NodeKey, size_t> index;
    for (size_t i = 0; i < records_.size(); ++i) index[records_[i].key] = i;
    const fs::path ordered = fs::path(partial_) / "blocks.bin";
    std::FILE* out = std::fopen(ordered.c_str(), "wb");
    if (!out) return Status::error(ordered.string() + ": cannot create (" + std::strerror(errno) + ")");
    std::map<uint32_t, int> open;  // placed blobs' files, a few open at a time
    std::vector<uint8_t> blob;
    uint64_t offset = 0;
    bool ok = true;
    Status failed;
    for (const NodeKey& key : hierarchyOrder(records_, info.pageDepth)) {
        const size_t i = index.at(key);
        failed = readBlob(i, open, blob);
        if (!failed.ok()) break;
        ok = std::fwrite(blob.data(), 1, blob.size(), out) == blob.size();
        if (!ok) break;
        records_[i].blockOffset = offset;
        offset += records_[i].blockSize;
    }
    for (auto [source, fd] : open) ::close(fd);
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
    info.hierarchyFile = "hierarchy.bin";
    info.nodes = records_.size();
    info.hierarchyBytes = hierarchy.size();
    info.hierarchyCrc = crc32(hierarchy.data(), hierarchy.size());
    info.hierarchyPages = le::get<uint32_t>(hierarchy.data() + 12);  // page count, header byte 12
    info.blocksBytes = blocksBytes_;
    info.blocksParts.clear();  // a new set: blocks.bin alone
    SC_TRY(writeFileSynced(partial_ + "/hierarchy.bin", hierarchy.data(), hierarchy.size()));
    if (!record_.empty()) {
        fs::rename(record_, fs::path(partial_) / buildRecordFile(info.hierarchyFile), ec);
        if (ec) return Status::error(record_ + ": cannot move into the set (" + ec.message() + ")");
    }
    std::string json = writeTilesetJson(info);
    SC_TRY(writeFileSynced(partial_ + "/tileset.json", json.data(), json.size()));
    return folder_->publish();
}

namespace {

// Writes `bytes` beside `path`, flushes, and renames it into place.
Status replaceFile(const std::string& path, const void* data, size_t size) {
    const std::string partial = path + ".partial";
    SC_TRY(writeFileSynced(partial, data, size));
    if (::rename(partial.c_str(), path.c_str()) != 0) return Status::error(path + ": cannot rename into place (" + std::strerror(errno) + ")");
    return {};
}

// Whether the set in folder `set` is still the version `current` that an
// update read at its start (its tileset.json names the same hierarchy and
// blocks.bin bytes): what another writer put there since must stay whole.
Status sameVersion(const std::string& set, const TilesetInfo& current) {
    const std::string path = set + "/tileset.json";
    std::ifstream in(path, std::ios::binary);
    if (!in) return Status::error(set + ": its tileset.json is gone since this update read the set; run the update again");
    auto now = readTilesetJson(std::string{std::istreambuf_iterator<char>(in), {}}, path);
    if (!now) return now.status();
    if (now->hierarchyFile != current.hierarchyFile || now->hierarchyCrc != current.hierarchyCrc ||
        now->hierarchyBytes != current.hierarchyBytes || now->blocksBytes != current.blocksBytes)
        return Status::error(set + ": changed since this update read it (another build, update or compaction wrote it); the update "
                             "stops before writing, leaving the set as that one wrote it: run the update again");
    return {};
}

Status syncFolder(const std::string& dir) {
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    const bool ok = fd >= 0 && ::fsync(fd) == 0;
    if (fd >= 0) ::close(fd);
    return ok ? Status{} : Status::error(dir + ": cannot flush the folder (" + std::strerror(errno) + ")");
}

}  // namespace

Status TilesetWriter::finishUpdate(TilesetInfo& info) {
    // The set must be the version the update read: its files are the ones
    // the kept nodes point into.
    SC_TRY(sameVersion(set_, current_));
    // The new blobs, in hierarchy order, into a file of their own: the next
    // part of the blocks' space after the current set's last byte. No file
    // of the set is written to (a static host or store keeps each file's
    // ETag), as an object store wants.
    const std::vector<BlocksPart> currentParts = blocksPartsOf(current_);
    const std::string newPath = partial_ + "/blocks.new";
    const int out = ::open(newPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (out < 0) return Status::error(newPath + ": cannot create (" + std::strerror(errno) + ")");
    struct Closer {
        int fd;
        ~Closer() { ::close(fd); }
    } closer{out};
    std::map<NodeKey, size_t> index;
    for (size_t i = 0; i < records_.size(); ++i) index[records_[i].key] = i;
    std::map<uint32_t, int> open;
    struct CloseAll {
        std::map<uint32_t, int>& fds;
        ~CloseAll() {
            for (auto [source, fd] : fds) ::close(fd);
        }
    } closeAll{open};
    std::vector<uint8_t> blob;
    // Built again to the same bytes: it keeps its place (and its ETag). The
    // current blobs of the same size and CRC are read in batches of about
    // 64 MiB (from a store, all of a batch at once) and compared. One that
    // cannot be read fails the update (written anew, its bytes would differ
    // from the same update's where it could).
    const std::vector<NodeKey> order = hierarchyOrder(records_, info.pageDepth);
    std::vector<bool> same(records_.size(), false);
    std::vector<size_t> batch;
    std::vector<NodeRecord> was;
    uint64_t batchBytes = 0;
    auto compare = [&]() -> Status {
        if (batch.empty()) return {};
        auto current = currentBlobs_(was);
        if (!current) return Status::error(set_ + ": reading the blocks built again to compare them: " + current.status().message());
        for (size_t k = 0; k < batch.size(); ++k) {
            SC_TRY(readBlob(batch[k], open, blob));
            same[batch[k]] = (*current)[k] == blob;
        }
        batch.clear();
        was.clear();
        batchBytes = 0;
        return {};
    };
    for (const NodeKey& key : order) {
        const size_t i = index.at(key);
        auto it = currentNodes_.find(key);
        if (sources_[i] == kKept || it == currentNodes_.end() || it->second.blockSize != records_[i].blockSize ||
            it->second.blockCrc != records_[i].blockCrc)
            continue;
        batch.push_back(i);
        was.push_back(it->second);
        if ((batchBytes += records_[i].blockSize) >= (64u << 20)) SC_TRY(compare());
    }
    SC_TRY(compare());
    uint64_t offset = current_.blocksBytes;
    uint32_t crc = 0;
    Status failed;
    for (const NodeKey& key : order) {
        const size_t i = index.at(key);
        if (sources_[i] == kKept) continue;
        if (same[i]) {
            records_[i].blockOffset = currentNodes_.at(key).blockOffset;
            continue;
        }
        failed = readBlob(i, open, blob);
        if (!failed.ok()) break;
        if (::write(out, blob.data(), blob.size()) != ssize_t(blob.size())) {
            failed = Status::error(newPath + ": write failed (disk full?)");
            break;
        }
        crc = crc32(blob.data(), blob.size(), crc);
        records_[i].blockOffset = offset;
        offset += records_[i].blockSize;
    }
    SC_TRY(failed);
    if (::fsync(out) != 0) return Status::error(newPath + ": cannot flush to disk (" + std::strerror(errno) + ")");
    std::fclose(blocks_);
    blocks_ = nullptr;
    info.blocksParts = current_.blocksParts;
    if (offset > current_.blocksBytes) {
        const std::string name = versionedBlocksFile(crc);
        for (const BlocksPart& p : currentParts)
            if (p.file == name)
                return Status::error(set_ + "/" + name + ": the new blocks' CRC-32 names a file the set holds already; "
                                     "compact the set (--compact) and update it again");
        if (::rename(newPath.c_str(), (set_ + "/" + name).c_str()) != 0)
            return Status::error(set_ + "/" + name + ": cannot move into the set (" + std::strerror(errno) + ")");
        info.blocksParts = currentParts;
        info.blocksParts.push_back({name, offset - current_.blocksBytes});
    }

    std::vector<uint8_t> hierarchy = writeHierarchy(records_, info.pageDepth);
    info.nodes = records_.size();
    info.hierarchyBytes = hierarchy.size();
    info.hierarchyCrc = crc32(hierarchy.data(), hierarchy.size());
    info.hierarchyPages = le::get<uint32_t>(hierarchy.data() + 12);  // page count, header byte 12
    info.hierarchyFile = versionedHierarchyFile(info.hierarchyCrc);
    info.blocksBytes = offset;
    SC_TRY(replaceFile(set_ + "/" + info.hierarchyFile, hierarchy.data(), hierarchy.size()));
    std::error_code ec;
    if (!record_.empty()) {
        fs::rename(record_, fs::path(set_) / buildRecordFile(info.hierarchyFile), ec);
        if (ec) return Status::error(record_ + ": cannot move into the set (" + ec.message() + ")");
    }
    SC_TRY(syncFolder(set_));
    // The switch: one rename.
    const std::string json = writeTilesetJson(info);
    SC_TRY(replaceFile(set_ + "/tileset.json", json.data(), json.size()));
    SC_TRY(syncFolder(set_));
    // The previous version stays for readers that opened it; older ones go.
    std::set<std::string> keep = {"blocks.bin"};
    for (const TilesetInfo* version : {&info, &current_})
        for (const std::string& file : versionFiles(*version)) keep.insert(file);
    for (const auto& e : fs::directory_iterator(set_, ec)) {
        const std::string name = e.path().filename().string();
        const bool versioned = versionFileName(name);
        const bool partial = name.size() > 8 && name.compare(name.size() - 8, 8, ".partial") == 0;  // a killed update's
        if ((versioned && !keep.count(name)) || partial) fs::remove(e.path(), ec);
    }
    fs::remove_all(partial_, ec);
    return {};
}

}  // namespace surfcast
