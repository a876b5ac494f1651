#include "octree_key.h"

#include <cstdio>

namespace surfcast {

namespace {
// Spread the low 21 bits of v so that bit i lands at bit 3i.
uint64_t spreadBits(uint64_t v) {
    v &= 0x1FFFFF;
    v = (v | v << 32) & 0x1F00000000FFFFull;
    v = (v | v << 16) & 0x1F0000FF0000FFull;
    v = (v | v << 8) & 0x100F00F00F00F00Full;
    v = (v | v << 4) & 0x10C30C30C30C30C3ull;
    v = (v | v << 2) & 0x1249249249249249ull;
    return v;
}
}  // namespace

uint64_t mortonCode(uint32_t x, uint32_t y, uint32_t z) { return spreadBits(x) << 2 | spreadBits(y) << 1 | spreadBits(z); }

uint64_t NodeKey::morton() const { return mortonCode(x, y, z); }

std::string NodeKey::name() const {
    return std::to_string(level) + "-" + std::to_string(x) + "-" + std::to_string(y) + "-" + std::to_string(z);
}

bool NodeKey::parse(const std::string& text, NodeKey* out) {
    unsigned level = 0, x = 0, y = 0, z = 0;
    int consumed = 0;
    if (std::sscanf(text.c_str(), "%u-%u-%u-%u%n", &level, &x, &y, &z, &consumed) != 4) return false;
    if (size_t(consumed) != text.size() || level > unsigned(kMaxLevel)) return false;
    uint32_t limit = 1u << level;
    if (x >= limit || y >= limit || z >= limit) return false;
    *out = NodeKey{uint8_t(level), x, y, z};
    return true;
}

}  // namespace surfcast
