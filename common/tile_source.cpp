#include "tile_source.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <unordered_map>
#include <utility>

#include "crc32.h"

namespace surfcast {

Result<std::vector<uint8_t>> TileSource::blocks(uint64_t offset, uint64_t size) {
    auto place = layout_.place(offset, size);
    if (!place) return Status::error(describe() + ": " + place.status().message());
    return range(place->file, place->offset, size);
}

Result<std::vector<std::vector<uint8_t>>> TileSource::blobs(const std::vector<NodeRecord>& nodes) {
    std::vector<std::vector<uint8_t>> out;
    for (const NodeRecord& n : nodes) {
        auto bytes = blocks(n.blockOffset, n.blockSize);
        if (!bytes) return bytes.status();
        out.push_back(std::move(*bytes));
    }
    return out;
}

Result<std::optional<std::vector<uint8_t>>> TileSource::changedFile(const std::string& name, uint64_t maxBytes,
                                                                    std::string* tag) {
    auto bytes = file(name, maxBytes);
    if (!bytes) return bytes.status();
    return ifOtherBytes(std::move(*bytes), tag);
}

std::optional<std::vector<uint8_t>> TileSource::ifOtherBytes(std::vector<uint8_t> bytes, std::string* tag) {
    const std::string crc = "crc-" + std::to_string(crc32(bytes.data(), bytes.size()));
    if (crc == *tag) return std::nullopt;
    *tag = crc;
    return bytes;
}

namespace {

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
        for (auto& [name, fd] : fds_) ::close(fd);
    }
    // Each file is opened once and read with pread from any thread. A set
    // rebuilt meanwhile (renamed over) is still read from the files opened.
    Result<std::vector<uint8_t>> range(const std::string& name, uint64_t offset, uint64_t size) override {
        std::string path = dir_ + "/" + name;
        int fd;
        {
            std::lock_guard lock(mutex_);
            auto it = fds_.find(name);
            if (it == fds_.end()) {
                const int opened = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
                if (opened < 0) return Status::error(path + ": " + std::strerror(errno));
                it = fds_.emplace(name, opened).first;
            }
            fd = it->second;
        }
        // The range comes from the set's own metadata: checked against the
        // file before anything is allocated for it.
        struct stat st{};
        if (::fstat(fd, &st) != 0) return Status::error(path + ": " + std::strerror(errno));
        const uint64_t fileSize = uint64_t(st.st_size);
        if (offset > fileSize || size > fileSize - offset)
            return Status::error(path + ": " + std::to_string(size) + " bytes at " + std::to_string(offset) +
                                 " reach past the end of the file (" + std::to_string(fileSize) + " bytes)");
        std::vector<uint8_t> out(size);
        for (uint64_t done = 0; done < size;) {
            ssize_t n = ::pread(fd, out.data() + done, size - done, off_t(offset + done));
            if (n <= 0)
                return Status::error(path + ": cannot read " + std::to_string(size) + " bytes at " + std::to_string(offset) +
                                     (n < 0 ? std::string(": ") + std::strerror(errno) : std::string(": end of file")));
            done += uint64_t(n);
        }
        return out;
    }
    Result<uint64_t> size(const std::string& name) override {
        struct stat st{};
        const std::string path = dir_ + "/" + name;
        if (::stat(path.c_str(), &st) != 0) return Status::error(path + ": " + std::strerror(errno));
        return uint64_t(st.st_size);
    }
    std::string describe() const override { return dir_; }

private:
    std::string dir_;
    std::mutex mutex_;
    std::unordered_map<std::string, int> fds_;  // opened files by name
};

}  // namespace

bool isUrl(const std::string& location) { return location.rfind("http://", 0) == 0 || location.rfind("https://", 0) == 0; }

std::unique_ptr<TileSource> openFolderSource(const std::string& folder) { return std::make_unique<LocalSource>(folder); }

}  // namespace surfcast
