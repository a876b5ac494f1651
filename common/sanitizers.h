// Which sanitizer this translation unit is built with: SURFCAST_ASAN and
// SURFCAST_TSAN are defined to 1 under AddressSanitizer and ThreadSanitizer.
// GCC defines __SANITIZE_*__; clang (both sanitizer presets) answers __has_feature.
#pragma once

#if defined(__SANITIZE_ADDRESS__)
#define SURFCAST_ASAN 1
#endif
#if defined(__SANITIZE_THREAD__)
#define SURFCAST_TSAN 1
#endif
#if defined(__has_feature)
#if __has_feature(address_sanitizer) && !defined(SURFCAST_ASAN)
#define SURFCAST_ASAN 1
#endif
#if __has_feature(thread_sanitizer) && !defined(SURFCAST_TSAN)
#define SURFCAST_TSAN 1
#endif
#endif
