#include "headless.h"

#include <algorithm>
#include <cstdio>
#include <unordered_map>
#include <nlohmann/json.hpp>

#include "context.h"
#include "cpu_reference.h"
#include "lod_selection.h"
#include "tileset_reader.h"

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

int runHeadlessLod(const ViewOptions& o) {
    auto reader = TilesetReader::open(o.set);
    if (!reader) return fail(reader.status().message());
    LodSelector selector(reader->info(), reader->nodes());
    const auto& nodes = selector.nodes();
    std::vector<Camera> cameras = o.cameras;
    if (cameras.empty()) cameras = {frameBox(reader->info().bounds, double(o.width) / o.height)};
    auto c = gpu::createContext({o.device, o.validation, {}, false});
    if (!c) return fail(c.status().message());
    std::unique_ptr<gpu::Context> ctx = std::move(*c);
    int status = 0;
    {
        auto renderer = SplatRenderer::create(*ctx, o.renderer);
        if (!renderer) status = fail(renderer.status().message());
        std::unordered_map<uint32_t, BlockData> blocks;  // decoded once per run
        LodParams params;
        params.targetPixels = *o.lod;
        params.frustumCulling = params.backfaceCulling = o.culling;
        for (size_t f = 0; f < cameras.size() && status == 0; ++f) {
            LodStats stats;
            auto selected = selector.select(cameras[f], o.width, o.height, params, [](uint32_t) { return true; }, &stats);
            SurfelSet set = emptySurfelSet(*reader);
            for (const SelectedNode& s : selected) {
                auto it = blocks.find(s.index);
                if (it == blocks.end()) {
                    auto block = reader->readBlock(nodes[s.index]);
                    if (!block) {
                        status = fail(block.status().message());
                        break;
                    }
                    it = blocks.emplace(s.index, std::move(*block)).first;
                }
                appendNode(set, *reader, nodes[s.index], it->second);
            }
            if (status) break;
            sortMorton(set);
            RenderSettings settings = o.settings;
            auto view = makeViewTransform(cameras[f], set.origin, o.width, o.height);
            Status up = view ? renderer.value()->upload(set) : view.status();
            if (!up) {
                status = fail("frame " + std::to_string(f) + ": " + up.message());
                break;
            }
            GpuFrameStats gpuStats;
            auto image = renderer.value()->render(*view, settings, &gpuStats);
            Status written = image ? writePng(*image, framePath(o.out, f, cameras.size())) : image.status();
            if (!written) {
                status = fail(written.message());
                break;
            }
            nlohmann::ordered_json line;
            line["frame"] = f;
            line["mode"] = renderModeName(o.settings.mode);
            line["lod_target_px"] = *o.lod;
            line["nodes"] = selected.size();
            line["nodes_visited"] = stats.visited;
            line["frustum_culled"] = stats.frustumCulled;
            line["backface_culled"] = stats.backfaceCulled;
            line["splats"] = gpuStats.splats;
            line["pixels_covered"] = gpuStats.pixelsCovered;
            line["gpu_ms"] = {{"visibility", gpuStats.visibilityMs}, {"accumulate", gpuStats.accumulateMs},
                              {"resolve", gpuStats.resolveMs}, {"total", gpuStats.totalMs}};
            line["out"] = framePath(o.out, f, cameras.size());
            line["validation_errors"] = ctx->validationErrors.load();
            std::printf("%s\n", line.dump().c_str());
            std::fflush(stdout);
        }
    }
    int errors = ctx->validationErrors.load();
    gpu::destroyContext(ctx);
    if (errors > 0 && status == 0) status = fail(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

}  // namespace surfcast
