#include "window.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <optional>
#include <utility>

#include "context.h"
#include "surfcast_client.h"
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
    bool nextColoring = false, toggleGround = false;  // C, G: handled by the frame loop
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
    if (key == GLFW_KEY_C) s->nextColoring = true;
    if (key == GLFW_KEY_G) s->toggleGround = true;
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

// The colouring after the C and G keys: the next mode the set can show, and
// ground (ASPRS class 2) hidden or shown. Nullopt, with a message, when a key
// asks for what the set lacks or --color fixes the colour.
std::optional<Coloring> keyedColoring(WindowState& s, const ViewOptions& o, const TilesetInfo& info, Coloring c) {
    const bool next = std::exchange(s.nextColoring, false), ground = std::exchange(s.toggleGround, false);
    if (!next && !ground) return std::nullopt;
    if (o.color) {
        std::fprintf(stderr, "surfcast-view: --color fixes every surfel's colour; C and G do nothing\n");
        return std::nullopt;
    }
    if (ground && !info.attribute("classification")) {
        std::fprintf(stderr, "surfcast-view: the set stores no classification; G (hide ground) does nothing\n");
        return std::nullopt;
    }
    if (next) c.by = nextColorBy(c.by, info);
    if (ground) c.hidden[2] = !c.hidden[2];
    std::fprintf(stderr, "surfcast-view: colour by %s%s\n", colorByName(c.by), c.hidden[2] ? ", ground (class 2) hidden" : "");
    return c;
}

}  // namespace

int runWindow(const ViewOptions& o, const SurfelSet& set, const TilesetInfo& setInfo) {
    if (o.settings.mode == RenderMode::CpuReference)
        return viewError("the window draws the GPU modes; render cpu-reference with --headless");
    if (!glfwInit()) return viewError("cannot open a window (no display?); use --headless");
    glfwWindowHint(GLFW_CLIENT_API, GLFW_NO_API);
    GLFWwindow* window = glfwCreateWindow(o.width, o.height, "surfcast-view", nullptr, nullptr);
    if (!window) {
        glfwTerminate();
        return viewError("cannot create a window");
    }
    int status = 0;
    auto ctx = gpu::createContext({o.device, o.validation, gpu::windowInstanceExtensions(), true});
    if (!ctx) {
        glfwDestroyWindow(window);
        glfwTerminate();
        return viewError(ctx.status().message());
    }
    WindowState state;
    {
        auto swapchain = gpu::createSwapchain(**ctx, window);
        // Either a whole set on one renderer, or a streamed one (--lod).
        std::unique_ptr<SplatRenderer> renderer;
        std::unique_ptr<SurfcastClient> client;
        TilesetInfo info = setInfo;  // for the colour keys
        Coloring coloring = o.client.coloring;
        RenderSettings base = o.settings;
        Box3d bounds = set.bounds;
        size_t shownVersion = 0;  // of a following client: `base` and `info` are its
        Status s = swapchain ? Status{} : swapchain.status();
        if (s && o.lod) {
            ClientOptions options = o.client;
            options.lod.targetPixels = *o.lod;
            options.renderer = o.renderer;
            auto c = SurfcastClient::open(**ctx, o.set, options);
            if (c) {
                client = std::move(*c);
                base = effectiveSettings(o, client->defaultSettings());
                bounds = client->info().bounds;
                info = client->info();
            } else {
                s = c.status();
            }
        } else if (s) {
            auto r = SplatRenderer::create(**ctx, o.renderer);
            s = r ? r.value()->upload(set) : r.status();
            if (r) renderer = std::move(*r);
        }
        if (!s) status = viewError(s.message());
        const int direction = !o.lod && base.backfaceCull ? frontDirection(set) : 0;
        state.orbit.cam = o.cameras.empty() ? frameBox(bounds, double(o.width) / o.height, 45, direction) : o.cameras[0];
        state.mode = base.mode;
        state.shading = base.shading;
        glfwSetWindowUserPointer(window, &state);
        glfwSetKeyCallback(window, onKey);
        glfwSetMouseButtonCallback(window, onButton);
        glfwSetCursorPosCallback(window, onCursor);
        glfwSetScrollCallback(window, onScroll);

        int frame = 0, screenshots = 0;
        auto last = std::chrono::steady_clock::now();
        while (status == 0 && !glfwWindowShouldClose(window)) {
            glfwPollEvents();
            auto now = std::chrono::steady_clock::now();
            double seconds = std::chrono::duration<double>(now - last).count();
            last = now;
            fly(window, state, seconds);
            if (auto c = keyedColoring(state, o, info, coloring)) {
                // Streamed: decoded again from the kept blocks. Whole set:
                // read again from the folder.
                Status rs = client ? client->setColoring(*c) : Status{};
                std::optional<RenderSettings> setDefaults;
                if (client) {
                    setDefaults = client->defaultSettings();
                } else {
                    auto reloaded = loadSurfelSet(o.set, o.level, *c, o.client.http, o.client.gpuBudget);
                    rs = reloaded ? renderer->upload(*reloaded) : reloaded.status();
                    if (reloaded) setDefaults = settingsForSet(reloaded->kernelScale, reloaded->hasColor, reloaded->normalsOriented,
                                                               reloaded->translucent);
                }
                if (!rs) {
                    status = viewError(rs.message());
                    break;
                }
                coloring = *c;
                base = effectiveSettings(o, *setDefaults);
                state.shading = base.shading;
            }
            VkExtent2D extent = swapchain->extent;
            if (extent.width == 0 || extent.height == 0) continue;  // minimized
            RenderSettings settings = base;
            settings.mode = state.mode;
            settings.shading = state.shading;
            const int W = int(extent.width), H = int(extent.height);
            bool converged = true;
            ClientFrame streamed;
            std::function<void(VkCommandBuffer)> record;
            VkImage source = VK_NULL_HANDLE;
            Result<ViewTransform> view = makeViewTransform(state.orbit.cam, set.origin, W, H);
            if (client) {
                auto fr = client->update(state.orbit.cam, W, H);
                if (!fr) {
                    status = viewError(fr.status().message());
                    break;
                }
                streamed = *fr;
                converged = streamed.converged;
                if (streamed.version != shownVersion) {  // a follower switched: the new version's defaults and keys
                    shownVersion = streamed.version;
                    base = effectiveSettings(o, client->defaultSettings());
                    info = client->info();
                    settings = base;
                    settings.mode = state.mode;
                    settings.shading = state.shading;
                }
                record = [&](VkCommandBuffer cmd) { client->record(cmd, settings); };
                source = client->output().image;
            } else {
                if (Status rs = renderer->resize(extent.width, extent.height); !rs) {
                    status = viewError(rs.message());
                    break;
                }
                if (!view) continue;  // a degenerate orbit (zoomed to zero): skip the frame
                record = [&, v = *view](VkCommandBuffer cmd) { renderer->record(cmd, v, settings); };
                source = renderer->output().image;
            }
            auto presented = gpu::presentFrame(**ctx, *swapchain, window, source, record);
            if (!presented) {
                status = viewError(presented.status().message());
                break;
            }
            if (!*presented) continue;
            vkWaitForFences((*ctx)->device, 1, &swapchain->inFlight, VK_TRUE, UINT64_MAX);
            GpuFrameStats t = client ? client->timings() : renderer->timings();
            auto shownBy = resolveColorBy(coloring.by, info);
            char title[320];
            int used = std::snprintf(title, sizeof(title), "surfcast-view - %s, %s%s - %.1f ms frame, %.1f ms GPU, %zu splats",
                                     renderModeName(state.mode), o.color ? "--color" : colorByName(shownBy ? *shownBy : coloring.by),
                                     coloring.hidden[2] ? ", ground hidden" : "", seconds * 1e3, t.totalMs, t.splats);
            if (client)
                used += std::snprintf(title + used, sizeof(title) - size_t(used), " - %zu nodes, %.1f MB%s", streamed.nodes,
                                      double(streamed.stream.bytesDownloaded) / 1e6, converged ? "" : ", streaming");
            if (client && o.client.followSeconds > 0 && used > 0 && size_t(used) < sizeof(title))
                std::snprintf(title + used, sizeof(title) - size_t(used), " - version %zu%s", streamed.version,
                              streamed.loadingVersion ? ", loading the next" : "");
            glfwSetWindowTitle(window, title);
            if (converged) ++frame;  // --frames counts converged frames
            bool lastFrame = o.frames > 0 && frame >= o.frames;
            if (state.screenshot || (lastFrame && !o.screenshot.empty())) {
                auto image = client ? client->renderImage(settings)
                                    : (view ? renderer->render(*view, settings) : Result<Image>(view.status()));
                char name[64];
                std::snprintf(name, sizeof(name), "surfcast-%04d.png", screenshots++);
                std::string path = lastFrame && !o.screenshot.empty() ? o.screenshot : name;
                Status ws = image ? writePng(*image, path) : image.status();
                if (!ws) status = viewError(ws.message());
                else std::fprintf(stderr, "surfcast-view: wrote %s\n", path.c_str());
                state.screenshot = false;
            }
            if (lastFrame) glfwSetWindowShouldClose(window, GLFW_TRUE);
        }
        client.reset();
        renderer.reset();
        if (swapchain) gpu::destroySwapchain(**ctx, *swapchain);
    }
    int errors = (*ctx)->validationErrors.load();
    gpu::destroyContext(*ctx);
    glfwDestroyWindow(window);
    glfwTerminate();
    if (errors > 0 && status == 0) status = viewError(std::to_string(errors) + " Vulkan validation error(s)");
    return status;
}

}  // namespace surfcast
