#include "headless.h"

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "context.h"
#include "cpu_reference.h"

namespace surfcast {

namespace {

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0 : v[v.size() / 2];
}

int fail(const std::string& message) {
    std::fprintf(stderr, "surfcast-view: %s\n", message.c_str());
    return 1;
}

}  // namespace

int runHeadless(const ViewOptions& o, const SurfelSet& set) {
    std::vector<Camera> cameras = o.cameras;
    if (cameras.empty()) cameras = {frameBox(set.bounds, double(o.width) / o.height)};
    const bool cpu = o.settings.mode == RenderMode::CpuReference;

    std::unique_ptr<gpu::Context> ctx;
    std::unique_ptr<SplatRenderer> renderer;
    if (!cpu) {
        auto c = gpu::createContext({o.device, o.validation, {}, false});
        if (!c) return fail(c.status().message());
        ctx = std::move(*c);
        auto r = SplatRenderer::create(*ctx, o.renderer);
        Status s = r ? r.value()->upload(set) : r.status();
        if (r) renderer = std::move(*r);
        if (!s) {
            renderer.reset();  // before the device it lives on
            gpu::destroyContext(ctx);
            return fail(s.message());
        }
    }
    int status = 0;
    for (size_t f = 0; f < cameras.size() && status == 0; ++f) {
        auto view = makeViewTransform(cameras[f], set.origin, o.width, o.height);
        if (!view) {
            status = fail("frame " + std::to_string(f) + ": " + view.status().message());
            break;
        }
        nlohmann::ordered_json line;
        line["frame"] = f;
        line["mode"] = renderModeName(o.settings.mode);
        line["width"] = o.width;
        line["height"] = o.height;
        Image image;
        if (cpu) {
            std::vector<double> ms;
            CpuFrameStats stats;
            for (int i = 0; i < o.repeat; ++i) {
                image = renderCpuReference(set, *view, o.settings, &stats);
                ms.push_back(stats.milliseconds);
            }
            line["splats"] = stats.splats;
            line["pixels_covered"] = stats.pixelsCovered;
            line["cpu_ms"] = median(ms);
        } else {
            std::vector<double> vis, acc, res, total;
            GpuFrameStats stats;
            for (int i = 0; i < o.repeat; ++i) {
                auto img = renderer->render(*view, o.settings, &stats);
                if (!img) {
                    status = fail("frame " + std::to_string(f) + ": " + img.status().message());
                    break;
                }
                image = std::move(*img);
                vis.push_back(stats.visibilityMs);
                acc.push_back(stats.accumulateMs);
                res.push_back(stats.resolveMs);
                total.push_back(stats.totalMs);
            }
            if (status) break;
            line["splats"] = stats.splats;
            line["pixels_covered"] = stats.pixelsCovered;
            line["gpu_ms"] = {{"visibility", median(vis)}, {"accumulate", median(acc)},
                              {"resolve", median(res)}, {"total", median(total)}};
            line["device"] = ctx->properties.deviceName;
            line["expansion"] = renderer->expansion() == Expansion::Geometry ? "geometry" : "quad";
        }
        std::string path = framePath(o.out, f, cameras.size());
        if (Status s = writePng(image, path); !s) {
            status = fail(s.message());
            break;
        }
        line["out"] = path;
        if (ctx) line["validation_errors"] = ctx->validationErrors.load();
        std::printf("%s\n", line.dump().c_str());
        std::fflush(stdout);
    }
    int errors = ctx ? ctx->validationErrors.load() : 0;
    renderer.reset();
    if (ctx) {
        gpu::destroyContext(ctx);
    }
    if (errors > 0 && status == 0) status = fail(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

}  // namespace surfcast
