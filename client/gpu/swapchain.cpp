#include "swapchain.h"

#define GLFW_INCLUDE_VULKAN
#include <GLFW/glfw3.h>

#include <algorithm>

#include "resources.h"
#include "vk_check.h"

namespace surfcast::gpu {

std::vector<std::string> windowInstanceExtensions() {
    uint32_t count = 0;
    const char** names = glfwGetRequiredInstanceExtensions(&count);
    return std::vector<std::string>(names, names + count);
}

namespace {

Status buildChain(Context& ctx, Swapchain& sc, GLFWwindow* window) {
    VkSurfaceCapabilitiesKHR caps;
    VK_TRY(vkGetPhysicalDeviceSurfaceCapabilitiesKHR(ctx.physicalDevice, sc.surface, &caps));
    int fbw = 0, fbh = 0;
    glfwGetFramebufferSize(window, &fbw, &fbh);
    VkExtent2D extent = caps.currentExtent;
    if (extent.width == UINT32_MAX) extent = {uint32_t(fbw), uint32_t(fbh)};
    extent.width = std::clamp(extent.width, caps.minImageExtent.width, caps.maxImageExtent.width);
    extent.height = std::clamp(extent.height, caps.minImageExtent.height, caps.maxImageExtent.height);
    if (!(caps.supportedUsageFlags & VK_IMAGE_USAGE_TRANSFER_DST_BIT))
        return Status::error("the window's swapchain images cannot be blitted to (no TRANSFER_DST usage)");
    uint32_t count = 0;
    vkGetPhysicalDeviceSurfaceFormatsKHR(ctx.physicalDevice, sc.surface, &count, nullptr);
    std::vector<VkSurfaceFormatKHR> formats(count);
    vkGetPhysicalDeviceSurfaceFormatsKHR(ctx.physicalDevice, sc.surface, &count, formats.data());
    if (formats.empty()) return Status::error("the window's surface offers no formats");
    // UNORM: the renderer's output is already display-ready (no sRGB encode).
    VkSurfaceFormatKHR format = formats[0];
    for (const auto& f : formats)
        if (f.format == VK_FORMAT_B8G8R8A8_UNORM || f.format == VK_FORMAT_R8G8B8A8_UNORM) format = f;
    VkSwapchainKHR old = sc.swapchain;
    VkSwapchainCreateInfoKHR info{VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR};
    info.surface = sc.surface;
    info.minImageCount = std::max(caps.minImageCount, 2u);
    if (caps.maxImageCount) info.minImageCount = std::min(info.minImageCount, caps.maxImageCount);
    info.imageFormat = format.format;
    info.imageColorSpace = format.colorSpace;
    info.imageExtent = extent;
    info.imageArrayLayers = 1;
    info.imageUsage = VK_IMAGE_USAGE_TRANSFER_DST_BIT;
    info.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
    info.preTransform = caps.currentTransform;
    info.compositeAlpha = VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR;
    info.presentMode = VK_PRESENT_MODE_FIFO_KHR;  // always available
    info.clipped = VK_TRUE;
    info.oldSwapchain = old;
    VK_TRY(vkCreateSwapchainKHR(ctx.device, &info, nullptr, &sc.swapchain));
    if (old) vkDestroySwapchainKHR(ctx.device, old, nullptr);
    sc.format = format.format;
    sc.extent = extent;
    vkGetSwapchainImagesKHR(ctx.device, sc.swapchain, &count, nullptr);
    sc.images.resize(count);
    vkGetSwapchainImagesKHR(ctx.device, sc.swapchain, &count, sc.images.data());
    for (VkSemaphore s : sc.rendered) vkDestroySemaphore(ctx.device, s, nullptr);
    sc.rendered.assign(count, VK_NULL_HANDLE);
    VkSemaphoreCreateInfo semaphore{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    for (auto& s : sc.rendered) VK_TRY(vkCreateSemaphore(ctx.device, &semaphore, nullptr, &s));
    return {};
}

}  // namespace

Result<Swapchain> createSwapchain(Context& ctx, GLFWwindow* window) {
    Swapchain sc;
    VK_TRY(glfwCreateWindowSurface(ctx.instance, window, nullptr, &sc.surface));
    VkBool32 supported = VK_FALSE;
    vkGetPhysicalDeviceSurfaceSupportKHR(ctx.physicalDevice, ctx.queueFamily, sc.surface, &supported);
    Status s = supported ? buildChain(ctx, sc, window)
                         : Status::error("the chosen Vulkan device cannot present to this window");
    VkSemaphoreCreateInfo semaphore{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    VkFenceCreateInfo fence{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    fence.flags = VK_FENCE_CREATE_SIGNALED_BIT;
    VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    alloc.commandPool = ctx.commandPool;
    alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    alloc.commandBufferCount = 1;
    if (s) {
        VkResult r = vkCreateSemaphore(ctx.device, &semaphore, nullptr, &sc.acquired);
        if (r == VK_SUCCESS) r = vkCreateFence(ctx.device, &fence, nullptr, &sc.inFlight);
        if (r == VK_SUCCESS) r = vkAllocateCommandBuffers(ctx.device, &alloc, &sc.cmd);
        if (r != VK_SUCCESS) s = vkError("swapchain synchronization objects", r, __FILE__, __LINE__);
    }
    if (!s) {
        destroySwapchain(ctx, sc);
        return s;
    }
    return sc;
}

void destroySwapchain(Context& ctx, Swapchain& sc) {
    vkDeviceWaitIdle(ctx.device);
    if (sc.cmd) vkFreeCommandBuffers(ctx.device, ctx.commandPool, 1, &sc.cmd);
    if (sc.inFlight) vkDestroyFence(ctx.device, sc.inFlight, nullptr);
    if (sc.acquired) vkDestroySemaphore(ctx.device, sc.acquired, nullptr);
    for (VkSemaphore s : sc.rendered) vkDestroySemaphore(ctx.device, s, nullptr);
    if (sc.swapchain) vkDestroySwapchainKHR(ctx.device, sc.swapchain, nullptr);
    if (sc.surface) vkDestroySurfaceKHR(ctx.instance, sc.surface, nullptr);
    sc = Swapchain{};
}

Result<bool> presentFrame(Context& ctx, Swapchain& sc, GLFWwindow* window, VkImage source,
                          const std::function<void(VkCommandBuffer)>& record) {
    VK_TRY(vkWaitForFences(ctx.device, 1, &sc.inFlight, VK_TRUE, UINT64_MAX));
    uint32_t index = 0;
    VkResult r = vkAcquireNextImageKHR(ctx.device, sc.swapchain, UINT64_MAX, sc.acquired, VK_NULL_HANDLE, &index);
    if (r == VK_ERROR_OUT_OF_DATE_KHR) {
        vkDeviceWaitIdle(ctx.device);
        SC_TRY(buildChain(ctx, sc, window));
        return false;
    }
    if (r != VK_SUBOPTIMAL_KHR) VK_TRY(r);
    VK_TRY(vkResetFences(ctx.device, 1, &sc.inFlight));
    VK_TRY(vkResetCommandBuffer(sc.cmd, 0));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    VK_TRY(vkBeginCommandBuffer(sc.cmd, &begin));
    record(sc.cmd);
    VkImage target = sc.images[index];
    imageBarrier(sc.cmd, target, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                 VK_PIPELINE_STAGE_2_TRANSFER_BIT, 0, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT);
    VkImageBlit blit{};
    blit.srcSubresource = blit.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
    blit.srcOffsets[1] = blit.dstOffsets[1] = {int32_t(sc.extent.width), int32_t(sc.extent.height), 1};
    vkCmdBlitImage(sc.cmd, source, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, target, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1,
                   &blit, VK_FILTER_NEAREST);
    imageBarrier(sc.cmd, target, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                 VK_IMAGE_LAYOUT_PRESENT_SRC_KHR, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                 VK_PIPELINE_STAGE_2_BOTTOM_OF_PIPE_BIT, 0);
    VK_TRY(vkEndCommandBuffer(sc.cmd));
    VkPipelineStageFlags wait = VK_PIPELINE_STAGE_TRANSFER_BIT;
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.waitSemaphoreCount = 1;
    submit.pWaitSemaphores = &sc.acquired;
    submit.pWaitDstStageMask = &wait;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &sc.cmd;
    submit.signalSemaphoreCount = 1;
    submit.pSignalSemaphores = &sc.rendered[index];
    VK_TRY(vkQueueSubmit(ctx.queue, 1, &submit, sc.inFlight));
    VkPresentInfoKHR present{VK_STRUCTURE_TYPE_PRESENT_INFO_KHR};
    present.waitSemaphoreCount = 1;
    present.pWaitSemaphores = &sc.rendered[index];
    present.swapchainCount = 1;
    present.pSwapchains = &sc.swapchain;
    present.pImageIndices = &index;
    r = vkQueuePresentKHR(ctx.queue, &present);
    if (r == VK_ERROR_OUT_OF_DATE_KHR || r == VK_SUBOPTIMAL_KHR) {
        vkDeviceWaitIdle(ctx.device);
        SC_TRY(buildChain(ctx, sc, window));
        return r == VK_SUBOPTIMAL_KHR;
    }
    VK_TRY(r);
    return true;
}

}  // namespace surfcast::gpu
