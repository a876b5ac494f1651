// A GLFW window's surface and swapchain. Frames are drawn offscreen by the
// renderer and blitted to the acquired image (one path for window and
// headless). One frame in flight: the window program is interactive, not a
// throughput benchmark (that is the headless program's job).
#pragma once

#include <vulkan/vulkan.h>

#include <functional>
#include <vector>

#include "context.h"

struct GLFWwindow;

namespace surfcast::gpu {

struct Swapchain {
    VkSurfaceKHR surface = VK_NULL_HANDLE;
    VkSwapchainKHR swapchain = VK_NULL_HANDLE;
    VkFormat format = VK_FORMAT_UNDEFINED;
    VkExtent2D extent{};
    std::vector<VkImage> images;
    std::vector<VkSemaphore> rendered;  // one per image
    VkSemaphore acquired = VK_NULL_HANDLE;
    VkFence inFlight = VK_NULL_HANDLE;
    VkCommandBuffer cmd = VK_NULL_HANDLE;
};

// The instance extensions GLFW needs for a surface (call after glfwInit).
std::vector<std::string> windowInstanceExtensions();
Result<Swapchain> createSwapchain(Context& ctx, GLFWwindow* window);
void destroySwapchain(Context& ctx, Swapchain& swapchain);

// Draws one frame: `record` renders into `source` (left in TRANSFER_SRC_OPTIMAL,
// of the swapchain's extent), which is blitted to the window. When the window
// changed size the swapchain is rebuilt and the frame skipped (returns false).
Result<bool> presentFrame(Context& ctx, Swapchain& swapchain, GLFWwindow* window, VkImage source,
                          const std::function<void(VkCommandBuffer)>& record);

}  // namespace surfcast::gpu
