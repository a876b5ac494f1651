// surfcast-build: scans → tile set. main() only parses arguments and wires the
// builder (octree_builder.h) and the verifier (tileset_reader.h) together.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "octree_builder.h"
#include "reweight.h"
#include "tileset_reader.h"

namespace {

const char* kUsage = R"(usage: surfcast-build [options] INPUT... -o OUT
       surfcast-build --default-scene -o OUT
       surfcast-build --info SET

Builds a level-of-detail tile set (tileset.json, hierarchy.bin, blocks.bin)
from point clouds and meshes. Inputs: PLY (points, or meshes with faces or
triangle strips), LAS 1.0-1.4, text columns (.xyz .txt .pts .csv), and meshes
in OBJ/OFF/STL through OpenMesh. Several inputs merge into one tile set.

  -o, --output DIR        tile set folder to write (replaced atomically)
  --default-scene         add the built-in scanned scene (about 1.5 M points)
  --scene-points N        points of the built-in scene (default 1500000)
  --seed N                seed of the built-in scene and mesh sampling (default 1)
  --info SET              print a tile set's summary and verify every checksum
  --grid G                cells per axis of a node's sampling grid (default 128)
  --capacity N            surfels above which a node splits (default 20000)
  --memory SIZE           peak memory budget, e.g. 512M, 2G (default 2G)
  --threads N             worker threads (default: all cores)
  --normal-k K            neighbours for normal estimation (default 16)
  --spacing-k K           k of the k-th-neighbour spacing h (default 8)
  --position-fraction F   resampled levels: quantization step = cell / F (default 8)
  --normal-bits N         Draco quantization bits per normal component (default 10)
  --no-radius             no per-surfel radius, even where a node's sampling is irregular
  --kernel-scale K        reconstruction kernel V^r = (K h)^2 I the weights assume
                          (default 0.5, measured: see bench/BENCHMARKS.md)
  --weights MODE          analytic (default), capture (rendered on Vulkan, Ren 2002
                          §7.2; see surfcast-weights) or none
  --columns LAYOUT        text layout, e.g. x,y,z,r,g,b or x,y,z,_,nx,ny,nz
  --mesh-spacing S        mesh sampling spacing (default: half the median edge)
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

int usageError(const std::string& message) {
    std::fprintf(stderr, "surfcast-build: %s\n(see surfcast-build --help)\n", message.c_str());
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    surfcast::BuildOptions opt;
    bool captureWeights = false;
    std::string info;
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
            if (!value(&info)) return usageError("--info needs a tile set folder");
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
        } else if (a == "--capacity") {
            if (!number(&d, 16, 1e8)) return usageError("--capacity needs a value in [16, 1e8]");
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
        } else if (a == "--columns") {
            if (!value(&opt.inputs.columns)) return usageError("--columns needs a layout");
        } else if (a == "--mesh-spacing") {
            if (!number(&d, 1e-12, 1e12)) return usageError("--mesh-spacing needs a positive length");
            opt.inputs.mesh.spacing = d;
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
        auto summary = surfcast::verifyTileset(info);
        if (!summary) {
            std::fprintf(stderr, "surfcast-build: %s\n", summary.status().message().c_str());
            return 1;
        }
        std::printf("%s\n", summary->c_str());
        return 0;
    }
    if (opt.output.empty()) return usageError("no output folder (-o OUT)");
    if (opt.inputs.paths.empty() && !opt.inputs.defaultScene) return usageError("no inputs (give files or --default-scene)");

    auto summary = surfcast::buildTileset(opt);
    if (!summary) {
        std::fprintf(stderr, "surfcast-build: %s\n", summary.status().message().c_str());
        return 1;
    }
    std::printf("wrote %s\n%s", opt.output.c_str(), summary->text().c_str());
    if (captureWeights) {
        surfcast::ReweightOptions reweight;
        reweight.capture.progress = opt.progress;
        const char* env = std::getenv("SURFCAST_VALIDATION");
        reweight.validation = env && std::string(env) == "1";
        auto captured = surfcast::reweightTileset(opt.output, reweight);
        if (!captured) {
            std::fprintf(stderr, "surfcast-build: weight capture: %s (the set keeps its analytic weights)\n",
                         captured.status().message().c_str());
            return 1;
        }
        std::printf("weights captured: %s", captured->text().c_str());
    }
    return 0;
}
