#include "laz_export.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <sstream>

#include "byte_io.h"
#include "surfcast_laz.h"

namespace surfcast {

namespace {

// LAS 1.4 (ASPRS R15): the header, a VLR's header, point format 6's record and 7's.
constexpr size_t kHeaderBytes = 375, kVlrHeaderBytes = 54;
constexpr size_t kRecordBytes6 = 30, kRecordBytes7 = 36;
// Scan angle's unit in point formats 6-10 (degrees).
constexpr double kScanAngleUnit = 0.006;

Box3d nodeBox(const TilesetInfo& info, const NodeKey& key) {
    Box3d b;
    b.min = nodeMin(info, key);
    const double e = nodeEdge(info, key.level);
    b.max = b.min + Vec3d{e, e, e};
    return b;
}

bool overlaps(const Box3d& a, const Box3d& b) {
    for (int i = 0; i < 3; ++i)
        if (a.max[i] < b.min[i] || b.max[i] < a.min[i]) return false;
    return true;
}

bool inside(const Box3d& b, const Vec3d& p) {
    for (int i = 0; i < 3; ++i)
        if (p[i] < b.min[i] || p[i] > b.max[i]) return false;
    return true;
}

// The leaves the filter's box reaches, in hierarchy order.
std::vector<size_t> reachedLeaves(const TilesetReader& set, const PointFilter& filter) {
    std::vector<size_t> out;
    for (size_t i = 0; i < set.nodes().size(); ++i) {
        const NodeRecord& n = set.nodes()[i];
        if (!(n.flags & kFlagInputPoints)) continue;
        if (filter.box && !overlaps(*filter.box, nodeBox(set.info(), n.key))) continue;
        out.push_back(i);
    }
    return out;
}

// The LAS fields a set may carry as scalar attributes (the LAS reader's names).
struct LasScalars {
    const AttributeInfo *gpsTime = nullptr, *scanAngle = nullptr, *userData = nullptr, *pointSourceId = nullptr;
    bool any() const { return gpsTime || scanAngle || userData || pointSourceId; }
};

LasScalars lasScalars(const TilesetInfo& info) {
    return {info.attribute("gps_time"), info.attribute("scan_angle"), info.attribute("user_data"), info.attribute("point_source_id")};
}

// A scalar attribute's value for surfel i, or NaN where the block lacks it.
double scalarValue(const BlockData& b, const AttributeInfo* a, size_t i) {
    if (!a) return NAN;
    for (const ScalarAttribute& s : b.scalars)
        if (s.name == a->name) return s.values[i] * a->scale + a->offset;
    return NAN;
}

// Visits each kept point of the leaves `nodes` (decoding each once).
using Visit = std::function<Status(const NodeRecord&, const BlockData&, size_t, const Vec3d&)>;
Status forEachKept(const TilesetReader& set, const PointFilter& filter, const std::vector<size_t>& nodes, bool scalars,
                   const StopExport& stop, const Visit& visit) {
    std::vector<bool> keepClass(256, filter.classes.empty());
    for (uint8_t c : filter.classes) keepClass[c] = true;
    for (size_t index : nodes) {
        if (stop && stop()) return Status::error("export stopped");
        const NodeRecord& n = set.nodes()[index];
        auto bytes = set.readBlockBytes(n);
        if (!bytes) return bytes.status();
        BlockExpectation e = set.expectation(n);
        e.scalars = scalars;
        auto block = decodeBlock(bytes->data(), bytes->size(), e);
        if (!block) return Status::error(set.describe() + ": node " + n.key.name() + ": " + block.status().message());
        for (size_t i = 0; i < block->size(); ++i) {
            if (!filter.classes.empty() && !keepClass[block->classification.empty() ? 0 : block->classification[i]]) continue;
            const Vec3d p = set.position(n, *block, i);
            if (filter.box && !inside(*filter.box, p)) continue;
            SC_TRY(visit(n, *block, i, p));
        }
    }
    return {};
}

void putText(uint8_t* at, const std::string& text, size_t size) {
    std::memset(at, 0, size);
    std::memcpy(at, text.data(), std::min(text.size(), size));
}

// The LAS 1.4 header and the LASzip VLR.
std::vector<uint8_t> lasHeader(const LazExportPlan& plan, const std::vector<uint8_t>& laszipVlr) {
    const size_t recordBytes = plan.pointFormat == 7 ? kRecordBytes7 : kRecordBytes6;
    std::vector<uint8_t> h(kHeaderBytes + kVlrHeaderBytes + laszipVlr.size(), 0);
    std::memcpy(h.data(), "LASF", 4);
    le::put<uint16_t>(&h[6], 1u << 4);  // global encoding: WKT (required for formats 6-10)
    h[24] = 1;
    h[25] = 4;
    putText(&h[26], "surfcast", 32);
    putText(&h[58], "surfcast-export", 32);
    const std::time_t now = std::time(nullptr);
    std::tm utc{};
    gmtime_r(&now, &utc);
    le::put<uint16_t>(&h[90], uint16_t(utc.tm_yday + 1));
    le::put<uint16_t>(&h[92], uint16_t(utc.tm_year + 1900));
    le::put<uint16_t>(&h[94], uint16_t(kHeaderBytes));
    le::put<uint32_t>(&h[96], uint32_t(h.size()));  // offset to the point data
    le::put<uint32_t>(&h[100], 1);                  // one VLR: LASzip's
    h[104] = uint8_t(plan.pointFormat | 0x80);      // bit 7: compressed (LASzip's convention)
    le::put<uint16_t>(&h[105], uint16_t(recordBytes));
    for (int a = 0; a < 3; ++a) {
        le::put<double>(&h[131 + 8 * size_t(a)], plan.scale);
        le::put<double>(&h[155 + 8 * size_t(a)], plan.offset[a]);
        le::put<double>(&h[179 + 16 * size_t(a)], plan.points ? plan.bounds.max[a] : 0);
        le::put<double>(&h[187 + 16 * size_t(a)], plan.points ? plan.bounds.min[a] : 0);
    }
    le::put<uint64_t>(&h[247], plan.points);
    uint8_t* v = &h[kHeaderBytes];
    putText(v + 2, "laszip encoded", 16);
    le::put<uint16_t>(v + 18, 22204);
    le::put<uint16_t>(v + 20, uint16_t(laszipVlr.size()));
    putText(v + 22, "by surfcast-export (laz crate)", 32);
    std::memcpy(v + kVlrHeaderBytes, laszipVlr.data(), laszipVlr.size());
    return h;
}

struct WriteContext {
    const std::function<Status(const uint8_t*, size_t)>* out;
    Status failed;
    // Nothing may unwind into the Rust frames that call this.
    static int write(void* ctx, const uint8_t* data, uint64_t len) noexcept {
        auto* self = static_cast<WriteContext*>(ctx);
        try {
            self->failed = (*self->out)(data, size_t(len));
        } catch (const std::exception& e) {
            self->failed = Status::error(e.what());
        } catch (...) {
            self->failed = Status::error("the output failed");
        }
        return self->failed.ok() ? 0 : -1;
    }
};

}  // namespace

Result<Box3d> parseBox(const std::string& text) {
    std::vector<double> v;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        char* end = nullptr;
        const double x = std::strtod(item.c_str(), &end);
        if (item.empty() || *end != '\0' || !std::isfinite(x)) return Status::error("box '" + text + "': '" + item + "' is not a number");
        v.push_back(x);
    }
    if (v.size() != 6) return Status::error("box '" + text + "': six numbers wanted (xmin,ymin,zmin,xmax,ymax,zmax), " + std::to_string(v.size()) + " given");
    Box3d b;
    b.min = {v[0], v[1], v[2]};
    b.max = {v[3], v[4], v[5]};
    for (int a = 0; a < 3; ++a)
        if (b.min[a] > b.max[a]) return Status::error("box '" + text + "': its minimum exceeds its maximum on axis " + "xyz"[a]);
    return b;
}

Result<std::vector<uint8_t>> parseClasses(const std::string& text) {
    std::vector<uint8_t> out;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        char* end = nullptr;
        const long c = std::strtol(item.c_str(), &end, 10);
        if (item.empty() || *end != '\0' || c < 0 || c > 255) return Status::error("classes '" + text + "': '" + item + "' is not a class (0 to 255)");
        out.push_back(uint8_t(c));
    }
    if (out.empty()) return Status::error("classes: none given");
    return out;
}

uint64_t exportPointsAtMost(const TilesetReader& set, const PointFilter& filter) {
    uint64_t n = 0;
    for (size_t i : reachedLeaves(set, filter)) n += set.nodes()[i].surfelCount;
    return n;
}

Result<LazExportPlan> planLazExport(const TilesetReader& set, const PointFilter& filter, const StopExport& stop) {
    const TilesetInfo& info = set.info();
    if (!filter.classes.empty() && !info.attribute("classification"))
        return Status::error(set.describe() + ": the set stores no classification to choose classes by");
    LazExportPlan plan;
    plan.nodes = reachedLeaves(set, filter);
    plan.pointFormat = info.colorBits ? 7 : 6;
    // The finest step of the leaves' positions: the LAS scale is the power of
    // ten at or below it, so exporting loses less than half of it.
    double step = HUGE_VAL;
    for (size_t i : plan.nodes) {
        const NodeRecord& n = set.nodes()[i];
        step = std::min(step, nodeEdge(info, n.key.level) / double((uint64_t(1) << n.positionBits) - 1));
    }
    const bool whole = !filter.box && filter.classes.empty();
    if (whole) {
        // Every leaf whole, no decoding (a third of the export's time,
        // bench/BENCHMARKS.md "LAZ export"): the records count the points, and
        // tileset.json's bounds of the input points, grown by the coarsest
        // leaf's half step, hold the leaves' positions.
        double coarsest = 0;
        for (size_t i : plan.nodes) {
            const NodeRecord& n = set.nodes()[i];
            plan.points += n.surfelCount;
            coarsest = std::max(coarsest, nodeEdge(info, n.key.level) / double((uint64_t(1) << n.positionBits) - 1));
        }
        if (plan.points) {
            plan.bounds = info.bounds;
            plan.bounds.min = plan.bounds.min - Vec3d{1, 1, 1} * (coarsest / 2);
            plan.bounds.max = plan.bounds.max + Vec3d{1, 1, 1} * (coarsest / 2);
        }
    } else {
        SC_TRY(forEachKept(set, filter, plan.nodes, false, stop, [&](const NodeRecord&, const BlockData&, size_t, const Vec3d& p) -> Status {
            plan.bounds.extend(p);
            ++plan.points;
            return {};
        }));
    }
    if (plan.points == 0) return plan;
    plan.scale = std::pow(10.0, std::floor(std::log10(std::max(step, 1e-9))));
    for (int a = 0; a < 3; ++a) plan.offset[a] = std::floor(plan.bounds.min[a]);
    // Every coordinate must fit LAS's 32-bit integers.
    auto fits = [&] {
        for (int a = 0; a < 3; ++a)
            if ((plan.bounds.max[a] - plan.offset[a]) / plan.scale > 2147483647.0) return false;
        return true;
    };
    while (!fits()) plan.scale *= 10;
    // The bounds of the integers the records hold: rounding is monotonic, so
    // the points' own bounds round to theirs; grown bounds round outward.
    for (int a = 0; a < 3; ++a) {
        const double lo = (plan.bounds.min[a] - plan.offset[a]) / plan.scale, hi = (plan.bounds.max[a] - plan.offset[a]) / plan.scale;
        plan.bounds.min[a] = plan.offset[a] + (whole ? std::floor(lo) : double(std::llround(lo))) * plan.scale;
        plan.bounds.max[a] = plan.offset[a] + (whole ? std::ceil(hi) : double(std::llround(hi))) * plan.scale;
    }
    return plan;
}

Status writeLazExport(const TilesetReader& set, const PointFilter& filter, const LazExportPlan& plan,
                      const std::function<Status(const uint8_t*, size_t)>& out, const StopExport& stop) {
    uint8_t vlr[1024];
    size_t vlrBytes = 0;
    if (sc_laz_vlr(uint8_t(plan.pointFormat), 0, vlr, sizeof vlr, &vlrBytes) != 0)
        return Status::error("LAZ: no LASzip VLR for point format " + std::to_string(plan.pointFormat));
    const std::vector<uint8_t> header = lasHeader(plan, std::vector<uint8_t>(vlr, vlr + vlrBytes));
    SC_TRY(out(header.data(), header.size()));

    WriteContext context{&out, {}};
    char err[512] = {};
    ScLazWriter* writer = sc_laz_writer_open(&WriteContext::write, &context, header.size(), uint8_t(plan.pointFormat), 0, err, sizeof err);
    if (!writer) return Status::error(std::string("LAZ compressor: ") + err);
    const auto failure = [&](const char* what) {
        return context.failed.ok() ? Status::error(std::string("LAZ compressor: ") + what + ": " + err) : context.failed;
    };
    const TilesetInfo& info = set.info();
    const LasScalars scalars = lasScalars(info);
    const size_t recordBytes = plan.pointFormat == 7 ? kRecordBytes7 : kRecordBytes6;
    std::vector<uint8_t> records;
    uint64_t written = 0;
    const NodeRecord* current = nullptr;
    Status status = forEachKept(set, filter, plan.nodes, scalars.any(), stop, [&](const NodeRecord& n, const BlockData& b, size_t i, const Vec3d& p) -> Status {
        if (current != &n && !records.empty()) {  // a block's records at a time
            if (sc_laz_writer_write(writer, records.data(), records.size() / recordBytes, err, sizeof err) != 0) return failure("write");
            records.clear();
        }
        current = &n;
        if (++written > plan.points) return Status::error(set.describe() + ": the set changed during the export (more points than counted)");
        const size_t at = records.size();
        records.resize(at + recordBytes, 0);
        uint8_t* r = &records[at];
        for (int a = 0; a < 3; ++a) {
            const double q = std::round((p[a] - plan.offset[a]) / plan.scale);
            if (!(q >= -2147483648.0 && q <= 2147483647.0))
                return Status::error(set.describe() + ": node " + n.key.name() + ": a point outside the bounds the export planned");
            le::put<int32_t>(r + 4 * a, int32_t(q));
        }
        if (!b.intensity.empty()) le::put<uint16_t>(r + 12, b.intensity[i]);
        const uint8_t ret = b.returnNumber.empty() ? 1 : b.returnNumber[i], count = b.numberOfReturns.empty() ? 1 : b.numberOfReturns[i];
        r[14] = uint8_t((ret & 0x0F) | (count << 4));
        r[16] = b.classification.empty() ? 0 : b.classification[i];
        const double userData = scalarValue(b, scalars.userData, i), angle = scalarValue(b, scalars.scanAngle, i);
        const double source = scalarValue(b, scalars.pointSourceId, i), gps = scalarValue(b, scalars.gpsTime, i);
        if (!std::isnan(userData)) r[17] = uint8_t(std::clamp(std::lround(userData), 0L, 255L));
        if (!std::isnan(angle)) le::put<int16_t>(r + 18, int16_t(std::clamp(std::lround(angle / kScanAngleUnit), -32768L, 32767L)));
        if (!std::isnan(source)) le::put<uint16_t>(r + 20, uint16_t(std::clamp(std::lround(source), 0L, 65535L)));
        if (!std::isnan(gps)) le::put<double>(r + 22, gps);
        if (plan.pointFormat == 7)
            for (int c = 0; c < 3; ++c) {
                const uint16_t v = b.colors[3 * i + size_t(c)];
                le::put<uint16_t>(r + 30 + 2 * c, info.colorBits == 8 ? uint16_t(v * 257) : v);
            }
        return {};
    });
    if (status.ok() && !records.empty() && sc_laz_writer_write(writer, records.data(), records.size() / recordBytes, err, sizeof err) != 0)
        status = failure("write");
    if (status.ok() && written != plan.points)
        status = Status::error(set.describe() + ": the set changed during the export (fewer points than counted)");
    if (status.ok() && sc_laz_writer_finish(writer, err, sizeof err) != 0) status = failure("finish");
    sc_laz_writer_close(writer);
    return status;
}

}  // namespace surfcast
