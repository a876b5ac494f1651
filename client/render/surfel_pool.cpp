#include "surfel_pool.h"

#include <cstring>

#include "vk_check.h"

namespace surfcast {

using gpu_types::GpuSurfel;
constexpr VkDeviceSize kPageBytes = SurfelPool::kPageSurfels * sizeof(GpuSurfel);

Result<std::unique_ptr<SurfelPool>> SurfelPool::create(gpu::Context& ctx, size_t budgetBytes) {
    std::unique_ptr<SurfelPool> pool(new SurfelPool(ctx));
    pool->pageCount_ = std::max<size_t>(1, budgetBytes / kPageBytes);
    auto buffer = gpu::createBuffer(ctx, pool->pageCount_ * kPageBytes,
                                    VK_BUFFER_USAGE_VERTEX_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT, false);
    if (!buffer)
        return Status::error("cannot allocate the GPU surfel pool of " + std::to_string(budgetBytes >> 20) +
                             " MiB (lower --gpu-budget): " + buffer.status().message());
    pool->buffer_ = *buffer;
    for (uint32_t p = 0; p < pool->pageCount_; ++p) pool->free_.insert(pool->free_.end(), p);
    return pool;
}

SurfelPool::~SurfelPool() {
    vkDeviceWaitIdle(ctx_.device);
    gpu::destroyBuffer(ctx_, buffer_);
    gpu::destroyBuffer(ctx_, staging_);
}

Status SurfelPool::upload(const std::vector<std::pair<uint32_t, const SurfelSet*>>& nodes) {
    size_t pagesNeeded = 0, bytes = 0;
    for (const auto& [index, set] : nodes) {
        if (contains(index)) return Status::error("node " + std::to_string(index) + " is already in the GPU pool");
        pagesNeeded += (set->surfels.size() + kPageSurfels - 1) / kPageSurfels;
        bytes += set->surfels.size() * sizeof(GpuSurfel);
    }
    if (pagesNeeded > free_.size())
        return Status::error("the GPU surfel pool is full: " + std::to_string(pagesNeeded) + " pages needed, " +
                             std::to_string(freePages()) + " of " + std::to_string(pageCount_) + " free");
    if (bytes == 0) {
        for (const auto& [index, set] : nodes) nodes_[index] = std::make_shared<const Node>();
        return {};
    }
    if (staging_.size < bytes) {
        gpu::destroyBuffer(ctx_, staging_);
        auto staging = gpu::createBuffer(ctx_, bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, true);
        if (!staging) return staging.status();
        staging_ = *staging;
    }
    // The staging buffer is free: the previous upload waited for its copy.
    std::vector<VkBufferCopy> copies;
    VkDeviceSize at = 0;
    for (const auto& [index, set] : nodes) {
        Node node;
        node.surfels = uint32_t(set->surfels.size());
        if (node.surfels > 0)  // an empty node (every class hidden) has no data pointer to copy from
            std::memcpy(static_cast<char*>(staging_.mapped) + at, set->surfels.data(), node.surfels * sizeof(GpuSurfel));
        for (uint32_t done = 0; done < node.surfels; done += kPageSurfels) {
            uint32_t page = *free_.begin();
            free_.erase(free_.begin());
            node.pages.push_back(page);
            VkDeviceSize size = std::min<VkDeviceSize>(kPageSurfels, node.surfels - done) * sizeof(GpuSurfel);
            copies.push_back({at + done * sizeof(GpuSurfel), page * kPageBytes, size});
        }
        at += node.surfels * sizeof(GpuSurfel);
        nodes_[index] = std::make_shared<const Node>(std::move(node));
    }
    return gpu::submitAndWait(ctx_, [&](VkCommandBuffer cmd) {
        // Frames submitted earlier may still read pages freed since: their
        // vertex reads finish before the copy writes (write after read needs
        // only this execution dependency).
        gpu::memoryBarrier(cmd, VK_PIPELINE_STAGE_2_VERTEX_ATTRIBUTE_INPUT_BIT, VK_ACCESS_2_NONE,
                           VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_NONE);
        vkCmdCopyBuffer(cmd, staging_.buffer, buffer_.buffer, uint32_t(copies.size()), copies.data());
        gpu::memoryBarrier(cmd, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                           VK_PIPELINE_STAGE_2_VERTEX_ATTRIBUTE_INPUT_BIT, VK_ACCESS_2_VERTEX_ATTRIBUTE_READ_BIT);
    });
}

bool SurfelPool::share(uint32_t node, uint32_t from) {
    auto it = nodes_.find(from);
    if (it == nodes_.end() || nodes_.count(node)) return false;
    nodes_[node] = it->second;
    return true;
}

void SurfelPool::release(uint32_t index) {
    auto it = nodes_.find(index);
    if (it == nodes_.end()) return;
    if (it->second.use_count() == 1) free_.insert(it->second->pages.begin(), it->second->pages.end());
    nodes_.erase(it);
}

std::vector<DrawRange> SurfelPool::ranges(const std::vector<uint32_t>& indices) const {
    std::vector<DrawRange> out;
    for (uint32_t index : indices) {
        auto it = nodes_.find(index);
        if (it == nodes_.end()) continue;
        const Node& n = *it->second;
        for (size_t k = 0; k < n.pages.size(); ++k) {
            uint32_t first = n.pages[k] * kPageSurfels;
            uint32_t count = std::min<uint32_t>(kPageSurfels, n.surfels - uint32_t(k) * kPageSurfels);
            if (!out.empty() && out.back().first + out.back().count == first) out.back().count += count;
            else out.push_back({first, count});
        }
    }
    return out;
}

}  // namespace surfcast
