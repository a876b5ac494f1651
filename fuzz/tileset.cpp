// libFuzzer target: a tile set's metadata as a reader receives it. The input
// is tileset.json, then (after the first 0 byte, if any) hierarchy.bin, checked
// against each other with the one function every reader calls
// (readHierarchyOf); a set that passes is then checked node by node as the
// streamer does (blockExpectation).
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "tileset_format.h"
#include "tileset_reader.h"

using namespace surfcast;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const uint8_t* split = static_cast<const uint8_t*>(std::memchr(data, 0, size));
    const size_t jsonSize = split ? size_t(split - data) : size;
    auto info = readTilesetJson(std::string(reinterpret_cast<const char*>(data), jsonSize), "tileset.json");
    if (!info || !split) return 0;
    std::vector<uint8_t> hierarchy(split + 1, data + size);
    (void)readHierarchy(hierarchy, "hierarchy.bin");
    auto nodes = readHierarchyOf(*info, hierarchy, "hierarchy.bin");
    if (!nodes) return 0;
    for (const NodeRecord& n : *nodes) (void)blockExpectation(*info, n);
    return 0;
}
