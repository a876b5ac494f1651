// The one checking macro for VkResult (DESIGN.md, Style): in a function that
// returns Status or Result<T>, a failed call returns an error naming the call,
// the result, and the file and line.
#pragma once

#include <vulkan/vulkan.h>

#include <string>

#include "status.h"

namespace surfcast::gpu {
const char* vkResultName(VkResult result);
Status vkError(const char* call, VkResult result, const char* file, int line);
}  // namespace surfcast::gpu

#define VK_TRY(call)                                                                      \
    do {                                                                                  \
        VkResult vk_result_ = (call);                                                     \
        if (vk_result_ != VK_SUCCESS)                                                     \
            return ::surfcast::gpu::vkError(#call, vk_result_, __FILE__, __LINE__);       \
    } while (0)
