// Minimal 3-vector for preprocessing math. Double precision for world
// coordinates (DESIGN.md decision 4: precision is local, origins are doubles).
#pragma once

#include <cmath>

namespace surfcast {

template <typename T>
struct Vec3 {
    T x = 0, y = 0, z = 0;

    constexpr T& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
    constexpr T operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    constexpr Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
    constexpr Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
    constexpr Vec3 operator*(T s) const { return {x * s, y * s, z * s}; }
    constexpr Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
    constexpr bool operator==(const Vec3&) const = default;
};

using Vec3d = Vec3<double>;
using Vec3f = Vec3<float>;

template <typename T>
constexpr T dot(const Vec3<T>& a, const Vec3<T>& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
template <typename T>
constexpr Vec3<T> cross(const Vec3<T>& a, const Vec3<T>& b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <typename T>
T length(const Vec3<T>& a) { return std::sqrt(dot(a, a)); }
// Unit vector, or the zero vector when a has no direction.
template <typename T>
Vec3<T> normalizeOrZero(const Vec3<T>& a) {
    T len = length(a);
    return len > T(0) ? a * (T(1) / len) : Vec3<T>{};
}
template <typename To, typename From>
constexpr Vec3<To> cast(const Vec3<From>& a) { return {To(a.x), To(a.y), To(a.z)}; }

struct Box3d {
    Vec3d min{HUGE_VAL, HUGE_VAL, HUGE_VAL};
    Vec3d max{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};

    bool empty() const { return min.x > max.x; }
    bool operator==(const Box3d&) const = default;
    void extend(const Vec3d& p) {
        for (int i = 0; i < 3; ++i) {
            min[i] = std::fmin(min[i], p[i]);
            max[i] = std::fmax(max[i], p[i]);
        }
    }
    void extend(const Box3d& b) {
        if (!b.empty()) { extend(b.min); extend(b.max); }
    }
    // Closed boxes sharing at least a point.
    bool intersects(const Box3d& b) const {
        return min.x <= b.max.x && b.min.x <= max.x && min.y <= b.max.y && b.min.y <= max.y && min.z <= b.max.z &&
               b.min.z <= max.z;
    }
};

}  // namespace surfcast
