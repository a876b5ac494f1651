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
static_assert(offsetof(FrameParams, clipMin) == 80 && offsetof(FrameParams, clipMax) == 96);
static_assert(offsetof(FrameParams, background) == 112 && offsetof(FrameParams, mode) == 116);
static_assert(offsetof(FrameParams, flags) == 120 && offsetof(FrameParams, layer) == 124);
}  // namespace surfcast::gpu_types
