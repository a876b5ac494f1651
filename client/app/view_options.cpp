#include "view_options.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>

#include "context.h"
#include "http_tile_source.h"

namespace surfcast {

namespace {

const char* kUsage = R"(usage: surfcast-view SET [options]                 (a window)
       surfcast-view --headless SET [options]      (PNG files, one JSON line per frame)

Renders a tile set (a folder with tileset.json, or its http(s) URL) with
object-space EWA surface splatting on Vulkan, or with the CPU screen-space EWA
reference.

  --camera ex,ey,ez,tx,ty,tz,ux,uy,uz,fov
                        eye, target, up (world coordinates of the input) and
                        vertical field of view in degrees (default: frame the set)
  --camera-path FILE    JSON {"frames": [{"eye": [..], "target": [..], "up": [..], "fov": 45}, ...]}
  --size WxH            image size (default 1280x720)
  --mode MODE           points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel
                        (default), cpu-reference
  --out PATH            PNG to write (default frame.png; several frames: PATH_0000.png ...)
  --level N|leaves      draw level N (with the leaves above it) or every leaf (default)
  --kernel-scale K      reconstruction kernel V^r = (K h)^2 I (default: the set's
                        kernel_scale, which its weights assume; 0.5 unless built otherwise)
  --cutoff C            splats end at y'y = 2C (default 1)
  --zt Z                visibility depth offset z_t, a multiple of the splat's footprint
                        (h when magnified; default 0.5)
  --lowpass V           low-pass filter variance in pixels^2 (default 0.1, measured;
                        Zwicker's V^h = I is 1)
  --edge-aa on|off      edge antialiasing (Zwicker 2001 §7): silhouette pixels blend over
                        the background by their coverage (default: on)
  --edge-tau T          kernel sum at which a silhouette pixel counts as fully covered
                        (default 4)
  --opacity A           multiply every surfel's opacity by A in [0, 1]: see through
                        the whole set (default 1: as stored, opaque unless built translucent)
  --layers L            translucent frames: surfaces resolved per pixel, nearest first
                        (Zwicker 2001 §6; default 3); those behind merge into the last
  --shading S           unlit, lambert, phong (default: unlit for rgb and intensity, else lambert)
  --backface-cull on|off
                        drop splats facing away from the eye, in every mode (default:
                        on where the set's normals are oriented, i.e. its normal_source
                        is input or estimated-scan-origin; off for estimated-up and
                        estimated-outward, whose signs hold for ground or closed
                        objects only)
  --clip X0,Y0,Z0,X1,Y1,Z1
                        draw only the splats whose centre lies in this box (the set's
                        own coordinates, bounds included), in every mode; nodes outside
                        it are not fetched
  --background R,G,B    background colour in [0,1] (default 1,1,1)
  --color R,G,B         draw every surfel in this colour (for brightness measurements)
  --color-by A          rgb, intensity (through the set's 2-98 % range, gamma 1/2.2),
                        elevation (viridis), classification (ASPRS palette) or return
                        (single, first, intermediate, last); default: rgb where the set
                        has colour, else intensity where it has that, else elevation
  --classes LIST        draw only these classes, e.g. 2,6 (sets with classification)
  --hide-classes LIST   draw all classes but these, e.g. 7,18
  --expansion E         quad (instanced quads) or geometry (geometry shader); default:
                        geometry where the device has it (faster on lavapipe)
  --accumulation F      rgba32f (default) or rgba16f accumulation targets
  --device D            Vulkan device index or name substring (default: discrete GPU first)
  --list-devices        print the Vulkan devices and exit
  --validation          enable the Khronos validation layer (also SURFCAST_VALIDATION=1);
                        any validation error makes the exit status 1
  --repeat N            headless: render each frame N times, report the median GPU times
  --lod PX              level of detail per frame, refining nodes while their projected
                        spacing exceeds PX pixels (frustum and cone culling); streams
                        SET (a folder or an http(s) URL) in the window or headless
  --no-culling          with --lod: draw what culling would skip (for comparisons)
  --splat-budget N      with --lod: at most N splats per frame (default 5000000); views
                        that need more stay coarser, evenly
  --gpu-budget MIB      GPU memory for surfels; with --lod, least recently used nodes
                        evicted beyond it (default 1024, or a quarter of the device's)
  --block-cache MIB     with --lod: host memory for the compressed blocks of resident
                        nodes, kept so that changing the colouring fetches nothing
                        (default 512); beyond it the least recently used go, and a
                        recolour fetches those again
  --connections N       with --lod: concurrent block requests (default 6)
  --save-redraws        with --lod, headless: also write every redraw before
                        convergence, as OUT_rNNN.png (progressive streaming studies)
  --max-wait S          with --lod: stop streaming a frame after S seconds (default 120)
  --follow S            with --lod: follow SET as it changes (surfcast-build --add,
                        --replace, a rebuild), polling its tileset.json every S seconds
                        (2 is a good choice), and switch to each new version once it is
                        loaded for the view: only changed nodes are fetched. Headless,
                        the last frame follows until --max-wait, one JSON line per
                        redraw of other nodes; half of --gpu-budget holds the
                        version loading
  SET may be a URL: http(s)://HOST[:PORT]/sets/NAME (surfcast-serve) or any folder
  URL on a static host, object store or CDN with Range (a query string, such as a
  shared access signature, is sent with every request), or s3://BUCKET/PREFIX, its
  requests signed with the standard AWS credentials (docs/STORAGE.md). With --lod frames redraw
  as blocks arrive, one JSON line per redraw, until converged; without it every
  leaf is fetched first (at most --gpu-budget of them).
  --header 'NAME: VALUE'
                        with a URL: send this header with every request (repeatable)
  --token-file F        with a URL: send 'Authorization: Bearer TOKEN', the token read
                        from F (as surfcast-serve --token-file expects); never printed
  --redirect-credentials
                        with a URL: send --header and --token-file credentials to the
                        hosts that redirects lead to as well; by default only SET's
                        own origin (scheme, host, port) gets them. Redirects go to
                        http(s) only, and never from https to http
  --ca-file F           with an https URL: verify the host against the PEM certificates
                        in F instead of the system's
  --insecure            with an https URL: do not verify certificates (tests only)
  --frames N            window: close after N frames
  --screenshot PATH     window: write the last frame to PATH on exit
  -h, --help            this text

Window keys: drag left = orbit, drag right = pan, wheel = zoom, W/A/S/D/Q/E = fly,
1..5 = mode (points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel),
L = shading, C = next colour-by mode the set has, G = hide or show ground (class 2),
P = screenshot (surfcast-NNNN.png), Esc = quit.
)";

int usageError(const std::string& message) {
    std::fprintf(stderr, "surfcast-view: %s\n(see surfcast-view --help)\n", message.c_str());
    return 2;
}

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
    std::vector<std::string> positional;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        std::string v;
        // --name=value as well as --name value (values may start with '-').
        std::optional<std::string> inlineValue;
        if (size_t eq = a.find('='); a.rfind("--", 0) == 0 && eq != std::string::npos) {
            inlineValue = a.substr(eq + 1);
            a.resize(eq);
        }
        auto value = [&]() {
            if (inlineValue) {
                v = *inlineValue;
                return true;
            }
            if (i + 1 >= argc) return false;
            v = argv[++i];
            return true;
        };
        auto positive = [&](float* out, const char* what) {
            if (!value() || !parseFloat(v, out) || !(*out > 0)) {
                *exitCode = usageError(std::string(what) + " wants a positive number");
                return false;
            }
            return true;
        };
        auto count = [&](int* out, const char* what, long most = 1000000) {
            char* end = nullptr;
            long n = value() ? std::strtol(v.c_str(), &end, 10) : -1;
            if (!end || *end != '\0' || n < 1 || n > most) {
                *exitCode = usageError(std::string(what) + " wants a whole number >= 1");
                return false;
            }
            *out = int(n);
            return true;
        };
        if (a == "-h" || a == "--help") {
            std::fputs(kUsage, stdout);
            *exitCode = 0;
            return false;
        } else if (a == "--list-devices") {
            std::fputs(gpu::listDevices().c_str(), stdout);
            *exitCode = 0;
            return false;
        } else if (a == "--headless") {
            o->headless = true;
        } else if (a == "--camera") {
            if (!value()) return (*exitCode = usageError("--camera wants ex,ey,ez,tx,ty,tz,ux,uy,uz,fov")), false;
            auto c = parseCamera(v);
            if (!c) return (*exitCode = usageError(c.status().message())), false;
            o->cameras = {*c};
        } else if (a == "--camera-path") {
            if (!value()) return (*exitCode = usageError("--camera-path wants a JSON file")), false;
            std::ifstream in(v);
            if (!in) return (*exitCode = usageError("--camera-path: cannot read " + v)), false;
            std::stringstream text;
            text << in.rdbuf();
            auto path = parseCameraPath(text.str(), v);
            if (!path) return (*exitCode = usageError(path.status().message())), false;
            o->cameras = *path;
        } else if (a == "--size") {
            auto size = value() ? parseImageSize(v) : Result<std::pair<int, int>>(Status::error("--size wants WxH"));
            if (!size) return (*exitCode = usageError("--size wants WxH, each 1..16384")), false;
            o->width = size->first;
            o->height = size->second;
        } else if (a == "--mode") {
            auto m = value() ? parseRenderMode(v) : std::nullopt;
            if (!m)
                return (*exitCode = usageError("--mode wants points, circles, ewa-noprefilter, ewa-surfel, ewa-pixel or cpu-reference")),
                       false;
            o->settings.mode = *m;
        } else if (a == "--out") {
            if (!value()) return (*exitCode = usageError("--out wants a path")), false;
            o->out = v;
        } else if (a == "--level") {
            if (!value()) return (*exitCode = usageError("--level wants a level number or 'leaves'")), false;
            char* end = nullptr;
            long n = std::strtol(v.c_str(), &end, 10);
            if (v == "leaves") o->level.level = -1;
            else if (*end == '\0' && end != v.c_str() && n >= 0 && n <= 30) o->level.level = int(n);
            else return (*exitCode = usageError("--level wants a level number or 'leaves'")), false;
        } else if (a == "--kernel-scale") {
            if (!positive(&o->settings.kernelScale, "--kernel-scale")) return false;
            o->kernelScaleGiven = true;
        } else if (a == "--cutoff") {
            if (!positive(&o->settings.cutoff, "--cutoff")) return false;
        } else if (a == "--zt") {
            if (!value() || !parseFloat(v, &o->settings.zt) || o->settings.zt < 0)
                return (*exitCode = usageError("--zt wants a number >= 0")), false;
        } else if (a == "--lowpass") {
            if (!value() || !parseFloat(v, &o->settings.lowpassVariance) || o->settings.lowpassVariance < 0)
                return (*exitCode = usageError("--lowpass wants a number >= 0")), false;
        } else if (a == "--edge-aa") {
            if (!value() || (v != "on" && v != "off")) return (*exitCode = usageError("--edge-aa wants on or off")), false;
            o->settings.edgeAA = v == "on";
            o->edgeAAGiven = true;
        } else if (a == "--edge-tau") {
            if (!value() || !parseFloat(v, &o->settings.edgeTau) || !(o->settings.edgeTau > 0))
                return (*exitCode = usageError("--edge-tau wants a number > 0")), false;
        } else if (a == "--opacity") {
            if (!value() || !parseFloat(v, &o->settings.opacity) || !(o->settings.opacity >= 0 && o->settings.opacity <= 1))
                return (*exitCode = usageError("--opacity wants a number in [0, 1]")), false;
        } else if (a == "--clip") {
            if (!value()) return (*exitCode = usageError("--clip wants xmin,ymin,zmin,xmax,ymax,zmax")), false;
            auto box = parseBox(v);
            if (!box) return (*exitCode = usageError("--clip: " + box.status().message())), false;
            o->settings.clip = o->client.lod.clip = *box;
        } else if (a == "--layers") {
            float l = 0;
            if (!value() || !parseFloat(v, &l) || l != std::floor(l) || l < 1 || l > kMaxLayers)
                return (*exitCode = usageError("--layers wants a whole number in [1, " + std::to_string(kMaxLayers) + "]")), false;
            o->settings.layers = int(l);
        } else if (a == "--shading") {
            auto s = value() ? parseShading(v) : std::nullopt;
            if (!s) return (*exitCode = usageError("--shading wants unlit, lambert or phong")), false;
            o->settings.shading = *s;
            o->shadingGiven = true;
        } else if (a == "--backface-cull") {
            if (!value() || (v != "on" && v != "off")) return (*exitCode = usageError("--backface-cull wants on or off")), false;
            o->settings.backfaceCull = v == "on";
            o->backfaceCullGiven = true;
        } else if (a == "--background" || a == "--color") {
            Vec3f c;
            char tail = 0;
            if (!value() || std::sscanf(v.c_str(), "%f,%f,%f%c", &c.x, &c.y, &c.z, &tail) != 3 ||
                !(c.x >= 0 && c.x <= 1 && c.y >= 0 && c.y <= 1 && c.z >= 0 && c.z <= 1))
                return (*exitCode = usageError(a + " wants R,G,B in [0,1]")), false;
            if (a == "--color") o->color = c;
            else o->settings.background = c;
        } else if (a == "--color-by") {
            auto by = value() ? parseColorBy(v) : std::nullopt;
            if (!by)
                return (*exitCode = usageError("--color-by wants rgb, intensity, elevation, classification or return")), false;
            o->client.coloring.by = *by;
        } else if (a == "--classes" || a == "--hide-classes") {
            std::array<bool, 256> listed{};
            bool ok = value() && !v.empty();
            std::stringstream list(v);
            for (std::string item; ok && std::getline(list, item, ',');) {
                char* end = nullptr;
                long c = std::strtol(item.c_str(), &end, 10);
                ok = !item.empty() && *end == 0 && c >= 0 && c <= 255;
                if (ok) listed[size_t(c)] = true;
            }
            if (!ok) return (*exitCode = usageError(a + " wants class numbers in 0-255, comma-separated")), false;
            for (size_t c = 0; c < 256; ++c) o->client.coloring.hidden[c] = a == "--classes" ? !listed[c] : listed[c];
        } else if (a == "--expansion") {
            if (!value() || (v != "quad" && v != "geometry"))
                return (*exitCode = usageError("--expansion wants quad or geometry")), false;
            o->renderer.expansion = v == "quad" ? Expansion::Quad : Expansion::Geometry;
        } else if (a == "--accumulation") {
            if (!value() || (v != "rgba32f" && v != "rgba16f"))
                return (*exitCode = usageError("--accumulation wants rgba32f or rgba16f")), false;
            o->renderer.halfFloatAccumulation = v == "rgba16f";
        } else if (a == "--device") {
            if (!value()) return (*exitCode = usageError("--device wants an index or a name")), false;
            o->device = v;
        } else if (a == "--validation") {
            o->validation = true;
        } else if (a == "--lod") {
            float px = 0;
            if (!positive(&px, "--lod")) return false;
            o->lod = px;
        } else if (a == "--max-wait") {
            float s = 0;
            if (!positive(&s, "--max-wait")) return false;
            o->maxWait = s;
        } else if (a == "--no-culling") {
            o->client.lod.frustumCulling = o->client.lod.backfaceCulling = false;
        } else if (a == "--splat-budget") {
            int n = 0;
            if (!count(&n, "--splat-budget", 2000000000)) return false;
            o->client.lod.splatBudget = size_t(n);
        } else if (a == "--gpu-budget") {
            float mib = 0;
            if (!positive(&mib, "--gpu-budget")) return false;
            o->client.gpuBudget = size_t(double(mib) * (1 << 20));
        } else if (a == "--block-cache") {
            float mib = 0;
            if (!positive(&mib, "--block-cache")) return false;
            o->client.blockCache = size_t(double(mib) * (1 << 20));
        } else if (a == "--follow") {
            float s = 0;
            if (!positive(&s, "--follow")) return false;
            o->client.followSeconds = s;
        } else if (a == "--save-redraws") {
            o->saveRedraws = true;
        } else if (std::string error; parseHttpOption(a, [&](std::string* out) { return value() && (*out = v, true); }, o->client.http, &error)) {
            if (!error.empty()) return (*exitCode = usageError(error)), false;
        } else if (a == "--connections") {
            if (!count(&o->client.connections, "--connections")) return false;
        } else if (a == "--repeat") {
            if (!count(&o->repeat, "--repeat")) return false;
        } else if (a == "--frames") {
            if (!count(&o->frames, "--frames")) return false;
        } else if (a == "--screenshot") {
            if (!value()) return (*exitCode = usageError("--screenshot wants a path")), false;
            o->screenshot = v;
        } else if (!a.empty() && a[0] == '-') {
            return (*exitCode = usageError("unknown option " + a)), false;
        } else {
            positional.push_back(a);
        }
    }
    if (positional.size() != 1)
        return (*exitCode = usageError(positional.empty() ? "no tile set given" : "more than one tile set given")), false;
    if (o->client.followSeconds > 0 && !o->lod)
        return (*exitCode = usageError("--follow streams the set: it needs --lod")), false;
    o->set = positional[0];
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
