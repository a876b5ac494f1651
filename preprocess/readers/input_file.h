// An input file's bytes, read at any offset: a local file, or one at an
// http(s) or s3:// URL read by ranges through the project's HTTP client
// (net/http_tile_source.h, signed for S3), so that workers that do not share a file system
// with the scans read them from their host. ByteStream and the LAZ decoder
// read through it.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "status.h"
#include "tile_source.h"

namespace surfcast {

class InputFile {
public:
    // A path, an http(s) URL (reached as `http` says: credentials in
    // headers, or a presigned URL's query string: signedInput), or an s3://
    // object (net/object_store.h). Fails naming the file.
    static Result<std::unique_ptr<InputFile>> open(const std::string& path, const HttpOptions& http = {});
    virtual ~InputFile() = default;

    const std::string& path() const { return path_; }
    uint64_t size() const { return size_; }
    // Up to n bytes at `offset` into out (fewer only where the file ends), or
    // an error naming the file and the offset. One thread at a time.
    virtual Result<size_t> read(uint64_t offset, void* out, size_t n) = 0;

protected:
    std::string path_;
    uint64_t size_ = 0;
};

// An InputFile as the Rust readers (laz_ffi: LAZ, E57) read it, through a C
// callback (ScReadAt), keeping the last failure's message for their error.
struct FfiInput {
    std::unique_ptr<InputFile> file;
    std::string error;

    // Nothing may unwind into the Rust frames that call this.
    static int64_t readAt(void* ctx, uint64_t offset, uint8_t* out, uint64_t len) noexcept;
    // The decoder's message, with the read failure behind it where there was one.
    std::string explain(const char* decoder) const { return error.empty() ? std::string(decoder) : std::string(decoder) + " (" + error + ")"; }
};

// An http(s) URL or an s3:// URL: read by ranges, not from a file system.
bool isRemoteInput(const std::string& path);
// `url` as messages, logs and stored records show it: without user
// information, and with "?…" for its query string (which may hold a
// signature). Anything but an http(s) URL is returned as it is.
std::string redactUrl(const std::string& url);

// A presigned URL (its query string signs it) kept in this process's memory
// under its redacted form, which the function returns: the form plans,
// records, messages and InputFile::open take. Other paths come back as they are.
std::string signedInput(const std::string& url);

// The byte size of the file at `path` (a URL asks its host, reached as
// `http` says), or an error.
Result<uint64_t> inputFileSize(const std::string& path, const HttpOptions& http = {});

}  // namespace surfcast
