// surfcast-geom-error: geometric error of a tile set's level against an
// analytic surface, for bench/accuracy_bench.py's quantization sweep.
// Usage: surfcast-geom-error SET LEVEL plane NX NY NZ D | sphere CX CY CZ R
// (plane: n.p = d). Prints one JSON line: surfels, RMS and max distance, and
// the RMS angle between stored and true normals (degrees).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "tileset_reader.h"

int main(int argc, char** argv) {
    using namespace surfcast;
    if (argc != 8 && argc != 9) {
        std::fprintf(stderr, "usage: surfcast-geom-error SET LEVEL plane NX NY NZ D | sphere CX CY CZ R\n");
        return 2;
    }
    auto reader = TilesetReader::open(argv[1]);
    if (!reader) {
        std::fprintf(stderr, "surfcast-geom-error: %s\n", reader.status().message().c_str());
        return 1;
    }
    const int level = std::atoi(argv[2]);
    const std::string kind = argv[3];
    const Vec3d a{std::atof(argv[4]), std::atof(argv[5]), std::atof(argv[6])};
    const double b = std::atof(argv[7]);
    double sum2 = 0, worst = 0, angle2 = 0;
    size_t n = 0;
    for (const NodeRecord& node : reader->nodes()) {
        bool leaf = node.childMask == 0;
        if (!(node.key.level == level || (leaf && node.key.level < level))) continue;
        auto block = reader->readBlock(node);
        if (!block) {
            std::fprintf(stderr, "surfcast-geom-error: %s\n", block.status().message().c_str());
            return 1;
        }
        for (size_t i = 0; i < block->size(); ++i) {
            Vec3d p = reader->position(node, *block, i);
            Vec3d truth = kind == "plane" ? a : normalizeOrZero(p - a);
            double d = kind == "plane" ? dot(a, p) - b : length(p - a) - b;
            Vec3d nrm{block->normals[3 * i], block->normals[3 * i + 1], block->normals[3 * i + 2]};
            double c = std::fabs(dot(normalizeOrZero(nrm), truth));
            double ang = std::acos(std::fmin(1.0, c)) * 180 / M_PI;
            sum2 += d * d;
            angle2 += ang * ang;
            worst = std::fmax(worst, std::fabs(d));
            ++n;
        }
    }
    std::printf("{\"surfels\": %zu, \"rms\": %.9g, \"max\": %.9g, \"normal_rms_degrees\": %.6g}\n", n,
                n ? std::sqrt(sum2 / n) : 0.0, worst, n ? std::sqrt(angle2 / n) : 0.0);
    return 0;
}
