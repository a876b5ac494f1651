// Buffered sequential reading of an input file (a path or an http(s) URL:
// input_file.h), with the byte offset and line number every error message
// needs. Readers share it instead of each owning a FILE*.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "input_file.h"
#include "status.h"

namespace surfcast {

class ByteStream {
public:
    static Result<ByteStream> open(const std::string& path, const HttpOptions& http = {});  // a URL reached as `http` says
    ByteStream(ByteStream&&) noexcept;
    ByteStream& operator=(ByteStream&&) noexcept;
    ~ByteStream();

    const std::string& path() const { return path_; }
    uint64_t offset() const { return offset_; }  // bytes consumed so far
    uint64_t line() const { return line_; }      // 1-based line of the next byte (text formats)
    uint64_t fileSize() const { return fileSize_; }

    // Copies exactly n bytes; false at end of file, with what was left consumed
    // (the offset then names where the data ran out).
    bool readBytes(void* dst, size_t n);
    bool skip(uint64_t n);
    bool seek(uint64_t absolute);
    // Next line without its terminator ('\n' or "\r\n"); false at end of file.
    bool readLine(std::string* line);
    // Next whitespace-separated token (spans lines); false at end of file.
    bool readToken(std::string_view* token);
    // A read failed (an I/O or HTTP error): every read since returned false,
    // never a partial line or token; at() and atLine() say what failed, and a
    // reader that sees an end checks this before taking it for one.
    bool failed() const { return failed_; }

    // "PATH: byte N" / "PATH: line N" prefix for errors, with what failed
    // where a read did (an I/O or HTTP error: the reader then sees an end).
    std::string at() const { return path_ + ": byte " + std::to_string(offset_) + failure(); }
    std::string atLine() const { return path_ + ": line " + std::to_string(line_) + failure(); }

private:
    ByteStream() = default;
    bool fill();

    std::string path_;
    std::unique_ptr<InputFile> file_;
    std::vector<char> buffer_;
    size_t begin_ = 0, end_ = 0;
    uint64_t offset_ = 0, line_ = 1, fileSize_ = 0;
    bool failed_ = false;  // a read failed (an I/O or HTTP error, not the end)
    std::string error_;    // and how
    uint64_t fills_ = 0;   // reads of the file so far
    std::string failure() const { return failed_ ? " (read failed: " + error_ + ")" : ""; }
    std::string token_;
};

}  // namespace surfcast
