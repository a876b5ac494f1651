// Little-endian field access for the tile-set's binary records. Every read is
// bounds-checked by the caller; these helpers only fix byte order.
#pragma once

#include <cstdint>
#include <bit>
#include <cstring>
#include <type_traits>
#include <vector>

namespace surfcast::le {

template <typename T>
inline void put(uint8_t* dst, T value) {
    static_assert(std::is_trivially_copyable_v<T>);
    uint8_t bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    if constexpr (std::endian::native == std::endian::big)
        for (size_t i = 0; i < sizeof(T); ++i) dst[i] = bytes[sizeof(T) - 1 - i];
    else
        std::memcpy(dst, bytes, sizeof(T));
}

template <typename T>
inline T get(const uint8_t* src) {
    static_assert(std::is_trivially_copyable_v<T>);
    uint8_t bytes[sizeof(T)];
    if constexpr (std::endian::native == std::endian::big)
        for (size_t i = 0; i < sizeof(T); ++i) bytes[i] = src[sizeof(T) - 1 - i];
    else
        std::memcpy(bytes, src, sizeof(T));
    T value;
    std::memcpy(&value, bytes, sizeof(T));
    return value;
}

}  // namespace surfcast::le
