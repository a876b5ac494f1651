// libFuzzer target: a tile set as a reader receives it. The input is
// tileset.json, a 0 byte, then hierarchy.bin (tileset.json's hierarchy_bytes
// of it, or what is left), then the first bytes of blocks.bin (the rest).
//  1. The whole file at once, as local readers and the server check it
//     (readHierarchy, readHierarchyOf), every node's block expectation.
//  2. Page by page, as the streaming clients fetch it: the header and page
//     table from their own bytes, each page from its own range, its root from
//     the proxy that points to it. The table's and the pages' CRCs are
//     recomputed first, so that mutations reach the checks behind them.
//  3. Each block those pages admit that lies within the bytes given, decoded
//     against its record and turned into surfels (appendNode), as the
//     streamer does (block CRCs skipped for the same reason).
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "block_codec.h"
#include "byte_io.h"
#include "crc32.h"
#include "surfel_set.h"
#include "tileset_format.h"
#include "tileset_reader.h"

using namespace surfcast;

namespace {

constexpr size_t kMaxBlocksDecoded = 16;  // per input: bounds a run's time

void streamPages(const TilesetInfo& info, std::vector<uint8_t> hierarchy, std::span<const uint8_t> blocks) {
    if (hierarchy.size() < kHierarchyHeaderSize) return;
    const uint64_t pageCount = le::get<uint32_t>(hierarchy.data() + 12);
    const uint64_t tableEnd = kHierarchyHeaderSize + pageCount * kPageEntrySize;
    if (tableEnd > hierarchy.size()) return;
    for (uint64_t p = 0; p < pageCount; ++p) {  // each page's CRC, where its records lie in the bytes given
        uint8_t* entry = hierarchy.data() + kHierarchyHeaderSize + p * kPageEntrySize;
        const uint64_t offset = le::get<uint64_t>(entry), bytes = uint64_t(le::get<uint32_t>(entry + 8)) * kRecordSize;
        if (offset <= hierarchy.size() && bytes <= hierarchy.size() - offset)
            le::put<uint32_t>(entry + 12, crc32(hierarchy.data() + offset, bytes));
    }
    le::put<uint32_t>(hierarchy.data() + 24, crc32(hierarchy.data() + kHierarchyHeaderSize, tableEnd - kHierarchyHeaderSize));
    // The header and table alone, as StreamingSet::open fetches them.
    auto index = readHierarchyIndex(std::span(hierarchy).first(tableEnd), info.hierarchyBytes, "hierarchy.bin");
    if (!index) return;
    std::map<uint32_t, NodeKey> roots = {{0, NodeKey{}}};  // page -> the key of the proxy pointing to it
    SurfelSet set = emptySurfelSet(info);
    size_t decoded = 0;
    for (const auto& [page, root] : roots) {  // readHierarchyPage admits links to later pages only
        if (page >= index->pages.size()) break;
        const HierarchyPageEntry& e = index->pages[page];
        if (e.offset > hierarchy.size() || uint64_t(e.records) * kRecordSize > hierarchy.size() - e.offset) continue;
        auto records = readHierarchyPage(*index, page, std::span(hierarchy).subspan(e.offset, size_t(e.records) * kRecordSize),
                                         root, info.blocksBytes, "hierarchy.bin");
        if (!records) continue;
        for (const NodeRecord& r : *records) {
            if (r.flags & kFlagChildrenInPage) roots.emplace(r.childPage, r.key);
            if (decoded == kMaxBlocksDecoded || r.blockOffset > blocks.size() || r.blockSize > blocks.size() - r.blockOffset)
                continue;
            ++decoded;
            auto block = decodeBlock(blocks.data() + r.blockOffset, r.blockSize, blockExpectation(info, r));
            if (block) appendNode(set, info, r, *block);
        }
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const uint8_t* split = static_cast<const uint8_t*>(std::memchr(data, 0, size));
    const size_t jsonSize = split ? size_t(split - data) : size;
    auto info = readTilesetJson(std::string(reinterpret_cast<const char*>(data), jsonSize), "tileset.json");
    if (!info || !split) return 0;
    const size_t rest = size - jsonSize - 1;
    const size_t hierarchySize = size_t(std::min<uint64_t>(info->hierarchyBytes, rest));
    std::vector<uint8_t> hierarchy(split + 1, split + 1 + hierarchySize);
    (void)readHierarchy(hierarchy, "hierarchy.bin");
    auto nodes = readHierarchyOf(*info, hierarchy, "hierarchy.bin");
    if (nodes)
        for (const NodeRecord& n : *nodes) (void)blockExpectation(*info, n);
    streamPages(*info, std::move(hierarchy), std::span(split + 1 + hierarchySize, rest - hierarchySize));
    return 0;
}
