#include "splat_renderer.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "../gpu/vk_check.h"
#include "cpu_reference.h"
#include "shader_code.h"

namespace surfcast {

using gpu_types::FrameParams;
using gpu_types::GpuSurfel;

namespace {

constexpr VkFormat kDepthFormat = VK_FORMAT_D32_SFLOAT;
constexpr VkFormat kOutputFormat = VK_FORMAT_R8G8B8A8_UNORM;
enum Query : uint32_t { kQueryStart, kQueryVisibility, kQueryAccumulate, kQueryResolve, kQueryCount };
// Specialization constants of client/shaders (constant_id 0..2).
enum SpecId : uint32_t { kSpecPass, kSpecExpand, kSpecCircle };
enum Pass : int32_t { kPassVisibility = 0, kPassAccumulate = 1, kPassCircles = 2 };

// The surfel vertex layout: one binding, one attribute per GpuSurfel field.
void surfelInput(gpu::PipelineDesc& d, VkVertexInputRate rate) {
    d.bindings = {{0, sizeof(GpuSurfel), rate}};
    d.attributes = {{0, 0, VK_FORMAT_R32G32B32A32_SFLOAT, offsetof(GpuSurfel, px)},
                    {1, 0, VK_FORMAT_R32_UINT, offsetof(GpuSurfel, normal)},
                    {2, 0, VK_FORMAT_R8G8B8A8_UNORM, offsetof(GpuSurfel, color)},
                    {3, 0, VK_FORMAT_R32_SFLOAT, offsetof(GpuSurfel, weight)},
                    {4, 0, VK_FORMAT_R32_UINT, offsetof(GpuSurfel, edge)}};
}

void specialize(gpu::PipelineDesc& d, int32_t pass, int32_t expand, int32_t circle) {
    d.specEntries = {{kSpecPass, 0, 4}, {kSpecExpand, 4, 4}, {kSpecCircle, 8, 4}};
    d.specData = {pass, expand, circle};
}

VkRenderingAttachmentInfo attachment(VkImageView view, VkImageLayout layout, VkAttachmentLoadOp load,
                                     VkClearValue clear = {}) {
    VkRenderingAttachmentInfo a{VK_STRUCTURE_TYPE_RENDERING_ATTACHMENT_INFO};
    a.imageView = view;
    a.imageLayout = layout;
    a.loadOp = load;
    a.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    a.clearValue = clear;
    return a;
}

}  // namespace

Result<std::unique_ptr<SplatRenderer>> SplatRenderer::create(gpu::Context& ctx, const RendererOptions& options) {
    std::unique_ptr<SplatRenderer> r(new SplatRenderer(ctx));
    r->options_ = options;
    if (options.expansion == Expansion::Auto)
        r->options_.expansion = ctx.geometryShader ? Expansion::Geometry : Expansion::Quad;
    if (options.expansion == Expansion::Geometry && !ctx.geometryShader)
        return Status::error("the Vulkan device has no geometry shaders; use the quad expansion");
    r->accumFormat_ = options.halfFloatAccumulation ? VK_FORMAT_R16G16B16A16_SFLOAT : VK_FORMAT_R32G32B32A32_SFLOAT;
    SC_TRY(r->createPipelines());
    return r;
}

Status SplatRenderer::createPipelines() {
    VkDevice dev = ctx_.device;
    VkPushConstantRange push{VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_GEOMETRY_BIT | VK_SHADER_STAGE_FRAGMENT_BIT, 0,
                             sizeof(FrameParams)};
    if (!ctx_.geometryShader) push.stageFlags &= ~VK_SHADER_STAGE_GEOMETRY_BIT;
    VkPipelineLayoutCreateInfo layout{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout.pushConstantRangeCount = 1;
    layout.pPushConstantRanges = &push;
    VK_TRY(vkCreatePipelineLayout(dev, &layout, nullptr, &splatLayout_));

    VkDescriptorSetLayoutBinding bindings[2] = {
        {0, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 1, VK_SHADER_STAGE_FRAGMENT_BIT, nullptr},
        {1, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 1, VK_SHADER_STAGE_FRAGMENT_BIT, nullptr}};
    VkDescriptorSetLayoutCreateInfo setLayout{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    setLayout.bindingCount = 2;
    setLayout.pBindings = bindings;
    VK_TRY(vkCreateDescriptorSetLayout(dev, &setLayout, nullptr, &resolveSetLayout_));
    layout.setLayoutCount = 1;
    layout.pSetLayouts = &resolveSetLayout_;
    VK_TRY(vkCreatePipelineLayout(dev, &layout, nullptr, &resolveLayout_));
    // Translucent frames' sets: one image, or the three accumulation targets.
    VkDescriptorSetLayoutBinding three[3] = {bindings[0], bindings[1], bindings[1]};
    three[2].binding = 2;
    setLayout.bindingCount = 1;
    VK_TRY(vkCreateDescriptorSetLayout(dev, &setLayout, nullptr, &oneImageSetLayout_));
    setLayout.bindingCount = 3;
    setLayout.pBindings = three;
    VK_TRY(vkCreateDescriptorSetLayout(dev, &setLayout, nullptr, &threeImageSetLayout_));
    layout.pSetLayouts = &oneImageSetLayout_;
    VK_TRY(vkCreatePipelineLayout(dev, &layout, nullptr, &oneImageLayout_));
    layout.pSetLayouts = &threeImageSetLayout_;
    VK_TRY(vkCreatePipelineLayout(dev, &layout, nullptr, &threeImageLayout_));

    // Sets: resolve (2 images), two previous depths and the composite (1
    // each), the layer's targets (3).
    VkDescriptorPoolSize poolSize{VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 2 + 3 + 3};
    VkDescriptorPoolCreateInfo pool{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool.maxSets = 5;
    pool.poolSizeCount = 1;
    pool.pPoolSizes = &poolSize;
    VK_TRY(vkCreateDescriptorPool(dev, &pool, nullptr, &descriptorPool_));
    auto allocate = [&](VkDescriptorSetLayout l, VkDescriptorSet* set) {
        VkDescriptorSetAllocateInfo alloc{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
        alloc.descriptorPool = descriptorPool_;
        alloc.descriptorSetCount = 1;
        alloc.pSetLayouts = &l;
        return vkAllocateDescriptorSets(dev, &alloc, set);
    };
    VK_TRY(allocate(resolveSetLayout_, &resolveSet_));
    VK_TRY(allocate(oneImageSetLayout_, &previousDepthSets_[0]));
    VK_TRY(allocate(oneImageSetLayout_, &previousDepthSets_[1]));
    VK_TRY(allocate(oneImageSetLayout_, &compositeSet_));
    VK_TRY(allocate(threeImageSetLayout_, &layerSet_));
    VkSamplerCreateInfo sampler{VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO};
    sampler.magFilter = sampler.minFilter = VK_FILTER_NEAREST;
    VK_TRY(vkCreateSampler(dev, &sampler, nullptr, &sampler_));
    if (ctx_.timestamps) {
        VkQueryPoolCreateInfo q{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
        q.queryType = VK_QUERY_TYPE_TIMESTAMP;
        q.queryCount = kQueryCount;
        VK_TRY(vkCreateQueryPool(dev, &q, nullptr, &queries_));
    }

    // Shader modules live only while the pipelines are made.
    ShaderId ids[] = {ShaderId::SplatQuadVert, ShaderId::SplatPointVert, ShaderId::SplatGeom, ShaderId::SplatVisibilityFrag,
                      ShaderId::SplatAccumulateFrag, ShaderId::OpaqueFrag, ShaderId::FullscreenVert, ShaderId::ResolveFrag,
                      ShaderId::LayeredSplatQuadVert, ShaderId::LayeredSplatPointVert, ShaderId::LayeredSplatGeom,
                      ShaderId::SplatPeelFrag, ShaderId::SplatLayerFrag, ShaderId::ResolveLayerFrag, ShaderId::CompositeFrag};
    VkShaderModule modules[std::size(ids)] = {};
    auto module = [&](ShaderId id) { return modules[size_t(id)]; };
    Status status;
    for (size_t i = 0; i < std::size(ids) && status.ok(); ++i) {
        if ((ids[i] == ShaderId::SplatGeom || ids[i] == ShaderId::LayeredSplatGeom) && !ctx_.geometryShader) continue;
        ShaderCode code = shaderCode(ids[i]);
        auto m = gpu::createShaderModule(ctx_, code.code, code.bytes);
        if (m) modules[i] = *m;
        else status = m.status();
    }
    auto make = [&](const gpu::PipelineDesc& d, VkPipelineLayout l, VkPipeline& out) {
        if (!status.ok()) return;
        auto p = gpu::createGraphicsPipeline(ctx_, d, l);
        if (p) out = *p;
        else status = p.status();
    };
    bool geometry = options_.expansion == Expansion::Geometry;
    gpu::PipelineDesc splat;
    if (geometry) {
        splat.vertex = module(ShaderId::SplatPointVert);
        splat.geometry = module(ShaderId::SplatGeom);
        splat.topology = VK_PRIMITIVE_TOPOLOGY_POINT_LIST;
        surfelInput(splat, VK_VERTEX_INPUT_RATE_VERTEX);
    } else {
        splat.vertex = module(ShaderId::SplatQuadVert);
        surfelInput(splat, VK_VERTEX_INPUT_RATE_INSTANCE);
    }
    splat.depthFormat = kDepthFormat;
    splat.depthTest = true;

    gpu::PipelineDesc vis = splat;
    vis.fragment = module(ShaderId::SplatVisibilityFrag);
    vis.depthWrite = true;
    specialize(vis, kPassVisibility, 1, 0);
    make(vis, splatLayout_, visibility_);

    gpu::PipelineDesc acc = splat;
    acc.fragment = module(ShaderId::SplatAccumulateFrag);
    acc.colorFormats = {accumFormat_, accumFormat_};
    acc.additiveBlend = true;
    acc.depthCompare = VK_COMPARE_OP_GREATER_OR_EQUAL;
    specialize(acc, kPassAccumulate, 1, 0);
    make(acc, splatLayout_, accumulate_);

    gpu::PipelineDesc circles;
    circles.vertex = module(ShaderId::SplatQuadVert);
    circles.fragment = module(ShaderId::OpaqueFrag);
    surfelInput(circles, VK_VERTEX_INPUT_RATE_INSTANCE);
    circles.colorFormats = {accumFormat_, accumFormat_};
    circles.depthFormat = kDepthFormat;
    circles.depthTest = circles.depthWrite = true;
    specialize(circles, kPassCircles, 0, 1);
    make(circles, splatLayout_, circles_);

    gpu::PipelineDesc points = circles;
    points.vertex = module(ShaderId::SplatPointVert);
    points.topology = VK_PRIMITIVE_TOPOLOGY_POINT_LIST;
    surfelInput(points, VK_VERTEX_INPUT_RATE_VERTEX);
    specialize(points, kPassAccumulate, 0, 0);
    make(points, splatLayout_, points_);

    gpu::PipelineDesc resolve;
    resolve.vertex = module(ShaderId::FullscreenVert);
    resolve.fragment = module(ShaderId::ResolveFrag);
    resolve.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    resolve.colorFormats = {kOutputFormat};
    make(resolve, resolveLayout_, resolve_);

    // Translucent frames' splat passes take the SC_LAYERED stages.
    auto layered = [&](gpu::PipelineDesc d) {
        d.vertex = module(geometry ? ShaderId::LayeredSplatPointVert : ShaderId::LayeredSplatQuadVert);
        if (geometry) d.geometry = module(ShaderId::LayeredSplatGeom);
        return d;
    };
    gpu::PipelineDesc peel = layered(vis);
    peel.fragment = module(ShaderId::SplatPeelFrag);
    make(peel, oneImageLayout_, peel_);
    gpu::PipelineDesc layer = layered(acc);
    layer.fragment = module(ShaderId::SplatLayerFrag);
    layer.colorFormats = {accumFormat_, accumFormat_, alphaFormat()};
    make(layer, oneImageLayout_, layer_);
    layer.depthTest = false;  // the last layer: every fragment behind the others
    make(layer, oneImageLayout_, layerRest_);
    gpu::PipelineDesc resolveLayer = resolve;
    resolveLayer.fragment = module(ShaderId::ResolveLayerFrag);
    resolveLayer.colorFormats = {accumFormat_};
    resolveLayer.underBlend = true;
    make(resolveLayer, threeImageLayout_, resolveLayer_);
    gpu::PipelineDesc composite = resolve;
    composite.fragment = module(ShaderId::CompositeFrag);
    make(composite, oneImageLayout_, composite_);

    for (VkShaderModule m : modules)
        if (m) vkDestroyShaderModule(dev, m, nullptr);
    return status;
}

SplatRenderer::~SplatRenderer() {
    VkDevice dev = ctx_.device;
    vkDeviceWaitIdle(dev);
    destroyTargets();
    gpu::destroyBuffer(ctx_, surfels_);
    for (VkPipeline p : {points_, circles_, visibility_, accumulate_, resolve_, peel_, layer_, layerRest_, resolveLayer_, composite_})
        if (p) vkDestroyPipeline(dev, p, nullptr);
    for (VkPipelineLayout l : {splatLayout_, resolveLayout_, oneImageLayout_, threeImageLayout_})
        if (l) vkDestroyPipelineLayout(dev, l, nullptr);
    if (descriptorPool_) vkDestroyDescriptorPool(dev, descriptorPool_, nullptr);
    for (VkDescriptorSetLayout l : {resolveSetLayout_, oneImageSetLayout_, threeImageSetLayout_})
        if (l) vkDestroyDescriptorSetLayout(dev, l, nullptr);
    if (sampler_) vkDestroySampler(dev, sampler_, nullptr);
    if (queries_) vkDestroyQueryPool(dev, queries_, nullptr);
}

void SplatRenderer::destroyTargets() {
    for (gpu::Image* img : {&depth_, &colorWeight_, &normalWeight_, &output_, &depth2_, &alphaWeight_, &compositeImage_})
        gpu::destroyImage(ctx_, *img);
    gpu::destroyBuffer(ctx_, readback_);
}

Status SplatRenderer::upload(const SurfelSet& set) {
    vkDeviceWaitIdle(ctx_.device);
    gpu::destroyBuffer(ctx_, surfels_);
    setDraws(VK_NULL_HANDLE, {}, diagonalOf(set));
    if (set.surfels.empty()) return {};
    auto buffer = gpu::createBufferWithData(ctx_, set.surfels.data(), set.surfels.size() * sizeof(GpuSurfel),
                                            VK_BUFFER_USAGE_VERTEX_BUFFER_BIT);
    if (!buffer) return buffer.status();
    surfels_ = *buffer;
    setDraws(surfels_.buffer, {{0, uint32_t(set.surfels.size())}}, diagonal_);
    return {};
}

void SplatRenderer::setDraws(VkBuffer buffer, std::vector<DrawRange> ranges, double diagonal) {
    drawBuffer_ = buffer;
    ranges_ = std::move(ranges);
    diagonal_ = diagonal;
    splatCount_ = 0;
    for (const DrawRange& r : ranges_) splatCount_ += r.count;
}

Status SplatRenderer::resize(uint32_t width, uint32_t height) {
    if (width == output_.width && height == output_.height) return {};
    vkDeviceWaitIdle(ctx_.device);
    destroyTargets();
    auto make = [&](gpu::Image& img, VkFormat format, VkImageUsageFlags usage, VkImageAspectFlags aspect) -> Status {
        auto i = gpu::createImage(ctx_, width, height, format, usage, aspect);
        if (!i) return i.status();
        img = *i;
        return {};
    };
    // TRANSFER_SRC on depth and colour*w: capture() reads them back.
    // SAMPLED on the depths: translucent frames read the previous layer's.
    const VkImageUsageFlags depthUsage =
        VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_SAMPLED_BIT;
    SC_TRY(make(depth_, kDepthFormat, depthUsage, VK_IMAGE_ASPECT_DEPTH_BIT));
    SC_TRY(make(depth2_, kDepthFormat, depthUsage, VK_IMAGE_ASPECT_DEPTH_BIT));
    const VkImageUsageFlags accum = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_SAMPLED_BIT |
                                    VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
    SC_TRY(make(colorWeight_, accumFormat_, accum, VK_IMAGE_ASPECT_COLOR_BIT));
    SC_TRY(make(normalWeight_, accumFormat_, accum, VK_IMAGE_ASPECT_COLOR_BIT));
    SC_TRY(make(alphaWeight_, alphaFormat(), accum, VK_IMAGE_ASPECT_COLOR_BIT));
    SC_TRY(make(compositeImage_, accumFormat_, accum, VK_IMAGE_ASPECT_COLOR_BIT));
    SC_TRY(make(output_, kOutputFormat, VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
                VK_IMAGE_ASPECT_COLOR_BIT));
    auto rb = gpu::createBuffer(ctx_, VkDeviceSize(width) * height * 4, VK_BUFFER_USAGE_TRANSFER_DST_BIT, true);
    if (!rb) return rb.status();
    readback_ = *rb;
    const VkImageLayout read = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
    struct Binding { VkDescriptorSet set; uint32_t binding; VkImageView view; };
    const Binding bindings[] = {{resolveSet_, 0, colorWeight_.view},     {resolveSet_, 1, normalWeight_.view},
                                {layerSet_, 0, colorWeight_.view},       {layerSet_, 1, normalWeight_.view},
                                {layerSet_, 2, alphaWeight_.view},       {compositeSet_, 0, compositeImage_.view},
                                {previousDepthSets_[0], 0, depth_.view}, {previousDepthSets_[1], 0, depth2_.view}};
    VkDescriptorImageInfo images[std::size(bindings)];
    VkWriteDescriptorSet writes[std::size(bindings)];
    for (size_t i = 0; i < std::size(bindings); ++i) {
        images[i] = {sampler_, bindings[i].view, read};
        writes[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
        writes[i].dstSet = bindings[i].set;
        writes[i].dstBinding = bindings[i].binding;
        writes[i].descriptorCount = 1;
        writes[i].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
        writes[i].pImageInfo = &images[i];
    }
    vkUpdateDescriptorSets(ctx_.device, uint32_t(std::size(writes)), writes, 0, nullptr);
    return {};
}

void SplatRenderer::record(VkCommandBuffer cmd, const ViewTransform& view, const RenderSettings& settings) {
    const FrameParams params = makeFrameParams(view, settings, nearPlane(view));
    using namespace gpu;
    const uint32_t W = output_.width, H = output_.height;
    const VkRect2D area{{0, 0}, {W, H}};
    const VkViewport viewport{0, 0, float(W), float(H), 0, 1};
    auto timestamp = [&](uint32_t q, VkPipelineStageFlags2 stage) {
        if (queries_) vkCmdWriteTimestamp2(cmd, stage, queries_, q);
    };
    if (queries_) vkCmdResetQueryPool(cmd, queries_, 0, kQueryCount);
    timestamp(kQueryStart, VK_PIPELINE_STAGE_2_TOP_OF_PIPE_BIT);

    const VkImageLayout colorLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
    const VkImageLayout depthLayout = VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL;
    const VkPipelineStageFlags2 depthStages =
        VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT;
    const VkAccessFlags2 depthAccess =
        VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_READ_BIT | VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
    imageBarrier(cmd, depth_.image, VK_IMAGE_ASPECT_DEPTH_BIT, VK_IMAGE_LAYOUT_UNDEFINED, depthLayout, depthStages,
                 depthAccess, depthStages, depthAccess);
    for (gpu::Image* img : {&colorWeight_, &normalWeight_})
        imageBarrier(cmd, img->image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED, colorLayout,
                     VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, 0, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                     VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);
    imageBarrier(cmd, output_.image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED, colorLayout,
                 VK_PIPELINE_STAGE_2_TRANSFER_BIT, 0, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                 VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);

    const VkClearValue zero{};  // colour 0 and depth 0 (reversed Z: 0 is infinitely far)
    VkRenderingAttachmentInfo depthClear = attachment(depth_.view, depthLayout, VK_ATTACHMENT_LOAD_OP_CLEAR, zero);
    VkRenderingAttachmentInfo accum[2] = {attachment(colorWeight_.view, colorLayout, VK_ATTACHMENT_LOAD_OP_CLEAR, zero),
                                          attachment(normalWeight_.view, colorLayout, VK_ATTACHMENT_LOAD_OP_CLEAR, zero)};
    auto begin = [&](uint32_t colorCount, const VkRenderingAttachmentInfo* colors, const VkRenderingAttachmentInfo* depth) {
        VkRenderingInfo info{VK_STRUCTURE_TYPE_RENDERING_INFO};
        info.renderArea = area;
        info.layerCount = 1;
        info.colorAttachmentCount = colorCount;
        info.pColorAttachments = colors;
        info.pDepthAttachment = depth;
        vkCmdBeginRendering(cmd, &info);
        vkCmdSetViewport(cmd, 0, 1, &viewport);
        vkCmdSetScissor(cmd, 0, 1, &area);
    };
    VkShaderStageFlags pushStages = VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT |
                                    (ctx_.geometryShader ? VK_SHADER_STAGE_GEOMETRY_BIT : 0);
    FrameParams frame = params;  // translucent frames change the layer
    // Every pipeline layout has the same push-constant range, so pushing
    // through splatLayout_ serves them all.
    auto draw = [&](VkPipeline pipeline, bool quads) {
        vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipeline);
        vkCmdPushConstants(cmd, splatLayout_, pushStages, 0, sizeof(frame), &frame);
        if (splatCount_ == 0) return;
        VkDeviceSize offset = 0;
        vkCmdBindVertexBuffers(cmd, 0, 1, &drawBuffer_, &offset);
        for (const DrawRange& r : ranges_) {
            if (quads) vkCmdDraw(cmd, 4, r.count, 0, r.first);  // one instance per surfel
            else vkCmdDraw(cmd, r.count, 1, r.first, 0);
        }
    };
    const bool quads = options_.expansion == Expansion::Quad;
    ewaFrame_ = params.mode != SC_MODE_POINTS && params.mode != SC_MODE_CIRCLES;
    auto fullscreen = [&](VkPipeline pipeline, VkPipelineLayout layout, VkDescriptorSet set) {
        vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipeline);
        vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, layout, 0, 1, &set, 0, nullptr);
        vkCmdPushConstants(cmd, layout, pushStages, 0, sizeof(frame), &frame);
        vkCmdDraw(cmd, 3, 1, 0, 0);
    };
    if (ewaFrame_ && (params.flags & SC_FLAG_TRANSLUCENT) != 0u) {
        // Depth peeling, layer by layer (see the header). Layouts: a depth is
        // an attachment while its layer draws and sampled (`read`) while the
        // next one does; depth2_ starts sampled, as layer -1's.
        const VkImageLayout read = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
        const VkPipelineStageFlags2 shader = VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT;
        const VkPipelineStageFlags2 colorOut = VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT;
        const VkAccessFlags2 sampled = VK_ACCESS_2_SHADER_SAMPLED_READ_BIT, colorWrite = VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT;
        imageBarrier(cmd, depth2_.image, VK_IMAGE_ASPECT_DEPTH_BIT, VK_IMAGE_LAYOUT_UNDEFINED, read, depthStages, depthAccess,
                     shader, sampled);
        for (gpu::Image* img : {&alphaWeight_, &compositeImage_})
            imageBarrier(cmd, img->image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED, colorLayout, shader, 0, colorOut,
                         colorWrite);
        const gpu::Image* depths[2] = {&depth_, &depth2_};
        const uint32_t layers = uint32_t(std::clamp(settings.layers, 1, kMaxLayers));
        for (uint32_t k = 0; k < layers; ++k) {
            frame.layer = k;
            const gpu::Image& current = *depths[k % 2];
            const gpu::Image& previous = *depths[(k + 1) % 2];
            VkDescriptorSet previousSet = previousDepthSets_[(k + 1) % 2];
            if (k > 0) {
                imageBarrier(cmd, previous.image, VK_IMAGE_ASPECT_DEPTH_BIT, depthLayout, read, depthStages, depthAccess, shader,
                             sampled);
                imageBarrier(cmd, current.image, VK_IMAGE_ASPECT_DEPTH_BIT, read, depthLayout, shader, sampled, depthStages,
                             depthAccess);
                for (gpu::Image* img : {&colorWeight_, &normalWeight_, &alphaWeight_})
                    imageBarrier(cmd, img->image, VK_IMAGE_ASPECT_COLOR_BIT, read, colorLayout, shader, sampled, colorOut,
                                 colorWrite);
            }
            VkRenderingAttachmentInfo clearDepth = attachment(current.view, depthLayout, VK_ATTACHMENT_LOAD_OP_CLEAR, zero);
            begin(0, nullptr, &clearDepth);
            if (k > 0)
                vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, oneImageLayout_, 0, 1, &previousSet, 0, nullptr);
            draw(k == 0 ? visibility_ : peel_, quads);
            vkCmdEndRendering(cmd);
            if (k == 0) timestamp(kQueryVisibility, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
            imageBarrier(cmd, current.image, VK_IMAGE_ASPECT_DEPTH_BIT, depthLayout, depthLayout, depthStages, depthAccess,
                         depthStages, depthAccess);
            VkRenderingAttachmentInfo targets[3] = {accum[0], accum[1],
                                                    attachment(alphaWeight_.view, colorLayout, VK_ATTACHMENT_LOAD_OP_CLEAR, zero)};
            VkRenderingAttachmentInfo loadDepth = attachment(current.view, depthLayout, VK_ATTACHMENT_LOAD_OP_LOAD);
            begin(3, targets, &loadDepth);
            // Layer 0's shader reads no previous depth; depth2_ is bound, sampled, all the same.
            vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, oneImageLayout_, 0, 1, &previousSet, 0, nullptr);
            draw(k + 1 == layers ? layerRest_ : layer_, quads);
            vkCmdEndRendering(cmd);
            for (gpu::Image* img : {&colorWeight_, &normalWeight_, &alphaWeight_})
                imageBarrier(cmd, img->image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, read, colorOut, colorWrite, shader, sampled);
            if (k > 0)
                imageBarrier(cmd, compositeImage_.image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, colorLayout, colorOut, colorWrite,
                             colorOut, colorWrite | VK_ACCESS_2_COLOR_ATTACHMENT_READ_BIT);
            VkRenderingAttachmentInfo under = attachment(
                compositeImage_.view, colorLayout, k == 0 ? VK_ATTACHMENT_LOAD_OP_CLEAR : VK_ATTACHMENT_LOAD_OP_LOAD, zero);
            begin(1, &under, nullptr);
            fullscreen(resolveLayer_, threeImageLayout_, layerSet_);
            vkCmdEndRendering(cmd);
        }
        timestamp(kQueryAccumulate, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
        imageBarrier(cmd, compositeImage_.image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, read, colorOut, colorWrite, shader, sampled);
        VkRenderingAttachmentInfo out = attachment(output_.view, colorLayout, VK_ATTACHMENT_LOAD_OP_DONT_CARE);
        begin(1, &out, nullptr);
        fullscreen(composite_, oneImageLayout_, compositeSet_);
        vkCmdEndRendering(cmd);
        timestamp(kQueryResolve, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
        imageBarrier(cmd, output_.image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, colorOut,
                     colorWrite, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
        return;
    }
    if (ewaFrame_) {
        begin(0, nullptr, &depthClear);
        draw(visibility_, quads);
        vkCmdEndRendering(cmd);
        timestamp(kQueryVisibility, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
        imageBarrier(cmd, depth_.image, VK_IMAGE_ASPECT_DEPTH_BIT, depthLayout, depthLayout, depthStages, depthAccess,
                     depthStages, depthAccess);
        VkRenderingAttachmentInfo depthLoad = attachment(depth_.view, depthLayout, VK_ATTACHMENT_LOAD_OP_LOAD);
        begin(2, accum, &depthLoad);
        draw(accumulate_, quads);
        vkCmdEndRendering(cmd);
    } else {
        timestamp(kQueryVisibility, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
        begin(2, accum, &depthClear);
        if (params.mode == SC_MODE_POINTS) draw(points_, false);
        else draw(circles_, true);
        vkCmdEndRendering(cmd);
    }
    timestamp(kQueryAccumulate, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);

    for (gpu::Image* img : {&colorWeight_, &normalWeight_})
        imageBarrier(cmd, img->image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                     VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT, VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT,
                     VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, VK_ACCESS_2_SHADER_SAMPLED_READ_BIT);
    VkRenderingAttachmentInfo out = attachment(output_.view, colorLayout, VK_ATTACHMENT_LOAD_OP_DONT_CARE);
    begin(1, &out, nullptr);
    fullscreen(resolve_, resolveLayout_, resolveSet_);
    vkCmdEndRendering(cmd);
    timestamp(kQueryResolve, VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT);
    imageBarrier(cmd, output_.image, VK_IMAGE_ASPECT_COLOR_BIT, colorLayout, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                 VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT, VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT,
                 VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
}

GpuFrameStats SplatRenderer::timings() const {
    GpuFrameStats stats;
    stats.splats = splatCount_;
    if (!queries_) return stats;
    uint64_t t[kQueryCount] = {};
    if (vkGetQueryPoolResults(ctx_.device, queries_, 0, kQueryCount, sizeof(t), t, sizeof(uint64_t),
                              VK_QUERY_RESULT_64_BIT) != VK_SUCCESS)
        return stats;
    const double ms = ctx_.properties.limits.timestampPeriod * 1e-6;
    stats.visibilityMs = double(t[kQueryVisibility] - t[kQueryStart]) * ms;
    stats.accumulateMs = double(t[kQueryAccumulate] - t[kQueryVisibility]) * ms;
    stats.resolveMs = double(t[kQueryResolve] - t[kQueryAccumulate]) * ms;
    stats.totalMs = double(t[kQueryResolve] - t[kQueryStart]) * ms;
    return stats;
}

Result<Image> SplatRenderer::render(const ViewTransform& view, const RenderSettings& settings, GpuFrameStats* stats) {
    SC_TRY(resize(uint32_t(view.width), uint32_t(view.height)));
    SC_TRY(gpu::submitAndWait(ctx_, [&](VkCommandBuffer cmd) {
        record(cmd, view, settings);
        VkBufferImageCopy copy{};
        copy.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
        copy.imageExtent = {output_.width, output_.height, 1};
        vkCmdCopyImageToBuffer(cmd, output_.image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, readback_.buffer, 1, &copy);
        gpu::hostReadBarrier(cmd);
    }));
    Image image{view.width, view.height, std::vector<uint8_t>(readback_.size)};
    std::memcpy(image.rgba.data(), readback_.mapped, readback_.size);
    if (stats) {
        *stats = timings();
        for (size_t i = 3; i < image.rgba.size(); i += 4) stats->pixelsCovered += image.rgba[i] == 255;
    }
    return image;
}

Status SplatRenderer::capture(const ViewTransform& view, const RenderSettings& settings, std::vector<float>* weightSums,
                              std::vector<float>* depth) {
    SC_TRY(resize(uint32_t(view.width), uint32_t(view.height)));
    RenderSettings s = settings;
    s.mode = RenderMode::EwaNoPrefilter;
    s.translucent = false;  // the weights are those of the nearest surface
    s.opacity = 1.f;
    const VkDeviceSize pixels = VkDeviceSize(view.width) * view.height;
    const VkDeviceSize colorBytes = pixels * (options_.halfFloatAccumulation ? 8 : 16);
    auto colorBuffer = gpu::createBuffer(ctx_, colorBytes, VK_BUFFER_USAGE_TRANSFER_DST_BIT, true);
    if (!colorBuffer) return colorBuffer.status();
    auto depthBuffer = gpu::createBuffer(ctx_, pixels * 4, VK_BUFFER_USAGE_TRANSFER_DST_BIT, true);
    if (!depthBuffer) {
        gpu::destroyBuffer(ctx_, *colorBuffer);
        return depthBuffer.status();
    }
    Status status = gpu::submitAndWait(ctx_, [&](VkCommandBuffer cmd) {
        record(cmd, view, s);
        gpu::imageBarrier(cmd, colorWeight_.image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                          VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                          VK_ACCESS_2_SHADER_SAMPLED_READ_BIT, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
        const VkPipelineStageFlags2 depthStages =
            VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT;
        gpu::imageBarrier(cmd, depth_.image, VK_IMAGE_ASPECT_DEPTH_BIT, VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
                          VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, depthStages,
                          VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_READ_BIT | VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
                          VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
        VkBufferImageCopy copy{};
        copy.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
        copy.imageExtent = {uint32_t(view.width), uint32_t(view.height), 1};
        vkCmdCopyImageToBuffer(cmd, colorWeight_.image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, colorBuffer->buffer, 1, &copy);
        copy.imageSubresource.aspectMask = VK_IMAGE_ASPECT_DEPTH_BIT;
        vkCmdCopyImageToBuffer(cmd, depth_.image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, depthBuffer->buffer, 1, &copy);
        gpu::hostReadBarrier(cmd);
    });
    if (status) {
        weightSums->resize(pixels);
        depth->resize(pixels);
        std::memcpy(depth->data(), depthBuffer->mapped, pixels * 4);
        if (options_.halfFloatAccumulation) {
            // The RGBA16F alpha, widened (IEEE half: 1 sign, 5 exponent, 10 mantissa bits).
            const auto* h = static_cast<const uint16_t*>(colorBuffer->mapped);
            for (VkDeviceSize i = 0; i < pixels; ++i) {
                uint16_t v = h[4 * i + 3];
                int e = (v >> 10) & 31, m = v & 1023;
                float f = e == 0 ? std::ldexp(float(m), -24) : e == 31 ? INFINITY : std::ldexp(float(m | 1024), e - 25);
                (*weightSums)[i] = v & 0x8000 ? -f : f;
            }
        } else {
            const auto* f = static_cast<const float*>(colorBuffer->mapped);
            for (VkDeviceSize i = 0; i < pixels; ++i) (*weightSums)[i] = f[4 * i + 3];
        }
    }
    gpu::destroyBuffer(ctx_, *colorBuffer);
    gpu::destroyBuffer(ctx_, *depthBuffer);
    return status;
}

}  // namespace surfcast
