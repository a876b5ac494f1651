// The browser viewer's files (web/, built into build/web), held in memory and
// served at / by surfcast-serve (docs/PROTOCOL.md, "Viewer"). A flat folder
// of a few hundred kilobytes: reading it once at start keeps the server free
// of paths from requests touching the file system.
#pragma once

#include <cstdint>
#include <map>
#include <string>

#include "status.h"

namespace surfcast {

struct WebFile {
    std::string bytes;
    std::string type;  // Content-Type
    std::string etag;  // "w-<crc32>"
};

// File name (no slashes) -> file.
using WebFiles = std::map<std::string, WebFile>;

// Most bytes a viewer folder may hold.
inline constexpr uint64_t kMaxWebBytes = uint64_t(64) << 20;

// Reads every regular file directly in `dir` (not symlinks, not sub-folders);
// fails naming the folder when it cannot be read, lacks index.html or is over
// kMaxWebBytes.
Result<WebFiles> loadWebFiles(const std::string& dir);

// The folder surfcast-serve serves by default: `web` beside the folder of the
// running executable (build/bin/surfcast-serve -> build/web).
std::string defaultWebFolder();

}  // namespace surfcast
