#include "http_tile_source.h"

#include <curl/curl.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <optional>
#include <chrono>
#include <thread>
#include <type_traits>
#include <unordered_map>
#include <utility>

#include "object_store.h"
#include "sigpipe.h"
#include "tileset_format.h"
#include "transfer_errors.h"

namespace surfcast {
namespace {

// The body of an error response is read and dropped up to this much.
constexpr uint64_t kMaxErrorPageBytes = 1 << 20;
// A server that does not accept within this fails the request.
constexpr int kConnectTimeoutSeconds = 5;
// HTTP/1.1 connections to the host at once, as browsers allow; more
// concurrent requests queue for one (HTTP/2 multiplexes them over one).
constexpr int kMaxHostConnections = 6;
// A bearer token longer than this is not one (a wrong file).
constexpr size_t kMaxTokenBytes = 16 << 10;
// A Surfcast-Batch count above this is not taken (the browser's bound too).
constexpr unsigned long kMaxBatchNodesOffered = 1'000'000;

// A URL's scheme, host and port (the default one where none is given),
// lower case; all empty when libcurl cannot parse the URL.
struct Origin {
    std::string scheme, host, port;
    bool operator==(const Origin&) const = default;
};

Origin originOf(const std::string& url) {
    Origin o;
    CURLU* u = curl_url();
    if (!u) return o;
    if (curl_url_set(u, CURLUPART_URL, url.c_str(), 0) == CURLUE_OK) {
        const std::pair<CURLUPart, std::string*> parts[] = {
            {CURLUPART_SCHEME, &o.scheme}, {CURLUPART_HOST, &o.host}, {CURLUPART_PORT, &o.port}};
        for (auto [part, out] : parts) {
            char* value = nullptr;
            if (curl_url_get(u, part, &value, CURLU_DEFAULT_PORT) == CURLUE_OK && value) {
                *out = value;
                for (char& c : *out) c = char(std::tolower(static_cast<unsigned char>(c)));
            }
            curl_free(value);
        }
    }
    curl_url_cleanup(u);
    return o;
}

// Requests from any number of threads run on one libcurl multi handle,
// driven by one I/O thread. Over HTTP/2 they share one connection
// (multiplexed: CURLOPT_PIPEWAIT makes a transfer wait for the first
// connection rather than open its own); over HTTP/1.1 each concurrent request
// takes a keep-alive connection of the multi's pool, at most
// kMaxHostConnections, the rest queued. A calling thread prepares easy handles
// (from a pool), hands them over together and waits for all of them: the
// ranges of a batch of nodes are in flight at once.
// A set in an S3 bucket: what messages call it, and its requests' signature
// (CURLOPT_AWS_SIGV4, for the set's own origin only; none for a public bucket).
struct StoreAccess {
    std::string shown;    // "s3://BUCKET/PREFIX"
    std::string sigv4;    // "aws:amz:REGION:s3"
    std::string userpwd;  // "ACCESS_KEY:SECRET_KEY"; empty: unsigned
};

class HttpSource : public TileSource {
public:
    // base: scheme://host[:port]/path without a trailing slash; query: "" or
    // "?..."; store: where base is an S3 bucket's prefix (file names are then
    // object keys, percent-encoded in URLs).
    HttpSource(std::string base, std::string query, HttpOptions options, curl_slist* headers, CURLM* multi,
               std::optional<StoreAccess> store = std::nullopt)
        : base_(std::move(base)), query_(std::move(query)), shown_(store ? store->shown : base_), origin_(originOf(base_)),
          options_(std::move(options)), store_(std::move(store)), headers_(headers), multi_(multi), io_([this] { ioLoop(); }) {}
    ~HttpSource() override {
        {
            std::lock_guard lock(ioMutex_);
            stopping_ = true;
        }
        curl_multi_wakeup(multi_);
        io_.join();
        curl_multi_cleanup(multi_);
        for (CURL* h : idle_) curl_easy_cleanup(h);
        curl_slist_free_all(headers_);
    }
    Result<std::vector<uint8_t>> file(const std::string& name, uint64_t maxBytes) override {
        return withRetries([&] { return fileOnce(name, maxBytes); });
    }
    Result<std::vector<uint8_t>> range(const std::string& name, uint64_t offset, uint64_t size) override {
        auto r = ranges({{name, offset, size}});
        if (!r) return r.status();
        return std::move((*r)[0]);
    }
    Result<uint64_t> size(const std::string& name) override { return withRetries([&] { return sizeOnce(name); }); }
    // If-None-Match with the ETag of the last answer (304: unchanged); a host
    // that gives no ETag is compared by the bytes' CRC-32, as a folder is.
    Result<std::optional<std::vector<uint8_t>>> changedFile(const std::string& name, uint64_t maxBytes,
                                                           std::string* tag) override {
        Request q{name, "", nullptr, maxBytes, 0};
        if (tag->rfind("etag:", 0) == 0) q.ifNoneMatch = tag->substr(5);
        auto r = withRetries([&] { return std::move(run({q})[0]); });
        if (!r) return r.status();
        if (r->status == 304 && !q.ifNoneMatch.empty()) return std::optional<std::vector<uint8_t>>();
        if (r->status != 200) return httpError(shown_ + "/" + name, r->status);
        if (r->etag.empty()) return ifOtherBytes(std::move(r->body), tag);
        *tag = "etag:" + r->etag;
        return std::optional(std::move(r->body));
    }
    std::string describe() const override { return shown_; }
    void cancel() override {
        {
            std::lock_guard lock(ioMutex_);
            cancelled_ = true;
        }
        curl_multi_wakeup(multi_);
    }

private:
    // A request that fails transiently (a reset, a timeout, 408, 429, 5xx,
    // an answer cut short) is asked again, options_.retries times after
    // 0.5, 1, 2 ... s; never once the source is cancelled. Each request on
    // its own: of many ranges in flight, only those that failed.
    bool waitToRetry(int attempt) {
        {
            std::lock_guard lock(ioMutex_);
            if (cancelled_) return false;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(500 << std::min(attempt, 6)));
        return true;
    }
    template <class F>
    std::invoke_result_t<F&> withRetries(F request) {
        auto r = request();
        for (int attempt = 0; attempt < options_.retries && !r && r.status().isTransient() && waitToRetry(attempt); ++attempt) r = request();
        return r;
    }
    Result<std::vector<uint8_t>> fileOnce(const std::string& name, uint64_t maxBytes) {
        auto r = std::move(run({{name, "", nullptr, maxBytes, 200}})[0]);
        if (!r) return r.status();
        if (name == "tileset.json") {
            batchNodes_ = r->batchNodes;
            // Batches ask for this version (?v=), which the server keeps
            // serving after an update until the one after it (docs/PROTOCOL.md,
            // "Versions"); an unreadable file pins none (its reader fails).
            auto info = readTilesetJson(std::string(r->body.begin(), r->body.end()), shown_ + "/tileset.json");
            version_ = info ? uint64_t(info->hierarchyCrc) + 1 : 0;
        }
        return std::move(r->body);
    }
    // A one-byte range: its Content-Range answer names the file's length.
    Result<uint64_t> sizeOnce(const std::string& name) {
        auto r = std::move(run({{name, "0-0", nullptr, 1, 206}})[0]);
        if (!r) return r.status();
        if (!r->total) return Status::error(shown_ + "/" + name + ": the host's answer to a range request names no file length");
        return *r->total;
    }
    // The server's POST {set}/batch where tileset.json's answer offered it
    // (Surfcast-Batch: up to N keys a request), else the ranges, all in
    // flight at once.
    Result<std::vector<std::vector<uint8_t>>> blobs(const std::vector<NodeRecord>& nodes) override {
        const size_t most = batchNodes_;
        if (nodes.size() < 2 || most < 2) {
            std::vector<Span> spans;
            for (const NodeRecord& n : nodes) {
                auto place = blocksLayout().place(n.blockOffset, n.blockSize);
                if (!place) return Status::error(describe() + ": node " + n.key.name() + ": " + place.status().message());
                spans.push_back({place->file, place->offset, n.blockSize});
            }
            return ranges(spans);
        }
        std::vector<std::vector<uint8_t>> out;
        for (size_t at = 0; at < nodes.size(); at += most) {
            const std::vector<NodeRecord> some(nodes.begin() + long(at), nodes.begin() + long(std::min(nodes.size(), at + most)));
            auto part = withRetries([&] { return batch(some); });
            if (!part) return part.status();
            for (auto& b : *part) out.push_back(std::move(b));
        }
        return out;
    }

    // One POST {set}/batch of `nodes`: their blobs in order.
    Result<std::vector<std::vector<uint8_t>>> batch(const std::vector<NodeRecord>& nodes) {
        std::string body;
        uint64_t expected = 0;  // what the answer holds: a length and a blob per node
        for (const NodeRecord& n : nodes) {
            body += n.key.name() + ",";
            expected += 4 + uint64_t(n.blockSize);
        }
        auto r = std::move(run({{"batch", "", &body, expected, 0}})[0]);
        if (!r) return r.status();
        const std::string url = shown_ + "/batch";
        if (r->status != 200) return httpError(url, r->status);
        // For each key in order: u32 little-endian length, then the blob.
        std::vector<std::vector<uint8_t>> out;
        const uint8_t* p = r->body.data();
        size_t at = 0, size = r->body.size();
        for (size_t i = 0; i < nodes.size(); ++i) {
            if (size - at < 4) return Status::transient(url + ": response ends before node " + nodes[i].key.name());
            uint32_t length = uint32_t(p[at]) | uint32_t(p[at + 1]) << 8 | uint32_t(p[at + 2]) << 16 | uint32_t(p[at + 3]) << 24;
            at += 4;
            if (size - at < length) return Status::transient(url + ": response ends inside node " + nodes[i].key.name());
            out.emplace_back(p + at, p + at + length);
            at += length;
        }
        return out;
    }

    // A handle handed to the I/O thread, and how its transfer ended.
    struct Transfer {
        CURL* handle = nullptr;
        CURLcode code = CURLE_OK;
        bool done = false;
        bool redirected = false;  // pointed at a redirect's target, to run again
        bool withoutCredentials = false;  // a redirect left the user's headers behind
        bool moved = false;               // answered at a redirect's target
        curl_slist* headers = nullptr;    // the request's own (the source's, or with If-None-Match)
    };

    // One GET of `name` (of byte range `range`, if not empty), or POST of
    // `post` to it. `wanted`: the status whose body is kept (any other is an
    // error), 0 for any (a body is kept for 200 only). `ifNoneMatch`: an
    // ETag to send as If-None-Match.
    struct Request {
        std::string name, range;
        const std::string* post;
        uint64_t maxBytes;
        long wanted;
        std::string ifNoneMatch = {};
    };
    // One request's answer: the status, the body, kept up to a bound, and
    // its Surfcast-Batch header (0 where absent, not a count up to
    // kMaxBatchNodesOffered, or answered after a redirect).
    struct Response {
        long status = 0;
        std::vector<uint8_t> body;
        size_t batchNodes = 0;
        std::optional<uint64_t> total;  // a range's answer: the file's length, where Content-Range names it
        std::string etag;               // as the host quoted it; empty where it gave none
    };

    // Byte ranges of files of the set, all requested at once; all or nothing.
    struct Span {
        std::string name;
        uint64_t offset, size;
    };
    Result<std::vector<std::vector<uint8_t>>> ranges(const std::vector<Span>& spans) {
        std::vector<Request> requests;
        std::vector<size_t> asked;  // indices into spans: empty ranges are not asked for
        for (size_t i = 0; i < spans.size(); ++i) {
            const auto& [name, offset, size] = spans[i];
            if (size == 0) continue;
            requests.push_back({name, std::to_string(offset) + "-" + std::to_string(offset + size - 1), nullptr, size, 206});
            asked.push_back(i);
        }
        std::vector<std::vector<uint8_t>> out(spans.size());
        std::vector<Result<Response>> answers = run(requests);
        // An answer cut short (a connection that closed early) fails as a fault does.
        auto check = [&](size_t k) {
            const auto& [name, offset, size] = spans[asked[k]];
            if (answers[k] && answers[k]->body.size() != size)
                answers[k] = Status::transient(describe() + "/" + name + ": asked for " + std::to_string(size) + " bytes at " +
                                               std::to_string(offset) + ", got " + std::to_string(answers[k]->body.size()));
        };
        for (size_t k = 0; k < asked.size(); ++k) check(k);
        for (int attempt = 0; attempt < options_.retries; ++attempt) {
            std::vector<size_t> again;
            for (size_t k = 0; k < asked.size(); ++k)
                if (!answers[k] && answers[k].status().isTransient()) again.push_back(k);
            if (again.empty() || !waitToRetry(attempt)) break;
            std::vector<Request> retried;
            for (size_t k : again) retried.push_back(requests[k]);
            std::vector<Result<Response>> second = run(retried);
            for (size_t j = 0; j < again.size(); ++j) {
                answers[again[j]] = std::move(second[j]);
                check(again[j]);
            }
        }
        for (size_t k = 0; k < asked.size(); ++k) {
            if (!answers[k]) return answers[k].status();
            out[asked[k]] = std::move(answers[k]->body);
        }
        return out;
    }

    // What the write callback keeps: the body of a `wanted` answer up to
    // maxBytes (longer cancels the request), and of any other answer (an
    // error page) nothing, up to kMaxErrorPageBytes.
    struct Sink {
        CURL* handle;
        long wanted;  // 0: any status is kept (the batch decides afterwards)
        uint64_t maxBytes, dropped = 0;
        bool tooLong = false;
        std::vector<uint8_t>* body;
    };
    static size_t write(char* data, size_t, size_t length, void* user) {
        Sink& s = *static_cast<Sink*>(user);
        long status = 0;
        curl_easy_getinfo(s.handle, CURLINFO_RESPONSE_CODE, &status);
        const bool keep = s.wanted ? status == s.wanted : status == 200;
        if (!keep) return (s.dropped += length) <= kMaxErrorPageBytes ? length : 0;
        if (length > s.maxBytes - s.body->size()) {
            s.tooLong = true;
            return 0;
        }
        s.body->insert(s.body->end(), data, data + length);
        return length;
    }

    // An easy handle with the source's fixed options, from the pool.
    CURL* acquire() {
        {
            std::lock_guard lock(mutex_);
            if (!idle_.empty()) {
                CURL* h = idle_.back();
                idle_.pop_back();
                return h;
            }
        }
        CURL* h = curl_easy_init();
        if (!h) return nullptr;
        curl_easy_setopt(h, CURLOPT_NOSIGNAL, 1L);
        curl_easy_setopt(h, CURLOPT_PIPEWAIT, 1L);
        curl_easy_setopt(h, CURLOPT_PROTOCOLS_STR, "http,https");  // redirects are followed by run()
        curl_easy_setopt(h, CURLOPT_CONNECTTIMEOUT, long(kConnectTimeoutSeconds));
        // Stalled: under one byte per second for the whole timeout.
        curl_easy_setopt(h, CURLOPT_LOW_SPEED_LIMIT, 1L);
        curl_easy_setopt(h, CURLOPT_LOW_SPEED_TIME, long(options_.timeoutSeconds));
        curl_easy_setopt(h, CURLOPT_HTTPHEADER, headers_);
        curl_easy_setopt(h, CURLOPT_WRITEFUNCTION, &HttpSource::write);
        if (!options_.caFile.empty()) {  // instead of the system's store, folder included
            curl_easy_setopt(h, CURLOPT_CAINFO, options_.caFile.c_str());
            curl_easy_setopt(h, CURLOPT_CAPATH, nullptr);
        }
        if (options_.insecure) {
            curl_easy_setopt(h, CURLOPT_SSL_VERIFYPEER, 0L);
            curl_easy_setopt(h, CURLOPT_SSL_VERIFYHOST, 0L);
        }
        sign(h, true);
        return h;
    }
    void release(CURL* h) {
        sign(h, true);  // a redirect may have left it unsigned
        std::lock_guard lock(mutex_);
        idle_.push_back(h);
    }
    // Signs the handle's requests (S3), or stops signing them (`on` false: a
    // redirect to another origin, which never sees the keys).
    void sign(CURL* h, bool on) const {
        if (!store_ || store_->userpwd.empty()) return;
        curl_easy_setopt(h, CURLOPT_AWS_SIGV4, on ? store_->sigv4.c_str() : nullptr);
        curl_easy_setopt(h, CURLOPT_USERPWD, on ? store_->userpwd.c_str() : nullptr);
    }

    // Runs the requests at once on the I/O thread, following redirects
    // (redirect() says which); an answer or an error each.
    std::vector<Result<Response>> run(const std::vector<Request>& requests) {
        const size_t n = requests.size();
        std::vector<Response> responses(n);
        std::vector<Sink> sinks(n);
        std::vector<Transfer> transfers(n);
        std::vector<std::array<char, CURL_ERROR_SIZE>> errors(n);
        std::vector<std::optional<Status>> refused(n);  // a redirect not followed, and why
        // The headers of a conditional request: the source's and If-None-Match
        // (a redirect sends the source's only, or none).
        std::vector<std::unique_ptr<curl_slist, decltype(&curl_slist_free_all)>> conditional;
        std::vector<Transfer*> round;
        for (size_t i = 0; i < n; ++i) {
            const Request& q = requests[i];
            CURL* h = acquire();
            transfers[i].handle = h;
            if (!h) continue;
            sinks[i] = {h, q.wanted, q.maxBytes, 0, false, &responses[i].body};
            errors[i][0] = 0;
            std::string url = base_ + "/" + (store_ ? s3EncodeKey(q.name) : q.name) + query_;
            if (const uint64_t v = version_; q.post && v > 0) url += (query_.empty() ? "?v=" : "&v=") + std::to_string(v - 1);
            curl_easy_setopt(h, CURLOPT_URL, url.c_str());
            curl_slist* requestHeaders = headers_;
            if (!q.ifNoneMatch.empty()) {
                curl_slist* list = nullptr;
                for (curl_slist* l = headers_; l; l = l->next) list = curl_slist_append(list, l->data);
                list = curl_slist_append(list, ("If-None-Match: " + q.ifNoneMatch).c_str());
                conditional.emplace_back(list, &curl_slist_free_all);
                requestHeaders = list;
            }
            curl_easy_setopt(h, CURLOPT_HTTPHEADER, requestHeaders);
            transfers[i].headers = requestHeaders;
            curl_easy_setopt(h, CURLOPT_WRITEDATA, &sinks[i]);
            curl_easy_setopt(h, CURLOPT_ERRORBUFFER, errors[i].data());
            curl_easy_setopt(h, CURLOPT_RANGE, q.range.empty() ? nullptr : q.range.c_str());
            // Whole files may come compressed (whatever libcurl decodes); a
            // range is of the file's own bytes, so it is asked for without encoding.
            curl_easy_setopt(h, CURLOPT_ACCEPT_ENCODING, q.range.empty() ? "" : nullptr);
            if (q.post) {
                curl_easy_setopt(h, CURLOPT_POSTFIELDS, q.post->c_str());
                curl_easy_setopt(h, CURLOPT_POSTFIELDSIZE, long(q.post->size()));
            } else {
                curl_easy_setopt(h, CURLOPT_HTTPGET, 1L);
            }
            round.push_back(&transfers[i]);
        }
        for (int hops = 0; !round.empty(); ++hops) {
            perform(round);
            const std::vector<Transfer*> performed = std::exchange(round, {});
            for (Transfer* t : performed) {
                const size_t i = size_t(t - transfers.data());
                // A POST is never redirected; a redirect's body past
                // kMaxErrorPageBytes stopped the transfer, not the redirect.
                if (requests[i].post || (t->code != CURLE_OK && t->code != CURLE_WRITE_ERROR)) continue;
                Status why = redirect(*t, hops);
                if (!why.ok()) {
                    refused[i] = std::move(why);
                } else if (t->redirected) {
                    sinks[i].dropped = 0;
                    t->moved = true;
                    round.push_back(t);
                }
            }
        }
        std::vector<Result<Response>> out;
        for (size_t i = 0; i < n; ++i) {
            CURL* h = transfers[i].handle;
            const std::string shown = shown_ + "/" + requests[i].name;  // messages never show the query (it may hold a token)
            if (!h) {
                out.push_back(Status::error(shown + ": cannot start a libcurl transfer"));
                continue;
            }
            if (refused[i])
                out.push_back(Status::error(shown + ": " + refused[i]->message()));
            else
                out.push_back(answer(h, shown, transfers[i], errors[i].data(), sinks[i], requests[i], std::move(responses[i])));
            curl_easy_setopt(h, CURLOPT_ERRORBUFFER, nullptr);
            release(h);
        }
        return out;
    }

    // Hands the transfers to the I/O thread and waits until all are done.
    void perform(const std::vector<Transfer*>& transfers) {
        {
            std::lock_guard lock(ioMutex_);
            for (Transfer* t : transfers) {
                t->done = t->redirected = false;
                t->code = CURLE_OK;
                submitted_.push_back(t);
            }
        }
        curl_multi_wakeup(multi_);
        std::unique_lock lock(ioMutex_);
        ioDone_.wait(lock, [&] { return std::all_of(transfers.begin(), transfers.end(), [](const Transfer* t) { return t->done; }); });
    }

    // After a transfer: if the host redirected it and the redirect is to be
    // followed, points the handle at the new URL (Transfer::redirected) and
    // returns success; an error says why a redirect is refused. Followed: to
    // http or https only, never from https to http, at most kMaxRedirects
    // hops; the user's headers (--header, --token-file) go to the set's own
    // origin only, unless HttpOptions::redirectCredentials.
    Status redirect(Transfer& t, int hops) {
        CURL* h = t.handle;
        long status = 0;
        char* location = nullptr;
        char* from = nullptr;
        curl_easy_getinfo(h, CURLINFO_RESPONSE_CODE, &status);
        curl_easy_getinfo(h, CURLINFO_REDIRECT_URL, &location);
        curl_easy_getinfo(h, CURLINFO_EFFECTIVE_URL, &from);
        const bool redirect = status == 301 || status == 302 || status == 303 || status == 307 || status == 308;
        if (!redirect || !location || !from) return {};  // answered as it is
        const std::string target = location, shown = target.substr(0, target.find('?'));
        if (hops >= kMaxRedirects) return Status::error("more than " + std::to_string(kMaxRedirects) + " redirects (a loop?)");
        const Origin to = originOf(target), at = originOf(from);
        if (to.scheme != "http" && to.scheme != "https")
            return Status::error("redirected to " + shown + ", which is not followed: only http and https are");
        if (at.scheme == "https" && to.scheme == "http")
            return Status::error("redirected to " + shown + ", which is not followed: https never gives way to plain http");
        curl_easy_setopt(h, CURLOPT_URL, target.c_str());
        // A store's signature and keys never leave its endpoint, whatever
        // --redirect-credentials says.
        const bool credentials = to == origin_ || (options_.redirectCredentials && !store_);
        curl_easy_setopt(h, CURLOPT_HTTPHEADER, credentials ? t.headers : nullptr);
        sign(h, credentials);
        t.withoutCredentials |= !credentials && (headers_ || (store_ && !store_->userpwd.empty()));
        t.redirected = true;
        return {};
    }

    // What a finished transfer means for its request.
    Result<Response> answer(CURL* h, const std::string& shown, const Transfer& t, const char* error, const Sink& sink,
                            const Request& q, Response r) const {
        const CURLcode code = t.code;
        if (sink.tooLong)
            return Status::error(shown + ": response longer than the " + std::to_string(q.maxBytes) + " bytes expected");
        curl_easy_getinfo(h, CURLINFO_RESPONSE_CODE, &r.status);
        // The write callback stops an unwanted answer past kMaxErrorPageBytes:
        // its status says what went wrong, not the stopped transfer.
        const bool unwanted = q.wanted && r.status != q.wanted;
        if (code != CURLE_OK && !(code == CURLE_WRITE_ERROR && unwanted)) {
            const std::string message = shown + ": " + transferError(code, error);
            return permanentTransferError(code) ? Status::error(message) : Status::transient(message);
        }
        if (unwanted) {
            if ((r.status == 401 || r.status == 403) && store_ && !t.withoutCredentials)
                return Status::error(shown + ": HTTP " + std::to_string(r.status) +
                                     ": the store refuses the credentials, or they lack permission to read it (docs/STORAGE.md)");
            if (r.status == 404 && store_)
                return Status::error(shown + ": HTTP 404: no such object, or no bucket '" + store_->shown.substr(5, store_->shown.find('/', 5) - 5) + "'");
            if (r.status == 401 || r.status == 403)
                return Status::error(shown + ": HTTP " + std::to_string(r.status) + ": the host refuses access " +
                                     (t.withoutCredentials ? "(a redirect led to another origin, which was not sent the "
                                                             "credentials: --redirect-credentials sends them)"
                                                           : "(send credentials with --header or --token-file)"));
            if (q.wanted == 206 && r.status == 200)
                return Status::error(shown + ": the host ignores Range requests (it answered 200 with the whole file); "
                                     "serve it from one that honours Range (nginx, an object store or CDN, surfcast-serve)");
            return httpError(shown, r.status);
        }
        // A login page answers 200 in place of the file asked for.
        char* type = nullptr;
        curl_easy_getinfo(h, CURLINFO_CONTENT_TYPE, &type);
        if (q.wanted && type && std::strncmp(type, "text/html", 9) == 0)
            return Status::error(shown + ": the host answered with an HTML page, not the tile set's file (a login page?)");
        // "Content-Range: bytes FIRST-LAST/LENGTH" (LENGTH "*" where unknown):
        // the range asked for, or the answer is another's.
        curl_header* range = nullptr;
        if (q.wanted == 206 && curl_easy_header(h, "Content-Range", 0, CURLH_HEADER, -1, &range) == CURLHE_OK) {
            const std::string value = range->value;
            const size_t slash = value.find('/');
            if (value.rfind("bytes " + q.range + "/", 0) != 0)
                return Status::error(shown + ": asked for bytes " + q.range + ", the host answered " + value.substr(0, 64));
            char* end = nullptr;
            if (slash != std::string::npos && std::isdigit(static_cast<unsigned char>(value[slash + 1]))) {
                errno = 0;
                const unsigned long long n = std::strtoull(value.c_str() + slash + 1, &end, 10);
                if (errno == 0 && *end == '\0') r.total = uint64_t(n);
            }
        }
        curl_header* etag = nullptr;
        if (curl_easy_header(h, "ETag", 0, CURLH_HEADER, -1, &etag) == CURLHE_OK) r.etag = etag->value;
        // Batches go to the set's own URL (a POST is not redirected): one
        // offered at a redirect's target is not taken.
        curl_header* offered = nullptr;
        if (!t.moved && curl_easy_header(h, "Surfcast-Batch", 0, CURLH_HEADER, -1, &offered) == CURLHE_OK &&
            std::isdigit(static_cast<unsigned char>(offered->value[0]))) {
            char* end = nullptr;
            const unsigned long n = std::strtoul(offered->value, &end, 10);
            if (*end == '\0' && n <= kMaxBatchNodesOffered) r.batchNodes = size_t(n);
        }
        return r;
    }

    // An HTTP status that is not the answer wanted: transient where asking
    // again may succeed (transfer_errors.h), else permanent.
    static Status httpError(const std::string& shown, long status) {
        const std::string message = shown + ": HTTP " + std::to_string(status);
        return transientHttpStatus(status) ? Status::transient(message) : Status::error(message);
    }

    std::string transferError(CURLcode code, const char* detail) const {
        const std::string why = *detail ? detail : curl_easy_strerror(code);
        switch (code) {
        case CURLE_PEER_FAILED_VERIFICATION:
        case CURLE_SSL_CACERT_BADFILE:
        case CURLE_SSL_CERTPROBLEM:
        case CURLE_SSL_CONNECT_ERROR: {
            return "TLS with the host failed (" + why + ")" + (options_.caFile.empty() ? "" : "; --ca-file " + options_.caFile);
        }
        case CURLE_OPERATION_TIMEDOUT: return "no answer for " + std::to_string(options_.timeoutSeconds) + " s (" + why + ")";
        case CURLE_ABORTED_BY_CALLBACK: return "cancelled: the reader is closing";
        default: return why;
        }
    }

    void ioLoop() {
        SigpipeBlock noSigpipe;  // for the thread's life: sigpipe.h says why
        std::unordered_map<CURL*, Transfer*> running;
        while (true) {
            {
                std::lock_guard lock(ioMutex_);
                if (stopping_) break;
                if (cancelled_) {  // every transfer ends now, those waiting to start too
                    for (auto& [h, t] : running) {
                        curl_multi_remove_handle(multi_, h);
                        t->code = CURLE_ABORTED_BY_CALLBACK;
                        t->done = true;
                    }
                    running.clear();
                    for (Transfer* t : submitted_) {
                        t->code = CURLE_ABORTED_BY_CALLBACK;
                        t->done = true;
                    }
                    submitted_.clear();
                }
                for (Transfer* t : submitted_) {
                    if (curl_multi_add_handle(multi_, t->handle) == CURLM_OK) {
                        running[t->handle] = t;
                    } else {
                        t->code = CURLE_FAILED_INIT;
                        t->done = true;
                    }
                }
                submitted_.clear();
            }
            ioDone_.notify_all();  // any that failed to start
            int active = 0;
            curl_multi_perform(multi_, &active);
            int left = 0;
            bool finished = false;
            while (CURLMsg* m = curl_multi_info_read(multi_, &left)) {
                if (m->msg != CURLMSG_DONE) continue;
                CURL* h = m->easy_handle;
                const CURLcode result = m->data.result;
                curl_multi_remove_handle(multi_, h);
                auto it = running.find(h);
                if (it == running.end()) continue;
                std::lock_guard lock(ioMutex_);
                it->second->code = result;
                it->second->done = true;
                running.erase(it);
                finished = true;
            }
            if (finished) ioDone_.notify_all();
            curl_multi_poll(multi_, nullptr, 0, 1000, nullptr);  // until a socket is ready or a wakeup
        }
    }


    static constexpr int kMaxRedirects = 8;
    std::string base_, query_, shown_;
    Origin origin_;  // the set's: where the user's headers go
    HttpOptions options_;
    std::optional<StoreAccess> store_;
    curl_slist* headers_;
    std::atomic<size_t> batchNodes_{0};  // tileset.json's Surfcast-Batch: 0 where it offers none
    std::atomic<uint64_t> version_{0};   // 1 + the hierarchy CRC of the tileset.json read; 0: none
    std::mutex mutex_;
    std::vector<CURL*> idle_;  // easy handles not in use
    CURLM* multi_;
    std::mutex ioMutex_;
    std::condition_variable ioDone_;
    std::vector<Transfer*> submitted_;  // waiting for the I/O thread to start them
    bool stopping_ = false;
    bool cancelled_ = false;  // cancel(): no transfer runs from now on
    std::thread io_;  // last: starts when everything above is ready
};

}  // namespace

namespace {

CURLM* newMulti() {
    CURLM* multi = curl_multi_init();
    if (!multi) return nullptr;
    curl_multi_setopt(multi, CURLMOPT_MAX_HOST_CONNECTIONS, long(kMaxHostConnections));
    // Keep that many alive between requests (libcurl's default cache holds
    // 4 per easy handle in the multi at the time, and closes the rest).
    curl_multi_setopt(multi, CURLMOPT_MAXCONNECTS, long(kMaxHostConnections));
    return multi;
}

// A set (or an input's bucket) at s3://BUCKET/PREFIX, read as the HTTP source
// of its objects' URLs, every request signed where there are credentials.
Result<std::unique_ptr<TileSource>> openStoreSource(const std::string& location, const HttpOptions& http) {
    auto url = parseS3Url(location);
    if (!url) return url.status();
    while (!url->key.empty() && url->key.back() == '/') url->key.pop_back();
    auto env = s3Environment();
    if (!env) return env.status();
    curl_slist* headers = curl_slist_append(nullptr, "x-amz-content-sha256: UNSIGNED-PAYLOAD");
    if (headers && !env->sessionToken.empty()) headers = curl_slist_append(headers, ("x-amz-security-token: " + env->sessionToken).c_str());
    CURLM* multi = headers ? newMulti() : nullptr;
    if (!multi) {
        curl_slist_free_all(headers);
        return Status::error("libcurl: cannot start a multi handle");
    }
    StoreAccess access{"s3://" + url->bucket + (url->key.empty() ? "" : "/" + url->key), "aws:amz:" + env->region + ":s3",
                       env->accessKey.empty() ? "" : env->accessKey + ":" + env->secretKey};
    HttpOptions options = http;
    options.timeoutSeconds = std::max(options.timeoutSeconds, env->timeoutSeconds);
    return std::unique_ptr<TileSource>(new HttpSource(s3HttpUrl(*env, *url), "", options, headers, multi, std::move(access)));
}

}  // namespace

Result<std::unique_ptr<TileSource>> openTileSource(const std::string& location, const HttpOptions& http) {
    if (!isUrl(location) && !isS3Url(location)) return openFolderSource(location);
    static const CURLcode init = curl_global_init(CURL_GLOBAL_DEFAULT);  // once, before any thread uses libcurl
    if (init != CURLE_OK) return Status::error(std::string("libcurl: ") + curl_easy_strerror(init));
    if (isS3Url(location)) return openStoreSource(location, http);
    const size_t scheme = location.find("://") + 3;
    const size_t q = location.find('?');
    std::string base = location.substr(0, q), query = q == std::string::npos ? "" : location.substr(q);
    while (!base.empty() && base.back() == '/') base.pop_back();
    if (base.size() <= scheme || base.find_first_of(" \t\r\n") != std::string::npos)
        return Status::error(base + ": not an http(s)://HOST[:PORT]/PATH URL");
    // Headers: the user's, then the token's; each must be one "Name: value" line.
    std::vector<std::string> lines = http.headers;
    if (!http.tokenFile.empty()) {
        std::FILE* f = std::fopen(http.tokenFile.c_str(), "rb");
        if (!f) return Status::error(http.tokenFile + ": " + std::strerror(errno));
        std::string token;
        char buf[4096];
        for (size_t n; (n = std::fread(buf, 1, sizeof(buf), f)) > 0 && token.size() < kMaxTokenBytes;) token.append(buf, n);
        std::fclose(f);
        while (!token.empty() && std::isspace(static_cast<unsigned char>(token.back()))) token.pop_back();
        if (token.empty() || token.size() >= kMaxTokenBytes || token.find_first_of("\r\n") != std::string::npos)
            return Status::error(http.tokenFile + ": not a token (one line, under " + std::to_string(kMaxTokenBytes) + " bytes)");
        lines.push_back("Authorization: Bearer " + token);
    }
    curl_slist* headers = nullptr;
    for (const std::string& line : lines) {
        const size_t colon = line.find(':');
        if (colon == 0 || colon == std::string::npos || line.find_first_of("\r\n") != std::string::npos) {
            curl_slist_free_all(headers);
            return Status::error("--header wants 'Name: value' on one line; got '" + line.substr(0, line.find(':')) + ":...'");
        }
        curl_slist* more = curl_slist_append(headers, line.c_str());
        if (!more) {
            curl_slist_free_all(headers);
            return Status::error("libcurl: out of memory");
        }
        headers = more;
    }
    if (http.insecure)
        std::fprintf(stderr, "warning: --insecure: TLS certificates are NOT verified; anyone on the way to %s can read and change what is fetched\n",
                     base.substr(0, base.find('/', scheme)).c_str());
    CURLM* multi = newMulti();
    if (!multi) {
        curl_slist_free_all(headers);
        return Status::error("libcurl: cannot start a multi handle");
    }
    return std::unique_ptr<TileSource>(new HttpSource(base, query, http, headers, multi));
}

Result<TilesetReader> openTileset(const std::string& location, const HttpOptions& http) {
    if (!isUrl(location) && !isS3Url(location)) return TilesetReader::open(location);
    // A reader reads each byte once, in one go: a fault is asked again.
    HttpOptions options = http;
    options.retries = std::max(options.retries, 3);
    auto source = openTileSource(location, options);
    if (!source) return source.status();
    return TilesetReader::open(std::move(*source));
}

}  // namespace surfcast
