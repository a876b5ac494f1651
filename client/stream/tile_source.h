// Where a tile set's bytes come from: a local folder, or an HTTP folder URL
// (the project's server at http://HOST:PORT/sets/NAME, or any static host that
// honours Range). The only HTTP client code of the client library.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "status.h"
#include "tileset_format.h"

namespace surfcast {

class TileSource {
public:
    virtual ~TileSource() = default;
    // A whole file of the set: "tileset.json" or "hierarchy.bin". A file
    // longer than maxBytes is an error, found before more is read or kept.
    virtual Result<std::vector<uint8_t>> file(const std::string& name, uint64_t maxBytes) = 0;
    // Bytes [offset, offset + size) of blocks.bin; never more is kept. Thread-safe.
    virtual Result<std::vector<uint8_t>> blocks(uint64_t offset, uint64_t size) = 0;
    // Several nodes' blobs, in order: one request where the source batches
    // (the project's server), else one range each. All or nothing. Thread-safe.
    virtual Result<std::vector<std::vector<uint8_t>>> blobs(const std::vector<NodeRecord>& nodes);
    virtual std::string describe() const = 0;
};

// "http://..." opens an HTTP source (keep-alive, one connection per calling
// thread; a response that stalls for `timeoutSeconds` fails); anything else
// is a local folder.
Result<std::unique_ptr<TileSource>> openTileSource(const std::string& location, int timeoutSeconds = 20);
bool isUrl(const std::string& location);

}  // namespace surfcast
