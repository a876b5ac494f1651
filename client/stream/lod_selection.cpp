#include "lod_selection.h"

#include <algorithm>
#include <cmath>
#include <queue>
#include <unordered_map>

namespace surfcast {

namespace {

// Splat extent beyond the surfel centres that a node box must grow by before
// culling: sqrt(2c) k h with c = 1 and k <= 1, plus the low-pass filter's
// pixel, covered generously by 2 h.
constexpr double kExtentFactor = 2.0;

struct Frame {
    Vec3d eye, right, up, forward;
    double eta, halfW, halfH, near;
};

// Double precision: node boxes are world coordinates (10^6 for georeferenced data).
Frame frameOf(const Camera& c, int width, int height) {
    Frame f;
    const CameraAxes a = cameraAxes(c);
    f.right = a.right;
    f.up = a.up;
    f.forward = a.forward;
    f.eye = c.eye;
    f.eta = viewportScale(c, height);
    f.halfW = 0.5 * width;
    f.halfH = 0.5 * height;
    return f;
}

Vec3d toCamera(const Frame& f, const Vec3d& p) {
    Vec3d d = p - f.eye;
    return {dot(d, f.right), dot(d, f.up), dot(d, f.forward)};
}

// All 8 corners of the box on the outside of one frustum plane.
bool outsideFrustum(const Frame& f, const Box3d& b) {
    Vec3d c[8];
    for (int i = 0; i < 8; ++i)
        c[i] = toCamera(f, {i & 1 ? b.max.x : b.min.x, i & 2 ? b.max.y : b.min.y, i & 4 ? b.max.z : b.min.z});
    auto allOutside = [&](auto&& outside) {
        for (const Vec3d& p : c)
            if (!outside(p)) return false;
        return true;
    };
    return allOutside([&](const Vec3d& p) { return p.z <= 0; }) ||
           allOutside([&](const Vec3d& p) { return f.eta * p.x > f.halfW * p.z; }) ||
           allOutside([&](const Vec3d& p) { return -f.eta * p.x > f.halfW * p.z; }) ||
           allOutside([&](const Vec3d& p) { return f.eta * p.y > f.halfH * p.z; }) ||
           allOutside([&](const Vec3d& p) { return -f.eta * p.y > f.halfH * p.z; });
}

// Every normal of the cone faces away from the eye seen from every point of
// the box: the angle between the cone axis and the directions to the eye
// exceeds 90 degrees plus both half-angles (the box as its bounding sphere).
bool backfacing(const NodeRecord& n, const Box3d& b, const Vec3d& eye) {
    if (n.flags & kFlagConeFull || !(n.coneCosHalfAngle > -1)) return false;
    Vec3d centre = (b.min + b.max) * 0.5;
    double radius = 0.5 * length(b.max - b.min);
    Vec3d toEye = eye - centre;
    double distance = length(toEye);
    if (distance <= radius) return false;  // the eye is inside the box's sphere
    double beta = std::asin(radius / distance);
    double alpha = std::acos(std::fmax(-1.0, std::fmin(1.0, double(n.coneCosHalfAngle))));
    Vec3d axis = cast<double>(n.coneAxis);
    double gamma = std::acos(std::fmax(-1.0, std::fmin(1.0, dot(normalizeOrZero(axis), toEye * (1 / distance)))));
    return gamma > 0.5 * M_PI + alpha + beta;
}

}  // namespace

LodSelector::LodSelector(const TilesetInfo& info, std::vector<NodeRecord> nodes) : info_(info) { addNodes(nodes); }

void LodSelector::addNodes(const std::vector<NodeRecord>& nodes) {
    const size_t first = nodes_.size();
    nodes_.insert(nodes_.end(), nodes.begin(), nodes.end());
    children_.resize(nodes_.size(), {-1, -1, -1, -1, -1, -1, -1, -1});
    for (size_t i = first; i < nodes_.size(); ++i) {
        index_[nodes_[i].key] = int32_t(i);
        if (nodes_[i].key.level == 0) root_ = int32_t(i);
    }
    // Link the new nodes to their parents, which may be in an earlier page.
    for (size_t i = first; i < nodes_.size(); ++i) {
        const NodeKey& key = nodes_[i].key;
        if (key.level == 0) continue;
        auto parent = index_.find(key.parent());
        if (parent != index_.end()) children_[size_t(parent->second)][size_t(key.childIndex())] = int32_t(i);
    }
}

Box3d LodSelector::box(uint32_t i) const {
    Vec3d lo = nodeMin(info_, nodes_[i].key);
    double e = nodeEdge(info_, nodes_[i].key.level);
    return {lo, lo + Vec3d{e, e, e}};
}

std::vector<SelectedNode> LodSelector::select(const Camera& camera, int width, int height, const LodParams& params,
                                              const std::function<bool(uint32_t)>& resident, LodStats* stats) const {
    std::vector<SelectedNode> out;
    LodStats local;
    LodStats& st = stats ? *stats : local;
    st = {};
    if (root_ < 0 || width <= 0 || height <= 0) return out;
    const Frame f = frameOf(camera, width, height);
    // Boxes closer than this count as touching the eye: refine them.
    const double nearDistance = 1e-9 * std::fmax(1.0, info_.rootEdge);
    const bool cones = params.backfaceCulling && normalsOriented(info_.normalSource);

    // Whether node i is drawn (or reached by refinement) at all.
    auto culled = [&](uint32_t i, Box3d* grown) {
        Box3d b = box(i);
        if (params.clip && !b.intersects(*params.clip)) {
            ++st.clipCulled;
            return true;
        }
        double extent = kExtentFactor * nodes_[i].spacing;
        *grown = {b.min - Vec3d{extent, extent, extent}, b.max + Vec3d{extent, extent, extent}};
        if (params.frustumCulling && outsideFrustum(f, *grown)) {
            ++st.frustumCulled;
            return true;
        }
        if (cones && backfacing(nodes_[i], *grown, f.eye)) {
            ++st.backfaceCulled;
            return true;
        }
        return false;
    };
    // h times the largest pixels-per-unit over the box's corners.
    auto projectedSpacing = [&](uint32_t i, const Box3d& b) {
        double nearest = HUGE_VAL;
        for (int c = 0; c < 8; ++c)
            nearest = std::fmin(nearest, toCamera(f, {c & 1 ? b.max.x : b.min.x, c & 2 ? b.max.y : b.min.y,
                                                      c & 4 ? b.max.z : b.min.z}).z);
        if (!(nearest > nearDistance)) return HUGE_VAL;  // the box reaches the eye's plane: refine
        return nodes_[i].spacing * f.eta / nearest;
    };

    // Weight of a node's gap by where it is on screen: up to 2x at the view
    // centre, 1x at the corners and beyond.
    auto centreWeight = [&](const Box3d& b) {
        Vec3d c = toCamera(f, (b.min + b.max) * 0.5);
        if (!(c.z > nearDistance)) return 2.0;
        double x = f.eta * c.x / (c.z * f.halfW), y = f.eta * c.y / (c.z * f.halfH);
        return 1.0 + std::fmax(0.0, 1.0 - std::sqrt(0.5 * (x * x + y * y)));
    };

    // Greedy replacement refinement from the root: the drawn node with the
    // largest weighted gap is replaced by its children next, of equal gaps
    // the one with the smaller key (a total order, the browser's too:
    // web/src/lod_selection.ts), so that a budget cuts the same nodes in both.
    // Without a budget the result is the plain recursive traversal (each node
    // is refined or not on its own test), only the order differs.
    struct Drawn {
        uint32_t index;
        double spacing, priority;
        NodeKey key;
        // std::priority_queue pops the largest: the larger priority, then the smaller key.
        bool operator<(const Drawn& o) const { return priority != o.priority ? priority < o.priority : o.key < key; }
    };
    std::vector<Drawn> final;
    std::priority_queue<Drawn> open;  // drawn nodes that want refining
    // Splats counted against the budget: drawn ones, and for a node waiting
    // for its children, the children's. Reserving them keeps the budget's
    // choices from depending on what has arrived: otherwise a later arrival
    // takes budget from a refinement already drawn, whose nodes a tight
    // memory budget then evicts and refetches, back and forth.
    size_t reserved = 0, memory = 0;
    auto cost = [&](uint32_t i) { return residentBytes(nodes_[i].surfelCount, params.granule); };
    auto place = [&](uint32_t i, const Box3d& grown) {
        double spacing = projectedSpacing(i, grown);
        Drawn d{i, spacing, spacing * centreWeight(grown), nodes_[i].key};
        if (spacing > params.targetPixels && nodes_[i].childMask != 0) open.push(d);
        else final.push_back(d);
        reserved += nodes_[i].surfelCount;
        memory += cost(i);
        st.used.push_back(i);
    };
    ++st.visited;
    Box3d rootGrown;
    if (culled(uint32_t(root_), &rootGrown)) return out;
    if (!resident(uint32_t(root_))) {
        st.missing.push_back({uint32_t(root_), HUGE_VAL});  // nothing to stand in for it: first
        return out;
    }
    place(uint32_t(root_), rootGrown);
    while (!open.empty()) {
        Drawn d = open.top();
        open.pop();
        // Children in a hierarchy page not added yet: drawn meanwhile.
        if (nodes_[d.index].flags & kFlagChildrenInPage &&
            std::all_of(children_[d.index].begin(), children_[d.index].end(), [](int32_t c) { return c < 0; })) {
            st.missingPages.push_back({d.index, d.priority});
            ++st.waiting;
            final.push_back(d);
            continue;
        }
        // Replacement: refine only when every child that will be drawn or
        // refined (not culled) is resident; else draw this node meanwhile.
        std::vector<std::pair<uint32_t, Box3d>> needed;
        size_t childSplats = 0, childMemory = 0;
        bool ready = true;
        for (int32_t c : children_[d.index]) {
            if (c < 0) continue;
            ++st.visited;
            Box3d grown;
            if (culled(uint32_t(c), &grown)) continue;  // counted here, once
            needed.push_back({uint32_t(c), grown});
            childSplats += nodes_[size_t(c)].surfelCount;
            childMemory += cost(uint32_t(c));
        }
        // The parent stays in memory (refined through, or drawn meanwhile).
        if (reserved - nodes_[d.index].surfelCount + childSplats > params.splatBudget ||
            memory + childMemory > params.memoryBudget) {
            ++st.budgetLimited;
            final.push_back(d);
            continue;
        }
        reserved += childSplats - nodes_[d.index].surfelCount;
        memory += childMemory;
        for (const auto& [c, grown] : needed)
            if (!resident(c)) {
                ready = false;
                st.missing.push_back({c, d.priority});
            }
        if (!ready) {
            ++st.waiting;
            for (const auto& [c, grown] : needed)
                if (resident(c)) st.used.push_back(c);
            final.push_back(d);
            continue;
        }
        reserved -= childSplats;  // place() counts them again
        memory -= childMemory;
        for (const auto& [c, grown] : needed) place(c, grown);
    }
    for (const Drawn& d : final) {
        out.push_back({d.index, d.spacing});
        st.splats += nodes_[d.index].surfelCount;
    }
    return out;
}

}  // namespace surfcast
