#include "byte_stream.h"

#include "input_point.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <set>
#include <utility>

namespace surfcast {

std::string lowerExtension(const std::string& path) {
    // A URL's query (a presigned URL's, shown as "?…") is not the file's name.
    const bool url = path.find("://") != std::string::npos;
    std::string ext = std::filesystem::path(url ? path.substr(0, path.find_first_of("?#")) : path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return ext;
}

void warnOnce(const std::string& message) {
    static std::mutex mutex;
    static std::set<std::string> warned;
    std::lock_guard lock(mutex);
    if (warned.insert(message).second) std::fprintf(stderr, "warning: %s\n", message.c_str());
}

namespace {
constexpr uint64_t kBufferSize = 1 << 20;        // 1 MiB: large sequential reads, bounded memory
constexpr uint64_t kRemoteBufferSize = 4 << 20;  // a URL's: one request a buffer
constexpr size_t kFirstRead = 64 << 10;
}

Result<ByteStream> ByteStream::open(const std::string& path, const HttpOptions& http) {
    ByteStream s;
    s.path_ = path;
    auto file = InputFile::open(path, http);
    if (!file) return file.status();
    s.file_ = std::move(*file);
    s.fileSize_ = s.file_->size();
    // No bigger than the file: a build of thousands of small files opens each
    // several times, and a zero-filled 1 MiB per open cost more than decoding
    // them (BENCHMARKS.md, "Small files: a buffer per open").
    const uint64_t most = isRemoteInput(path) ? kRemoteBufferSize : kBufferSize;
    s.buffer_.resize(size_t(s.fileSize_ > 0 ? std::min(s.fileSize_, most) : most));
    return s;
}

ByteStream::ByteStream(ByteStream&& o) noexcept { *this = std::move(o); }

ByteStream& ByteStream::operator=(ByteStream&& o) noexcept {
    std::swap(path_, o.path_);
    std::swap(file_, o.file_);
    std::swap(buffer_, o.buffer_);
    std::swap(begin_, o.begin_);
    std::swap(end_, o.end_);
    std::swap(offset_, o.offset_);
    std::swap(line_, o.line_);
    std::swap(fileSize_, o.fileSize_);
    std::swap(failed_, o.failed_);
    std::swap(error_, o.error_);
    std::swap(fills_, o.fills_);
    return *this;
}

ByteStream::~ByteStream() = default;

bool ByteStream::fill() {
    if (begin_ < end_) return true;
    begin_ = end_ = 0;
    if (failed_) return false;
    // The first read is small: many opens read a header or the magic bytes
    // only, and a URL's read is a request of that size.
    const size_t want = fills_++ == 0 ? std::min<size_t>(buffer_.size(), kFirstRead) : buffer_.size();
    auto n = file_->read(offset_, buffer_.data(), want);
    if (!n) {
        failed_ = true;
        error_ = n.status().message();
        return false;
    }
    end_ = *n;
    return end_ > 0;
}

bool ByteStream::readBytes(void* dst, size_t n) {
    auto* out = static_cast<char*>(dst);
    while (n > 0) {
        if (!fill()) return false;
        size_t take = std::min(n, end_ - begin_);
        std::memcpy(out, buffer_.data() + begin_, take);
        begin_ += take;
        offset_ += take;
        out += take;
        n -= take;
    }
    return true;
}

bool ByteStream::seek(uint64_t absolute) {
    if (absolute > fileSize_) return false;
    begin_ = end_ = 0;
    offset_ = absolute;
    return true;
}

bool ByteStream::skip(uint64_t n) {
    if (n <= end_ - begin_) {
        begin_ += n;
        offset_ += n;
        return true;
    }
    return seek(offset_ + n);
}

bool ByteStream::readLine(std::string* line) {
    line->clear();
    bool any = false;
    while (fill()) {
        any = true;
        const char* start = buffer_.data() + begin_;
        const void* nl = std::memchr(start, '\n', end_ - begin_);
        size_t take = nl ? size_t(static_cast<const char*>(nl) - start) : end_ - begin_;
        line->append(start, take);
        begin_ += take;
        offset_ += take;
        if (nl) {
            ++begin_;
            ++offset_;
            ++line_;
            break;
        }
    }
    if (failed_) {  // not a partial line: the rest of it never came
        line->clear();
        return false;
    }
    if (!line->empty() && line->back() == '\r') line->pop_back();
    return any;
}

bool ByteStream::readToken(std::string_view* token) {
    token_.clear();
    while (fill()) {
        char c = buffer_[begin_];
        bool space = c == ' ' || c == '\t' || c == '\n' || c == '\r';
        if (space && !token_.empty()) break;
        if (!space) token_.push_back(c);
        if (c == '\n') ++line_;
        ++begin_;
        ++offset_;
    }
    if (failed_) token_.clear();  // not a partial token
    *token = token_;
    return !token_.empty();
}

}  // namespace surfcast
