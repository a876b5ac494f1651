// Out-of-core distribution (the scheme of PotreeConverter 2, Schütz et al. 2020):
// a counting pass fills a 2^kCountLevel-per-axis grid, cells merge bottom-up
// into chunks (octree nodes) of at most maxChunkPoints, and a distribution pass
// writes every point to its chunk's file. Each chunk also receives a halo: the
// points of neighbouring chunks within a margin of its box, so neighbour
// searches see across chunk borders.
#pragma once

#include <cstdint>
#include <cstdio>
#include <span>
#include <string>
#include <vector>

#include "octree_key.h"
#include "status.h"
#include "surfel.h"

namespace surfcast {

// Counting grid: 128³ cells (8 MiB of counters) resolves chunks down to 1/128
// of the root edge.
inline constexpr int kCountLevel = 7;
// Halo width in units of the chunk root's G³ cell (edge / G): the spacing and
// weight neighbourhoods reach about 3 cells at the chunk's coarsest level. A
// chunk root sampled on a coarser grid (kGridCoarsening) has fewer of its own
// cells in it: 2.0 after four steps, still the 8th neighbour's 1.5-2, and
// fewer than that beyond (nothing bounds the steps).
inline constexpr double kHaloCells = 4.0;

// One writer's files of a chunk (a ChunkWriter's: one part of the inputs).
struct ChunkPiece {
    uint64_t points = 0;
    uint64_t haloPoints = 0;
    std::string file{}, haloFile{};  // ({}: ChunkPiece{} leaves them empty, no -Wmissing-field-initializers)
    std::string scalarFile{};  // the points' stored scalar fields (ChunkWriter's scalarsPerPoint each), in file's order
};

struct Chunk {
    NodeKey key;
    uint64_t points = 0;      // in all pieces
    uint64_t haloPoints = 0;
    ChunkPiece written{};     // what this process's ChunkWriter wrote
    std::vector<ChunkPiece> pieces{};  // every part's, in part order (readDistribution)
};

class ChunkLayout {
public:
    // One chunk holding everything (inputs that fit the memory budget).
    static ChunkLayout single(double rootEdge, int grid);
    // From counts per cell of the counting grid (index x·128² + y·128 + z).
    static ChunkLayout fromCounts(const std::vector<uint32_t>& counts, uint64_t maxChunkPoints, double rootEdge, int grid);

    static size_t cellIndex(const Vec3d& p, double rootEdge);  // p relative to the root minimum

    std::vector<Chunk>& chunks() { return chunks_; }
    const std::vector<Chunk>& chunks() const { return chunks_; }
    int chunkOf(const Vec3d& p) const;
    // Chunks (other than p's own) whose halo margin contains p.
    void haloChunksOf(const Vec3d& p, std::vector<int>* out) const;
    double margin(int chunk) const;  // halo width of a chunk

private:
    double rootEdge_ = 1;
    int grid_ = 128;
    std::vector<Chunk> chunks_;
    std::vector<int32_t> cellChunk_;  // empty for a single chunk
    std::vector<uint8_t> interior_;   // per cell: no other chunk's margin reaches it
};

// Writes points (and halos) to per-chunk files under `dir` (each chunk's
// `written` names them and counts what went in), and each own
// point's quantized scalar fields (scalarsPerPoint of them) to the chunk's
// scalar file (halo points need none: they are never stored).
class ChunkWriter {
public:
    ChunkWriter(ChunkLayout& layout, std::string dir, size_t scalarsPerPoint = 0);
    // The files a writer into `dir` names for `chunk` (no counts).
    static ChunkPiece files(const std::string& dir, size_t chunk);
    ~ChunkWriter();
    // scalars: scalarsPerPoint per point.
    Status add(std::span<const Surfel> points, std::span<const uint32_t> scalars = {});
    Status finish();

private:
    Status append(int chunk, bool halo, const Surfel& s, const uint32_t* scalars);
    Status flush(size_t slot);
    Status write(size_t file, const std::string& path, const void* data, size_t size, size_t count);

    ChunkLayout& layout_;
    std::string dir_;
    size_t scalarsPerPoint_;
    std::vector<std::vector<Surfel>> buffers_;  // 2 per chunk: own, halo
    std::vector<std::vector<uint32_t>> scalarBuffers_;  // per chunk: its own points' scalars
    std::vector<std::FILE*> files_;             // 3 per chunk: own, halo, scalars
    std::vector<int> halo_;
};

// Appends a chunk's point or halo file written by ChunkWriter (`expected`
// points) to `out`.
Status appendChunkFile(const std::string& path, uint64_t expected, std::vector<Surfel>* out);
// Appends a chunk's scalar file: `expected` values.
Status appendChunkScalars(const std::string& path, uint64_t expected, std::vector<uint32_t>* out);

}  // namespace surfcast
