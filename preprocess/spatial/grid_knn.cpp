#include "grid_knn.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <limits>
#include <tuple>

#include "octree_key.h"

namespace surfcast {

namespace {

// Inverse of mortonCode's spreading: bit 3i of v to bit i.
uint32_t compactBits(uint64_t v) {
    v &= 0x1249249249249249ull;
    v = (v | v >> 2) & 0x10C30C30C30C30C3ull;
    v = (v | v >> 4) & 0x100F00F00F00F00Full;
    v = (v | v >> 8) & 0x1F0000FF0000FFull;
    v = (v | v >> 16) & 0x1F00000000FFFFull;
    v = (v | v >> 32) & 0x1FFFFF;
    return uint32_t(v);
}

// Keeps the k smallest of d[0..n) with their ids, sorted ascending (ties keep
// the earlier one first), merged into best/bestIds which hold `count` already.
int keepNearest(const float* d, const uint32_t* ids, size_t n, int k, float* best, uint32_t* bestIds, int count) {
    for (size_t j = 0; j < n; ++j) {
        const float v = d[j];
        if (count == k && !(v < best[k - 1])) continue;
        int pos = count < k ? count++ : k - 1;
        while (pos > 0 && best[pos - 1] > v) {
            best[pos] = best[pos - 1];
            bestIds[pos] = bestIds[pos - 1];
            --pos;
        }
        best[pos] = v;
        bestIds[pos] = ids[j];
    }
    return count;
}

// Writes to keys, in order, (distance bits << 32 | index) of every d[i] whose
// bits are at most limitBits; returns how many. Its own function: inlined in
// the query loop, its pointers and bounds were spilled and reloaded on every
// iteration.
[[gnu::noinline]] size_t keysWithin(const float* d, size_t n, uint32_t limitBits, uint64_t* keys) {
    size_t m = 0;
    for (size_t i = 0; i < n; ++i) {
        const uint32_t bits = std::bit_cast<uint32_t>(d[i]);
        keys[m] = uint64_t(bits) << 32 | i;
        m += bits <= limitBits;
    }
    return m;
}

}  // namespace

// The points of the 3×3×3 cells around one cell of a level, as runs of sorted
// positions, and the block's faces: no point outside the block lies nearer to
// a point of the middle cell than that point's distance to the nearest face.
struct GridKnn::Block {
    std::vector<std::pair<uint32_t, uint32_t>> runs;
    double faceLo[3], faceHi[3];  // ±infinity where no point lies beyond

    // Distance from p to the nearest face (a lower bound on the distance to
    // any point outside), less a hair for the rounding of cell assignment.
    double clearance(const Vec3f& p, double hair) const {
        double c = std::numeric_limits<double>::infinity();
        for (int a = 0; a < 3; ++a) c = std::min({c, double(p[a]) - faceLo[a], faceHi[a] - double(p[a])});
        return c - hair;
    }
};

GridKnn::GridKnn(std::span<const Vec3f> points) {
    const size_t n = points.size();
    assert(n < (uint64_t(1) << 32));
    if (n == 0) return;
    Vec3f hi = points[0];
    lo_ = points[0];
    for (const Vec3f& p : points)
        for (int a = 0; a < 3; ++a) {
            lo_[a] = std::min(lo_[a], p[a]);
            hi[a] = std::max(hi[a], p[a]);
        }
    double extent = std::max({double(hi.x) - lo_.x, double(hi.y) - lo_.y, double(hi.z) - lo_.z});
    edge_ = extent > 0 ? extent * (1 + 1e-6) : 1.0;

    const double scale = double(1u << kBits) / edge_;
    const uint32_t maxQ = (1u << kBits) - 1;
    std::vector<std::pair<uint64_t, uint32_t>> keyed(n);
    for (size_t i = 0; i < n; ++i) {
        uint32_t q[3];
        for (int a = 0; a < 3; ++a)
            q[a] = uint32_t(std::clamp((double(points[i][a]) - lo_[a]) * scale, 0.0, double(maxQ)));
        keyed[i] = {mortonCode(q[0], q[1], q[2]), uint32_t(i)};
    }
    // Within a cell of the finest level, coincident points next to each other
    // (forEach finds stacks of them by adjacency), then input order.
    std::sort(keyed.begin(), keyed.end(), [&](const auto& a, const auto& b) {
        if (a.first != b.first) return a.first < b.first;
        const Vec3f &p = points[a.second], &q = points[b.second];
        return std::tie(p.x, p.y, p.z, a.second) < std::tie(q.x, q.y, q.z, b.second);
    });
    codes_.resize(n);
    order_.resize(n);
    sorted_.resize(n);
    for (size_t i = 0; i < n; ++i) {
        codes_[i] = keyed[i].first;
        order_[i] = keyed[i].second;
        sorted_[i] = points[keyed[i].second];
    }
    std::vector<std::pair<uint64_t, uint32_t>>().swap(keyed);

    // Occupied cells per level, from where neighbours in the curve first differ:
    // two codes whose highest differing bit is b lie in different cells from
    // level kBits - b/3 on.
    uint64_t firstDiffering[kBits + 1] = {};
    for (size_t i = 1; i < n; ++i) {
        uint64_t x = codes_[i] ^ codes_[i - 1];
        if (x) firstDiffering[kBits - (63 - std::countl_zero(x)) / 3]++;
    }
    uint64_t cells = 1;
    for (int l = 0; l <= kBits; ++l) {
        cells += firstDiffering[l];
        if (double(n) / double(cells) < kKnnPointsPerCell) break;
        level_ = l;
    }
    const int shift = 3 * (kBits - level_);
    for (size_t i = 0; i < n; ++i)
        if (i == 0 || codes_[i] >> shift != codes_[i - 1] >> shift) {
            cellCodes_.push_back(codes_[i] >> shift);
            cellBegin_.push_back(uint32_t(i));
        }
    cellBegin_.push_back(uint32_t(n));

    // An overfull cell's points split at the next level, and again, by where
    // their codes differ there (each finer cell is a contiguous run).
    // Not past kFinestSplit: a block of 3 cells of a level below it is no wider
    // than forEach's rounding hair, so no query is answered there.
    const auto split = [&](auto& self, int level, uint32_t begin, uint32_t end, uint32_t hint) -> void {
        if (end - begin <= kKnnMaxCellPoints || level >= kFinestSplit) {
            work_.push_back({level, begin, end, hint});
            tooCoarse_ |= end - begin > kKnnMaxCellPoints && !(sorted_[begin] == sorted_[end - 1]);
            return;
        }
        const int finer = 3 * (kBits - level - 1);
        for (uint32_t b = begin; b < end;) {
            uint32_t e = b + 1;
            while (e < end && codes_[e] >> finer == codes_[b] >> finer) ++e;
            self(self, level + 1, b, e, hint);
            b = e;
        }
    };
    for (size_t c = 0; c + 1 < cellBegin_.size(); ++c) split(split, level_, cellBegin_[c], cellBegin_[c + 1], uint32_t(c));
}

uint32_t GridKnn::lowerBound(uint64_t code) const {
    return uint32_t(std::lower_bound(codes_.begin(), codes_.end(), code) - codes_.begin());
}

// Galloping search from `hint`: a neighbour cell lies near its cell on the
// curve, so this touches a few cache lines where a binary search over all
// cells would miss the cache at every step.
size_t GridKnn::findCell(uint64_t cellCode, size_t hint) const {
    const size_t n = cellCodes_.size();
    size_t lo, hi;  // cellCode lies in [lo, hi)
    if (cellCodes_[hint] <= cellCode) {
        size_t step = 1;
        lo = hint;
        hi = hint + 1;
        while (hi < n && cellCodes_[hi] <= cellCode) {
            lo = hi;
            hi = std::min(n, hi + step);
            step *= 2;
        }
    } else {
        size_t step = 1;
        hi = hint;
        while (true) {
            lo = hi > step ? hi - step : 0;
            if (lo == 0 || cellCodes_[lo] <= cellCode) break;
            hi = lo;
            step *= 2;
        }
    }
    size_t i = size_t(std::upper_bound(cellCodes_.begin() + long(lo), cellCodes_.begin() + long(hi), cellCode) - cellCodes_.begin());
    return i > 0 && cellCodes_[i - 1] == cellCode ? i - 1 : n;
}

void GridKnn::gather(int level, const uint32_t cell[3], size_t hint, Block* block) const {
    const int shift = 3 * (kBits - level);
    const uint32_t cells = 1u << level;
    const double size = edge_ / cells;
    uint32_t from[3], to[3];
    for (int a = 0; a < 3; ++a) {
        from[a] = cell[a] > 0 ? cell[a] - 1 : 0;
        to[a] = std::min(cell[a] + 1, cells - 1);
        block->faceLo[a] = cell[a] > 0 ? lo_[a] + double(from[a]) * size : -std::numeric_limits<double>::infinity();
        block->faceHi[a] = to[a] + 1 < cells ? lo_[a] + double(to[a] + 1) * size : std::numeric_limits<double>::infinity();
    }
    block->runs.clear();
    const uint64_t span = shift >= 64 ? 0 : uint64_t(1) << shift;
    for (uint32_t x = from[0]; x <= to[0]; ++x)
        for (uint32_t y = from[1]; y <= to[1]; ++y)
            for (uint32_t z = from[2]; z <= to[2]; ++z) {
                if (level == level_) {
                    const size_t i = findCell(mortonCode(x, y, z), hint);
                    if (i < cellCodes_.size()) block->runs.push_back({cellBegin_[i], cellBegin_[i + 1]});
                    continue;
                }
                const uint64_t first = level == 0 ? 0 : mortonCode(x, y, z) << shift;
                const uint32_t b = lowerBound(first);
                const uint32_t e = level == 0 ? uint32_t(codes_.size()) : lowerBound(first + span);
                if (b < e) block->runs.push_back({b, e});
            }
    // In curve order, adjacent runs merged: fewer, longer reads.
    std::sort(block->runs.begin(), block->runs.end());
    size_t out = 0;
    for (auto r : block->runs) {
        if (out > 0 && block->runs[out - 1].second == r.first) block->runs[out - 1].second = r.second;
        else block->runs[out++] = r;
    }
    block->runs.resize(out);
}

void GridKnn::forEach(int k, int threads, const std::function<bool(uint32_t)>& wanted, const Visit& visit) const {
    assert(k > 0);
    if (codes_.empty()) return;
    const double scale = double(1u << kBits) / edge_;
    const uint32_t maxQ = (1u << kBits) - 1;
    const double hair = edge_ * 1e-6;

#pragma omp parallel num_threads(std::max(1, threads))
    {
        Block block, wide;
        std::vector<float> cx, cy, cz, d, dw;
        std::vector<uint32_t> cid, runIds, stackBegin, stackEnd;
        std::vector<float> best(static_cast<size_t>(k));
        std::vector<uint32_t> bestIds(static_cast<size_t>(k)), neighbours(static_cast<size_t>(k));
        std::vector<Vec3f> positions(static_cast<size_t>(k));
        std::vector<uint64_t> keys;
        // The previous query and its k-th distance²: the ball around p of radius
        // |p - prev| + that distance holds at least k points.
        Vec3f prev;
        float prevKth = -1;
        auto exact = [&](const Block& b, const Vec3f& p, int found) {
            const double c = b.clearance(p, hair);
            if (std::isinf(c)) return true;  // the block holds every point
            return found == k && c > 0 && double(best[size_t(k) - 1]) <= c * c;
        };

#pragma omp for schedule(dynamic, 64)
        for (size_t c = 0; c < work_.size(); ++c) {
            const auto [cellLevel, begin, end, hint] = work_[c];
            bool any = !wanted;
            for (uint32_t s = begin; s < end && !any; ++s) any = wanted(order_[s]);
            if (!any) continue;
            // The cell's block as candidates, a struct of arrays for the distance loop.
            const uint64_t code = codes_[begin] >> (3 * (kBits - cellLevel));
            const uint32_t cell[3] = {compactBits(code >> 2), compactBits(code >> 1), compactBits(code)};
            gather(cellLevel, cell, hint, &block);
            size_t count = 0;
            for (auto [b, e] : block.runs) count += e - b;
            cx.resize(count), cy.resize(count), cz.resize(count), cid.resize(count), d.resize(count), keys.resize(count);
            size_t j = 0;
            for (auto [b, e] : block.runs)
                for (uint32_t s = b; s < e; ++s, ++j) {
                    cx[j] = sorted_[s].x, cy[j] = sorted_[s].y, cz[j] = sorted_[s].z;
                    cid[j] = s;
                }

            // Stacks of coincident points (adjacent: the constructor sorts them
            // together). A query in a stack of k or more has its k nearest at
            // distance 0, and the stack's first k are an exact answer; without
            // this a cell of n coincident points costs n² distances
            // (BadInput.AMillionCoincidentPointsBuild).
            stackBegin.resize(end - begin), stackEnd.resize(end - begin);
            for (uint32_t s = begin; s < end; ++s)
                stackBegin[s - begin] = s > begin && sorted_[s] == sorted_[s - 1] ? stackBegin[s - 1 - begin] : s;
            for (uint32_t s = end; s-- > begin;)
                stackEnd[s - begin] = s + 1 < end && sorted_[s + 1] == sorted_[s] ? stackEnd[s + 1 - begin] : s + 1;

            for (uint32_t s = begin; s < end; ++s) {
                if (wanted && !wanted(order_[s])) continue;
                const Vec3f p = sorted_[s];
                if (stackEnd[s - begin] - stackBegin[s - begin] >= uint32_t(k)) {
                    for (int i = 0; i < k; ++i) {
                        best[size_t(i)] = 0;
                        neighbours[size_t(i)] = order_[stackBegin[s - begin] + uint32_t(i)];
                        positions[size_t(i)] = p;
                    }
                    prev = p;
                    prevKth = 0;
                    visit(order_[s], {{neighbours.data(), size_t(k)}, {best.data(), size_t(k)}, {positions.data(), size_t(k)}});
                    continue;
                }
                for (size_t i = 0; i < count; ++i) {
                    const float dx = cx[i] - p.x, dy = cy[i] - p.y, dz = cz[i] - p.z;
                    d[i] = dx * dx + dy * dy + dz * dz;
                }
                // Candidates inside the previous query's ball, when they are k or
                // more, hold the k nearest; else all candidates are ranked. Keys
                // put the distance's bits (ordered as the non-negative floats
                // are) above the candidate, so selecting integers selects
                // distances. The ball's candidates are compacted into keys in one
                // pass, then shrunk by the area they should need (a surface's
                // count grows with r²) while that still holds k.
                int found = -1;
                if (prevKth >= 0) {
                    const float r = std::sqrt(prevKth) + length(p - prev);
                    const uint32_t limitBits = std::bit_cast<uint32_t>(r * r * (1 + 1e-5f));
                    uint64_t* const kp = keys.data();
                    size_t m = keysWithin(d.data(), count, limitBits, kp);
                    if (m > size_t(2 * k)) {
                        const float tighter = std::bit_cast<float>(limitBits) * float(k + k / 4 + 1) / float(m);
                        const uint64_t tighterKey = uint64_t(std::bit_cast<uint32_t>(tighter)) << 32 | 0xFFFFFFFFu;
                        size_t m2 = 0;
                        for (size_t i = 0; i < m; ++i) m2 += kp[i] <= tighterKey;
                        if (m2 >= size_t(k)) {
                            size_t w = 0;
                            for (size_t i = 0; i < m; ++i) {
                                const uint64_t key = kp[i];
                                kp[w] = key;
                                w += key <= tighterKey;
                            }
                            m = w;
                        }
                    }
                    if (m >= size_t(k)) {
                        // The k-th lands at k - 1: exact() and the next query's
                        // ball read it there.
                        std::nth_element(kp, kp + (k - 1), kp + m);
                        std::sort(kp, kp + (k - 1));
                        for (int i = 0; i < k; ++i) {
                            const uint64_t key = kp[i];
                            best[size_t(i)] = std::bit_cast<float>(uint32_t(key >> 32));
                            bestIds[size_t(i)] = cid[uint32_t(key)];
                        }
                        found = k;
                    }
                }
                if (found < 0) found = keepNearest(d.data(), cid.data(), count, k, best.data(), bestIds.data(), 0);
                // Coarser levels until the block provably holds the k nearest.
                const Block* holds = &block;
                for (int level = cellLevel - 1; level >= 0 && !exact(*holds, p, found); --level) {
                    uint32_t coarse[3];
                    for (int a = 0; a < 3; ++a) {
                        uint32_t q = uint32_t(std::clamp((double(p[a]) - lo_[a]) * scale, 0.0, double(maxQ)));
                        coarse[a] = q >> (kBits - level);
                    }
                    gather(level, coarse, 0, &wide);
                    found = 0;
                    for (auto [b, e] : wide.runs) {
                        runIds.resize(e - b);
                        dw.resize(e - b);
                        for (uint32_t i = b; i < e; ++i) {
                            const Vec3f v = sorted_[i] - p;
                            dw[i - b] = dot(v, v);
                            runIds[i - b] = i;
                        }
                        found = keepNearest(dw.data(), runIds.data(), e - b, k, best.data(), bestIds.data(), found);
                    }
                    holds = &wide;
                }
                prev = p;
                prevKth = found == k ? best[size_t(k) - 1] : -1;
                for (int i = 0; i < found; ++i) {
                    neighbours[size_t(i)] = order_[bestIds[size_t(i)]];
                    positions[size_t(i)] = sorted_[bestIds[size_t(i)]];
                }
                visit(order_[s], {{neighbours.data(), size_t(found)}, {best.data(), size_t(found)}, {positions.data(), size_t(found)}});
            }
        }
    }
}

}  // namespace surfcast
