// A GoogleTest fixture for the renderer's tests: one Vulkan context per suite
// with the Khronos validation layer on, zero validation errors checked after
// every test, and a one-call render of a SurfelSet.
#pragma once

#include <gtest/gtest.h>

#include <memory>

#include "context.h"
#include "splat_renderer.h"
#include "surfel_set.h"

namespace surfcast::test {

class GpuTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        auto ctx = gpu::createContext({"", true, {}, false});
        ASSERT_TRUE(ctx) << ctx.status().message();
        context_ = std::move(*ctx);
    }
    static void TearDownTestSuite() { gpu::destroyContext(context_); }
    void SetUp() override { ASSERT_TRUE(context_); }
    void TearDown() override {
        if (context_) {
            EXPECT_EQ(context_->validationErrors.load(), 0) << "Vulkan validation errors (see stderr)";
        }
    }

    // Renders `set` with a fresh renderer; an empty image (and a test
    // failure) when anything fails.
    Image gpuRender(const SurfelSet& set, const Camera& camera, int width, int height, const RenderSettings& settings = {},
                    const RendererOptions& options = {}, GpuFrameStats* stats = nullptr) {
        auto renderer = SplatRenderer::create(*context_, options);
        EXPECT_TRUE(renderer) << renderer.status().message();
        if (!renderer) return {};
        Status s = renderer.value()->upload(set);
        EXPECT_TRUE(s) << s.message();
        auto view = makeViewTransform(camera, set.origin, width, height);
        EXPECT_TRUE(view);
        if (!s || !view) return {};
        auto img = renderer.value()->render(*view, settings, stats);
        EXPECT_TRUE(img) << img.status().message();
        return img ? *img : Image{};
    }

    static inline std::unique_ptr<gpu::Context> context_;
};

}  // namespace surfcast::test
