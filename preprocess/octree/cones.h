// Visibility cones (Ren 2002 §6.2 culls whole blocks with them): an axis and
// half-angle that bound every surfel normal of a node.
#pragma once

#include <span>

#include "surfel.h"

namespace surfcast {

struct NormalCone {
    Vec3f axis{0, 0, 1};
    float cosHalfAngle = -1;  // every normal n satisfies dot(n, axis) >= cosHalfAngle
    bool full = true;         // normals span more than a hemisphere: the cone culls nothing
};

// Axis: the normalized mean normal; half-angle: the widest normal from it.
// Not the minimal cone, but bounding, and one pass.
NormalCone computeCone(std::span<const Surfel> surfels);

}  // namespace surfcast
