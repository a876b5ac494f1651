#include "cones.h"

#include <algorithm>

namespace surfcast {

NormalCone computeCone(std::span<const Surfel> surfels) {
    Vec3d sum;
    for (const Surfel& s : surfels) sum += cast<double>(s.normal);
    NormalCone cone;
    Vec3d axis = normalizeOrZero(sum);
    if (axis == Vec3d{}) return cone;  // normals cancel: no useful cone
    double minDot = 1;
    for (const Surfel& s : surfels) minDot = std::min(minDot, dot(axis, cast<double>(s.normal)));
    cone.axis = cast<float>(axis);
    if (minDot <= 0) return cone;  // wider than a hemisphere
    // Round the cosine down by float epsilon so float normals stay inside.
    cone.cosHalfAngle = float(std::max(0.0, minDot - 1e-6));
    cone.full = false;
    return cone;
}

}  // namespace surfcast
