// How an object of a given size goes up to an S3 store fastest: one PUT
// against multipart uploads of several part sizes, side by side, each way
// `reps` times, alternated. For ObjectStore::kMultipartThreshold and
// kPartBytes (bench/BENCHMARKS.md, "Object storage"). The store and the
// credentials come from the AWS environment (net/object_store.h).
//
// Usage: surfcast-store-put-bench s3://BUCKET/PREFIX MIB [REPS]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "object_store.h"

int main(int argc, char** argv) {
    using namespace surfcast;
    if (argc < 3) {
        std::fprintf(stderr, "usage: surfcast-store-put-bench s3://BUCKET/PREFIX MIB [REPS]\n");
        return 2;
    }
    auto prefix = parseS3Url(argv[1]);
    if (!prefix) {
        std::fprintf(stderr, "%s\n", prefix.status().message().c_str());
        return 2;
    }
    const uint64_t bytes = std::strtoull(argv[2], nullptr, 10) << 20;
    const int reps = argc > 3 ? std::atoi(argv[3]) : 3;
    auto store = ObjectStore::shared();
    if (!store) {
        std::fprintf(stderr, "%s\n", store.status().message().c_str());
        return 1;
    }
    const std::string path = (std::filesystem::temp_directory_path() / "surfcast-put-bench.bin").string();
    {
        std::FILE* f = std::fopen(path.c_str(), "wb");
        std::mt19937_64 rng(1);
        std::vector<uint64_t> chunk(1 << 17);
        for (uint64_t done = 0; done < bytes; done += chunk.size() * 8) {
            for (auto& v : chunk) v = rng();
            std::fwrite(chunk.data(), 1, std::min<uint64_t>(chunk.size() * 8, bytes - done), f);
        }
        std::fclose(f);
    }
    // 0: one PUT; else multipart with parts of that many MiB.
    const std::vector<uint64_t> ways = {0, 8, 16, 32, 64};
    std::map<uint64_t, std::vector<double>> seconds;
    for (int r = 0; r < reps; ++r)
        for (uint64_t mib : ways) {
            const ObjectStore::Multipart shape{mib == 0 ? ~uint64_t(0) : 0, mib << 20};
            const S3Url object{prefix->bucket, prefix->key + "/put-" + std::to_string(mib) + "-" + std::to_string(r)};
            const auto t0 = std::chrono::steady_clock::now();
            auto put = (*store)->putFile(object, path, {}, shape);
            const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            if (!put) {
                std::fprintf(stderr, "%s\n", put.status().message().c_str());
                return 1;
            }
            seconds[mib].push_back(s);
            (void)(*store)->remove(object);
        }
    std::remove(path.c_str());
    std::printf("| %llu MiB as | best s | MB/s | runs (s) |\n|---|---|---|---|\n", (unsigned long long)(bytes >> 20));
    for (uint64_t mib : ways) {
        double best = 1e30;
        std::string runs;
        for (double s : seconds[mib]) {
            best = std::min(best, s);
            char b[32];
            std::snprintf(b, sizeof b, "%s%.2f", runs.empty() ? "" : ", ", s);
            runs += b;
        }
        std::printf("| %s | %.2f | %.0f | %s |\n", mib == 0 ? "one PUT" : (std::to_string(mib) + " MiB parts").c_str(), best,
                    double(bytes) / best / 1e6, runs.c_str());
    }
    return 0;
}
