// Helpers shared by the libFuzzer targets (fuzz/README.md).
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <string>

namespace surfcast::fuzz {

// A per-process file in the temporary folder ending in `extension`, removed
// when the process exits normally (libFuzzer's exit() at the end of a run;
// a crash leaves it, next to its artifact).
struct ScratchFile {
    std::string path;
    explicit ScratchFile(const char* extension) {
        const char* tmp = std::getenv("TMPDIR");
        path = std::string(tmp && *tmp ? tmp : "/tmp") + "/surfcast-fuzz-" + std::to_string(::getpid()) + extension;
    }
    ~ScratchFile() { ::unlink(path.c_str()); }
    ScratchFile(const ScratchFile&) = delete;
    ScratchFile& operator=(const ScratchFile&) = delete;
};

// Replaces the file's contents with the input; false if that failed.
inline bool writeScratch(const std::string& path, const uint8_t* data, size_t size) {
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
    if (fd < 0) return false;
    size_t done = 0;
    while (done < size) {
        ssize_t n = ::write(fd, data + done, size - done);
        if (n <= 0) break;
        done += size_t(n);
    }
    ::close(fd);
    return done == size;
}

}  // namespace surfcast::fuzz
