// SplitMix64: a tiny deterministic generator, so generated scenes and mesh
// samples are identical on every machine and every pass over them.
#pragma once

#include <cstdint>

namespace surfcast {

class SplitMix64 {
public:
    explicit SplitMix64(uint64_t seed) : state_(seed) {}
    uint64_t next() {
        uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    // Uniform in [0, 1).
    double uniform() { return double(next() >> 11) * 0x1.0p-53; }
    // Standard normal (Box-Muller).
    double normal();

private:
    uint64_t state_;
};

}  // namespace surfcast
