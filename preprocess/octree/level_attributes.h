// Per-level attributes that need neighbours: the node spacing h, the optional
// per-surfel radius, and the analytic normalization weights. Neighbours come
// from every node of the level plus a halo of surfels from beyond the chunk, so
// nothing is inflated at node borders.
//
// h comes from FLANN k-nearest-neighbour queries (DESIGN.md decision 3) of an
// evenly strided subsample of at most kSpacingSamples surfels per node: h is
// one number per node, and a percentile of 2048 samples is within about 1% of
// the whole node's (docs/ARCHITECTURE.md, "Spacing", has the measurement). A
// node the sample finds irregular is queried whole: its radii need every d_k.
// The weights need only the neighbours within the kernel's reach, found
// exactly by a fixed-radius search on a uniform grid of that reach.
//
// Spacing rule (docs/ARCHITECTURE.md, "Spacing"): d_k(i) is the distance from
// surfel i to its k-th nearest neighbour (k = 8) among those whose normals face
// the same side (a close surface behind does not sample this one). A node's h is the 95th
// percentile of d_k over its surfels: up to 5% isolated outliers cannot blow
// it up. A node whose sampling is too irregular for one h (95th / 5th
// percentile > kIrregularRatio) also stores a per-surfel radius
// r_i = clamp(d_k(i), P5, h), so r_i <= h always and h stays the bound the
// client's level choice relies on.
//
// Isolated surfels (DESIGN.md decision 19; docs/ARCHITECTURE.md, "Isolated
// surfels"): h is the bound level selection needs, not the size to draw a
// point with no surface around it. A node's yardstick rho is about the largest
// 8th-neighbour distance of a surface sampled on its grid: kIsolationSpacing
// times its cell (the level's cell, or the coarser one it was resampled on;
// for input points, at least the spacing of a surface that fills a leaf at
// capacity). rho depends on the node's own grid and the options, never on
// which chunk built it or which other points share its level. A surfel is isolated when no
// neighbour faces its side, when d_k > isolation * rho, or when d_k > rho and
// its neighbours spread off its tangent plane (kScatteredSpread): a stray
// return, a leaf hit by a few points, but also a crease of a sparse surface.
// It is drawn at rho (at h where that is smaller); every other surfel of its
// node at most at isolation * rho. Input points whose normals were estimated
// (a node of them all with Surfel::scanDk) are judged by d_k and spread among
// their scan's points, as the estimate measured them (neighbours of either
// side), not at the level: their node needs no query for it. A regular node
// whose sample (and measurements) find no isolated surfel draws every surfel
// at its h, which is at most the largest sampled d_k <= isolation * rho (or
// the fallback, where no sample has a neighbour at a distance). h itself is
// what the spacing rule gives with or without isolation. --no-radius
// (radii = false) turns isolation off with the radii.
//
// Weights (Ren et al. 2002, §7.1, analytic form): s_k = 1 / Σ_j g_j(u_j - u_k),
// summed over surfel k and its neighbours j, with u_j - u_k projected into the
// tangent plane of k, g_j(u) = exp(-|u|²/(2 ρ_j²)) with each neighbour's own
// width as the renderer draws it, ρ_j = kernelScale · (r_j, or j's node's h) (a
// halo surfel takes ρ_k), truncated at the renderer's cutoff |u| <= sqrt(2c)·ρ_j,
// and only over neighbours within z_t·ρ_k of k's tangent plane whose normals
// face the same side (a close opposite surface is hidden by the visibility
// pass and must not darken this one).
#pragma once

#include <span>
#include <vector>

#include "surfel.h"

namespace surfcast {

inline constexpr double kSpacingPercentile = 0.95;
inline constexpr double kIrregularPercentile = 0.05;
inline constexpr double kIrregularRatio = 4.0;
inline constexpr size_t kSpacingSamples = 2048;
// The default of LevelParams::isolation (bench/BENCHMARKS.md, "Where real
// scans fail": the chart it was chosen from).
inline constexpr double kDefaultIsolation = 6.0;
// rho over the sampling cell: a plane resampled on a grid has its 8th
// neighbour within about 2 cells whatever its orientation (1.41 aligned with
// the grid, 1.73 and about 2 tilted).
inline constexpr double kIsolationSpacing = 2.0;
// The RMS distance of a surfel's k neighbours from its tangent plane over
// d_k beyond which they are scattered, not a surface (0 on a plane; the
// spread measured on strays, leaves and noise: bench/BENCHMARKS.md, "Where
// real scans fail").
inline constexpr double kScatteredSpread = 0.2;

struct LevelNode {
    std::span<const Surfel> surfels;  // input
    double cell = 0;                  // input: the grid cell it was resampled on; 0 for input points
    float h = 0;                      // outputs
    std::vector<float> weights;       // empty when weights are off
    std::vector<float> radii;         // empty for regular nodes
};

struct LevelParams {
    int spacingK = 8;
    int fetchK = 24;           // neighbours fetched per d_k query: room to skip those facing away
    double cutoff = 1.0;       // c of the renderer's kernel cutoff y'y <= 2c
    double kernelScale = 1.0;  // k of the renderer's kernel V^r = (k r)^2 I
    bool radii = true;         // per-surfel radii where a node's sampling is irregular
    double isolation = kDefaultIsolation;  // 0 (off) or >= 1: see "Isolated surfels" above
    double levelCell = 0;      // the level's G³ cell, rho's unit for resampled nodes (or their coarser cell); 0: no isolation
    double leafCell = 0;       // rho's unit for input points: at least levelCell, and the spacing of a
                               // surface filling a leaf at capacity (node edge / sqrt(capacity))
    double fallbackSpacing = 0;  // h of a node with no neighbours at all: the level's largest sampling cell
    bool weights = true;
    int threads = 1;
};

// The spacing rule above, for one node's d_k values (reordered in place).
struct SpacingResult {
    float h = 0;
    bool irregular = false;
    float minRadius = 0;  // P5, the clamp floor of per-surfel radii
};
SpacingResult spacingRule(std::vector<float>& dk, double fallback);

// Fills h, weights and radii of `nodes`; `extra` are neighbour-only surfels
// (the halo, or the level's nodes computed elsewhere).
void computeLevelAttributes(std::span<LevelNode* const> nodes, std::span<const Surfel> extra, const LevelParams& params);

}  // namespace surfcast
