// Helpers shared by the libFuzzer targets (fuzz/README.md).
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "inputs.h"

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

// Reads the input file at `path` whole through the build's own input path
// (forEachInput: the reader chosen by extension and magic bytes, every scalar
// field asked for), its errors dropped: what the reader targets run.
inline void readWhole(const std::string& path, size_t meshMaxSurfels = 100000) {
    InputOptions options;
    options.paths = {path};
    options.scalars.all = true;
    options.mesh.maxSurfels = meshMaxSurfels;  // as --mesh-max-surfels: a few faces may ask for any density
    std::vector<InputPoint> points(4096);
    (void)forEachInput(options, [&](size_t, PointReader& reader) -> Status {
        for (;;) {
            auto n = reader.read(points.data(), points.size());
            if (!n) return n.status();
            if (*n == 0) return {};
        }
    });
}

}  // namespace surfcast::fuzz
