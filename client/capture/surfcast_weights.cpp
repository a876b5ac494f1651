// surfcast-weights: recompute an existing tile set's normalization weights in
// place (atomically). main() only parses arguments.
#include <cstdio>
#include <cstdlib>
#include <string>

#include "reweight.h"

namespace {

const char* kUsage = R"(usage: surfcast-weights SET [--method capture|none] [options]

Recomputes the per-surfel normalization weights of a tile set in place; the
set is replaced atomically. `capture` renders every level from viewpoints on a
bounding sphere (Ren et al. 2002, §7.2) on Vulkan (a GPU, or lavapipe); `none`
drops the weights. Analytic weights come from surfcast-build (--weights analytic).

  --method M        capture (default) or none
  --views N         capture viewpoints (default 32)
  --size N          capture image edge in pixels (default 1024)
  --zt Z            visibility offset z_t, as surfcast-view --zt (default 0.5)
  --no-edge-weights capture no per-vertex weights at the model's edges (smaller blocks;
                    per-surfel renders fade at boundaries)
  --device D        Vulkan device index or name substring
  --validation      enable the Khronos validation layer (errors fail the run)
  -q, --quiet       no progress output
  -h, --help        this text
)";

int usageError(const std::string& message) {
    std::fprintf(stderr, "surfcast-weights: %s\n(see surfcast-weights --help)\n", message.c_str());
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    surfcast::ReweightOptions opt;
    const char* env = std::getenv("SURFCAST_VALIDATION");
    opt.validation = env && std::string(env) == "1";
    std::string set;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto value = [&](std::string* out) {
            if (i + 1 >= argc) return false;
            *out = argv[++i];
            return true;
        };
        auto count = [&](int* out, int lo, int hi) {
            std::string v;
            char* end = nullptr;
            long n = value(&v) ? std::strtol(v.c_str(), &end, 10) : -1;
            if (!end || *end != '\0' || n < lo || n > hi) return false;
            *out = int(n);
            return true;
        };
        std::string v;
        if (a == "-h" || a == "--help") {
            std::fputs(kUsage, stdout);
            return 0;
        } else if (a == "--method") {
            if (!value(&v) || (v != "capture" && v != "none")) return usageError("--method is capture or none");
            opt.method = v == "capture" ? surfcast::WeightMethod::Capture : surfcast::WeightMethod::None;
        } else if (a == "--views") {
            if (!count(&opt.capture.views, 1, 10000)) return usageError("--views wants 1..10000");
        } else if (a == "--size") {
            if (!count(&opt.capture.size, 16, 16384)) return usageError("--size wants 16..16384");
        } else if (a == "--zt") {
            char* end = nullptr;
            double z = value(&v) ? std::strtod(v.c_str(), &end) : -1;
            if (!end || *end != '\0' || !(z >= 0)) return usageError("--zt wants a number >= 0");
            opt.capture.zt = float(z);
        } else if (a == "--no-edge-weights") {
            opt.capture.edgeWeights = false;
        } else if (a == "--device") {
            if (!value(&opt.device)) return usageError("--device wants an index or a name");
        } else if (a == "--validation") {
            opt.validation = true;
        } else if (a == "-q" || a == "--quiet") {
            opt.capture.progress = false;
        } else if (!a.empty() && a[0] == '-') {
            return usageError("unknown option " + a);
        } else if (set.empty()) {
            set = a;
        } else {
            return usageError("more than one tile set given");
        }
    }
    if (set.empty()) return usageError("no tile set given");
    auto summary = surfcast::reweightTileset(set, opt);
    if (!summary) {
        std::fprintf(stderr, "surfcast-weights: %s\n", summary.status().message().c_str());
        return 1;
    }
    std::printf("%s: weights %s\n%s", set.c_str(), opt.method == surfcast::WeightMethod::Capture ? "captured" : "removed",
                summary->text().c_str());
    return 0;
}
