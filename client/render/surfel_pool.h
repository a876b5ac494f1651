// Device memory for streamed nodes: one device-local vertex buffer of fixed
// size (the GPU memory budget) cut into pages of kPageSurfels surfels. A node
// takes whole pages, adjacent or not, so evicting and loading in any order
// never fragments the pool; a node's draw is one range per run of adjacent
// pages. The arrivals of a frame are uploaded through one staging buffer in
// one submission, which the upload waits for.
//
// A released page is free at once. An upload's copy starts with a barrier
// after the vertex reads of everything submitted before it, so a frame in
// flight finishes reading a page before the copy overwrites it. (Record a
// frame after the update that chose its nodes, as SurfcastClient does: a
// command buffer recorded earlier and submitted after the upload would read
// the new contents.) The queue is the one the frames go to, so the upload's
// wait also covers the frames submitted before it.
#pragma once

#include <memory>
#include <set>
#include <unordered_map>
#include <vector>

#include "../gpu/resources.h"
#include "splat_renderer.h"
#include "surfel_set.h"

namespace surfcast {

class SurfelPool {
public:
    static constexpr uint32_t kPageSurfels = 1024;  // 32 KiB
    static Result<std::unique_ptr<SurfelPool>> create(gpu::Context& ctx, size_t budgetBytes);
    ~SurfelPool();
    SurfelPool(const SurfelPool&) = delete;
    SurfelPool& operator=(const SurfelPool&) = delete;

    // Copies each node's surfels into free pages and waits for the copy.
    // Fails, uploading nothing, when the pool cannot hold them.
    Status upload(const std::vector<std::pair<uint32_t, const SurfelSet*>>& nodes);
    // `node` draws `from`'s pages too (a follower's node that two versions
    // share); false where `from` is not here or `node` is. A page is free
    // once every node that draws it is released.
    bool share(uint32_t node, uint32_t from);
    void release(uint32_t node);
    bool contains(uint32_t node) const { return nodes_.count(node) != 0; }
    // The draw ranges of these nodes, in order.
    std::vector<DrawRange> ranges(const std::vector<uint32_t>& nodes) const;

    VkBuffer buffer() const { return buffer_.buffer; }
    size_t pageCount() const { return pageCount_; }
    size_t freePages() const { return free_.size(); }

private:
    explicit SurfelPool(gpu::Context& ctx) : ctx_(ctx) {}
    struct Node {
        std::vector<uint32_t> pages;
        uint32_t surfels = 0;
    };
    gpu::Context& ctx_;
    gpu::Buffer buffer_, staging_;
    size_t pageCount_ = 0;
    std::set<uint32_t> free_;  // lowest first: loads tend to take adjacent pages
    std::unordered_map<uint32_t, std::shared_ptr<const Node>> nodes_;
};

}  // namespace surfcast
