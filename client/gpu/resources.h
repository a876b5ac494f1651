// Buffers, images and pipelines as plain structs with create/destroy (niagara
// style). Memory is one allocation per resource: a frame owns a handful.
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <vector>

#include "context.h"

namespace surfcast::gpu {

struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceSize size = 0;
    void* mapped = nullptr;  // host-visible buffers stay mapped
};

// hostVisible: HOST_VISIBLE | HOST_COHERENT and mapped; else DEVICE_LOCAL.
Result<Buffer> createBuffer(Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage, bool hostVisible);
void destroyBuffer(Context& ctx, Buffer& buffer);
// A device-local buffer filled through a staging buffer.
Result<Buffer> createBufferWithData(Context& ctx, const void* data, VkDeviceSize size, VkBufferUsageFlags usage);

struct Image {
    VkImage image = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkImageView view = VK_NULL_HANDLE;
    VkFormat format = VK_FORMAT_UNDEFINED;
    uint32_t width = 0, height = 0;
};

Result<Image> createImage(Context& ctx, uint32_t width, uint32_t height, VkFormat format, VkImageUsageFlags usage,
                          VkImageAspectFlags aspect);
void destroyImage(Context& ctx, Image& image);

// A layout transition with synchronization2.
void imageBarrier(VkCommandBuffer cmd, VkImage image, VkImageAspectFlags aspect, VkImageLayout from, VkImageLayout to,
                  VkPipelineStageFlags2 srcStage, VkAccessFlags2 srcAccess, VkPipelineStageFlags2 dstStage,
                  VkAccessFlags2 dstAccess);

// A global memory barrier (synchronization2).
void memoryBarrier(VkCommandBuffer cmd, VkPipelineStageFlags2 srcStage, VkAccessFlags2 srcAccess,
                   VkPipelineStageFlags2 dstStage, VkAccessFlags2 dstAccess);
// Makes transfer writes visible to the host (before mapping a readback buffer).
void hostReadBarrier(VkCommandBuffer cmd);

Result<VkShaderModule> createShaderModule(Context& ctx, const uint32_t* code, size_t bytes);

// What differs between the renderer's graphics pipelines (dynamic rendering).
struct PipelineDesc {
    VkShaderModule vertex = VK_NULL_HANDLE, geometry = VK_NULL_HANDLE, fragment = VK_NULL_HANDLE;
    std::vector<VkSpecializationMapEntry> specEntries;  // one set of values for every stage
    std::vector<int32_t> specData;
    VkPrimitiveTopology topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_STRIP;
    std::vector<VkVertexInputBindingDescription> bindings;
    std::vector<VkVertexInputAttributeDescription> attributes;
    std::vector<VkFormat> colorFormats;
    bool additiveBlend = false;
    // Front-to-back "under" compositing of premultiplied colour: dst += (1 - dst.a) * src.
    bool underBlend = false;
    VkFormat depthFormat = VK_FORMAT_UNDEFINED;
    bool depthTest = false, depthWrite = false;
    VkCompareOp depthCompare = VK_COMPARE_OP_GREATER;  // reversed Z
};
Result<VkPipeline> createGraphicsPipeline(Context& ctx, const PipelineDesc& desc, VkPipelineLayout layout);

}  // namespace surfcast::gpu
