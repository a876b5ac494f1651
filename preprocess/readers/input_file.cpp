#include "input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <thread>
#include <cstring>
#include <map>
#include <mutex>
#include <vector>

#include "http_tile_source.h"
#include "object_store.h"

namespace surfcast {

namespace {

// A remote file is read in blocks of this much: one request each, the last
// one kept for the small reads around it (headers, a LAZ chunk table). The
// first block is small: a file is opened for its magic bytes and header too.
constexpr uint64_t kRemoteBlock = 4 << 20;
constexpr uint64_t kFirstBlock = 64 << 10;

class LocalFile final : public InputFile {
public:
    LocalFile(std::string path, int fd, uint64_t size) : fd_(fd) {
        path_ = std::move(path);
        size_ = size;
    }
    ~LocalFile() override { ::close(fd_); }
    Result<size_t> read(uint64_t offset, void* out, size_t n) override {
        size_t done = 0;
        while (done < n) {
            const ssize_t got = ::pread(fd_, static_cast<char*>(out) + done, n - done, off_t(offset + done));
            if (got < 0 && errno == EINTR) continue;
            if (got < 0) return Status::error(path_ + ": byte " + std::to_string(offset + done) + ": " + std::strerror(errno));
            if (got == 0) break;
            done += size_t(got);
        }
        return done;
    }

private:
    int fd_;
};

std::mutex gHttpMutex;
// One HTTP source per origin and way of reaching it (HttpOptions), shared by
// every file there: its connections (and its one I/O thread) serve every
// input from that host. A cache of connections: each caller says how to reach the file.
std::map<std::string, std::shared_ptr<TileSource>> gSources;
std::map<std::string, uint64_t> gSizes;  // by URL and way of reaching it: a file is asked its size once
// Presigned URLs by the redacted form every other part of the build sees.
std::map<std::string, std::string> gSigned;

// A transient failure (a 5xx, a reset connection) is asked again this many
// times, after 0.5, 1 and 2 s, before it fails the read.
constexpr int kRetries = 3;

template <class F>
auto withRetries(F request) {
    auto r = request();
    for (int i = 0; i < kRetries && !r && r.status().isTransient(); ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(500 << i));
        r = request();
    }
    return r;
}

// One source per origin (an http(s) host, a bucket), or per folder and
// query where a URL's query string signs its requests (a presigned URL):
// `location` as openTileSource takes it.
// `location` (a URL) with how it is reached, as the caches key them.
std::string reachKey(const std::string& location, const HttpOptions& http) {
    std::string key = location + '\n' + http.tokenFile + '\n' + http.caFile + '\n' + char('0' + http.insecure) +
                      char('0' + http.redirectCredentials) + std::to_string(http.timeoutSeconds) + ',' + std::to_string(http.retries);
    for (const std::string& h : http.headers) key += '\n' + h;
    return key;
}

Result<std::shared_ptr<TileSource>> source(const std::string& location, const HttpOptions& http) {
    const std::string key = reachKey(location, http);
    std::lock_guard lock(gHttpMutex);
    auto it = gSources.find(key);
    if (it == gSources.end()) {
        auto source = openTileSource(location, http);
        if (!source) return source.status();
        it = gSources.emplace(key, std::shared_ptr<TileSource>(std::move(*source))).first;
    }
    return it->second;
}

// The source of `url`'s origin (an s3:// URL's bucket) and the file's path
// (key) there.
Result<std::pair<std::shared_ptr<TileSource>, std::string>> remote(const std::string& url, const HttpOptions& http) {
    std::string location, name;
    if (isS3Url(url)) {
        auto object = parseS3Url(url);
        if (!object) return object.status();
        if (object->key.empty() || object->key.back() == '/') return Status::error(url + ": not the URL of an object");
        location = "s3://" + object->bucket;
        name = object->key;
    } else {
        const size_t scheme = url.find("://") + 3, slash = url.find('/', scheme);
        const size_t at = url.substr(scheme, slash == std::string::npos ? std::string::npos : slash - scheme).rfind('@');
        if (at != std::string::npos)
            return Status::error(redactUrl(url) + ": an input URL with a user name or password is not taken; give credentials with --header or --token-file");
        const size_t end = url.find_first_of("?#");
        const std::string path = url.substr(0, end);
        if (slash == std::string::npos || slash + 1 >= path.size() || path.back() == '/') return Status::error(redactUrl(url) + ": not the URL of a file");
        // A query string (a presigned URL's signature) goes with every
        // request for the file and shows nowhere: the file's folder with the
        // query is a source of its own.
        const size_t last = path.rfind('/');
        const std::string query = end == std::string::npos || url[end] == '#' ? "" : url.substr(end, url.find('#', end) - end);
        location = (query.empty() ? url.substr(0, slash) : path.substr(0, last)) + query;
        name = query.empty() ? path.substr(slash + 1) : path.substr(last + 1);
    }
    auto opened = source(location, http);
    if (!opened) return opened.status();
    return std::make_pair(*opened, name);
}

Result<uint64_t> remoteSize(const std::string& url, const HttpOptions& http, TileSource& source, const std::string& name) {
    const std::string key = reachKey(url, http);
    {
        std::lock_guard lock(gHttpMutex);
        if (auto it = gSizes.find(key); it != gSizes.end()) return it->second;
    }
    auto size = withRetries([&] { return source.size(name); });
    if (!size) return size.status();
    std::lock_guard lock(gHttpMutex);
    gSizes[key] = *size;
    return *size;
}

class RemoteFile final : public InputFile {
public:
    RemoteFile(std::string url, std::shared_ptr<TileSource> source, std::string name, uint64_t size)
        : source_(std::move(source)), name_(std::move(name)) {
        path_ = std::move(url);
        size_ = size;
    }
    Result<size_t> read(uint64_t offset, void* out, size_t n) override {
        if (offset >= size_) return size_t(0);
        n = size_t(std::min<uint64_t>(n, size_ - offset));
        if (n >= kRemoteBlock) {  // a large read: its own request, not cached
            auto bytes = withRetries([&] { return source_->range(name_, offset, n); });
            if (!bytes) return bytes.status();
            std::memcpy(out, bytes->data(), n);
            return n;
        }
        size_t done = 0;
        while (done < n) {
            const uint64_t at = offset + done;
            if (at < blockStart_ || at >= blockStart_ + block_.size()) {
                // The first read of a file (a header, magic bytes) takes a small block.
                const uint64_t block = block_.empty() && blockStart_ == 0 ? kFirstBlock : kRemoteBlock;
                blockStart_ = at / block * block;
                auto bytes = withRetries([&] { return source_->range(name_, blockStart_, std::min(block, size_ - blockStart_)); });
                if (!bytes) {
                    block_.clear();
                    return bytes.status();
                }
                block_ = std::move(*bytes);
            }
            const size_t take = size_t(std::min<uint64_t>(n - done, blockStart_ + block_.size() - at));
            std::memcpy(static_cast<char*>(out) + done, block_.data() + (at - blockStart_), take);
            done += take;
        }
        return done;
    }

private:
    std::shared_ptr<TileSource> source_;
    std::string name_;
    uint64_t blockStart_ = 0;
    std::vector<uint8_t> block_;
};

}  // namespace

std::string redactUrl(const std::string& url) {
    if (!isUrl(url)) return url;
    const size_t scheme = url.find("://") + 3, end = url.find_first_of("?#"), slash = url.find('/', scheme);
    const size_t at = url.substr(scheme, std::min(slash, end) - scheme).rfind('@');
    std::string shown = at == std::string::npos ? url.substr(0, end) : url.substr(0, scheme) + url.substr(scheme + at + 1, end == std::string::npos ? std::string::npos : end - scheme - at - 1);
    return end != std::string::npos && url[end] == '?' ? shown + "?…" : shown;
}

bool isRemoteInput(const std::string& path) { return isUrl(path) || isS3Url(path); }

namespace {

// A presigned URL as redactUrl shows it (expanding inputs twice keeps it).
bool isRedacted(const std::string& url) { return url.size() >= 4 && url.compare(url.size() - 4, 4, "?…") == 0; }

}  // namespace

std::string signedInput(const std::string& url) {
    // A URL with user information but no query stays as it is, for
    // InputFile::open to refuse by name.
    if (!isUrl(url) || url.find('?') == std::string::npos || isRedacted(url)) return url;
    const std::string shown = redactUrl(url);
    std::lock_guard lock(gHttpMutex);
    gSigned[shown] = url;
    return shown;
}

namespace {

// The URL to ask for `path`: a redacted presigned URL's whole self.
Result<std::string> realUrl(const std::string& path) {
    if (!isRedacted(path)) return path;
    std::lock_guard lock(gHttpMutex);
    auto it = gSigned.find(path);
    if (it == gSigned.end())
        return Status::error(path + ": a presigned URL's query string is kept in memory only, never stored: give the URL on the command line of this process");
    return it->second;
}

}  // namespace

Result<std::unique_ptr<InputFile>> InputFile::open(const std::string& path, const HttpOptions& http) {
    if (isRemoteInput(path)) {
        auto url = realUrl(path);
        if (!url) return url.status();
        auto r = remote(*url, http);
        if (!r) return r.status();
        auto size = remoteSize(path, http, *r->first, r->second);
        if (!size) return size.status();
        return std::unique_ptr<InputFile>(new RemoteFile(redactUrl(path), std::move(r->first), std::move(r->second), *size));
    }
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return Status::error(path + ": cannot open (" + std::strerror(errno) + ")");
    struct stat st{};
    if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        ::close(fd);
        return Status::error(path + ": not a regular file");
    }
    return std::unique_ptr<InputFile>(new LocalFile(path, fd, uint64_t(st.st_size)));
}

Result<uint64_t> inputFileSize(const std::string& path, const HttpOptions& http) {
    if (!isRemoteInput(path)) {
        struct stat st{};
        if (::stat(path.c_str(), &st) != 0) return Status::error(path + ": " + std::strerror(errno));
        return uint64_t(st.st_size);
    }
    auto url = realUrl(path);
    if (!url) return url.status();
    auto r = remote(*url, http);
    if (!r) return r.status();
    return remoteSize(path, http, *r->first, r->second);
}

int64_t FfiInput::readAt(void* ctx, uint64_t offset, uint8_t* out, uint64_t len) noexcept {
    auto* self = static_cast<FfiInput*>(ctx);
    try {
        auto n = self->file->read(offset, out, size_t(len));
        if (n) return int64_t(*n);
        self->error = n.status().message();
    } catch (const std::exception& e) {
        self->error = e.what();
    }
    return -1;
}

}  // namespace surfcast
