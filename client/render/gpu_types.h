// C++ view of client/shaders/shared_types.h, with the layout pinned.
#pragma once

#include <cstddef>

#include "../shaders/shared_types.h"

namespace surfcast::gpu_types {
static_assert(sizeof(GpuSurfel) == 32);
static_assert(offsetof(GpuSurfel, radius) == 12 && offsetof(GpuSurfel, normal) == 16);
static_assert(offsetof(GpuSurfel, color) == 20 && offsetof(GpuSurfel, weight) == 24);
static_assert(offsetof(GpuSurfel, edge) == 28);
static_assert(sizeof(FrameParams) == 128);
static_assert(offsetof(FrameParams, viewport) == 48 && offsetof(FrameParams, kernel) == 64);
static_assert(offsetof(FrameParams, resolve) == 80 && offsetof(FrameParams, mode) == 96);
static_assert(offsetof(FrameParams, circleScale) == 108 && offsetof(FrameParams, flags) == 112);
static_assert(offsetof(FrameParams, opacity) == 116 && offsetof(FrameParams, layers) == 124);
}  // namespace surfcast::gpu_types
