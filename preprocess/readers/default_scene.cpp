#include "default_scene.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>

#include "random.h"

namespace surfcast {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kGroundHalfSize = 12.0;         // metres: the ground is a 24 m square
constexpr double kRangeNoise = 0.003;            // metres, one standard deviation
constexpr double kPositionPrecision = 1e-4;      // metres: the scanner reports 0.1 mm
constexpr double kMinElevation = -70.0 * kPi / 180.0;
constexpr double kMaxElevation = 35.0 * kPi / 180.0;
// Share of rays that hit something, measured for this scene; sizes the ray grid.
constexpr double kHitFraction = 0.62;
constexpr int kScanners = 2;
const Vec3d kScannerPositions[kScanners] = {{7.0, -6.0, 1.7}, {-6.5, 6.0, 1.6}};

struct Hit {
    double t;
    Vec3d color;  // linear [0,1]
};

Vec3d checker(double u, double v, double size, Vec3d a, Vec3d b) {
    long k = long(std::floor(u / size)) + long(std::floor(v / size));
    return (k & 1) ? a : b;
}

void keepNearest(std::optional<Hit>& best, double t, const Vec3d& color) {
    if (t > 1e-6 && (!best || t < best->t)) best = Hit{t, color};
}

// Ray o + t·d (|d| = 1) against the scene.
std::optional<Hit> castRay(const Vec3d& o, const Vec3d& d) {
    std::optional<Hit> best;
    // Ground z = 0, 1 m checkerboard in warm greys.
    if (d.z < 0) {
        double t = -o.z / d.z;
        Vec3d p = o + d * t;
        if (std::fabs(p.x) < kGroundHalfSize && std::fabs(p.y) < kGroundHalfSize)
            keepNearest(best, t, checker(p.x, p.y, 1.0, {0.85, 0.82, 0.75}, {0.25, 0.24, 0.22}));
    }
    // Sphere at (2, 1, 1), radius 1, red/white latitude stripes.
    {
        Vec3d c{2, 1, 1}, oc = o - c;
        double b = dot(oc, d), disc = b * b - (dot(oc, oc) - 1.0);
        if (disc >= 0) {
            double t = -b - std::sqrt(disc);
            Vec3d p = o + d * t - c;
            bool stripe = long(std::floor(std::acos(std::clamp(p.z, -1.0, 1.0)) / (kPi / 16))) & 1;
            keepNearest(best, t, stripe ? Vec3d{0.8, 0.1, 0.1} : Vec3d{0.95, 0.95, 0.95});
        }
    }
    // Box [-3,-1]x[-1,1]x[0,1.5], 0.25 m blue/yellow checkerboard on every face.
    {
        Vec3d lo{-3, -1, 0}, hi{-1, 1, 1.5};
        double t0 = -HUGE_VAL, t1 = HUGE_VAL;
        int axis = -1;
        for (int a = 0; a < 3; ++a) {
            double inv = 1.0 / d[a];
            double ta = (lo[a] - o[a]) * inv, tb = (hi[a] - o[a]) * inv;
            if (ta > tb) std::swap(ta, tb);
            if (ta > t0) { t0 = ta; axis = a; }
            t1 = std::min(t1, tb);
        }
        if (t0 <= t1 && axis >= 0) {
            Vec3d p = o + d * t0;
            int u = (axis + 1) % 3, v = (axis + 2) % 3;
            keepNearest(best, t0, checker(p[u], p[v], 0.25, {0.1, 0.2, 0.8}, {0.95, 0.85, 0.1}));
        }
    }
    // Cylinder axis (0,-3), radius 0.6, height 2: 24 green/white vertical stripes, open top.
    {
        double ox = o.x, oy = o.y + 3, a = d.x * d.x + d.y * d.y;
        double b = ox * d.x + oy * d.y, c = ox * ox + oy * oy - 0.36, disc = b * b - a * c;
        if (a > 0 && disc >= 0) {
            double t = (-b - std::sqrt(disc)) / a;
            Vec3d p = o + d * t;
            if (p.z >= 0 && p.z <= 2) {
                double angle = std::atan2(p.y + 3, p.x);
                bool stripe = long(std::floor((angle + kPi) / (2 * kPi / 24))) & 1;
                keepNearest(best, t, stripe ? Vec3d{0.1, 0.6, 0.2} : Vec3d{0.9, 0.9, 0.9});
            }
        }
    }
    return best;
}

class ScanReader final : public PointReader {
public:
    ScanReader(int scanner, const SceneOptions& options) : rng_(options.seed * 1000003u + uint64_t(scanner)) {
        origin_ = kScannerPositions[scanner];
        double rays = double(options.targetPoints) / kScanners / kHitFraction;
        // Square angular steps: elevations × azimuths = rays.
        double span = kMaxElevation - kMinElevation;
        step_ = std::sqrt(span * 2 * kPi / rays);
        rows_ = uint64_t(std::ceil(span / step_));
        cols_ = uint64_t(std::ceil(2 * kPi / step_));
        desc_.path = "<default scene, scan " + std::to_string(scanner + 1) + ">";
        desc_.format = "scene";
        desc_.hasColors = true;
        desc_.colorBits = 8;
        desc_.scanOrigins = {origin_};
        desc_.precision = kPositionPrecision;
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        while (n < max && ray_ < rows_ * cols_) {
            uint64_t row = ray_ / cols_, col = ray_ % cols_;
            ++ray_;
            // Jitter within the angular cell, as a real scanner's encoder does.
            double el = kMinElevation + (double(row) + rng_.uniform()) * step_;
            double az = (double(col) + rng_.uniform()) * step_;
            Vec3d d{std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)};
            double noise = rng_.normal() * kRangeNoise;
            auto hit = castRay(origin_, d);
            if (!hit) continue;
            InputPoint& p = out[n++];
            p = InputPoint{};
            p.position = origin_ + d * (hit->t + noise);
            for (int c = 0; c < 3; ++c) p.color[c] = uint16_t(std::lround(hit->color[c] * 255.0) * 257);
        }
        return n;
    }

private:
    SplitMix64 rng_;
    Vec3d origin_;
    double step_;
    uint64_t rows_, cols_, ray_ = 0;
    InputDescription desc_;
};

}  // namespace

std::vector<std::unique_ptr<PointReader>> openDefaultScene(const SceneOptions& options) {
    std::vector<std::unique_ptr<PointReader>> readers;
    for (int s = 0; s < kScanners; ++s) readers.push_back(std::make_unique<ScanReader>(s, options));
    return readers;
}

}  // namespace surfcast
