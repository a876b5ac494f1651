#include "window.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "context.h"
#include "streamer.h"
#include "swapchain.h"

namespace surfcast {

namespace {

// Rotate v about the unit axis k by angle a (Rodrigues).
Vec3d rotate(const Vec3d& v, const Vec3d& k, double a) {
    return v * std::cos(a) + cross(k, v) * std::sin(a) + k * (dot(k, v) * (1 - std::cos(a)));
}

// The interactive camera: orbit about the target around the camera's own up
// axis, pan, zoom and fly; in double (world coordinates can be 10^6). Until
// the user moves it, it is exactly the camera it started from.
struct Orbit {
    Camera cam;

    Vec3d forward() const { return normalizeOrZero(cam.target - cam.eye); }
    Vec3d right() const { return normalizeOrZero(cross(forward(), cam.up)); }
    void orbit(double yaw, double pitch) {
        Vec3d up = normalizeOrZero(cam.up);
        Vec3d offset = rotate(cam.eye - cam.target, up, -yaw);
        Vec3d axis = normalizeOrZero(cross(offset, up));
        Vec3d pitched = rotate(offset, axis, pitch);
        // Stop short of the poles, where the view direction meets the up axis.
        if (std::fabs(dot(normalizeOrZero(pitched), up)) < 0.995) offset = pitched;
        cam.eye = cam.target + offset;
    }
    void move(const Vec3d& delta) {
        cam.eye += delta;
        cam.target += delta;
    }
    void zoom(double factor) { cam.eye = cam.target + (cam.eye - cam.target) * factor; }
};

struct WindowState {
    Orbit orbit;
    double lastX = 0, lastY = 0;
    bool orbiting = false, panning = false;
    RenderMode mode = RenderMode::EwaPixel;
    Shading shading = Shading::Unlit;
    bool screenshot = false;
};

void onKey(GLFWwindow* w, int key, int, int action, int) {
    auto* s = static_cast<WindowState*>(glfwGetWindowUserPointer(w));
    if (action != GLFW_PRESS) return;
    const RenderMode modes[] = {RenderMode::Points, RenderMode::Circles, RenderMode::EwaNoPrefilter, RenderMode::EwaSurfel,
                                RenderMode::EwaPixel};
    if (key >= GLFW_KEY_1 && key <= GLFW_KEY_5) s->mode = modes[key - GLFW_KEY_1];
    if (key == GLFW_KEY_L)
        s->shading = s->shading == Shading::Unlit ? Shading::Lambert
                     : s->shading == Shading::Lambert ? Shading::Phong : Shading::Unlit;
    if (key == GLFW_KEY_P) s->screenshot = true;
    if (key == GLFW_KEY_ESCAPE) glfwSetWindowShouldClose(w, GLFW_TRUE);
}

void onButton(GLFWwindow* w, int button, int action, int) {
    auto* s = static_cast<WindowState*>(glfwGetWindowUserPointer(w));
    glfwGetCursorPos(w, &s->lastX, &s->lastY);
    if (button == GLFW_MOUSE_BUTTON_LEFT) s->orbiting = action == GLFW_PRESS;
    if (button == GLFW_MOUSE_BUTTON_RIGHT || button == GLFW_MOUSE_BUTTON_MIDDLE) s->panning = action == GLFW_PRESS;
}

void onCursor(GLFWwindow* w, double x, double y) {
    auto* s = static_cast<WindowState*>(glfwGetWindowUserPointer(w));
    double dx = x - s->lastX, dy = y - s->lastY;
    s->lastX = x;
    s->lastY = y;
    int width = 1, height = 1;
    glfwGetWindowSize(w, &width, &height);
    if (s->orbiting) {
        s->orbit.orbit(dx * 0.01, dy * 0.01);
    } else if (s->panning) {
        const Camera& c = s->orbit.cam;
        Vec3d right = s->orbit.right(), up = cross(right, s->orbit.forward());
        double perPixel = 2 * length(c.eye - c.target) * std::tan(0.5 * c.fovYDegrees * M_PI / 180) / std::max(height, 1);
        s->orbit.move(right * (-dx * perPixel) + up * (dy * perPixel));
    }
}

void onScroll(GLFWwindow* w, double, double dy) {
    auto* s = static_cast<WindowState*>(glfwGetWindowUserPointer(w));
    s->orbit.zoom(std::pow(0.9, dy));
}

// Fly: move eye and target together along the view axes.
void fly(GLFWwindow* w, WindowState& s, double seconds) {
    Vec3d f = s.orbit.forward(), right = s.orbit.right(), up = normalizeOrZero(s.orbit.cam.up);
    Vec3d move;
    if (glfwGetKey(w, GLFW_KEY_W) == GLFW_PRESS) move += f;
    if (glfwGetKey(w, GLFW_KEY_S) == GLFW_PRESS) move = move - f;
    if (glfwGetKey(w, GLFW_KEY_D) == GLFW_PRESS) move += right;
    if (glfwGetKey(w, GLFW_KEY_A) == GLFW_PRESS) move = move - right;
    if (glfwGetKey(w, GLFW_KEY_E) == GLFW_PRESS) move += up;
    if (glfwGetKey(w, GLFW_KEY_Q) == GLFW_PRESS) move = move - up;
    // Half the distance to the target per second.
    s.orbit.move(move * (0.5 * length(s.orbit.cam.eye - s.orbit.cam.target) * seconds));
}

int fail(const std::string& message) {
    std::fprintf(stderr, "surfcast-view: %s\n", message.c_str());
    return 1;
}

}  // namespace

int runWindow(const ViewOptions& o, const SurfelSet& initial, StreamingSet* stream) {
    SurfelSet set = initial;
    std::vector<uint32_t> drawn;  // the streamed nodes in `set`
    bool converged = stream == nullptr;
    if (o.settings.mode == RenderMode::CpuReference)
        return fail("the window draws the GPU modes; render cpu-reference with --headless");
    if (!glfwInit()) return fail("cannot open a window (no display?); use --headless");
    glfwWindowHint(GLFW_CLIENT_API, GLFW_NO_API);
    GLFWwindow* window = glfwCreateWindow(o.width, o.height, "surfcast-view", nullptr, nullptr);
    if (!window) {
        glfwTerminate();
        return fail("cannot create a window");
    }
    WindowState state;
    state.orbit.cam = o.cameras.empty() ? frameBox(set.bounds, double(o.width) / o.height) : o.cameras[0];
    state.mode = o.settings.mode;
    state.shading = o.settings.shading;
    glfwSetWindowUserPointer(window, &state);
    glfwSetKeyCallback(window, onKey);
    glfwSetMouseButtonCallback(window, onButton);
    glfwSetCursorPosCallback(window, onCursor);
    glfwSetScrollCallback(window, onScroll);

    int status = 0;
    auto ctx = gpu::createContext({o.device, o.validation, gpu::windowInstanceExtensions(), true});
    if (!ctx) {
        glfwDestroyWindow(window);
        glfwTerminate();
        return fail(ctx.status().message());
    }
    {
        auto swapchain = gpu::createSwapchain(**ctx, window);
        auto renderer = swapchain ? SplatRenderer::create(**ctx, o.renderer) : swapchain.status();
        Status s = renderer ? renderer.value()->upload(set) : renderer.status();
        if (!s) status = fail(s.message());
        int frame = 0, screenshots = 0;
        auto last = std::chrono::steady_clock::now();
        while (status == 0 && !glfwWindowShouldClose(window)) {
            glfwPollEvents();
            auto now = std::chrono::steady_clock::now();
            double seconds = std::chrono::duration<double>(now - last).count();
            last = now;
            fly(window, state, seconds);
            SplatRenderer& r = **renderer;
            VkExtent2D extent = swapchain->extent;
            if (extent.width == 0 || extent.height == 0) continue;  // minimized
            if (Status rs = r.resize(extent.width, extent.height); !rs) {
                status = fail(rs.message());
                break;
            }
            RenderSettings settings = o.settings;
            settings.mode = state.mode;
            settings.shading = state.shading;
            if (stream) {
                LodParams lod;
                lod.targetPixels = *o.lod;
                lod.frustumCulling = lod.backfaceCulling = o.culling;
                auto selected = stream->update(state.orbit.cam, int(extent.width), int(extent.height), lod, nullptr, &converged);
                std::vector<uint32_t> now;
                for (const auto& s : selected) now.push_back(s.index);
                if (now != drawn) {  // rebuild and upload only when the drawn nodes change
                    set = emptySurfelSet(stream->info());
                    for (uint32_t i : now)
                        if (auto block = stream->block(i)) appendNode(set, stream->info(), stream->nodes()[i], *block);
                    sortMorton(set);
                    if (Status us = r.upload(set); !us) {
                        status = fail(us.message());
                        break;
                    }
                    drawn = std::move(now);
                }
            }
            auto view = makeViewTransform(state.orbit.cam, set.origin, int(extent.width), int(extent.height));
            if (!view) continue;  // a degenerate orbit (zoomed to zero): skip the frame
            auto params = makeFrameParams(*view, settings, r.nearPlane(*view));
            auto presented = gpu::presentFrame(**ctx, *swapchain, window, r.output().image,
                                               [&](VkCommandBuffer cmd) { r.record(cmd, params); });
            if (!presented) {
                status = fail(presented.status().message());
                break;
            }
            if (!*presented) continue;
            vkWaitForFences((*ctx)->device, 1, &swapchain->inFlight, VK_TRUE, UINT64_MAX);
            GpuFrameStats t = r.timings();
            char title[320];
            int used = std::snprintf(title, sizeof(title), "surfcast-view - %s - %.1f ms frame, %.1f ms GPU, %zu splats",
                                     renderModeName(state.mode), seconds * 1e3, t.totalMs, t.splats);
            if (stream) {
                StreamStats ss = stream->stats();
                std::snprintf(title + used, sizeof(title) - size_t(used), " - %zu nodes, %.1f MB%s", drawn.size(),
                              double(ss.bytesDownloaded) / 1e6, converged ? "" : ", streaming");
            }
            glfwSetWindowTitle(window, title);
            if (converged) ++frame;  // --frames counts converged frames
            bool lastFrame = o.frames > 0 && frame >= o.frames;
            if (state.screenshot || (lastFrame && !o.screenshot.empty())) {
                auto image = r.render(*view, settings);
                char name[64];
                std::snprintf(name, sizeof(name), "surfcast-%04d.png", screenshots++);
                std::string path = lastFrame && !o.screenshot.empty() ? o.screenshot : name;
                Status ws = image ? writePng(*image, path) : image.status();
                if (!ws) status = fail(ws.message());
                else std::fprintf(stderr, "surfcast-view: wrote %s\n", path.c_str());
                state.screenshot = false;
            }
            if (lastFrame) glfwSetWindowShouldClose(window, GLFW_TRUE);
        }
        if (renderer) renderer->reset();
        if (swapchain) gpu::destroySwapchain(**ctx, *swapchain);
    }
    int errors = (*ctx)->validationErrors.load();
    gpu::destroyContext(*ctx);
    glfwDestroyWindow(window);
    glfwTerminate();
    if (errors > 0 && status == 0) status = fail(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

}  // namespace surfcast
