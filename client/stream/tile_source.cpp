#include "tile_source.h"

#include <fcntl.h>
#include <httplib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <thread>
#include <unordered_map>

#include "sigpipe.h"

namespace surfcast {

Result<std::vector<std::vector<uint8_t>>> TileSource::blobs(const std::vector<NodeRecord>& nodes) {
    std::vector<std::vector<uint8_t>> out;
    for (const NodeRecord& n : nodes) {
        auto bytes = blocks(n.blockOffset, n.blockSize);
        if (!bytes) return bytes.status();
        out.push_back(std::move(*bytes));
    }
    return out;
}

namespace {

// The body of an error response is read and dropped up to this much.
constexpr uint64_t kMaxErrorPageBytes = 1 << 20;
// A server that does not accept within this fails the request.
constexpr int kConnectTimeoutSeconds = 5;

class LocalSource : public TileSource {
public:
    explicit LocalSource(std::string dir) : dir_(std::move(dir)) {}
    Result<std::vector<uint8_t>> file(const std::string& name, uint64_t maxBytes) override {
        std::string path = dir_ + "/" + name;
        std::FILE* f = std::fopen(path.c_str(), "rb");
        if (!f) return Status::error(path + ": " + std::strerror(errno));
        std::vector<uint8_t> out;
        uint8_t buf[1 << 16];
        for (size_t n; (n = std::fread(buf, 1, sizeof(buf), f)) > 0;) {
            if (n > maxBytes - out.size()) {
                std::fclose(f);
                return Status::error(path + ": longer than the " + std::to_string(maxBytes) + " bytes expected");
            }
            out.insert(out.end(), buf, buf + n);
        }
        std::fclose(f);
        return out;
    }
    ~LocalSource() override {
        if (fd_ >= 0) ::close(fd_);
    }
    // blocks.bin is opened once and read with pread from any thread. A set
    // rebuilt meanwhile (renamed over) is still read from the file opened.
    Result<std::vector<uint8_t>> blocks(uint64_t offset, uint64_t size) override {
        std::string path = dir_ + "/blocks.bin";
        {
            std::lock_guard lock(mutex_);
            if (fd_ < 0) fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
            if (fd_ < 0) return Status::error(path + ": " + std::strerror(errno));
        }
        // The range comes from the set's own metadata: checked against the
        // file before anything is allocated for it.
        struct stat st{};
        if (::fstat(fd_, &st) != 0) return Status::error(path + ": " + std::strerror(errno));
        const uint64_t fileSize = uint64_t(st.st_size);
        if (offset > fileSize || size > fileSize - offset)
            return Status::error(path + ": " + std::to_string(size) + " bytes at " + std::to_string(offset) +
                                 " reach past the end of the file (" + std::to_string(fileSize) + " bytes)");
        std::vector<uint8_t> out(size);
        for (uint64_t done = 0; done < size;) {
            ssize_t n = ::pread(fd_, out.data() + done, size - done, off_t(offset + done));
            if (n <= 0)
                return Status::error(path + ": cannot read " + std::to_string(size) + " bytes at " + std::to_string(offset) +
                                     (n < 0 ? std::string(": ") + std::strerror(errno) : std::string(": end of file")));
            done += uint64_t(n);
        }
        return out;
    }
    std::string describe() const override { return dir_; }

private:
    std::string dir_;
    std::mutex mutex_;
    int fd_ = -1;
};

class HttpSource : public TileSource {
public:
    HttpSource(std::string origin, std::string path, int timeoutSeconds)
        : origin_(std::move(origin)), path_(std::move(path)), timeoutSeconds_(timeoutSeconds) {}
    Result<std::vector<uint8_t>> file(const std::string& name, uint64_t maxBytes) override {
        return get(name, nullptr, maxBytes);
    }
    Result<std::vector<uint8_t>> blocks(uint64_t offset, uint64_t size) override {
        if (size == 0) return std::vector<uint8_t>{};
        std::pair<uint64_t, uint64_t> range{offset, offset + size - 1};
        auto bytes = get("blocks.bin", &range, size);
        if (bytes && bytes->size() != size)
            return Status::error(describe() + "/blocks.bin: asked for " + std::to_string(size) + " bytes at " +
                                 std::to_string(offset) + ", got " + std::to_string(bytes->size()));
        return bytes;
    }
    std::string describe() const override { return origin_ + path_; }

    // The server's POST {set}/batch where it answers (tried once); a static
    // host refuses it (404/405) and every later call takes the ranges.
    Result<std::vector<std::vector<uint8_t>>> blobs(const std::vector<NodeRecord>& nodes) override {
        if (nodes.size() < 2 || batch_ == Batch::No) return TileSource::blobs(nodes);
        std::string body, url = path_ + "/batch";
        uint64_t expected = 0;  // what the answer holds: a length and a blob per node
        for (const NodeRecord& n : nodes) {
            body += n.key.name() + ",";
            expected += 4 + uint64_t(n.blockSize);
        }
        httplib::Request req;
        req.method = "POST";
        req.path = url;
        req.body = body;
        req.set_header("Content-Type", "text/plain");
        // An error page is not kept (its status decides), but it is bounded too.
        int status = 0;
        req.response_handler = [&](const httplib::Response& r) {
            status = r.status;
            return true;
        };
        std::string received;
        bool tooLong = false;
        req.content_receiver = [&](const char* data, size_t length, uint64_t, uint64_t) {
            const uint64_t limit = status == 200 ? expected : kMaxErrorPageBytes;
            if (length > limit - received.size()) return !(tooLong = true);
            if (status == 200) received.append(data, length);
            else received.resize(received.size() + length);
            return true;
        };
        SigpipeBlock noSigpipe;  // sigpipe.h says why
        auto res = client().send(req);
        if (tooLong) return Status::error(origin_ + url + ": response longer than the " + std::to_string(expected) + " bytes asked for");
        if (!res) return Status::error(origin_ + url + ": " + httplib::to_string(res.error()));
        if (res->status == 200) res->body = std::move(received);
        if (res->status != 200) {
            if (batch_ == Batch::Unknown && res->status >= 400 && res->status < 500) {
                batch_ = Batch::No;
                return TileSource::blobs(nodes);
            }
            return Status::error(origin_ + url + ": HTTP " + std::to_string(res->status));
        }
        batch_ = Batch::Yes;
        // For each key in order: u32 little-endian length, then the blob.
        std::vector<std::vector<uint8_t>> out;
        const auto* p = reinterpret_cast<const uint8_t*>(res->body.data());
        size_t at = 0, size = res->body.size();
        for (size_t i = 0; i < nodes.size(); ++i) {
            if (size - at < 4) return Status::error(origin_ + url + ": response ends before node " + nodes[i].key.name());
            uint32_t length = uint32_t(p[at]) | uint32_t(p[at + 1]) << 8 | uint32_t(p[at + 2]) << 16 | uint32_t(p[at + 3]) << 24;
            at += 4;
            if (size - at < length)
                return Status::error(origin_ + url + ": response ends inside node " + nodes[i].key.name());
            out.emplace_back(p + at, p + at + length);
            at += length;
        }
        return out;
    }

private:
    enum class Batch { Unknown, Yes, No };

    httplib::Client& client() {
        std::lock_guard lock(mutex_);
        auto& c = clients_[std::this_thread::get_id()];
        if (!c) {
            c = std::make_unique<httplib::Client>(origin_);
            c->set_keep_alive(true);
            c->set_connection_timeout(kConnectTimeoutSeconds, 0);
            c->set_read_timeout(timeoutSeconds_, 0);
        }
        return *c;
    }
    // The body is kept only up to maxBytes: a longer one (a hostile or broken
    // host) cancels the request.
    Result<std::vector<uint8_t>> get(const std::string& name, const std::pair<uint64_t, uint64_t>* range, uint64_t maxBytes) {
        std::string url = path_ + "/" + name;
        httplib::Headers headers;
        if (range)
            headers.emplace("Range", "bytes=" + std::to_string(range->first) + "-" + std::to_string(range->second));
        const int wanted = range ? 206 : 200;
        int status = 0;
        std::vector<uint8_t> body;
        uint64_t dropped = 0;  // of an error page: not kept, but bounded too
        bool tooLong = false;
        SigpipeBlock noSigpipe;  // sigpipe.h says why
        auto res = client().Get(
            url, headers,
            [&](const httplib::Response& r) {
                status = r.status;
                return true;
            },
            [&](const char* data, size_t length) {
                if (status != wanted) return (dropped += length) <= kMaxErrorPageBytes;
                if (length > maxBytes - body.size()) return !(tooLong = true);
                body.insert(body.end(), data, data + length);
                return true;
            });
        if (tooLong)
            return Status::error(origin_ + url + ": response longer than the " + std::to_string(maxBytes) + " bytes expected");
        if (!res) return Status::error(origin_ + url + ": " + httplib::to_string(res.error()));
        if (res->status != wanted) return Status::error(origin_ + url + ": HTTP " + std::to_string(res->status));
        return body;
    }

    std::string origin_, path_;
    int timeoutSeconds_;
    std::atomic<Batch> batch_{Batch::Unknown};
    std::mutex mutex_;
    std::unordered_map<std::thread::id, std::unique_ptr<httplib::Client>> clients_;
};

}  // namespace

bool isUrl(const std::string& location) { return location.rfind("http://", 0) == 0; }

Result<std::unique_ptr<TileSource>> openTileSource(const std::string& location, int timeoutSeconds) {
    if (!isUrl(location)) return std::unique_ptr<TileSource>(new LocalSource(location));
    size_t slash = location.find('/', 7);
    std::string origin = location.substr(0, slash), path = slash == std::string::npos ? "" : location.substr(slash);
    while (!path.empty() && path.back() == '/') path.pop_back();
    if (origin.size() <= 7) return Status::error(location + ": not an http://HOST[:PORT]/PATH URL");
    return std::unique_ptr<TileSource>(new HttpSource(origin, path, std::max(1, timeoutSeconds)));
}

}  // namespace surfcast
