#include "compact.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <vector>

#include "crc32.h"
#include "folder_publish.h"
#include "http_tile_source.h"
#include "set_lock.h"
#include "object_store.h"
#include "set_publisher.h"
#include "tileset_reader.h"
#include "tileset_writer.h"

namespace surfcast {

namespace fs = std::filesystem;

namespace {

// Compacts the set `reader` reads, whose block files lie in folder `parts`
// (named as its tileset.json names them), into `writer`; `record`: its build
// record's path, or empty.
Status compactInto(const TilesetReader& reader, const std::string& parts, const std::string& record, TilesetWriter& writer,
                   CompactReport* report) {
    std::error_code ec;
    if (!record.empty()) {
        const std::string copy = writer.partialDir() + "/build.record";
        fs::copy_file(record, copy, ec);
        if (ec) return Status::error(record + ": cannot copy (" + ec.message() + ")");
        writer.setBuildRecord(copy);
    }
    // Each block file's nodes, placed where they lie in it.
    const BlocksLayout layout(blocksPartsOf(reader.info()));
    std::vector<std::vector<NodeRecord>> placed(layout.parts().size());
    for (NodeRecord n : reader.nodes()) {
        auto place = layout.place(n.blockOffset, n.blockSize);
        if (!place) return Status::error(reader.describe() + ": node " + n.key.name() + ": " + place.status().message());
        n.blockOffset = place->offset;
        placed[place->part].push_back(n);
    }
    for (size_t i = 0; i < placed.size(); ++i) {
        const std::string path = parts + "/" + layout.parts()[i].file;
        const uint64_t size = fs::file_size(path, ec);
        if (ec) return Status::error(path + ": " + ec.message());
        SC_TRY(writer.addPlacedNodes(path, size, placed[i]));
        report->before += size;
    }
    TilesetInfo info = reader.info();
    SC_TRY(writer.finish(info));
    report->blocksBytes = info.blocksBytes;
    return {};
}

Result<uint32_t> fileCrc(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<char> buffer(1 << 20);
    uint32_t crc = 0;
    while (in) {
        in.read(buffer.data(), std::streamsize(buffer.size()));
        crc = crc32(reinterpret_cast<const uint8_t*>(buffer.data()), size_t(in.gcount()), crc);
    }
    if (!in.eof()) return Status::error(path + ": cannot read");
    return crc;
}

}  // namespace

Result<CompactReport> compactFolder(const std::string& dir) {
    auto reader = TilesetReader::open(dir);
    if (!reader) return reader.status();
    auto writer = TilesetWriter::create(dir);
    if (!writer) return writer.status();
    const std::string record = dir + "/" + buildRecordFile(reader->info().hierarchyFile);
    CompactReport report;
    SC_TRY(compactInto(*reader, dir, fs::exists(record) ? record : "", **writer, &report));
    return report;
}

Result<CompactReport> compactStored(const std::string& url, const std::string& staging) {
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    const uint64_t requestsBefore = (*store)->counts().requests;
    const std::string mirror = staging + "/current", compacted = staging + "/compacted";
    std::error_code ec;
    fs::create_directories(mirror, ec);
    if (ec) return Status::error(mirror + ": cannot create (" + ec.message() + ")");
    auto base = mirrorSetMetadata(url, mirror);
    if (!base) return base.status();
    auto reader = openTileset(base->url);
    if (!reader) return reader.status();
    if (reader->info().hierarchyCrc != base->info.hierarchyCrc || versionFiles(reader->info()) != versionFiles(base->info))
        return Status::error(base->url + ": changed while the compaction read it (an update wrote it); run it again");
    CompactReport report;
    const std::vector<BlocksPart> parts = blocksPartsOf(base->info);
    uint64_t used = 0;
    for (const NodeRecord& n : reader->nodes()) used += n.blockSize;
    if (parts.size() == 1 && used == base->info.blocksBytes) {
        report.already = true;
        report.blocksBytes = report.before = used;
        return report;
    }
    auto prefix = parseS3Url(base->url);
    if (!prefix) return prefix.status();
    for (const BlocksPart& part : parts)
        SC_TRY((*store)->getToFile({prefix->bucket, prefix->key + part.file}, part.bytes, mirror + "/" + part.file, 64ull << 20));
    {
        auto writer = TilesetWriter::create(compacted);
        if (!writer) return writer.status();
        const std::string record = mirror + "/" + buildRecordFile(base->info.hierarchyFile);
        SC_TRY(compactInto(*reader, mirror, fs::exists(record) ? record : "", **writer, &report));
    }
    // Objects are never rewritten: the compacted blocks and hierarchy take
    // names of their own (their CRCs), which tileset.json gives.
    std::ifstream in(compacted + "/tileset.json", std::ios::binary);
    auto info = readTilesetJson(std::string{std::istreambuf_iterator<char>(in), {}}, compacted + "/tileset.json");
    if (!info) return info.status();
    auto crc = fileCrc(compacted + "/blocks.bin");
    if (!crc) return crc.status();
    const std::string blocks = versionedBlocksFile(*crc), hierarchy = versionedHierarchyFile(info->hierarchyCrc);
    for (const auto& [from, to] : {std::pair{std::string("blocks.bin"), blocks}, {info->hierarchyFile, hierarchy},
                                   {buildRecordFile(info->hierarchyFile), buildRecordFile(hierarchy)}}) {
        if (!fs::exists(compacted + "/" + from)) continue;  // (a set without a build record)
        fs::rename(compacted + "/" + from, compacted + "/" + to, ec);
        if (ec) return Status::error(compacted + "/" + from + ": cannot rename (" + ec.message() + ")");
    }
    info->hierarchyFile = hierarchy;
    info->blocksParts = {BlocksPart{blocks, info->blocksBytes}};
    const std::string json = writeTilesetJson(*info);
    SC_TRY(writeFileSynced(compacted + "/tileset.json", json.data(), json.size()));
    auto published = publishVersion(compacted, *base);
    if (!published) return published.status();
    if (!published->warning.empty()) std::fprintf(stderr, "surfcast-build: warning: %s\n", published->warning.c_str());
    report.removed = published->removed;
    report.requests = (*store)->counts().requests - requestsBefore;
    return report;
}

Result<CompactReport> compactSet(const std::string& set) {
    if (isS3Url(set)) {
        auto staging = PublishStaging::create();
        if (!staging) return staging.status();
        return compactStored(set, (*staging)->dir());
    }
    SetLock lock;
    SC_TRY(lockSet(set, &lock));
    return compactFolder(set);
}

}  // namespace surfcast
