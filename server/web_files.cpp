#include "web_files.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "crc32.h"

namespace surfcast {

namespace {
std::string contentType(const std::string& name) {
    static const std::pair<const char*, const char*> kTypes[] = {
        {".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"}, {".css", "text/css; charset=utf-8"},
        {".wasm", "application/wasm"},         {".map", "application/json"},               {".json", "application/json"},
        {".png", "image/png"},                 {".svg", "image/svg+xml"},
    };
    for (auto [ext, type] : kTypes)
        if (name.size() > std::string(ext).size() && name.ends_with(ext)) return type;
    return "application/octet-stream";
}
}  // namespace

Result<WebFiles> loadWebFiles(const std::string& dir) {
    namespace fs = std::filesystem;
    std::error_code ec;
    WebFiles files;
    uint64_t total = 0;
    fs::directory_iterator it(dir, ec);
    if (ec) return Status::error("viewer folder " + dir + ": " + ec.message());
    for (const fs::directory_entry& e : it) {
        if (e.is_symlink(ec) || !e.is_regular_file(ec)) continue;
        const std::string name = e.path().filename().string();
        total += e.file_size(ec);
        if (ec || total > kMaxWebBytes)
            return Status::error("viewer folder " + dir + ": more than " + std::to_string(kMaxWebBytes >> 20) + " MiB");
        std::ifstream f(e.path(), std::ios::binary);
        std::ostringstream text;
        text << f.rdbuf();
        if (!f) return Status::error("viewer folder " + dir + ": cannot read " + name);
        WebFile& w = files[name];
        w.bytes = text.str();
        w.type = contentType(name);
        char tag[16];
        std::snprintf(tag, sizeof tag, "%08x", crc32(reinterpret_cast<const uint8_t*>(w.bytes.data()), w.bytes.size()));
        w.etag = "\"w-" + std::string(tag) + "\"";
    }
    if (!files.count("index.html")) return Status::error("viewer folder " + dir + " has no index.html (build it: cmake --build build)");
    return files;
}

std::string defaultWebFolder() {
    std::error_code ec;
    std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
    if (ec) return "web";
    return (exe.parent_path().parent_path() / "web").string();
}

}  // namespace surfcast
