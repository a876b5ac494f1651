#include "view_options.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>

#include "command_line.h"
#include "context.h"
#include "http_tile_source.h"

namespace surfcast {

namespace {

constexpr const char* kUsage = R"(surfcast-view SET [options]                 (a window)
       surfcast-view --headless SET [options]      (PNG files, one JSON line per frame))";

constexpr const char* kDescription = R"(Renders a tile set (a folder with tileset.json, or its http(s) URL) with
object-space EWA surface splatting on Vulkan, or with the CPU screen-space EWA
reference.

SET may be a URL: http(s)://HOST[:PORT]/sets/NAME (surfcast-serve) or any folder
URL on a static host, object store or CDN with Range (a query string, such as a
shared access signature, is sent with every request), or s3://BUCKET/PREFIX, its
requests signed with the standard AWS credentials (docs/STORAGE.md). With --lod
frames redraw as blocks arrive, one JSON line per redraw, until converged;
without it every leaf is fetched first (at most --gpu-budget of them).)";

constexpr const char* kKeys = R"(Window keys: drag left = orbit, drag right = pan, wheel = zoom, W/A/S/D/Q/E = fly,
1..5 = mode (points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel),
L = shading, C = next colour-by mode the set has, G = hide or show ground (class 2),
P = screenshot (surfcast-NNNN.png), Esc = quit.)";

bool parseFloat(const std::string& s, float* out) {
    char* end = nullptr;
    double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || *end != '\0' || !std::isfinite(v)) return false;
    *out = float(v);
    return true;
}

}  // namespace

int viewError(const std::string& message) {
    std::fprintf(stderr, "surfcast-view: %s\n", message.c_str());
    return 1;
}

std::string framePath(const std::string& out, size_t frame, size_t frames) {
    if (frames <= 1) return out;
    char suffix[32];
    std::snprintf(suffix, sizeof(suffix), "_%04zu", frame);
    size_t dot = out.rfind('.');
    size_t slash = out.rfind('/');
    if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return out + suffix;
    return out.substr(0, dot) + suffix + out.substr(dot);
}

bool parseViewOptions(int argc, char** argv, ViewOptions* o, int* exitCode) {
    const char* env = std::getenv("SURFCAST_VALIDATION");
    o->validation = env && std::string(env) == "1";
#ifndef NDEBUG
    o->validation = true;  // debug builds always validate
#endif
    using cli::UsageError;
    bool listDevices = false;
    CLI::App app{kDescription, "surfcast-view"};
    cli::configure(app)->usage(&app, kUsage);
    app.footer(kKeys);
    app.add_option("SET", o->set, "the tile set: a folder, or its http(s) or s3:// URL");
    std::string group = "Options";
    auto option = [&](const std::string& spec, const std::string& type, const std::string& help, std::function<void(const std::string&)> f) {
        cli::option(app, spec, type, help, std::move(f))->group(group);
    };
    auto flag = [&](const std::string& spec, const std::string& help, std::function<void()> f) {
        cli::flag(app, spec, help, std::move(f))->group(group);
    };
    auto positive = [](const std::string& v, const std::string& what) {
        float f = 0;
        if (!parseFloat(v, &f) || !(f > 0)) throw UsageError(what + " wants a positive number");
        return f;
    };
    auto count = [](const std::string& v, const std::string& what, long most = 1000000) {
        char* end = nullptr;
        long n = std::strtol(v.c_str(), &end, 10);
        if (*end != '\0' || v.empty() || n < 1 || n > most) throw UsageError(what + " wants a whole number >= 1");
        return int(n);
    };
    auto onOff = [](const std::string& v, const std::string& what) {
        if (v != "on" && v != "off") throw UsageError(what + " wants on or off");
        return v == "on";
    };

    group = "The view";
    flag("--headless", "render to PNG files, one JSON line per frame, without a window", [o] { o->headless = true; });
    option("--camera", "EX,EY,EZ,TX,TY,TZ,UX,UY,UZ,FOV",
           "eye, target, up (world coordinates of the input) and vertical field of view in degrees (default: frame the set)",
           [o](const std::string& v) {
               auto c = parseCamera(v);
               if (!c) throw UsageError(c.status().message());
               o->cameras = {*c};
           });
    option("--camera-path", "FILE", "JSON {\"frames\": [{\"eye\": [..], \"target\": [..], \"up\": [..], \"fov\": 45}, ...]}",
           [o](const std::string& v) {
               std::ifstream in(v);
               if (!in) throw UsageError("--camera-path: cannot read " + v);
               std::stringstream text;
               text << in.rdbuf();
               auto path = parseCameraPath(text.str(), v);
               if (!path) throw UsageError(path.status().message());
               o->cameras = *path;
           });
    option("--size", "WxH", "image size (default 1280x720)", [o](const std::string& v) {
        auto size = parseImageSize(v);
        if (!size) throw UsageError("--size wants WxH, each 1..16384");
        o->width = size->first;
        o->height = size->second;
    });
    option("--out", "PATH", "PNG to write (default frame.png; several frames: PATH_0000.png ...)", [o](const std::string& v) { o->out = v; });
    option("--level", "N|leaves", "draw level N (with the leaves above it) or every leaf (default)", [o](const std::string& v) {
        char* end = nullptr;
        long n = std::strtol(v.c_str(), &end, 10);
        if (v == "leaves") o->level.level = -1;
        else if (*end == '\0' && end != v.c_str() && n >= 0 && n <= 30) o->level.level = int(n);
        else throw UsageError("--level wants a level number or 'leaves'");
    });
    option("--clip", "X0,Y0,Z0,X1,Y1,Z1",
           "draw only the splats whose centre lies in this box (the set's own coordinates, bounds included), in every mode; nodes "
           "outside it are not fetched",
           [o](const std::string& v) {
               auto box = parseBox(v);
               if (!box) throw UsageError("--clip: " + box.status().message());
               o->settings.clip = o->client.lod.clip = *box;
           });
    option("--repeat", "N", "headless: render each frame N times, report the median GPU times",
           [o, count](const std::string& v) { o->repeat = count(v, "--repeat"); });
    option("--frames", "N", "window: close after N frames", [o, count](const std::string& v) { o->frames = count(v, "--frames"); });
    option("--screenshot", "PATH", "window: write the last frame to PATH on exit", [o](const std::string& v) { o->screenshot = v; });

    group = "Rendering";
    option("--mode", "MODE", "points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel (default), cpu-reference", [o](const std::string& v) {
        auto m = parseRenderMode(v);
        if (!m) throw UsageError("--mode wants points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel or cpu-reference");
        o->settings.mode = *m;
    });
    option("--kernel-scale", "K",
           "reconstruction kernel V^r = (K h)^2 I (default: the set's kernel_scale, which its weights assume; 0.5 unless built "
           "otherwise)",
           [o, positive](const std::string& v) {
               o->settings.kernelScale = positive(v, "--kernel-scale");
               o->kernelScaleGiven = true;
           });
    option("--cutoff", "C", "splats end at y'y = 2C (default 1)", [o, positive](const std::string& v) { o->settings.cutoff = positive(v, "--cutoff"); });
    option("--zt", "Z", "visibility depth offset z_t, a multiple of the splat's footprint (h when magnified; default 0.5)",
           [o](const std::string& v) {
               if (!parseFloat(v, &o->settings.zt) || o->settings.zt < 0) throw UsageError("--zt wants a number >= 0");
           });
    option("--lowpass", "V", "low-pass filter variance in pixels^2 (default 0.1, measured; Zwicker's V^h = I is 1)", [o](const std::string& v) {
        if (!parseFloat(v, &o->settings.lowpassVariance) || o->settings.lowpassVariance < 0) throw UsageError("--lowpass wants a number >= 0");
    });
    option("--edge-aa", "on|off", "edge antialiasing (Zwicker 2001 §7): silhouette pixels blend over the background by their coverage (default: on)",
           [o, onOff](const std::string& v) {
               o->settings.edgeAA = onOff(v, "--edge-aa");
               o->edgeAAGiven = true;
           });
    option("--edge-tau", "T", "kernel sum at which a silhouette pixel counts as fully covered (default 4)", [o](const std::string& v) {
        if (!parseFloat(v, &o->settings.edgeTau) || !(o->settings.edgeTau > 0)) throw UsageError("--edge-tau wants a number > 0");
    });
    option("--opacity", "A",
           "multiply every surfel's opacity by A in [0, 1]: see through the whole set (default 1: as stored, opaque unless built "
           "translucent)",
           [o](const std::string& v) {
               if (!parseFloat(v, &o->settings.opacity) || !(o->settings.opacity >= 0 && o->settings.opacity <= 1))
                   throw UsageError("--opacity wants a number in [0, 1]");
           });
    option("--layers", "L",
           "translucent frames: surfaces resolved per pixel, nearest first (Zwicker 2001 §6; default 3); those behind merge into the last",
           [o](const std::string& v) {
               float l = 0;
               if (!parseFloat(v, &l) || l != std::floor(l) || l < 1 || l > kMaxLayers)
                   throw UsageError("--layers wants a whole number in [1, " + std::to_string(kMaxLayers) + "]");
               o->settings.layers = int(l);
           });
    option("--shading", "S", "unlit, lambert, phong (default: unlit for rgb and intensity, else lambert)", [o](const std::string& v) {
        auto s = parseShading(v);
        if (!s) throw UsageError("--shading wants unlit, lambert or phong");
        o->settings.shading = *s;
        o->shadingGiven = true;
    });
    option("--backface-cull", "on|off",
           "drop splats facing away from the eye, in every mode (default: on where the set's normals are oriented, i.e. its "
           "normal_source is input or estimated-scan-origin; off for estimated-up and estimated-outward, whose signs hold for ground "
           "or closed objects only)",
           [o, onOff](const std::string& v) {
               o->settings.backfaceCull = onOff(v, "--backface-cull");
               o->backfaceCullGiven = true;
           });
    auto rgb = [](const std::string& v, const std::string& what) {
        Vec3f c;
        char tail = 0;
        if (std::sscanf(v.c_str(), "%f,%f,%f%c", &c.x, &c.y, &c.z, &tail) != 3 ||
            !(c.x >= 0 && c.x <= 1 && c.y >= 0 && c.y <= 1 && c.z >= 0 && c.z <= 1))
            throw UsageError(what + " wants R,G,B in [0,1]");
        return c;
    };
    option("--background", "R,G,B", "background colour in [0,1] (default 1,1,1)",
           [o, rgb](const std::string& v) { o->settings.background = rgb(v, "--background"); });
    option("--color", "R,G,B", "draw every surfel in this colour (for brightness measurements)",
           [o, rgb](const std::string& v) { o->color = rgb(v, "--color"); });
    option("--color-by", "A",
           "rgb, intensity (through the set's 2-98 % range, gamma 1/2.2), elevation (viridis), classification (ASPRS palette) or "
           "return (single, first, intermediate, last); default: rgb where the set has colour, else intensity where it has that, "
           "else elevation",
           [o](const std::string& v) {
               auto by = parseColorBy(v);
               if (!by) throw UsageError("--color-by wants rgb, intensity, elevation, classification or return");
               o->client.coloring.by = *by;
           });
    auto classes = [o](const std::string& v, const std::string& what) {
        std::array<bool, 256> listed{};
        bool ok = !v.empty();
        std::stringstream list(v);
        for (std::string item; ok && std::getline(list, item, ',');) {
            char* end = nullptr;
            long c = std::strtol(item.c_str(), &end, 10);
            ok = !item.empty() && *end == 0 && c >= 0 && c <= 255;
            if (ok) listed[size_t(c)] = true;
        }
        if (!ok) throw UsageError(what + " wants class numbers in 0-255, comma-separated");
        for (size_t c = 0; c < 256; ++c) o->client.coloring.hidden[c] = what == "--classes" ? !listed[c] : listed[c];
    };
    option("--classes", "LIST", "draw only these classes, e.g. 2,6 (sets with classification)",
           [classes](const std::string& v) { classes(v, "--classes"); });
    option("--hide-classes", "LIST", "draw all classes but these, e.g. 7,18", [classes](const std::string& v) { classes(v, "--hide-classes"); });

    group = "Vulkan";
    option("--expansion", "E", "quad (instanced quads) or geometry (geometry shader); default: geometry where the device has it (faster on lavapipe)",
           [o](const std::string& v) {
               if (v != "quad" && v != "geometry") throw UsageError("--expansion wants quad or geometry");
               o->renderer.expansion = v == "quad" ? Expansion::Quad : Expansion::Geometry;
           });
    option("--accumulation", "F", "rgba32f (default) or rgba16f accumulation targets", [o](const std::string& v) {
        if (v != "rgba32f" && v != "rgba16f") throw UsageError("--accumulation wants rgba32f or rgba16f");
        o->renderer.halfFloatAccumulation = v == "rgba16f";
    });
    option("--device", "D", "Vulkan device index or name substring (default: discrete GPU first)", [o](const std::string& v) { o->device = v; });
    flag("--list-devices", "print the Vulkan devices and exit", [&listDevices] { listDevices = true; });
    flag("--validation", "enable the Khronos validation layer (also SURFCAST_VALIDATION=1); any validation error makes the exit status 1",
         [o] { o->validation = true; });

    group = "Streaming (--lod)";
    option("--lod", "PX",
           "level of detail per frame, refining nodes while their projected spacing exceeds PX pixels (frustum and cone culling); "
           "streams SET (a folder or an http(s) URL) in the window or headless",
           [o, positive](const std::string& v) { o->lod = positive(v, "--lod"); });
    flag("--no-culling", "with --lod: draw what culling would skip (for comparisons)",
         [o] { o->client.lod.frustumCulling = o->client.lod.backfaceCulling = false; });
    option("--splat-budget", "N",
           "with --lod: at most N splats per frame (default 5000000); views that need more stay coarser, evenly",
           [o, count](const std::string& v) { o->client.lod.splatBudget = size_t(count(v, "--splat-budget", 2000000000)); });
    option("--gpu-budget", "MIB",
           "GPU memory for surfels; with --lod, least recently used nodes evicted beyond it (default 1024, or a quarter of the device's)",
           [o, positive](const std::string& v) { o->client.gpuBudget = size_t(double(positive(v, "--gpu-budget")) * (1 << 20)); });
    option("--block-cache", "MIB",
           "with --lod: host memory for the compressed blocks of resident nodes, kept so that changing the colouring fetches nothing "
           "(default 512); beyond it the least recently used go, and a recolour fetches those again",
           [o, positive](const std::string& v) { o->client.blockCache = size_t(double(positive(v, "--block-cache")) * (1 << 20)); });
    option("--connections", "N", "with --lod: concurrent block requests (default 6)",
           [o, count](const std::string& v) { o->client.connections = count(v, "--connections"); });
    flag("--save-redraws", "with --lod, headless: also write every redraw before convergence, as OUT_rNNN.png (progressive streaming studies)",
         [o] { o->saveRedraws = true; });
    option("--max-wait", "S", "with --lod: stop streaming a frame after S seconds (default 120)",
           [o, positive](const std::string& v) { o->maxWait = positive(v, "--max-wait"); });
    option("--follow", "S",
           "with --lod: follow SET as it changes (surfcast-build --add, --replace, a rebuild), polling its tileset.json every S "
           "seconds (2 is a good choice), and switch to each new version once it is loaded for the view: only changed nodes are "
           "fetched. Headless, the last frame follows until --max-wait, one JSON line per redraw of other nodes; half of "
           "--gpu-budget holds the version loading",
           [o, positive](const std::string& v) { o->client.followSeconds = positive(v, "--follow"); });
    cli::addHttpOptions(app, o->client.http, "Reaching a set at a URL (--redirect-credentials: also to the hosts redirects lead to)");

    if (int status = cli::parse(app, std::vector<std::string>(argv + 1, argv + argc), nullptr,
                                [](const CLI::App&, const std::string& arg) {
                                    return arg.size() > 1 && arg[0] == '-' ? "unknown option " + arg : std::string("more than one tile set given");
                                });
        status >= 0) {
        *exitCode = status;
        return false;
    }
    if (listDevices) {
        std::fputs(gpu::listDevices().c_str(), stdout);
        *exitCode = 0;
        return false;
    }
    const auto usageError = [](const std::string& m) { return cli::usageError("surfcast-view", m); };
    if (o->set.empty()) return (*exitCode = usageError("no tile set given")), false;
    if (o->client.followSeconds > 0 && !o->lod)
        return (*exitCode = usageError("--follow streams the set: it needs --lod")), false;
    return true;
}

RenderSettings effectiveSettings(const ViewOptions& o, const RenderSettings& setDefaults) {
    RenderSettings s = o.settings;
    if (!o.kernelScaleGiven) s.kernelScale = setDefaults.kernelScale;
    if (!o.shadingGiven) s.shading = setDefaults.shading;
    if (!o.backfaceCullGiven) s.backfaceCull = setDefaults.backfaceCull;
    if (!o.edgeAAGiven) s.edgeAA = setDefaults.edgeAA;
    s.translucent = setDefaults.translucent;
    return s;
}

}  // namespace surfcast
