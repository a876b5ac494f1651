#include "headless.h"

#include <algorithm>
#include <cstdio>
#include <chrono>
#include <thread>
#include <nlohmann/json.hpp>

#include "context.h"
#include "cpu_reference.h"
#include "surfcast_client.h"

namespace surfcast {

namespace {

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0 : v[v.size() / 2];
}

// While streaming, frames are redrawn at most this often.
constexpr int kStreamPollMs = 30;

}  // namespace

int runHeadless(const ViewOptions& o, const SurfelSet& set) {
    std::vector<Camera> cameras = o.cameras;
    if (cameras.empty())
        cameras = {frameBox(set.bounds, double(o.width) / o.height, 45, o.settings.backfaceCull ? frontDirection(set) : 0)};
    const bool cpu = o.settings.mode == RenderMode::CpuReference;

    std::unique_ptr<gpu::Context> ctx;
    std::unique_ptr<SplatRenderer> renderer;
    if (!cpu) {
        auto c = gpu::createContext({o.device, o.validation, {}, false});
        if (!c) return viewError(c.status().message());
        ctx = std::move(*c);
        auto r = SplatRenderer::create(*ctx, o.renderer);
        Status s = r ? r.value()->upload(set) : r.status();
        if (r) renderer = std::move(*r);
        if (!s) {
            renderer.reset();  // before the device it lives on
            gpu::destroyContext(ctx);
            return viewError(s.message());
        }
    }
    int status = 0;
    for (size_t f = 0; f < cameras.size() && status == 0; ++f) {
        auto view = makeViewTransform(cameras[f], set.origin, o.width, o.height);
        if (!view) {
            status = viewError("frame " + std::to_string(f) + ": " + view.status().message());
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
                    status = viewError("frame " + std::to_string(f) + ": " + img.status().message());
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
            status = viewError(s.message());
            break;
        }
        line["out"] = path;
        if (ctx) line["validation_errors"] = ctx->validationErrors.load();
        std::printf("%s\n", line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
        std::fflush(stdout);
    }
    int errors = ctx ? ctx->validationErrors.load() : 0;
    renderer.reset();
    if (ctx) {
        gpu::destroyContext(ctx);
    }
    if (errors > 0 && status == 0) status = viewError(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

int runHeadlessLod(const ViewOptions& o) {
    auto c = gpu::createContext({o.device, o.validation, {}, false});
    if (!c) return viewError(c.status().message());
    std::unique_ptr<gpu::Context> ctx = std::move(*c);
    int status = 0;
    const auto start = std::chrono::steady_clock::now();
    auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
    {
        ClientOptions options = o.client;
        options.lod.targetPixels = *o.lod;
        options.renderer = o.renderer;
        auto client = SurfcastClient::open(*ctx, o.set, options);
        if (!client) status = viewError(client.status().message());
        RenderSettings settings = o.settings;
        size_t settingsVersion = 0;  // the version `settings` are the defaults of (a follower switches)
        std::vector<Camera> cameras = o.cameras;
        if (client) {
            settings = effectiveSettings(o, client.value()->defaultSettings());
            if (cameras.empty()) cameras = {frameBox(client.value()->info().bounds, double(o.width) / o.height)};
        }
        for (size_t f = 0; f < cameras.size() && status == 0; ++f) {
            // Progressive: draw what is resident, until nothing more is wanted
            // for this view (converged) or --max-wait runs out. Following, the
            // last frame goes on until --max-wait, printing a line where the
            // state changes and drawing only where other nodes or another
            // version are drawn (a version loading beside leaves the image).
            const double frameStart = seconds();
            const bool following = o.client.followSeconds > 0 && f + 1 == cameras.size();
            size_t shownVersion = 0;
            uint32_t shownNodes = 0;
            bool shownConverged = false, shownLoading = false;
            Image image;
            GpuFrameStats gpuStats;
            for (int iteration = 0; status == 0; ++iteration) {
                const double updateStart = seconds();
                auto frame = client.value()->update(cameras[f], o.width, o.height);
                const double updateMs = (seconds() - updateStart) * 1e3;
                bool timedOut = seconds() - frameStart > o.maxWait;
                if (frame && frame->version != settingsVersion) {
                    settings = effectiveSettings(o, client.value()->defaultSettings());
                    settingsVersion = frame->version;
                }
                bool redraw = true;
                if (frame && following) {
                    redraw = iteration == 0 || frame->nodesCrc != shownNodes || frame->version != shownVersion;
                    const bool changed = redraw || timedOut || frame->converged != shownConverged ||
                                         frame->loadingVersion != shownLoading;
                    shownVersion = frame->version;
                    shownNodes = frame->nodesCrc;
                    shownConverged = frame->converged;
                    shownLoading = frame->loadingVersion;
                    if (!changed) {
                        std::this_thread::sleep_for(std::chrono::milliseconds(kStreamPollMs));
                        continue;
                    }
                }
                if (redraw) {
                    auto rendered = frame ? client.value()->renderImage(settings, &gpuStats) : Result<Image>(frame.status());
                    if (!rendered) {
                        status = viewError("frame " + std::to_string(f) + ": " + rendered.status().message());
                        break;
                    }
                    image = std::move(*rendered);
                }
                const ClientFrame& cf = *frame;
                nlohmann::ordered_json line;
                line["frame"] = f;
                line["iteration"] = iteration;
                line["time_s"] = seconds();
                line["lod_target_px"] = *o.lod;
                line["nodes"] = cf.nodes;
                line["nodes_crc"] = cf.nodesCrc;
                line["splats"] = gpuStats.splats;
                line["pixels_covered"] = gpuStats.pixelsCovered;
                line["nodes_visited"] = cf.lod.visited;
                line["frustum_culled"] = cf.lod.frustumCulled;
                line["clip_culled"] = cf.lod.clipCulled;
                line["backface_culled"] = cf.lod.backfaceCulled;
                line["wanted"] = cf.lod.missing.size();
                line["budget_limited"] = cf.lod.budgetLimited;
                line["bytes_downloaded"] = cf.stream.bytesDownloaded;
                line["requests"] = cf.stream.requests;
                line["hierarchy_bytes"] = cf.stream.hierarchyBytes;
                line["hierarchy_pages"] = cf.stream.pages;
                line["requests_in_flight"] = cf.stream.requestsInFlight;
                line["nodes_in_flight"] = cf.stream.inFlight;
                line["resident_nodes"] = cf.stream.resident;
                line["resident_bytes"] = cf.stream.residentBytes;
                line["evictions"] = cf.stream.evictions;
                line["fetch_ms"] = cf.stream.fetchMs;
                line["decode_ms"] = cf.stream.decodeMs;
                line["failures"] = cf.stream.failures;
                if (!cf.stream.lastError.empty()) line["last_error"] = cf.stream.lastError;
                line["update_ms"] = updateMs;
                line["gpu_ms"] = gpuStats.totalMs;
                line["converged"] = cf.converged;
                if (const uint32_t stride = client.value()->info().previewStride) {
                    line["preview"] = stride;
                    line["preview_done"] = client.value()->info().previewDone;
                }
                if (o.client.followSeconds > 0) {
                    line["version"] = cf.version;
                    line["loading_version"] = cf.loadingVersion;
                    line["adopted"] = cf.stream.adopted;
                    line["shared"] = cf.stream.shared;
                    line["next_bytes_downloaded"] = cf.next.bytesDownloaded;
                    if (!cf.followError.empty()) line["follow_error"] = cf.followError;
                }
                if (o.saveRedraws) {
                    std::string path = framePath(o.out, f, cameras.size());
                    char suffix[32];
                    std::snprintf(suffix, sizeof suffix, "_r%03d.png", iteration);
                    path = path.substr(0, path.size() - (path.size() >= 4 && path.ends_with(".png") ? 4 : 0)) + suffix;
                    if (Status w = writePng(image, path); !w) {
                        status = viewError(w.message());
                        break;
                    }
                    line["redraw"] = path;
                }
                std::printf("%s\n", line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
                std::fflush(stdout);
                if (cf.converged && !following) break;
                if (timedOut && following) break;
                if (timedOut) {
                    std::fprintf(stderr, "surfcast-view: frame %zu not converged after --max-wait %.0f s\n", f, o.maxWait);
                    break;
                }
                std::this_thread::sleep_for(std::chrono::milliseconds(kStreamPollMs));
            }
            if (status) break;
            if (Status w = writePng(image, framePath(o.out, f, cameras.size())); !w) status = viewError(w.message());
        }
    }
    int errors = ctx->validationErrors.load();
    gpu::destroyContext(ctx);
    if (errors > 0 && status == 0) status = viewError(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

}  // namespace surfcast
