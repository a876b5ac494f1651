#include "window.h"

#include <GLFW/glfw3.h>

#include <chrono>
#include <cmath>
#include <cstdio>

#include "context.h"
#include "swapchain.h"

namespace surfcast {

namespace {

// Orbit camera around a target, in double (world coordinates can be 10^6).
struct Orbit {
    Vec3d target;
    double distance = 1, yaw = 0, pitch = 0.3;  // radians
    double fov = 45;

    Camera camera() const {
        Vec3d dir{std::cos(pitch) * std::sin(yaw), -std::cos(pitch) * std::cos(yaw), std::sin(pitch)};
        return {target + dir * distance, target, {0, 0, 1}, fov};
    }
    Vec3d forward() const { return normalizeOrZero(target - camera().eye); }
};

Orbit orbitFrom(const Camera& c) {
    Orbit o;
    Vec3d d = c.eye - c.target;
    o.target = c.target;
    o.distance = std::max(length(d), 1e-9);
    o.pitch = std::asin(std::clamp(d.z / o.distance, -1.0, 1.0));
    o.yaw = std::atan2(d.x, -d.y);
    o.fov = c.fovYDegrees;
    return o;
}

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
        s->orbit.yaw += dx * 0.01;
        s->orbit.pitch = std::clamp(s->orbit.pitch + dy * 0.01, -1.55, 1.55);
    } else if (s->panning) {
        Camera c = s->orbit.camera();
        Vec3d f = s->orbit.forward();
        Vec3d right = normalizeOrZero(cross(f, c.up)), up = cross(right, f);
        double perPixel = 2 * s->orbit.distance * std::tan(0.5 * s->orbit.fov * M_PI / 180) / std::max(height, 1);
        s->orbit.target = s->orbit.target - right * (dx * perPixel) + up * (dy * perPixel);
    }
}

void onScroll(GLFWwindow* w, double, double dy) {
    auto* s = static_cast<WindowState*>(glfwGetWindowUserPointer(w));
    s->orbit.distance *= std::pow(0.9, dy);
}

// Fly: move eye and target together along the view axes.
void fly(GLFWwindow* w, WindowState& s, double seconds) {
    Vec3d f = s.orbit.forward();
    Vec3d right = normalizeOrZero(cross(f, Vec3d{0, 0, 1}));
    Vec3d move;
    if (glfwGetKey(w, GLFW_KEY_W) == GLFW_PRESS) move += f;
    if (glfwGetKey(w, GLFW_KEY_S) == GLFW_PRESS) move = move - f;
    if (glfwGetKey(w, GLFW_KEY_D) == GLFW_PRESS) move += right;
    if (glfwGetKey(w, GLFW_KEY_A) == GLFW_PRESS) move = move - right;
    if (glfwGetKey(w, GLFW_KEY_E) == GLFW_PRESS) move += Vec3d{0, 0, 1};
    if (glfwGetKey(w, GLFW_KEY_Q) == GLFW_PRESS) move = move - Vec3d{0, 0, 1};
    s.orbit.target += move * (0.5 * s.orbit.distance * seconds);
}

int fail(const std::string& message) {
    std::fprintf(stderr, "surfcast-view: %s\n", message.c_str());
    return 1;
}

}  // namespace

int runWindow(const ViewOptions& o, const SurfelSet& set) {
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
    state.orbit = orbitFrom(o.cameras.empty() ? frameBox(set.bounds, double(o.width) / o.height) : o.cameras[0]);
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
            auto view = makeViewTransform(state.orbit.camera(), set.origin, int(extent.width), int(extent.height));
            if (!view) continue;  // a degenerate orbit (zoomed to zero): skip the frame
            auto params = makeFrameParams(*view, settings, r.nearPlane());
            auto presented = gpu::presentFrame(**ctx, *swapchain, window, r.output().image,
                                               [&](VkCommandBuffer cmd) { r.record(cmd, params); });
            if (!presented) {
                status = fail(presented.status().message());
                break;
            }
            if (!*presented) continue;
            vkWaitForFences((*ctx)->device, 1, &swapchain->inFlight, VK_TRUE, UINT64_MAX);
            GpuFrameStats t = r.timings();
            char title[256];
            std::snprintf(title, sizeof(title), "surfcast-view - %s - %.1f ms frame, %.1f ms GPU, %zu splats",
                          renderModeName(state.mode), seconds * 1e3, t.totalMs, t.splats);
            glfwSetWindowTitle(window, title);
            ++frame;
            bool last = o.frames > 0 && frame >= o.frames;
            if (state.screenshot || (last && !o.screenshot.empty())) {
                auto image = r.render(*view, settings);
                char name[64];
                std::snprintf(name, sizeof(name), "surfcast-%04d.png", screenshots++);
                std::string path = last && !o.screenshot.empty() ? o.screenshot : name;
                Status ws = image ? writePng(*image, path) : image.status();
                if (!ws) status = fail(ws.message());
                else std::fprintf(stderr, "surfcast-view: wrote %s\n", path.c_str());
                state.screenshot = false;
            }
            if (last) glfwSetWindowShouldClose(window, GLFW_TRUE);
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
