// Octree node keys. A node at level L covers the cube
//   [root_min + (x,y,z)·e_L, root_min + (x+1,y+1,z+1)·e_L),  e_L = root_edge / 2^L.
// Child i of (L,x,y,z) is (L+1, 2x+(i>>2&1), 2y+(i>>1&1), 2z+(i&1)).
#pragma once

#include <compare>
#include <cassert>
#include <cstdint>
#include <string>

namespace surfcast {

// Morton (Z-order) code of a cell: the low 21 bits of x, y, z interleaved,
// x highest (bit 3i+2), z lowest.
uint64_t mortonCode(uint32_t x, uint32_t y, uint32_t z);

// Deepest level a key can name: 3·kMaxLevel bits of Morton code fit in 64 bits
// with room for the level.
inline constexpr int kMaxLevel = 20;

struct NodeKey {
    uint8_t level = 0;
    uint32_t x = 0, y = 0, z = 0;

    constexpr NodeKey child(int i) const {
        return {uint8_t(level + 1), 2 * x + ((i >> 2) & 1), 2 * y + ((i >> 1) & 1), 2 * z + (i & 1)};
    }
    constexpr NodeKey parent() const { return {uint8_t(level - 1), x / 2, y / 2, z / 2}; }
    // The node's ancestor at `up` (a level at or above its own).
    constexpr NodeKey ancestor(int up) const {
        assert(up >= 0 && up <= level);
        const int shift = level - up;
        return {uint8_t(up), x >> shift, y >> shift, z >> shift};
    }
    // Which child of its parent this node is.
    constexpr int childIndex() const { return int(((x & 1) << 2) | ((y & 1) << 1) | (z & 1)); }
    // Morton code of the node at its level: sorts children after parents' siblings
    // in depth-first order when compared together with level.
    uint64_t morton() const;
    // "L-X-Y-Z", the name used in URLs and logs.
    std::string name() const;
    static bool parse(const std::string& text, NodeKey* out);

    auto operator<=>(const NodeKey&) const = default;
};

struct NodeKeyHash {
    size_t operator()(const NodeKey& k) const {
        return size_t(k.morton() * 0x9E3779B97F4A7C15ull) ^ k.level;
    }
};

}  // namespace surfcast
