// Where a tile set's bytes come from: a local folder, or an http(s) folder URL
// (the project's server at http://HOST:PORT/sets/NAME, or any static host,
// object store or CDN that honours Range). The project's only HTTP client
// code, used by the viewer's streamer and by TilesetReader (surfcast-build
// --info, surfcast-view without --lod): libcurl (TLS verified against the
// system store, HTTP/2 where the host offers it, proxies from the
// environment), following redirects to http(s) only, never from https to
// http, and with the user's headers to the set's own origin only.
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
    // Bytes [offset, offset + size) of a file of the set ("blocks.bin", or a
    // page of "hierarchy.bin"); never more is kept. Thread-safe.
    virtual Result<std::vector<uint8_t>> range(const std::string& name, uint64_t offset, uint64_t size) = 0;
    Result<std::vector<uint8_t>> blocks(uint64_t offset, uint64_t size) { return range("blocks.bin", offset, size); }
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
};

// tileset.json is a few kilobytes; this bounds what a broken host can make a
// reader hold before the JSON parser rejects it.
inline constexpr uint64_t kMaxTilesetJsonBytes = 16u << 20;

// How an http(s) source talks to its host.
struct HttpOptions {
    int timeoutSeconds = 20;           // a response that stalls this long fails
    std::vector<std::string> headers;  // "Name: value", sent with every request (never logged)
    std::string tokenFile;             // a file holding a bearer token: "Authorization: Bearer TOKEN"
    std::string caFile;                // PEM certificates to verify the host with, instead of the system store
    bool insecure = false;             // no certificate verification (tests only; warns on stderr)
    // Send `headers` and the token to whatever origin a redirect leads to, too;
    // by default only the set's own origin gets them.
    bool redirectCredentials = false;
};

// "http://..." and "https://..." open an HTTP source (all requests run on one
// libcurl multi handle driven by one I/O thread: one multiplexed connection
// over HTTP/2, up to 6 keep-alive connections over HTTP/1.1; a query string,
// such as a shared access signature, is kept on every request and left out of
// messages); anything else is a local folder.
Result<std::unique_ptr<TileSource>> openTileSource(const std::string& location, const HttpOptions& http = {});
bool isUrl(const std::string& location);

}  // namespace surfcast
