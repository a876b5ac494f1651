// The Vulkan instance and device: the only place that picks a GPU. Prefers a
// discrete GPU, then integrated, virtual, and the CPU (Mesa lavapipe).
#pragma once

#include <vulkan/vulkan.h>

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "status.h"

namespace surfcast::gpu {

struct ContextOptions {
    std::string device;                         // "" (best), an index, or a substring of the name
    bool validation = false;                    // VK_LAYER_KHRONOS_validation; an error if missing
    std::vector<std::string> instanceExtensions; // e.g. what GLFW needs for a surface
    bool swapchain = false;                     // enable VK_KHR_swapchain on the device
};

struct Context {
    VkInstance instance = VK_NULL_HANDLE;
    VkDebugUtilsMessengerEXT messenger = VK_NULL_HANDLE;
    VkPhysicalDevice physicalDevice = VK_NULL_HANDLE;
    VkPhysicalDeviceProperties properties{};
    VkDevice device = VK_NULL_HANDLE;
    uint32_t queueFamily = 0;
    VkQueue queue = VK_NULL_HANDLE;
    VkCommandPool commandPool = VK_NULL_HANDLE;
    bool geometryShader = false;  // the device supports (and has enabled) geometry shaders
    bool timestamps = false;      // the queue writes timestamps
    bool ownsDevice = true;       // false: the host's device (wrapContext), not destroyed here
    std::atomic<int> validationErrors{0};
    std::atomic<int> validationWarnings{0};
};

// Fails with a clear message when there is no Vulkan driver or no device with
// Vulkan 1.3, dynamic rendering and synchronization2.
Result<std::unique_ptr<Context>> createContext(const ContextOptions& options);
void destroyContext(std::unique_ptr<Context>& context);

// A device the host application made, for embedding: Vulkan 1.3 with
// dynamicRendering and synchronization2 enabled (and geometryShader, if it
// should be used). The context borrows it: destroyContext frees only what the
// context created (a command pool). The library submits to `queue` (uploads,
// offscreen renders): call it from the thread that owns the queue.
struct HostDevice {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physicalDevice = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    uint32_t queueFamily = 0;  // graphics
    VkQueue queue = VK_NULL_HANDLE;
    bool geometryShaderEnabled = false;
};
Result<std::unique_ptr<Context>> wrapContext(const HostDevice& host);

// The available devices, one per line ("index: name (type)"), for --help/--device.
std::string listDevices();

// Record commands into a one-time command buffer, submit and wait.
Status submitAndWaitImpl(Context& ctx, void (*record)(VkCommandBuffer, void*), void* user);
template <typename F>
Status submitAndWait(Context& ctx, F&& record) {
    return submitAndWaitImpl(ctx, [](VkCommandBuffer cmd, void* f) { (*static_cast<F*>(f))(cmd); }, &record);
}

}  // namespace surfcast::gpu
