#include "sampler.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <numeric>

namespace surfcast {

namespace {

constexpr int kAxisBits = 21;
constexpr uint64_t kAxisMask = (uint64_t(1) << kAxisBits) - 1;

uint64_t packCell(uint64_t x, uint64_t y, uint64_t z) { return x << (2 * kAxisBits) | y << kAxisBits | z; }

uint32_t cellCoord(double v, const SampleGrid& g, int axis) {
    double c = std::floor((v - g.origin[axis]) / g.cellSize);
    return uint32_t(std::clamp(c, 0.0, double(g.cells - 1)));
}

struct Cell {
    uint64_t key;
    uint32_t begin, end;  // range in the sorted order
};

// The value with the most input points behind it among a cell's members (the
// lowest such value on a tie): categorical attributes are never averaged.
template <typename Get>
uint32_t majority(std::span<const Surfel> points, const std::vector<std::pair<uint64_t, uint32_t>>& order, const Cell& cell,
                  std::vector<std::pair<uint32_t, float>>& tally, Get get) {
    tally.clear();
    for (uint32_t k = cell.begin; k < cell.end; ++k) {
        const Surfel& s = points[order[k].second];
        const uint32_t v = get(s);
        auto it = std::find_if(tally.begin(), tally.end(), [&](const auto& t) { return t.first == v; });
        if (it == tally.end()) tally.push_back({v, s.count});
        else it->second += s.count;
    }
    auto best = tally.begin();
    for (auto it = tally.begin(); it != tally.end(); ++it)
        if (it->second > best->second || (it->second == best->second && it->first < best->first)) best = it;
    return best->first;
}

uint64_t cellKey(const Vec3d& p, const SampleGrid& grid) {
    return packCell(cellCoord(p.x, grid, 0), cellCoord(p.y, grid, 1), cellCoord(p.z, grid, 2));
}

}  // namespace

size_t occupiedCells(std::span<const Surfel> points, const SampleGrid& grid) {
    std::vector<uint64_t> keys(points.size());
    for (size_t i = 0; i < points.size(); ++i) keys[i] = cellKey(points[i].position, grid);
    std::sort(keys.begin(), keys.end());
    return size_t(std::unique(keys.begin(), keys.end()) - keys.begin());
}

std::vector<Surfel> resample(std::span<const Surfel> points, const SampleGrid& grid, bool withAttributes, ScalarTable* table) {
    assert(grid.cells >= 1 && grid.cells <= kMaxGridCells);
    const size_t n = points.size();
    std::vector<std::pair<uint64_t, uint32_t>> order(n);
    for (size_t i = 0; i < n; ++i) {
        order[i] = {cellKey(points[i].position, grid), uint32_t(i)};
    }
    std::sort(order.begin(), order.end());

    std::vector<Cell> cells;
    for (uint32_t i = 0; i < n;) {
        uint32_t j = i;
        while (j < n && order[j].first == order[i].first) ++j;
        cells.push_back({order[i].first, i, j});
        i = j;
    }

    std::vector<Surfel> out(cells.size());
    std::vector<std::pair<uint32_t, float>> tally;
    const size_t fields = withAttributes && table ? table->fields() : 0;
    // Per output surfel: its scalar row, categorical fields filled here, the
    // continuous ones below.
    std::vector<uint32_t> rows(out.size() * fields);
    for (size_t c = 0; c < cells.size(); ++c) {
        const Cell& cell = cells[c];
        Vec3d centroid;
        Vec3f normal;
        double weight = 0;
        for (uint32_t k = cell.begin; k < cell.end; ++k) {
            const Surfel& s = points[order[k].second];
            centroid += s.position * double(s.count);
            normal += s.normal * s.count;
            weight += s.count;
        }
        centroid = centroid * (1.0 / weight);
        uint32_t nearest = order[cell.begin].second;
        double best = HUGE_VAL;
        for (uint32_t k = cell.begin; k < cell.end; ++k) {
            Vec3d d = points[order[k].second].position - centroid;
            if (dot(d, d) < best) { best = dot(d, d); nearest = order[k].second; }
        }
        Surfel& s = out[c];
        s = points[nearest];
        s.normal = normalizeOrZero(normal);
        s.scanDk = -1, s.scanSpread = 0;  // an input point's own sampling, not the cell's
        s.count = float(weight);
        if (withAttributes && cell.end - cell.begin > 1) {
            s.classification = uint8_t(majority(points, order, cell, tally, [](const Surfel& p) { return p.classification; }));
            s.returns = uint8_t(majority(points, order, cell, tally, [](const Surfel& p) { return p.returns; }));
        }
        for (size_t f = 0; f < fields; ++f)
            rows[c * fields + f] = table->categorical[f]
                                       ? majority(points, order, cell, tally, [&](const Surfel& p) { return table->row(p.row)[f]; })
                                       : table->row(points[nearest].row)[f];  // until prefiltered below
    }
    if (!withAttributes) return out;

    // Colours: Gaussian-weighted over the 3x3x3 block of cells around each
    // cell. Keys put z lowest, so each (x, y) column of three cells is one
    // range of the sorted cells. In cell order, where a column's range starts
    // only moves forward (cell keys grow, and so does each neighbour column's
    // first key), so one cursor per column offset walks the cells once.
    const float inv2Sigma2 = float(1.0 / (2.0 * std::pow(kPrefilterSigma * grid.cellSize, 2)));
    size_t cursor[9] = {};
    std::vector<double> scalarSum(fields);
    for (size_t c = 0; c < cells.size(); ++c) {
        std::fill(scalarSum.begin(), scalarSum.end(), 0.0);
        int64_t x = int64_t(cells[c].key >> (2 * kAxisBits)), y = int64_t((cells[c].key >> kAxisBits) & kAxisMask),
                z = int64_t(cells[c].key & kAxisMask);
        float sum[5] = {0, 0, 0, 0, 0}, wsum = 0;  // colour, intensity, opacity
        for (int64_t nx = x - 1; nx <= x + 1; ++nx)
            for (int64_t ny = y - 1; ny <= y + 1; ++ny) {
                if (nx < 0 || ny < 0 || nx >= grid.cells || ny >= grid.cells) continue;
                uint64_t first = packCell(uint64_t(nx), uint64_t(ny), uint64_t(std::max<int64_t>(z - 1, 0)));
                uint64_t last = packCell(uint64_t(nx), uint64_t(ny), uint64_t(std::min<int64_t>(z + 1, grid.cells - 1)));
                size_t& at = cursor[(nx - x + 1) * 3 + (ny - y + 1)];
                while (at < cells.size() && cells[at].key < first) ++at;
                for (size_t it = at; it < cells.size() && cells[it].key <= last; ++it)
                    for (uint32_t k = cells[it].begin; k < cells[it].end; ++k) {
                        const Surfel& p = points[order[k].second];
                        Vec3f d = cast<float>(p.position - out[c].position);
                        float w = p.count * std::exp(-dot(d, d) * inv2Sigma2);
                        for (int ch = 0; ch < 3; ++ch) sum[ch] += w * float(p.color[ch]);
                        sum[3] += w * float(p.intensity);
                        sum[4] += w * float(p.alpha);
                        wsum += w;
                        for (size_t f = 0; f < fields; ++f) scalarSum[f] += double(w) * table->row(p.row)[f];
                    }
            }
        if (wsum > 0) {
            for (int ch = 0; ch < 3; ++ch) out[c].color[ch] = uint16_t(std::clamp(std::lround(sum[ch] / wsum), 0l, 65535l));
            out[c].intensity = uint16_t(std::clamp(std::lround(sum[3] / wsum), 0l, 65535l));
            out[c].alpha = uint8_t(std::clamp(std::lround(sum[4] / wsum), 0l, 255l));
            for (size_t f = 0; f < fields; ++f)
                if (!table->categorical[f]) rows[c * fields + f] = uint32_t(std::llround(scalarSum[f] / wsum));
        }
        if (fields) out[c].row = table->append(rows.data() + c * fields);
    }
    return out;
}

}  // namespace surfcast
