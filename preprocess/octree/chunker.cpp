#include "chunker.h"

#include <filesystem>

#include <algorithm>
#include <cassert>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <functional>

namespace surfcast {

namespace {
constexpr uint32_t kCountCells = 1u << kCountLevel;
constexpr size_t kBufferedPoints = 2048;  // per chunk file: 96 KiB

uint32_t cellCoord(double v, double cellEdge) {
    return uint32_t(std::clamp(std::floor(v / cellEdge), 0.0, double(kCountCells - 1)));
}
}  // namespace

ChunkLayout ChunkLayout::single(double rootEdge, int grid) {
    ChunkLayout l;
    l.rootEdge_ = rootEdge;
    l.grid_ = grid;
    l.chunks_.push_back(Chunk{NodeKey{}});
    return l;
}

size_t ChunkLayout::cellIndex(const Vec3d& p, double rootEdge) {
    double e = rootEdge / kCountCells;
    return (size_t(cellCoord(p.x, e)) * kCountCells + cellCoord(p.y, e)) * kCountCells + cellCoord(p.z, e);
}

ChunkLayout ChunkLayout::fromCounts(const std::vector<uint32_t>& counts, uint64_t maxChunkPoints, double rootEdge, int grid) {
    ChunkLayout l;
    l.rootEdge_ = rootEdge;
    l.grid_ = grid;
    l.cellChunk_.assign(counts.size(), -1);
    // Sums of the counts over each node's cells, levels 0 to kCountLevel - 1
    // (a node (x, y, z) of level L at (x·2^L + y)·2^L + z), summed bottom-up
    // once; level kCountLevel is `counts` itself. Freed after the placement
    // (2.3 MiB).
    std::vector<std::vector<uint64_t>> sums(kCountLevel);
    for (int level = kCountLevel; level > 0; --level) {
        const size_t n = size_t(1) << level, half = n / 2;
        std::vector<uint64_t>& coarse = sums[size_t(level) - 1];
        coarse.assign(half * half * half, 0);
        for (size_t x = 0; x < n; ++x)
            for (size_t y = 0; y < n; ++y)
                for (size_t z = 0; z < n; ++z) {
                    const size_t i = (x * n + y) * n + z;
                    coarse[((x / 2) * half + y / 2) * half + z / 2] += level == kCountLevel ? counts[i] : sums[size_t(level)][i];
                }
    }
    auto countOf = [&](const NodeKey& k) -> uint64_t {
        const size_t n = size_t(1) << k.level;
        const size_t i = (size_t(k.x) * n + k.y) * n + k.z;
        return k.level == kCountLevel ? counts[i] : sums[k.level][i];
    };
    std::function<void(const NodeKey&, uint64_t)> place = [&](const NodeKey& k, uint64_t count) {
        if (count == 0) return;
        if (count <= maxChunkPoints || k.level == kCountLevel) {
            int id = int(l.chunks_.size());
            l.chunks_.push_back(Chunk{k, 0});
            uint32_t span = 1u << (kCountLevel - k.level);
            for (uint32_t x = 0; x < span; ++x)
                for (uint32_t y = 0; y < span; ++y)
                    for (uint32_t z = 0; z < span; ++z)
                        l.cellChunk_[((size_t(k.x) * span + x) * kCountCells + (k.y * span + y)) * kCountCells + k.z * span + z] = id;
            return;
        }
        for (int c = 0; c < 8; ++c) {
            NodeKey child = k.child(c);
            place(child, countOf(child));
        }
    };
    place(NodeKey{}, countOf(NodeKey{}));
    sums.clear();
    sums.shrink_to_fit();

    // Cells whose 26 neighbours all belong to their own chunk (or to none):
    // their points are halo to no other chunk, the common case by far. A
    // chunk is a cube of cells, so a cell off its cube's faces is interior
    // without a look; only the faces' cells read their neighbours (the 27
    // reads of every cell were a hot spot of CI's many small builds:
    // bench/RELIABILITY.md, "CI stages").
    l.interior_.assign(counts.size(), 0);
    const int64_t n = kCountCells;
    auto anotherBeside = [&](int64_t x, int64_t y, int64_t z, int32_t own) {
        for (int64_t nx = std::max<int64_t>(x - 1, 0); nx <= std::min(x + 1, n - 1); ++nx)
            for (int64_t ny = std::max<int64_t>(y - 1, 0); ny <= std::min(y + 1, n - 1); ++ny)
                for (int64_t nz = std::max<int64_t>(z - 1, 0); nz <= std::min(z + 1, n - 1); ++nz) {
                    const int32_t id = l.cellChunk_[size_t((nx * n + ny) * n + nz)];
                    if (id >= 0 && id != own) return true;
                }
        return false;
    };
    for (int64_t x = 0; x < n; ++x)
        for (int64_t y = 0; y < n; ++y)
            for (int64_t z = 0; z < n; ++z) {
                const int32_t own = l.cellChunk_[size_t((x * n + y) * n + z)];
                if (own < 0) continue;
                const NodeKey& k = l.chunks_[size_t(own)].key;
                const int64_t span = int64_t(1) << (kCountLevel - k.level);
                const int64_t local[3] = {x - k.x * span, y - k.y * span, z - k.z * span};
                const bool onFace = !std::all_of(local, local + 3, [span](int64_t v) { return v > 0 && v < span - 1; });
                l.interior_[size_t((x * n + y) * n + z)] = !(onFace && anotherBeside(x, y, z, own));
            }
    return l;
}

int ChunkLayout::chunkOf(const Vec3d& p) const {
    return cellChunk_.empty() ? 0 : cellChunk_[cellIndex(p, rootEdge_)];
}

double ChunkLayout::margin(int chunk) const {
    double edge = std::ldexp(rootEdge_, -chunks_[chunk].key.level);
    // Capped at one counting cell, so only the 26 neighbouring cells can hold
    // a chunk whose margin reaches p.
    return std::min(kHaloCells * edge / grid_, rootEdge_ / kCountCells);
}

void ChunkLayout::haloChunksOf(const Vec3d& p, std::vector<int>* out) const {
    out->clear();
    if (cellChunk_.empty()) return;
    const double cell = rootEdge_ / kCountCells;
    int32_t c[3];
    for (int a = 0; a < 3; ++a) c[a] = int32_t(cellCoord(p[a], cell));
    const size_t index = (size_t(c[0]) * kCountCells + size_t(c[1])) * kCountCells + size_t(c[2]);
    if (interior_[index]) return;
    const int own = cellChunk_[index];
    for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz) {
                int32_t n[3] = {c[0] + dx, c[1] + dy, c[2] + dz};
                if (std::any_of(n, n + 3, [](int32_t v) { return v < 0 || v >= int32_t(kCountCells); })) continue;
                int id = cellChunk_[(size_t(n[0]) * kCountCells + size_t(n[1])) * kCountCells + size_t(n[2])];
                if (id < 0 || id == own || std::find(out->begin(), out->end(), id) != out->end()) continue;
                // Distance from p to the chunk's box.
                const NodeKey& k = chunks_[id].key;
                double e = std::ldexp(rootEdge_, -k.level), d2 = 0;
                uint32_t kc[3] = {k.x, k.y, k.z};
                for (int a = 0; a < 3; ++a) {
                    double lo = kc[a] * e, hi = lo + e;
                    double d = p[a] < lo ? lo - p[a] : (p[a] > hi ? p[a] - hi : 0);
                    d2 += d * d;
                }
                double m = margin(id);
                if (d2 < m * m) out->push_back(id);
            }
}

ChunkWriter::ChunkWriter(ChunkLayout& layout, std::string dir, size_t scalarsPerPoint)
    : layout_(layout), dir_(std::move(dir)), scalarsPerPoint_(scalarsPerPoint) {
    size_t n = layout_.chunks().size();
    buffers_.resize(2 * n);
    scalarBuffers_.resize(n);
    files_.assign(3 * n, nullptr);
    for (size_t i = 0; i < n; ++i) layout_.chunks()[i].written = files(dir_, i);
}

ChunkPiece ChunkWriter::files(const std::string& dir, size_t chunk) {
    ChunkPiece p;
    const std::string base = dir + "/chunk-" + std::to_string(chunk);
    p.file = base + ".bin";
    p.haloFile = base + ".halo";
    p.scalarFile = base + ".scalars";
    return p;
}

ChunkWriter::~ChunkWriter() {
    for (std::FILE* f : files_)
        if (f) std::fclose(f);
}

Status ChunkWriter::write(size_t file, const std::string& path, const void* data, size_t size, size_t count) {
    if (!files_[file]) {
        files_[file] = std::fopen(path.c_str(), "wb");
        if (!files_[file]) return Status::error(path + ": cannot create (" + std::strerror(errno) + ")");
    }
    if (std::fwrite(data, size, count, files_[file]) != count)
        return Status::error(dir_ + ": writing chunk files failed (disk full?)");
    return {};
}

Status ChunkWriter::flush(size_t slot) {
    auto& buf = buffers_[slot];
    if (buf.empty()) return {};
    const size_t chunk = slot / 2;
    const ChunkPiece& c = layout_.chunks()[chunk].written;
    const bool halo = slot % 2;
    SC_TRY(write(3 * chunk + (halo ? 1 : 0), halo ? c.haloFile : c.file, buf.data(), sizeof(Surfel), buf.size()));
    buf.clear();
    auto& scalars = scalarBuffers_[chunk];
    if (!halo && !scalars.empty()) {
        SC_TRY(write(3 * chunk + 2, c.scalarFile, scalars.data(), sizeof(uint32_t), scalars.size()));
        scalars.clear();
    }
    return {};
}

Status ChunkWriter::append(int chunk, bool halo, const Surfel& s, const uint32_t* scalars) {
    size_t slot = size_t(chunk) * 2 + (halo ? 1 : 0);
    buffers_[slot].push_back(s);
    if (!halo) scalarBuffers_[size_t(chunk)].insert(scalarBuffers_[size_t(chunk)].end(), scalars, scalars + scalarsPerPoint_);
    ChunkPiece& c = layout_.chunks()[chunk].written;
    (halo ? c.haloPoints : c.points)++;
    if (buffers_[slot].size() >= kBufferedPoints) return flush(slot);
    return {};
}

Status ChunkWriter::add(std::span<const Surfel> points, std::span<const uint32_t> scalars) {
    assert(scalars.size() == points.size() * scalarsPerPoint_);
    for (size_t i = 0; i < points.size(); ++i) {
        const Surfel& s = points[i];
        const int chunk = layout_.chunkOf(s.position);
        // Counted points always have a chunk; an update's decoded ones, moved
        // by quantization into a cell no point was counted in, may not.
        if (chunk < 0)
            return Status::error("a point at (" + std::to_string(s.position.x) + ", " + std::to_string(s.position.y) + ", " +
                                 std::to_string(s.position.z) + ") from the root's corner lies in no chunk of the plan");
        SC_TRY(append(chunk, false, s, scalars.data() + i * scalarsPerPoint_));
        layout_.haloChunksOf(s.position, &halo_);
        for (int h : halo_) SC_TRY(append(h, true, s, nullptr));
    }
    return {};
}

Status ChunkWriter::finish() {
    for (size_t slot = 0; slot < buffers_.size(); ++slot) SC_TRY(flush(slot));
    for (std::FILE*& f : files_) {
        if (f && std::fclose(f) != 0) {
            f = nullptr;
            return Status::error(dir_ + ": closing a chunk file failed");
        }
        f = nullptr;
    }
    return {};
}

namespace {
// Appends the `expected` records of the file at `path` to `out`: the file
// must hold exactly those, checked before anything is allocated.
template <typename T>
Status appendRecords(const std::string& path, uint64_t expected, const char* what, std::vector<T>* out) {
    if (expected == 0) return {};
    std::error_code ec;
    const uintmax_t bytes = std::filesystem::file_size(path, ec);
    if (ec) return Status::error(path + ": cannot read chunk file (" + ec.message() + ")");
    if (expected > bytes / sizeof(T) || bytes != expected * sizeof(T))
        return Status::error(path + ": chunk file holds " + std::to_string(bytes) + " bytes, not " + std::to_string(expected) + " " +
                             what + " (truncated, or written by another plan)");
    const size_t at = out->size();
    out->resize(at + expected);
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return Status::error(path + ": cannot open chunk file");
    size_t got = std::fread(out->data() + at, sizeof(T), expected, f);
    std::fclose(f);
    if (got != expected)
        return Status::error(path + ": chunk file holds " + std::to_string(got) + " of " + std::to_string(expected) + " " + what);
    return {};
}
}  // namespace

Status appendChunkFile(const std::string& path, uint64_t expected, std::vector<Surfel>* out) {
    return appendRecords(path, expected, "points", out);
}

Status appendChunkScalars(const std::string& path, uint64_t expected, std::vector<uint32_t>* out) {
    return appendRecords(path, expected, "scalar values", out);
}

}  // namespace surfcast
