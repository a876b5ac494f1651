// surfcast-read-bench: decodes inputs through the project's readers and
// reports points/s, for comparing decoders (bench/laz_bench.py). No octree.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "inputs.h"

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: surfcast-read-bench THREADS FILE...\n");
        return 2;
    }
    surfcast::InputOptions options;
    options.threads = std::atoi(argv[1]);
    for (int i = 2; i < argc; ++i) options.paths.push_back(argv[i]);
    auto start = std::chrono::steady_clock::now();
    std::vector<surfcast::InputPoint> batch(1 << 16);
    uint64_t points = 0;
    double checksum = 0;
    surfcast::Status st = surfcast::forEachInput(options, [&](size_t, surfcast::PointReader& r) -> surfcast::Status {
        while (true) {
            auto n = r.read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) return {};
            points += *n;
            checksum += batch[0].position.x;  // keeps the loop honest
        }
    });
    if (!st.ok()) {
        std::fprintf(stderr, "%s\n", st.message().c_str());
        return 1;
    }
    double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("{\"points\": %llu, \"seconds\": %.4f, \"points_per_second\": %.0f, \"checksum\": %.3f}\n",
                static_cast<unsigned long long>(points), s, double(points) / s, checksum);
    return 0;
}
