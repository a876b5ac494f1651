// Normal estimation for points that come without one: PCA of the k nearest
// neighbours (Hoppe et al. 1992), the eigenvector of the smallest eigenvalue of
// their covariance. Orientation, per input (docs/ARCHITECTURE.md, "Normals"):
//   1. toward the scan origin, when the input names one (PCD VIEWPOINT, the
//      built-in scene's scanners);
//   2. else up (+z), for airborne LiDAR (LAS input);
//   3. else outward, away from the centre of the whole data set's bounds.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "surfel.h"

namespace surfcast {

struct OrientationRule {
    std::optional<Vec3d> scanOrigin;  // in the surfel frame (world minus root minimum)
    bool up = false;
};

struct NormalContext {
    std::vector<OrientationRule> rules;  // indexed by Surfel::source
    Vec3d centre;                        // data set centre, surfel frame
    int k = 16;
    int spacingK = 8;  // the d_k each estimated point records (Surfel::scanDk), when k > spacingK
    bool measure = true;  // record scanDk and scanSpread (the isolation of input points needs them)
    bool mergesCopies = false;  // the build merges exact duplicates: copies of a point do not count as its neighbours
    int threads = 1;
};

// Name of the rule an input's normals follow, for tileset.json and the summary.
std::string orientationName(const OrientationRule& rule);

// Fills the zero normals of `points`; where context.measure, also measures
// their scanDk and scanSpread and those of points marked kScanDkToMeasure
// (normals kept). Neighbours come from points and halo.
void estimateNormals(std::span<Surfel> points, std::span<const Surfel> halo, const NormalContext& context);

}  // namespace surfcast
