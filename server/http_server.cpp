// HTTP front on GNU libmicrohttpd: an epoll event loop per core, like nginx,
// instead of a thread per connection. cpp-httplib (thread per keep-alive
// connection) reached 0.62x nginx's requests/s here, below the 0.8x target;
// see bench/BENCHMARKS.md. This file and export_stream.cpp are the only ones
// that include microhttpd.h.
#include "http_server.h"

#include <arpa/inet.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdlib>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <functional>
#include <cstring>
#include <mutex>
#include <optional>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>
#include <unordered_map>
#include <utility>

#include "byte_io.h"
#include "byte_ranges.h"
#include "camera.h"
#include "crc32.h"
#include "export_stream.h"
#include "laz_export.h"

namespace surfcast {

namespace {

using Clock = std::chrono::steady_clock;

constexpr const char* kImmutable = "public, max-age=31536000, immutable";
constexpr const char* kRevalidate = "no-cache";
constexpr size_t kMaxBatchBody = 64 * 1024;
// A request for a block file's bytes of a set in a bucket is fetched whole
// before it is sent: viewers ask for nodes' blocks (kilobytes to a few MB).
constexpr uint64_t kMaxBucketBytes = 64ull << 20;
// RequestState::fetchError of a request the store's budget of bytes in
// flight refused (BucketBlocks::fetch): a 503, not a 502.
constexpr const char* kBusy = "\x01busy";
// Per-connection buffer for the request line and headers: bounds header size.
constexpr size_t kConnectionMemory = 32 * 1024;
// Connections one client address may hold: one client cannot take them all.
constexpr unsigned kPerAddressConnections = 256;
constexpr unsigned kMaxConnections = 4096;

std::string hex8(uint32_t v) {
    char b[16];
    std::snprintf(b, sizeof b, "%08x", v);
    return b;
}

// State of one request, from its first byte to the completion callback.
struct RequestState {
    Clock::time_point start = Clock::now();
    std::string method, path, route = "other", body;
    int status = 0;
    uint64_t bytes = 0;
    bool bodyTooLarge = false;
    std::shared_ptr<ExportStream> exportStream;  // an export's body, which counts its own bytes
    // A set in a bucket: the snapshot the request began with, and the block
    // bytes fetched for it (by BucketBlocks::Range::id) while it waited,
    // suspended (Impl::fetchThenRespond).
    std::shared_ptr<const TilesetSnapshot> held;
    std::unordered_map<std::string, BucketBlocks::Buffer> fetched;
    std::string fetchError;
    int fetchRounds = 0;
};

// What a response body points into, released with the response.
struct BodyOwner {
    std::shared_ptr<const TilesetSnapshot> snapshot;
    std::shared_ptr<const MappedFile> file;  // an earlier hierarchy file, outside the snapshot
    std::vector<std::string> texts;  // multipart framing, batch length prefixes
    std::string owned;               // a body built in memory (JSON, metrics)
    std::vector<BucketBlocks::Buffer> buffers;  // block bytes from a bucket
};

void releaseBody(void* cls) { delete static_cast<BodyOwner*>(cls); }

// Requests suspended while their bytes are fetched from a bucket. A fetch
// resumes its connection under the gate's mutex, unless abortFetches resumed
// it already (with an error) before the daemon stops; the gate outlives the
// server, since the store's pool (which outlives it too) may end a fetch later.
struct PendingFetch {
    MHD_Connection* connection;
    RequestState* request;
    bool finished = false;
};
struct FetchGate {
    std::mutex mutex;
    std::vector<std::shared_ptr<PendingFetch>> pending;
    bool closed = false;
};

struct Reply {
    RequestState* request = nullptr;
    int status = 200;
    // Block bytes of a set in a bucket that neither the cache nor the
    // request held: fetched, then the request is routed again.
    std::vector<BucketBlocks::Range> missing;
    std::shared_ptr<ExportStream> stream;  // a body produced as it is sent
    std::vector<std::pair<std::string, std::string>> headers;
    // Body: owned text, or iovecs into the owner's snapshot and texts.
    std::unique_ptr<BodyOwner> owner = std::make_unique<BodyOwner>();
    std::vector<MHD_IoVec> iov;
    bool useIov = false;

    void header(const std::string& k, const std::string& v) { headers.emplace_back(k, v); }
    void text(std::string s, const std::string& type) {
        owner->owned = std::move(s);
        header("Content-Type", type);
        useIov = false;
    }
    void piece(const void* p, size_t n) {
        iov.push_back({p, n});
        useIov = true;
    }
};

std::string header(MHD_Connection* c, const char* name) {
    const char* v = MHD_lookup_connection_value(c, MHD_HEADER_KIND, name);
    return v ? v : "";
}

bool etagMatches(const std::string& inm, const std::string& etag) {
    std::stringstream ss(inm);
    std::string tag;
    while (std::getline(ss, tag, ',')) {
        size_t b = tag.find_first_not_of(" \t"), e = tag.find_last_not_of(" \t");
        if (b == std::string::npos) continue;
        tag = tag.substr(b, e - b + 1);
        if (tag.rfind("W/", 0) == 0) tag = tag.substr(2);
        if (tag == "*" || tag == etag) return true;
    }
    return false;
}

// "/sets/NAME/REST" -> NAME, REST; false for other paths.
bool splitSetPath(const std::string& path, std::string* name, std::string* rest) {
    const std::string prefix = "/sets/";
    if (path.rfind(prefix, 0) != 0) return false;
    size_t slash = path.find('/', prefix.size());
    if (slash == std::string::npos) return false;
    *name = path.substr(prefix.size(), slash - prefix.size());
    *rest = path.substr(slash + 1);
    return true;
}

}  // namespace

struct HttpServer::Impl {
    TilesetStore& store;
    ServerConfig config;
    Metrics metrics;
    MHD_Daemon* daemon = nullptr;
    int boundPort = -1;
    std::mutex mutex;
    std::condition_variable stopped;
    bool stopRequested = false;
    // Set with stopRequested: new connections are closed as they are accepted.
    std::atomic<bool> refusing{false};
    // Requests whose line has arrived and whose completion MHD has not yet
    // reported: what run() drains (idle keep-alive connections are not waited for).
    std::atomic<int> inFlight{0};
    // Exports in progress: counted for the concurrency limit, and aborted
    // before the daemon stops.
    std::atomic<int> liveExports{0};
    std::mutex exportsMutex;
    std::vector<std::weak_ptr<ExportStream>> exports;
    bool exportsClosed = false;  // once aborted, no export starts (a keep-alive request may still arrive)

    void abortExports() {
        std::lock_guard lock(exportsMutex);
        exportsClosed = true;
        for (auto& weak : exports)
            if (auto s = weak.lock()) s->abort();
        exports.clear();
    }

    // Requests suspended while their bytes are fetched (FetchGate).
    std::shared_ptr<FetchGate> fetches = std::make_shared<FetchGate>();

    MHD_Result fetchThenRespond(MHD_Connection* c, RequestState& st, std::vector<BucketBlocks::Range> ranges) {
        // One fetch a range, however often the request names it.
        std::sort(ranges.begin(), ranges.end(), [](const auto& a, const auto& b) { return a.id() < b.id(); });
        ranges.erase(std::unique(ranges.begin(), ranges.end(), [](const auto& a, const auto& b) { return a.id() == b.id(); }), ranges.end());
        auto pending = std::make_shared<PendingFetch>(PendingFetch{c, &st});
        {
            // Suspended and registered at once: abortFetches resumes only
            // what is suspended.
            std::lock_guard lock(fetches->mutex);
            if (fetches->closed) {
                st.fetchError = "the server is stopping";
                pending = nullptr;
            } else {
                MHD_suspend_connection(c);
                fetches->pending.push_back(pending);
            }
        }
        if (!pending) return respond(c, st);
        std::vector<std::string> ids;
        for (const auto& range : ranges) ids.push_back(range.id());
        const bool queued = store.bucket()->fetch(std::move(ranges), [gate = fetches, pending, ids](Result<std::vector<BucketBlocks::Buffer>> got) {
            std::lock_guard lock(gate->mutex);
            if (pending->finished) return;
            if (got)
                for (size_t i = 0; i < ids.size(); ++i) pending->request->fetched[ids[i]] = (*got)[i];
            else
                pending->request->fetchError = got.status().message();
            pending->finished = true;
            std::erase(gate->pending, pending);
            MHD_resume_connection(pending->connection);
        });
        if (!queued) {  // the store's bytes in flight at their most: 503, at once
            std::lock_guard lock(fetches->mutex);
            if (!pending->finished) {
                st.fetchError = kBusy;
                pending->finished = true;
                std::erase(fetches->pending, pending);
                MHD_resume_connection(c);
            }
        }
        return MHD_YES;
    }

    void abortFetches() {
        std::lock_guard lock(fetches->mutex);
        fetches->closed = true;
        for (auto& pending : fetches->pending) {
            pending->request->fetchError = "the server is stopping";
            pending->finished = true;
            MHD_resume_connection(pending->connection);
        }
        fetches->pending.clear();
    }

    Impl(TilesetStore& s, ServerConfig c) : store(s), config(std::move(c)) {}

    void fail(Reply& r, int status, const std::string& kind, const std::string& message) {
        r.status = status;
        r.iov.clear();
        // Messages quote the request (a batch key, a path), which need not be
        // UTF-8: such bytes are replaced. (Thrown, the exception ended the
        // whole server: fuzz_http_request.)
        r.text(nlohmann::json{{"error", message}}.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n",
               "application/json");
        metrics.error(kind);
    }

    std::shared_ptr<const TilesetSnapshot> snapshot(const std::string& name, Reply& r) {
        // A request routed again after a fetch sees the version it began with.
        if (r.request->held && r.request->held->name == name) return r.request->held;
        std::string error;
        auto snap = store.get(name, &error);
        if (!snap) fail(r, TilesetStore::validName(name) ? 404 : 400, "not_found", error);
        if (snap && snap->bucket) r.request->held = snap;
        return snap;
    }

    // Bytes [offset, offset + size) of block file `file` of `snap`: its
    // mapping, or for a set in a bucket the request's fetched bytes or the
    // cache's (held by the reply until sent). Null where neither has them:
    // noted in r.missing, for respond() to fetch.
    const uint8_t* blockBytes(Reply& r, const TilesetSnapshot& snap, const std::string& file, uint64_t offset, uint64_t size,
                              std::optional<uint32_t> crc = {}) {
        if (!snap.bucket) {
            uint64_t declared = 0;
            return snap.partFile(file, &declared)->data() + offset;
        }
        BucketBlocks::Range range = snap.range(file, offset, size, crc);
        const std::string id = range.id();
        BucketBlocks::Buffer bytes;
        if (auto it = r.request->fetched.find(id); it != r.request->fetched.end()) bytes = it->second;
        else if ((bytes = snap.bucket->cached(range))) r.request->fetched[id] = bytes;  // kept for a later round too
        if (!bytes) {
            r.missing.push_back(std::move(range));
            return nullptr;
        }
        r.owner->buffers.push_back(bytes);
        return bytes->data();
    }
    const uint8_t* nodeBytes(Reply& r, const TilesetSnapshot& snap, const NodeRecord& n) {
        if (!snap.bucket) return snap.block(n);
        auto place = snap.layout.place(n.blockOffset, n.blockSize);  // load checked every node's
        return blockBytes(r, snap, place->file, place->offset, n.blockSize, n.blockCrc);
    }

    // Clients that pin a version (?v=, tileset.json's hierarchy.crc32) get
    // immutable caching; a stale pin is refused so they reload tileset.json.
    // A request's ?v=: the snapshot of that version (the current one or the
    // one it replaced) in *snap; 409 for any other.
    bool checkVersion(MHD_Connection* c, Reply& r, const std::string& name, std::shared_ptr<const TilesetSnapshot>* snap,
                      bool* pinned) {
        const char* v = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "v");
        *pinned = v != nullptr;
        if (!v || std::string(v) == std::to_string((*snap)->info.hierarchyCrc)) return true;
        char* end = nullptr;
        errno = 0;
        const unsigned long long version = std::strtoull(v, &end, 10);
        auto old = *v && *end == 0 && errno == 0 && version <= UINT32_MAX ? store.pinned(name, uint32_t(version)) : nullptr;
        if (!old) {
            fail(r, 409, "stale", std::string("version ") + v + " is neither the current one (" +
                                      std::to_string((*snap)->info.hierarchyCrc) + ") nor the one before it; reload tileset.json");
            return false;
        }
        *snap = std::move(old);
        return true;
    }

    // Where bytes [first, first + length) of what serveBytes serves lie
    // (null: not at hand yet, blockBytes).
    using Bytes = std::function<const uint8_t*(uint64_t first, uint64_t length)>;
    static Bytes at(const uint8_t* data) {
        return [data](uint64_t first, uint64_t) { return data + first; };
    }

    // Bytes of a file with ETag, conditional requests and Range; `most`: the
    // most bytes one request may take (a block file of a set in a bucket,
    // which the server fetches before it sends).
    void serveBytes(MHD_Connection* c, Reply& r, std::shared_ptr<const TilesetSnapshot> snap, const Bytes& data,
                    uint64_t size, const std::string& type, const std::string& etag, const char* cacheControl,
                    std::shared_ptr<const MappedFile> file = nullptr, uint64_t most = ~uint64_t(0)) {
        r.header("ETag", etag);
        r.header("Cache-Control", cacheControl);
        r.header("Accept-Ranges", "bytes");
        if (etagMatches(header(c, "If-None-Match"), etag)) {
            r.status = 304;
            return;
        }
        RangeRequest rr = parseRange(header(c, "Range"), size, config.maxRanges);
        uint64_t asked = rr.kind == RangeRequest::Kind::Whole ? size : 0;
        for (const ByteRange& b : rr.ranges) asked += b.length();
        if (rr.kind != RangeRequest::Kind::Unsatisfiable && rr.kind != RangeRequest::Kind::TooMany && asked > most)
            return fail(r, 413, "too_large", std::to_string(asked) + " bytes asked of a set in a bucket, whose block files this server "
                                                 "sends by ranges of at most " + std::to_string(most) + " bytes a request");
        switch (rr.kind) {
            case RangeRequest::Kind::Whole:
                r.header("Content-Type", type);
                r.piece(data(0, size), size_t(size));
                break;
            case RangeRequest::Kind::Unsatisfiable:
                r.header("Content-Range", "bytes */" + std::to_string(size));
                return fail(r, 416, "range", "no requested range overlaps the " + std::to_string(size) + " bytes");
            case RangeRequest::Kind::TooMany:
                return fail(r, 400, "range", "more than " + std::to_string(config.maxRanges) + " ranges");
            case RangeRequest::Kind::Partial:
                r.status = 206;
                if (rr.ranges.size() == 1) {
                    const ByteRange& b = rr.ranges[0];
                    r.header("Content-Type", type);
                    r.header("Content-Range", "bytes " + std::to_string(b.first) + "-" + std::to_string(b.last) + "/" +
                                                  std::to_string(size));
                    r.piece(data(b.first, b.length()), size_t(b.length()));
                } else {
                    const std::string boundary = "surfcast-" + etag.substr(1, etag.size() - 2);
                    auto& texts = r.owner->texts;
                    texts.reserve(rr.ranges.size() + 1);  // pointers into it must stay put
                    for (const ByteRange& b : rr.ranges) {
                        texts.push_back("\r\n--" + boundary + "\r\nContent-Type: " + type + "\r\nContent-Range: bytes " +
                                        std::to_string(b.first) + "-" + std::to_string(b.last) + "/" + std::to_string(size) +
                                        "\r\n\r\n");
                        r.piece(texts.back().data(), texts.back().size());
                        r.piece(data(b.first, b.length()), size_t(b.length()));
                    }
                    texts.push_back("\r\n--" + boundary + "--\r\n");
                    r.piece(texts.back().data(), texts.back().size());
                    r.header("Content-Type", "multipart/byteranges; boundary=" + boundary);
                }
                break;
        }
        r.owner->snapshot = std::move(snap);  // keeps the mappings alive until sent
        r.owner->file = std::move(file);
    }

    void route(MHD_Connection* c, RequestState& st, Reply& r) {
        const std::string& path = st.path;
        const bool post = st.method == "POST";
        if (st.method == "OPTIONS") {
            st.route = "options";
            r.status = 204;
            return;
        }
        if (path == "/healthz" && !post) {
            st.route = "healthz";
            return r.text("ok\n", "text/plain");
        }
        if (path == "/metrics" && !post) {
            st.route = "metrics";
            std::string text = metrics.text(liveExports.load());
            if (const auto& bucket = store.bucket()) {
                const BucketBlocks::Counts k = bucket->counts();
                text += "# HELP surfcast_bucket_cache_hits_total Block ranges of sets in a bucket found in the cache.\n"
                        "# TYPE surfcast_bucket_cache_hits_total counter\nsurfcast_bucket_cache_hits_total " + std::to_string(k.hits) +
                        "\n# HELP surfcast_bucket_cache_misses_total Block ranges the cache did not hold.\n"
                        "# TYPE surfcast_bucket_cache_misses_total counter\nsurfcast_bucket_cache_misses_total " + std::to_string(k.misses) +
                        "\n# HELP surfcast_bucket_fetched_bytes_total Bytes fetched from the store.\n"
                        "# TYPE surfcast_bucket_fetched_bytes_total counter\nsurfcast_bucket_fetched_bytes_total " + std::to_string(k.bytesFetched) +
                        "\n# HELP surfcast_bucket_cached_bytes Bytes the cache holds.\n"
                        "# TYPE surfcast_bucket_cached_bytes gauge\nsurfcast_bucket_cached_bytes " + std::to_string(k.cachedBytes) + "\n";
            }
            return r.text(std::move(text), "text/plain; version=0.0.4");
        }
        if (path == "/sets" && !post) {
            st.route = "sets";
            nlohmann::ordered_json list = nlohmann::ordered_json::array();
            for (const auto& s : store.list()) {
                const TilesetInfo& i = s->info;
                list.push_back({{"name", s->name},
                                {"points", i.inputPoints},
                                {"surfels", i.surfels},
                                {"nodes", i.nodes},
                                {"bounds", {{"min", {i.bounds.min.x, i.bounds.min.y, i.bounds.min.z}},
                                            {"max", {i.bounds.max.x, i.bounds.max.y, i.bounds.max.z}}}},
                                {"version", i.hierarchyCrc}});
            }
            r.header("Cache-Control", kRevalidate);
            return r.text(list.dump(2) + "\n", "application/json");
        }
        if (!post && isViewerPath(path)) return viewer(c, st, r);
        std::string name, rest;
        if (!splitSetPath(path, &name, &rest)) return fail(r, 404, "not_found", "no such resource");
        if (!post && (rest == "tileset.json" || validBlocksFile(rest) || validHierarchyFile(rest))) {
            const bool hierarchy = rest[0] == 'h';
            // One metrics label a kind of file, whatever its name (names come from clients).
            st.route = hierarchy ? "hierarchy.bin" : rest[0] == 'b' ? "blocks.bin" : rest;
            auto snap = snapshot(name, r);
            if (!snap) return;
            if (hierarchy && rest != snap->info.hierarchyFile) {
                // An earlier version's hierarchy, which an update in place
                // keeps for clients that opened the set before it, served as
                // a static host would (docs/FORMAT.md, "Updates in place").
                auto old = store.hierarchyFile(name, rest);
                if (!old) return fail(r, 404, "not_found", "no such resource");
                std::shared_ptr<const MappedFile> file = std::move(*old);
                // hierarchy-XXXXXXXX.bin names its CRC; hierarchy.bin's CRC is
                // computed (a compaction or rebuild writes it anew).
                const std::string tag = rest == "hierarchy.bin" ? hex8(crc32(file->data(), size_t(file->size()))) : rest.substr(10, 8);
                return serveBytes(c, r, snap, at(file->data()), file->size(), "application/octet-stream", "\"h-" + tag + "\"",
                                  kRevalidate, file);
            }
            const std::optional<uint64_t> declared = rest[0] == 'b' ? snap->partBytes(rest) : std::nullopt;
            if (rest[0] == 'b' && !declared) return fail(r, 404, "not_found", "no such resource");
            // Clients batch only where tileset.json's answer offers it
            // (docs/PROTOCOL.md, "Batch"); a static host never does.
            if (rest == "tileset.json") r.header("Surfcast-Batch", std::to_string(config.maxBatch));
            // The JSON's CRC changes whenever any byte of the set does; a
            // blocks-XXXXXXXX.bin's name is its own CRC.
            std::string etag = rest.size() == 19 && rest[0] == 'b' ? "\"p-" + rest.substr(7, 8) + "\""
                                                                    : "\"" + std::string(1, rest[0] == 't' ? 'j' : rest[0]) + "-" + hex8(snap->version) + "\"";
            const char* type = rest == "tileset.json" ? "application/json" : "application/octet-stream";
            if (rest[0] == 'b' && snap->bucket) {
                const TilesetSnapshot& s = *snap;
                return serveBytes(c, r, snap, [&](uint64_t first, uint64_t length) { return blockBytes(r, s, rest, first, length); },
                                  declared.value_or(0), type, etag, kRevalidate, nullptr, kMaxBucketBytes);
            }
            uint64_t mapped = 0;
            const MappedFile& m = rest == "tileset.json" ? *snap->json : hierarchy ? *snap->hierarchy : *snap->partFile(rest, &mapped);
            // A block file: only what this version declares (blocks.bin of a
            // set updated before version 3 may hold a killed update's tail).
            const uint64_t size = declared ? std::min<uint64_t>(m.size(), *declared) : m.size();
            return serveBytes(c, r, snap, at(m.data()), size, type, etag, kRevalidate);
        }
        if (!post && rest.rfind("nodes/", 0) == 0) {
            st.route = "nodes";
            auto snap = snapshot(name, r);
            if (!snap) return;
            NodeKey key;
            if (!NodeKey::parse(rest.substr(6), &key)) return fail(r, 400, "bad_request", "node keys look like L-X-Y-Z");
            bool pinned = false;
            if (!checkVersion(c, r, name, &snap, &pinned)) return;
            auto it = snap->nodes.find(key);
            if (it == snap->nodes.end()) return fail(r, 404, "not_found", "no node " + key.name());
            const NodeRecord& n = it->second;
            std::string etag = "\"n-" + hex8(n.blockCrc) + "-" + std::to_string(n.blockSize) + "\"";
            const TilesetSnapshot& s = *snap;
            return serveBytes(c, r, snap, [&](uint64_t first, uint64_t) {
                const uint8_t* block = nodeBytes(r, s, n);
                return block ? block + first : nullptr;
            }, n.blockSize, "application/octet-stream", etag, pinned ? kImmutable : kRevalidate);
        }
        if (post && rest == "batch") {
            st.route = "batch";
            return batch(c, st, r, name);
        }
        if (!post && rest == "export.laz" && config.exportMaxPoints > 0) {
            st.route = "export";
            return exportLaz(c, r, name);
        }
        fail(r, 404, "not_found", "no such resource");
    }

    // One of the exportConcurrency places, or a 503 in `r`. Counted under
    // the lock that abortExports takes: no two requests take the last place.
    std::optional<ExportSlot> takeExportSlot(Reply& r) {
        std::lock_guard lock(exportsMutex);
        if (exportsClosed) {
            fail(r, 503, "busy", "the server is stopping");
            return std::nullopt;
        }
        if (liveExports.load() >= config.exportConcurrency) {
            r.header("Retry-After", "5");
            fail(r, 503, "busy", std::to_string(config.exportConcurrency) + " exports in progress, this server's most; try again later");
            return std::nullopt;
        }
        ++liveExports;
        return ExportSlot(liveExports);
    }

    // GET /sets/NAME/export.laz?bbox=X0,Y0,Z0,X1,Y1,Z1&classes=2,6: the input
    // points inside the box, as LAZ, sent as they are produced. On the event
    // loop it does no work that grows with the set before it can refuse: the
    // place first (so a busy server answers 503 at once), then the limit from
    // the snapshot's node table; the reader opens on the export's own thread.
    void exportLaz(MHD_Connection* c, Reply& r, const std::string& name) {
        std::optional<ExportSlot> slot = takeExportSlot(r);
        if (!slot) return;
        auto snap = snapshot(name, r);
        if (!snap) return;
        PointFilter filter;
        if (const char* box = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "bbox")) {
            auto b = parseBox(box);
            if (!b) return fail(r, 400, "bad_request", b.status().message());
            filter.box = *b;
        }
        if (const char* classes = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "classes")) {
            auto list = parseClasses(classes);
            if (!list) return fail(r, 400, "bad_request", list.status().message());
            filter.classes = *list;
            if (!snap->info.attribute("classification"))
                return fail(r, 400, "bad_request", "set '" + name + "' stores no classification to choose classes by");
        }
        // The leaves the box reaches bound the export before any decoding.
        const uint64_t most = leafPointsAtMost(*snap, filter.box, config.exportMaxPoints);
        if (most > config.exportMaxPoints)
            return fail(r, 413, "too_large", "the box reaches nodes of " + std::to_string(most) + " points or more, over this server's limit of " +
                                                 std::to_string(config.exportMaxPoints) + " per export; ask for a smaller box");
        const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(config.exportSeconds));
        // Registered under the lock abortExports takes: none starts once the
        // server has aborted its exports.
        std::lock_guard lock(exportsMutex);
        if (exportsClosed) return fail(r, 503, "busy", "the server is stopping");
        r.stream = std::make_shared<ExportStream>(snap, std::move(filter), c, std::move(*slot), deadline);
        std::erase_if(exports, [](const std::weak_ptr<ExportStream>& w) { return w.expired(); });
        exports.push_back(r.stream);
        r.header("Content-Type", "application/vnd.laszip");
        r.header("Content-Disposition", "attachment; filename=\"" + name + ".laz\"");
        r.header("Cache-Control", "no-store");
    }

    // "/" and "/NAME" without further slashes: the viewer's page and assets.
    static bool isViewerPath(const std::string& path) {
        return path == "/" || (path.size() > 1 && path.find('/', 1) == std::string::npos && path != "/sets" &&
                               path != "/healthz" && path != "/metrics");
    }

    void viewer(MHD_Connection* c, RequestState& st, Reply& r) {
        st.route = "viewer";
        if (config.web.empty())
            return fail(r, 404, "not_found", "no viewer here: surfcast-serve found no built viewer (build web/, or pass --web DIR)");
        auto it = config.web.find(st.path == "/" ? "index.html" : st.path.substr(1));
        if (it == config.web.end()) return fail(r, 404, "not_found", "no such resource");
        const WebFile& f = it->second;
        r.header("ETag", f.etag);
        r.header("Cache-Control", kRevalidate);
        if (etagMatches(header(c, "If-None-Match"), f.etag)) {
            r.status = 304;
            return;
        }
        r.header("Content-Type", f.type);
        r.piece(f.bytes.data(), f.bytes.size());
    }

    void batch(MHD_Connection* c, RequestState& st, Reply& r, const std::string& name) {
        if (st.bodyTooLarge) return fail(r, 413, "bad_request", "batch body over " + std::to_string(kMaxBatchBody) + " bytes");
        auto snap = snapshot(name, r);
        if (!snap) return;
        bool pinned = false;
        if (!checkVersion(c, r, name, &snap, &pinned)) return;
        std::vector<const NodeRecord*> nodes;
        std::string body = st.body;
        for (char& ch : body)
            if (ch == ',') ch = ' ';
        std::stringstream words(body);
        std::string word;
        while (words >> word) {
            NodeKey key;
            if (!NodeKey::parse(word, &key)) return fail(r, 400, "bad_request", "'" + word + "' is not a node key");
            auto it = snap->nodes.find(key);
            if (it == snap->nodes.end()) return fail(r, 404, "not_found", "no node " + word);
            if (nodes.size() == config.maxBatch)
                return fail(r, 400, "bad_request", "more than " + std::to_string(config.maxBatch) + " nodes");
            nodes.push_back(&it->second);
        }
        if (nodes.empty()) return fail(r, 400, "bad_request", "no node keys in the body");
        // Length-prefixed blobs in request order: u32 LE size, then the bytes.
        auto& texts = r.owner->texts;
        texts.reserve(nodes.size());
        for (const NodeRecord* n : nodes) {
            std::string len(4, '\0');
            le::put<uint32_t>(reinterpret_cast<uint8_t*>(len.data()), n->blockSize);
            texts.push_back(len);
            r.piece(texts.back().data(), 4);
            r.piece(nodeBytes(r, *snap, *n), n->blockSize);
        }
        r.header("Content-Type", "application/x-surfcast-batch");
        r.header("Cache-Control", "no-store");
        r.owner->snapshot = std::move(snap);
    }

    bool authorized(MHD_Connection* c, const RequestState& st) const {
        if (config.token.empty() || st.path == "/healthz" || st.method == "OPTIONS") return true;
        if (st.method != "POST" && isViewerPath(st.path)) return true;  // the viewer's files hold no data
        std::string auth = header(c, "Authorization");
        std::string expected = "Bearer " + config.token;
        // Constant time in the token's length: no timing oracle.
        unsigned diff = auth.size() == expected.size() ? 0u : 1u;
        for (size_t i = 0; i < expected.size(); ++i)
            diff |= unsigned(uint8_t(expected[i]) ^ uint8_t(i < auth.size() ? auth[i] : 0));
        return diff == 0;
    }

    MHD_Result respond(MHD_Connection* c, RequestState& st) {
        Reply r;
        r.request = &st;
        if (st.fetchError == kBusy) {
            r.header("Retry-After", "1");
            fail(r, 503, "busy", "this server is fetching as many bytes from the store as it may at once; try again");
        } else if (!st.fetchError.empty()) {
            fail(r, 502, "store", "the store: " + st.fetchError);
        } else if (st.method != "GET" && st.method != "HEAD" && st.method != "POST" && st.method != "OPTIONS") {
            fail(r, 405, "bad_request", "read-only server: " + st.method + " is not allowed");
            r.header("Allow", "GET, HEAD, POST, OPTIONS");
        } else if (!authorized(c, st)) {
            fail(r, 401, "unauthorized", "missing or wrong bearer token");
            r.header("WWW-Authenticate", "Bearer realm=\"surfcast\"");
        } else {
            route(c, st, r);
            // Bytes of a set in a bucket to fetch first: the connection waits,
            // off the event loop, and the request is routed again with them
            // (in at most three rounds: what a round found is the request's
            // own, and a later round fetches only what the cache lost since).
            if (!r.missing.empty() && r.status < 400) {
                if (++st.fetchRounds <= 3) return fetchThenRespond(c, st, std::move(r.missing));
                fail(r, 503, "busy", "the store's bytes for this request could not be gathered; try again");
            }
        }
        if (!config.corsOrigin.empty()) {
            r.header("Access-Control-Allow-Origin", config.corsOrigin);
            r.header("Access-Control-Allow-Methods", "GET, HEAD, POST, OPTIONS");
            r.header("Access-Control-Allow-Headers", "Authorization, Range, If-None-Match, Content-Type");
            r.header("Access-Control-Expose-Headers", "Content-Range, Content-Length, ETag, Accept-Ranges, Surfcast-Batch");
            r.header("Vary", "Origin");
        }
        MHD_Response* res = nullptr;
        BodyOwner* owner = r.owner.release();
        if (r.stream) {
            delete owner;
            owner = nullptr;
            std::shared_ptr<ExportStream> stream = r.stream;
            st.exportStream = stream;
            // The response holds the stream too, until MHD frees it.
            auto* held = new std::shared_ptr<ExportStream>(stream);
            res = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 64 * 1024, &ExportStream::read, held, &ExportStream::release);
            if (!res) {
                delete held;
                return MHD_NO;
            }
        } else if (r.useIov) {
            res = MHD_create_response_from_iovec(r.iov.data(), unsigned(r.iov.size()), releaseBody, owner);
            for (const auto& v : r.iov) st.bytes += v.iov_len;
        } else {
            res = MHD_create_response_from_buffer_with_free_callback_cls(owner->owned.size(), owner->owned.data(),
                                                                         releaseBody, owner);
            st.bytes = owner->owned.size();
        }
        if (!res) {
            delete owner;
            return MHD_NO;
        }
        for (const auto& [k, v] : r.headers) MHD_add_response_header(res, k.c_str(), v.c_str());
        st.status = r.status;
        if (st.method == "HEAD" || r.status == 304 || r.status == 204) st.bytes = 0;
        MHD_Result ok = MHD_queue_response(c, unsigned(r.status), res);
        MHD_destroy_response(res);
        return ok;
    }

    // MHD callbacks. The URI callback makes MHD report the request's completion
    // whatever ends it (an answer, an error of MHD's own, a timeout, the client
    // leaving, the daemon stopping), so every count taken here is given back.
    // Not MHD_quiesce_daemon: with a pool of epoll threads, libmicrohttpd
    // 0.9.75-0.9.77 removes the listening socket from each thread's epoll set
    // while the thread may be removing it too, and aborts when it loses that
    // race ("Failed to remove listen FD from epoll set", bench/RELIABILITY.md).
    static MHD_Result onAccept(void* cls, const sockaddr*, socklen_t) {
        return static_cast<Impl*>(cls)->refusing.load() ? MHD_NO : MHD_YES;
    }

    static void* onUri(void* cls, const char*, MHD_Connection*) {
        static_cast<Impl*>(cls)->inFlight.fetch_add(1);
        return new RequestState;
    }

    static MHD_Result onRequest(void* cls, MHD_Connection* c, const char* url, const char* method, const char*,
                                const char* upload, size_t* uploadSize, void** reqCls) {
        auto* self = static_cast<Impl*>(cls);
        auto* st = static_cast<RequestState*>(*reqCls);
        if (st->method.empty()) {
            // Answer only from the second call on: MHD then knows the request
            // (and any body) was read whole and keeps the connection alive.
            st->method = method;
            st->path = url;
            return MHD_YES;
        }
        if (*uploadSize > 0) {
            if (st->body.size() + *uploadSize > kMaxBatchBody) st->bodyTooLarge = true;
            else st->body.append(upload, *uploadSize);
            *uploadSize = 0;
            return MHD_YES;
        }
        return self->respond(c, *st);
    }

    static void onCompleted(void* cls, MHD_Connection*, void** reqCls, MHD_RequestTerminationCode) {
        auto* self = static_cast<Impl*>(cls);
        std::unique_ptr<RequestState> st(static_cast<RequestState*>(*reqCls));
        *reqCls = nullptr;
        if (!st) return;
        self->inFlight.fetch_sub(1);
        if (st->method.empty()) return;
        if (st->exportStream && st->method != "HEAD") st->bytes = st->exportStream->sent();
        double seconds = std::chrono::duration<double>(Clock::now() - st->start).count();
        int status = st->status ? st->status : 500;
        self->metrics.record(st->route, status, st->bytes, seconds);
        const LogLevel level = self->config.log;
        if (level == LogLevel::Requests || (level == LogLevel::Errors && status >= 400))
            std::fprintf(stderr, "%s %s %d %llu %.2fms\n", st->method.c_str(), st->path.c_str(), status,
                         static_cast<unsigned long long>(st->bytes), seconds * 1e3);
    }

    static void onLog(void* cls, const char* fmt, va_list ap) {
        auto* self = static_cast<Impl*>(cls);
        if (self->config.log == LogLevel::Quiet) return;
        std::fprintf(stderr, "surfcast-serve: ");
        std::vfprintf(stderr, fmt, ap);
    }
};

HttpServer::HttpServer(TilesetStore& store, ServerConfig config) : impl_(new Impl(store, std::move(config))) {}

HttpServer::~HttpServer() {
    if (impl_->daemon) {
        impl_->abortExports();
        impl_->abortFetches();
        MHD_stop_daemon(impl_->daemon);
    }
}

Status HttpServer::bind() {
    const ServerConfig& c = impl_->config;
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(uint16_t(c.port));
    if (::inet_pton(AF_INET, c.host.c_str(), &addr.sin_addr) != 1)
        return Status::error("cannot listen on " + c.host + ": not an IPv4 address");
    unsigned threads = c.threads > 0 ? unsigned(c.threads) : std::max(1u, std::thread::hardware_concurrency());
    // Suspend and resume: an export's connection waits, off the event loop, for its bytes.
    unsigned flags = MHD_USE_EPOLL_INTERNAL_THREAD | MHD_USE_ERROR_LOG | MHD_USE_TURBO | MHD_USE_ITC | MHD_ALLOW_SUSPEND_RESUME;
    const bool tls = !c.tlsCertificate.empty();
    if (tls && MHD_is_feature_supported(MHD_FEATURE_TLS) != MHD_YES)
        return Status::error("this libmicrohttpd was built without TLS");
    if (tls) flags |= MHD_USE_TLS;
    // The key and certificate only with TLS (libmicrohttpd refuses them without).
    MHD_OptionItem tlsOptions[] = {
        {tls ? MHD_OPTION_HTTPS_MEM_KEY : MHD_OPTION_END, 0, const_cast<char*>(c.tlsKey.c_str())},
        {MHD_OPTION_HTTPS_MEM_CERT, 0, const_cast<char*>(c.tlsCertificate.c_str())},
        {MHD_OPTION_END, 0, nullptr}};
    impl_->daemon = MHD_start_daemon(
        flags, 0, &Impl::onAccept, impl_.get(), &Impl::onRequest, impl_.get(),                       //
        MHD_OPTION_EXTERNAL_LOGGER, &Impl::onLog, impl_.get(),  /* first: it logs what the others say */  //
        MHD_OPTION_ARRAY, tlsOptions,                                                                  //
        MHD_OPTION_SOCK_ADDR, reinterpret_cast<sockaddr*>(&addr),                                      //
        MHD_OPTION_THREAD_POOL_SIZE, threads,                                                          //
        MHD_OPTION_CONNECTION_TIMEOUT, unsigned(std::max(c.timeoutSeconds, 1)),                       //
        MHD_OPTION_CONNECTION_MEMORY_LIMIT, kConnectionMemory,                                         //
        MHD_OPTION_CONNECTION_LIMIT, kMaxConnections,                                                  //
        MHD_OPTION_PER_IP_CONNECTION_LIMIT, kPerAddressConnections,                                    //
        MHD_OPTION_URI_LOG_CALLBACK, &Impl::onUri, impl_.get(),                                        //
        MHD_OPTION_NOTIFY_COMPLETED, &Impl::onCompleted, impl_.get(),                                  //
        MHD_OPTION_END);
    if (!impl_->daemon)
        return Status::error("cannot listen on " + c.host + ":" + std::to_string(c.port) +
                             (tls ? " (or the TLS certificate and key do not load: are they PEM, and a pair?)" : ""));
    const MHD_DaemonInfo* info = MHD_get_daemon_info(impl_->daemon, MHD_DAEMON_INFO_BIND_PORT);
    impl_->boundPort = info ? int(info->port) : c.port;
    return {};
}

int HttpServer::port() const { return impl_->boundPort; }

void HttpServer::run() {
    std::unique_lock lock(impl_->mutex);
    impl_->stopped.wait(lock, [&] { return impl_->stopRequested; });
    if (!impl_->daemon) return;
    // New connections are closed on accept (onAccept, since stop()); let
    // requests in flight finish (up to drainSeconds), then end the exports
    // still going and close every connection, idle keep-alive ones included,
    // and the listening socket.
    auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(impl_->config.drainSeconds));
    while (Clock::now() < deadline && impl_->inFlight.load() > 0) {
        lock.unlock();
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        lock.lock();
    }
    impl_->abortExports();
    impl_->abortFetches();
    MHD_stop_daemon(impl_->daemon);
    impl_->daemon = nullptr;
}

void HttpServer::stop() {
    std::lock_guard lock(impl_->mutex);
    impl_->refusing = true;
    impl_->stopRequested = true;
    impl_->stopped.notify_all();
}

const Metrics& HttpServer::metrics() const { return impl_->metrics; }

}  // namespace surfcast
