// Where a tile set's bytes come from: a local folder here, or an http(s)
// folder URL through net/http_tile_source.h (libcurl), which the clients and
// surfcast-build link: common/ has no HTTP.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
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
    // Bytes [offset, offset + size) of a file of the set ("blocks.bin", or a
    // page of "hierarchy.bin"); never more is kept. Thread-safe.
    virtual Result<std::vector<uint8_t>> range(const std::string& name, uint64_t offset, uint64_t size) = 0;
    // The files the set's blocks lie in (tileset.json's, blocksPartsOf):
    // set once, by whoever reads tileset.json, before blocks() and blobs().
    void setBlocksLayout(BlocksLayout layout) { layout_ = std::move(layout); }
    const BlocksLayout& blocksLayout() const { return layout_; }
    // Bytes [offset, offset + size) of the blocks' space, from the part that holds them.
    Result<std::vector<uint8_t>> blocks(uint64_t offset, uint64_t size);
    // A whole file again unless it is unchanged since the last read through
    // this call, whose validator `tag` keeps (empty: never read): nullopt
    // then. The base reads the file and compares its CRC-32; an http(s)
    // source asks with If-None-Match and takes 304 as unchanged. Unlike
    // file(), it leaves what the source pinned at its tileset.json read
    // (batches' version) as it was: a follower polls with it.
    virtual Result<std::optional<std::vector<uint8_t>>> changedFile(const std::string& name, uint64_t maxBytes, std::string* tag);
    // changedFile's comparison by content: `bytes` unless they are what
    // `tag` names (nullopt then), `tag` naming them from now on.
    static std::optional<std::vector<uint8_t>> ifOtherBytes(std::vector<uint8_t> bytes, std::string* tag);
    // A file's size in bytes (an input read by ranges: preprocess/readers/input_file.h).
    virtual Result<uint64_t> size(const std::string& name) = 0;
    // Several nodes' blobs, in order: POST {set}/batch requests of up to N
    // keys where tileset.json's answer (file(), read first) offered
    // Surfcast-Batch: N without a redirect (surfcast-serve), else one range
    // each, all in flight at once. All or nothing. Thread-safe.
    virtual Result<std::vector<std::vector<uint8_t>>> blobs(const std::vector<NodeRecord>& nodes);
    virtual std::string describe() const = 0;
    // Ends every request in flight at once, with an error, and fails every
    // later one: so that a reader closes at once while its host stalls,
    // rather than after the timeout. Thread-safe; for shutting down.
    virtual void cancel() {}

private:
    BlocksLayout layout_{{BlocksPart{"blocks.bin", ~uint64_t(0)}}};  // until tileset.json says
};

// tileset.json is a few kilobytes; this bounds what a broken host can make a
// reader hold before the JSON parser rejects it.
inline constexpr uint64_t kMaxTilesetJsonBytes = 16u << 20;

// How an http(s) source talks to its host (net/http_tile_source.h); here so
// that readers' options can carry it without linking HTTP.
struct HttpOptions {
    int timeoutSeconds = 20;           // a response that stalls this long fails
    std::vector<std::string> headers;  // "Name: value", sent with every request (never logged)
    std::string tokenFile;             // a file holding a bearer token: "Authorization: Bearer TOKEN"
    std::string caFile;                // PEM certificates to verify the host with, instead of the system store
    bool insecure = false;             // no certificate verification (tests only; warns on stderr)
    // Send `headers` and the token to whatever origin a redirect leads to, too;
    // by default only the set's own origin gets them.
    bool redirectCredentials = false;
    // Reads that fail transiently (a reset, a timeout, 408, 429, 5xx, an
    // answer cut short) are asked again this many times, after 0.5, 1, 2 ...
    // s: the readers of openTileset take 3; the streamer 0, as it schedules
    // its own.
    int retries = 0;
};

// A local folder's files, read with pread from any thread.
std::unique_ptr<TileSource> openFolderSource(const std::string& folder);
// "http://..." and "https://..." (net/http_tile_source.h opens them).
bool isUrl(const std::string& location);

}  // namespace surfcast
