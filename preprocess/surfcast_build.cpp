// surfcast-build: scans → tile set. main() only parses arguments and wires the
// builder (octree_builder.h) and the verifier (tileset_reader.h) together.
// Weight capture renders, so it runs as its own program (surfcast-weights, next
// to this one): the build itself needs no Vulkan.
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "block_codec.h"
#include "octree_builder.h"
#include "http_tile_source.h"
#include "tileset_reader.h"

extern char** environ;

namespace {

const char* kUsage = R"(usage: surfcast-build [options] INPUT... -o OUT      (INPUT: a file, a folder, or @LIST)
       surfcast-build --default-scene -o OUT
       surfcast-build --info SET            (SET: a folder or an http(s) URL)

Builds a level-of-detail tile set (tileset.json, hierarchy.bin, blocks.bin)
from point clouds and meshes. Inputs: PLY (points, or meshes with faces or
triangle strips), LAS 1.0-1.4, text columns (.xyz .txt .pts .csv), and meshes
in OBJ/OFF/STL through OpenMesh. Several inputs merge into one tile set. A
folder stands for every readable file under it; @LIST for the paths listed in
the text file LIST, one per line.

  -o, --output DIR        tile set folder to write (replaced atomically)
  --default-scene         add the built-in scanned scene (about 1.5 M points)
  --scene-points N        points of the built-in scene (default 1500000)
  --seed N                seed of the built-in scene and mesh sampling (default 1)
  --info SET              print a tile set's summary and verify every checksum; with
                          a URL, --header 'NAME: VALUE' (repeatable), --token-file F,
                          --redirect-credentials, --ca-file F and --insecure say how
                          to reach it, as in surfcast-view
  --grid G                cells per axis of a node's finest sampling grid (default 128)
  --page-depth D          levels per hierarchy page, which a viewer fetches as it
                          reaches them (default 5)
  --capacity N            surfels above which a node splits (default 20000, at most 4194304)
  --memory SIZE           peak memory budget, e.g. 512M, 2G (default 2G)
  --threads N             worker threads (default: all cores)
  --normal-k K            neighbours for normal estimation (default 16)
  --spacing-k K           k of the k-th-neighbour spacing h (default 8)
  --position-fraction F   resampled levels: quantization step = cell / F (default 8)
  --normal-bits N         Draco quantization bits per normal component (default 8)
  --no-radius             no per-surfel radius, even where a node's sampling is irregular
  --kernel-scale K        reconstruction kernel V^r = (K h)^2 I the weights assume
                          (default 0.5, measured: see bench/BENCHMARKS.md)
  --weights MODE          none (default: ewa-pixel, the default renderer mode, reads
                          no weights), analytic (for ewa-surfel), or capture
                          (rendered on Vulkan, Ren 2002 §7.2; see surfcast-weights)
  --attributes LIST       attributes to store: a comma-separated list of names; all;
                          or none. Default: intensity, classification, return_number
                          and number_of_returns, each where some input carries it and
                          it varies across the set (LAS/LAZ: all four; PLY/PCD/text:
                          intensity, classification where a field holds them). On
                          request: LAS/LAZ scan_angle, user_data, point_source_id,
                          gps_time, nir and Extra Bytes dimensions by name; PLY and
                          PCD properties by name
  --opacity A             multiply every point's opacity by A in [0, 1] (all inputs);
                          the set stores opacity only where some point is translucent
                          (PLY alpha/opacity properties; see --read-alpha)
  --read-alpha            PCD: take the packed colour's top byte (rgba's alpha) as
                          opacity; off by default, as many PCD files leave junk there
  --columns LAYOUT        text layout, e.g. x,y,z,r,g,b or x,y,z,_,nx,ny,nz
  --mesh-spacing S        mesh sampling spacing (default: one surfel per texel on a
                          textured mesh, else half the median edge; coarsened where
                          that would exceed --mesh-max-surfels)
  --mesh-max-surfels N    most surfels a mesh gives at its default spacing (5000000)
  --texture-filter F      colours of textured meshes' surfels, on every level: optimal
                          (least-squares coefficients for the renderer's kernels;
                          default), ewa (the texture filtered with each surfel's
                          kernel: faster to build, blurrier) or nearest (the texture
                          at each leaf's centre, averaged above)
  --allow-missing-textures
                          a diffuse texture (OBJ map_Kd) that is missing or unreadable
                          is a warning, its faces take vertex colours (default: error)
  --allow-outside-paths   let a mesh's external files (glTF buffers and images, OBJ
                          material libraries and maps, PLY TextureFile) lie outside
                          its folder (default: an error naming the file, so that a
                          model from elsewhere cannot read any file you can)
  --vertices-only         read a mesh file's vertices as points, no sampling
  -q, --quiet             no progress output
  -h, --help              this text
)";

bool parseSize(const std::string& s, uint64_t* out) {
    char* end = nullptr;
    double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || !(v > 0)) return false;
    std::string unit(end);
    double mult = unit.empty() || unit == "B" ? 1
                  : unit == "K" || unit == "KiB" ? 1024.0
                  : unit == "M" || unit == "MiB" ? 1024.0 * 1024
                  : unit == "G" || unit == "GiB" ? 1024.0 * 1024 * 1024
                                                 : 0;
    if (mult == 0) return false;
    *out = uint64_t(v * mult);
    return true;
}

bool parseNumber(const std::string& s, double* out) {
    char* end = nullptr;
    *out = std::strtod(s.c_str(), &end);
    return end != s.c_str() && *end == '\0';
}

// Runs surfcast-weights from this program's folder on `set`; its exit status,
// or -1 when it cannot be started.
int runWeightCapture(const std::string& set, bool quiet) {
    std::error_code ec;
    std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
    std::string program = ec ? std::string("surfcast-weights") : (self.parent_path() / "surfcast-weights").string();
    std::vector<std::string> args = {program};
    if (quiet) args.push_back("-q");
    const char* env = std::getenv("SURFCAST_VALIDATION");
    if (env && std::string(env) == "1") args.push_back("--validation");
    args.push_back(set);
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    pid_t pid = 0;
    if (posix_spawnp(&pid, program.c_str(), nullptr, nullptr, argv.data(), environ) != 0) return -1;
    int status = 0;
    while (waitpid(pid, &status, 0) < 0)
        if (errno != EINTR) return -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int usageError(const std::string& message) {
    std::fprintf(stderr, "surfcast-build: %s\n(see surfcast-build --help)\n", message.c_str());
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    surfcast::BuildOptions opt;
    bool captureWeights = false;
    std::string info;
    surfcast::HttpOptions http;  // how --info reaches a URL
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto value = [&](std::string* out) {
            if (i + 1 >= argc) return false;
            *out = argv[++i];
            return true;
        };
        auto number = [&](double* out, double lo, double hi) {
            std::string v;
            return value(&v) && parseNumber(v, out) && *out >= lo && *out <= hi;
        };
        std::string v;
        double d = 0;
        if (a == "-h" || a == "--help") {
            std::fputs(kUsage, stdout);
            return 0;
        } else if (a == "-o" || a == "--output") {
            if (!value(&opt.output)) return usageError(a + " needs a folder");
        } else if (a == "--info") {
            if (!value(&info)) return usageError("--info needs a tile set folder or URL");
        } else if (a == "--header") {
            if (!value(&v) || v.find(':') == std::string::npos || v.find(':') == 0)
                return usageError("--header wants 'Name: value'");
            http.headers.push_back(v);
        } else if (a == "--token-file") {
            if (!value(&http.tokenFile)) return usageError("--token-file wants a file");
        } else if (a == "--ca-file") {
            if (!value(&http.caFile)) return usageError("--ca-file wants a PEM file");
        } else if (a == "--insecure") {
            http.insecure = true;
        } else if (a == "--redirect-credentials") {
            http.redirectCredentials = true;
        } else if (a == "--default-scene") {
            opt.inputs.defaultScene = true;
        } else if (a == "--scene-points") {
            if (!number(&d, 1, 1e10)) return usageError("--scene-points needs a positive count");
            opt.inputs.scene.targetPoints = uint64_t(d);
        } else if (a == "--seed") {
            if (!number(&d, 0, 1e18)) return usageError("--seed needs a non-negative integer");
            opt.inputs.scene.seed = opt.inputs.mesh.seed = uint64_t(d);
        } else if (a == "--grid") {
            if (!number(&d, 4, 1024)) return usageError("--grid needs a value in [4, 1024]");
            opt.grid = int(d);
        } else if (a == "--page-depth") {
            if (!number(&d, 2, surfcast::kMaxLevel + 1)) return usageError("--page-depth needs a value in [2, 21]");
            opt.pageDepth = uint32_t(d);
        } else if (a == "--capacity") {
            if (!number(&d, 16, surfcast::kMaxBlockPoints))
                return usageError("--capacity needs a value in [16, " + std::to_string(surfcast::kMaxBlockPoints) + "]");
            opt.capacity = uint32_t(d);
        } else if (a == "--memory") {
            if (!value(&v) || !parseSize(v, &opt.memoryBytes)) return usageError("--memory needs a size such as 512M or 2G");
        } else if (a == "--threads") {
            if (!number(&d, 1, 1024)) return usageError("--threads needs a value in [1, 1024]");
            opt.threads = int(d);
        } else if (a == "--normal-k") {
            if (!number(&d, 3, 256)) return usageError("--normal-k needs a value in [3, 256]");
            opt.normalK = int(d);
        } else if (a == "--kernel-scale") {
            if (!number(&d, 0.05, 10)) return usageError("--kernel-scale needs a value in [0.05, 10]");
            opt.kernelScale = d;
        } else if (a == "--normal-bits") {
            if (!number(&d, 4, 16)) return usageError("--normal-bits needs a value in [4, 16]");
            opt.normalBits = int(d);
        } else if (a == "--no-radius") {
            opt.radii = false;
        } else if (a == "--spacing-k") {
            if (!number(&d, 1, 64)) return usageError("--spacing-k needs a value in [1, 64]");
            opt.spacingK = int(d);
        } else if (a == "--position-fraction") {
            if (!number(&d, 1, 1 << 16)) return usageError("--position-fraction needs a value in [1, 65536]");
            opt.positionFraction = d;
        } else if (a == "--weights") {
            if (!value(&v) || (v != "analytic" && v != "none" && v != "capture"))
                return usageError("--weights is capture, analytic or none");
            // Capture starts from analytic weights: they stay for surfels no view sees.
            opt.weights = v != "none";
            captureWeights = v == "capture";
        } else if (a == "--attributes") {
            if (!value(&v)) return usageError("--attributes needs a list, all or none");
            std::vector<std::string> names;
            if (v == "all") {
                names.assign(std::begin(surfcast::kLidarAttributes), std::end(surfcast::kLidarAttributes));
                opt.inputs.scalars.all = true;
            } else if (v != "none") {
                std::stringstream list(v);
                for (std::string name; std::getline(list, name, ',');) {
                    if (name.empty()) return usageError("--attributes: an empty name in '" + v + "'");
                    names.push_back(name);
                }
            }
            opt.attributes = names;
        } else if (a == "--opacity") {
            if (!number(&d, 0, 1)) return usageError("--opacity needs a value in [0, 1]");
            opt.inputs.opacity = d;
        } else if (a == "--read-alpha") {
            opt.inputs.readAlpha = true;
        } else if (a == "--columns") {
            if (!value(&opt.inputs.columns)) return usageError("--columns needs a layout");
        } else if (a == "--mesh-spacing") {
            if (!number(&d, 1e-12, 1e12)) return usageError("--mesh-spacing needs a positive length");
            opt.inputs.mesh.spacing = d;
        } else if (a == "--mesh-max-surfels") {
            if (!number(&d, 1, 1e12) || d != std::floor(d)) return usageError("--mesh-max-surfels needs a whole number >= 1");
            opt.inputs.mesh.maxSurfels = uint64_t(d);
        } else if (a == "--texture-filter") {
            std::string f;
            if (!value(&f) || (f != "ewa" && f != "nearest" && f != "optimal"))
                return usageError("--texture-filter needs ewa, optimal or nearest");
            using Filter = surfcast::BuildOptions::TextureFilter;
            opt.textureFilter = f == "ewa" ? Filter::Ewa : f == "optimal" ? Filter::Optimal : Filter::Nearest;
        } else if (a == "--allow-missing-textures") {
            opt.inputs.mesh.allowMissingTextures = true;
        } else if (a == "--allow-outside-paths") {
            opt.inputs.mesh.allowOutsidePaths = true;
        } else if (a == "--vertices-only") {
            opt.inputs.verticesOnly = true;
        } else if (a == "-q" || a == "--quiet") {
            opt.progress = false;
        } else if (!a.empty() && a[0] == '-') {
            return usageError("unknown option " + a);
        } else {
            opt.inputs.paths.push_back(a);
        }
    }

    if (!info.empty()) {
        auto reader = surfcast::openTileset(info, http);
        auto summary = reader ? surfcast::verifyTileset(*reader) : surfcast::Result<std::string>(reader.status());
        if (!summary) {
            std::fprintf(stderr, "surfcast-build: %s\n", summary.status().message().c_str());
            return 1;
        }
        std::printf("%s\n", summary->c_str());
        return 0;
    }
    if (opt.output.empty()) return usageError("no output folder (-o OUT)");
    if (opt.inputs.paths.empty() && !opt.inputs.defaultScene) return usageError("no inputs (give files or --default-scene)");
    auto paths = surfcast::expandInputPaths(opt.inputs.paths);
    if (!paths) {
        std::fprintf(stderr, "surfcast-build: %s\n", paths.status().message().c_str());
        return 1;
    }
    opt.inputs.paths = std::move(*paths);

    auto summary = surfcast::buildTileset(opt);
    if (!summary) {
        std::fprintf(stderr, "surfcast-build: %s\n", summary.status().message().c_str());
        return 1;
    }
    std::printf("wrote %s\n%s", opt.output.c_str(), summary->text().c_str());
    if (captureWeights) {
        std::fflush(stdout);
        int status = runWeightCapture(opt.output, !opt.progress);
        if (status != 0) {
            std::fprintf(stderr, "surfcast-build: weight capture (surfcast-weights) %s; the set keeps its analytic weights\n",
                         status < 0 ? "could not be started" : ("failed with status " + std::to_string(status)).c_str());
            return 1;
        }
    }
    return 0;
}
