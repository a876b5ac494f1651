// surfcast-decode-bench: how long a set's blocks take to decode, as a client
// decodes them (decodeBlock, scalar attributes skipped), for
// bench/block_coding.py. Every block is read first; then all are decoded
// REPEATS times (default 3) and the fastest pass counts.
// Usage: surfcast-decode-bench SET [REPEATS]. Prints one JSON line.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "tileset_reader.h"

int main(int argc, char** argv) {
    using namespace surfcast;
    if (argc < 2 || argc > 3) {
        std::fprintf(stderr, "usage: surfcast-decode-bench SET [REPEATS]\n");
        return 2;
    }
    const int repeats = argc == 3 ? std::max(1, std::atoi(argv[2])) : 3;
    auto reader = TilesetReader::open(argv[1]);
    if (!reader) {
        std::fprintf(stderr, "surfcast-decode-bench: %s\n", reader.status().message().c_str());
        return 1;
    }
    const std::vector<NodeRecord>& nodes = reader->nodes();
    auto blobs = reader->readBlocksBytes(nodes);
    if (!blobs) {
        std::fprintf(stderr, "surfcast-decode-bench: %s\n", blobs.status().message().c_str());
        return 1;
    }
    uint64_t surfels = 0;
    double best = 1e30;
    for (int r = 0; r < repeats; ++r) {
        const auto start = std::chrono::steady_clock::now();
        surfels = 0;
        for (size_t i = 0; i < nodes.size(); ++i) {
            const std::vector<uint8_t>& b = (*blobs)[i];
            auto block = decodeBlock(b.data(), b.size(), blockExpectation(reader->info(), nodes[i]));
            if (!block) {
                std::fprintf(stderr, "surfcast-decode-bench: node %s: %s\n", nodes[i].key.name().c_str(), block.status().message().c_str());
                return 1;
            }
            surfels += block->size();
        }
        best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
    std::printf("{\"surfels\": %llu, \"blocks\": %zu, \"seconds\": %.4f, \"ns_per_surfel\": %.1f}\n", (unsigned long long)surfels,
                nodes.size(), best, 1e9 * best / double(surfels));
    return 0;
}
