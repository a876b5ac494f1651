// Little-endian records of the work folder's files (stages.h): a writer that
// appends, and a reader that checks every length against what is left, so a
// truncated or corrupt file fails with its name, never reads past its end.
#pragma once

#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "built_node.h"
#include "byte_io.h"
#include "status.h"

namespace surfcast {

class ByteWriter {
public:
    template <typename T>
    void put(T value) {
        uint8_t b[sizeof(T)];
        le::put(b, value);
        bytes_.insert(bytes_.end(), b, b + sizeof(T));
    }
    void putString(const std::string& s) {
        put(uint32_t(s.size()));
        bytes_.insert(bytes_.end(), s.begin(), s.end());
    }
    void putBytes(const void* data, size_t size) {
        const uint8_t* p = static_cast<const uint8_t*>(data);
        bytes_.insert(bytes_.end(), p, p + size);
    }
    std::vector<uint8_t>& bytes() { return bytes_; }

private:
    std::vector<uint8_t> bytes_;
};

class ByteReader {
public:
    explicit ByteReader(std::span<const uint8_t> bytes) : bytes_(bytes) {}
    // False once any read ran past the end; reads after that return zeros.
    bool ok() const { return ok_; }
    size_t left() const { return bytes_.size() - pos_; }
    template <typename T>
    T get() {
        if (!take(sizeof(T))) return T{};
        return le::get<T>(bytes_.data() + pos_ - sizeof(T));
    }
    std::string getString() {
        const uint32_t n = get<uint32_t>();
        if (!take(n)) return {};
        return std::string(reinterpret_cast<const char*>(bytes_.data() + pos_ - n), n);
    }
    bool getBytes(void* out, size_t size) {
        if (!take(size)) return false;
        std::memcpy(out, bytes_.data() + pos_ - size, size);
        return true;
    }
    // A count of items of `itemBytes` each that must fit in what is left.
    uint64_t getCount(size_t itemBytes) {
        const uint64_t n = get<uint64_t>();
        if (itemBytes > 0 && n > left() / itemBytes) ok_ = false;
        return ok_ ? n : 0;
    }

private:
    bool take(size_t n) {
        if (!ok_ || n > left()) return ok_ = false;
        pos_ += n;
        return true;
    }
    std::span<const uint8_t> bytes_;
    size_t pos_ = 0;
    bool ok_ = true;
};

// A name beside `path` for writing it before the rename into place, unique
// to this host and process (the work folder may be shared by many machines).
std::string partialName(const std::string& path);

// A work file: `magic` (8 bytes), the payload, then the CRC-32 of both.
// Written beside the path and renamed into place, so a reader sees it whole
// or not at all.
Status writeWorkFile(const std::string& path, const char (&magic)[9], ByteWriter& payload);
// The payload of a work file, once its magic and CRC are checked.
Result<std::vector<uint8_t>> readWorkFile(const std::string& path, const char (&magic)[9]);

// A chunk's output beside its blocks file: the plan it was built to, its
// nodes' records (offsets into the blocks file), where its time went, its
// texture fits, and its root's key and surfels with their scalar rows (none
// for the chunk at the root: the merge has nothing to build above it).
struct ChunkOutput {
    uint32_t plan = 0;  // BuildPlan::id of the plan the chunk was built to
    std::vector<NodeRecord> records;
    uint64_t blocksBytes = 0;
    uint64_t stepNs[kStepCount] = {};
    FitReport fits;
    uint64_t removedOutliers = 0;  // read points BuildOptions::removeOutliers took out
    std::unique_ptr<BuiltNode> root;
    ScalarTable rootScalars;  // row i: root->surfels[i]'s (Surfel::row == i)
};
Status writeChunkOutput(const std::string& path, const ChunkOutput& out);
// `empty`: the table the root's rows go in (BuildContext::emptyTable).
Result<ChunkOutput> readChunkOutput(const std::string& path, const ScalarTable& empty);

}  // namespace surfcast
