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
        if (filter.box && !filter.box->intersects(nodeBox(set.info(), n.key))) continue;
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
        auto block = set.readBlock(n, scalars);
        if (!block) return block.status();
        for (size_t i = 0; i < block->size(); ++i) {
            if (!filter.classes.empty() && !keepClass[block->classification.empty() ? 0 : block->classification[i]]) continue;
            const Vec3d p = set.position(n, *block, i);
            if (filter.box && !inside(*filter.box, p)) continue;
            SC_TRY(visit(n, *block, i, p));
        }
    }
    return {};
}

// Point format 6's fields (and 7's colour) of surfel i of block b at p into
// `r` (zeroed, of the format's size); its coordinates' integers in q.
Status fillRecord(uint8_t* r, const LazExportPlan& plan, const TilesetInfo& info, const LasScalars& scalars, const NodeRecord& n,
                  const BlockData& b, size_t i, const Vec3d& p, int32_t q[3]) {
    for (int a = 0; a < 3; ++a) {
        const double v = std::round((p[a] - plan.offset[a]) / plan.scale);
        if (!(v >= -2147483648.0 && v <= 2147483647.0))
            return Status::error("node " + n.key.name() + ": a point outside the bounds the export planned");
        q[a] = int32_t(v);
        le::put<int32_t>(r + 4 * a, q[a]);
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
}

void putText(uint8_t* at, const std::string& text, size_t size) {
    std::memset(at, 0, size);
    std::memcpy(at, text.data(), std::min(text.size(), size));
}

void putVlr(uint8_t* v, const char* user, uint16_t record, size_t bytes, const char* description) {
    putText(v + 2, user, 16);
    le::put<uint16_t>(v + 18, record);
    le::put<uint16_t>(v + 20, uint16_t(bytes));
    putText(v + 22, description, 32);
}

// The LAS 1.4 header and its VLRs: COPC's info VLR first where given (COPC
// wants it there), then the LASzip VLR; `evlrStart` and `evlrs` say where
// extended VLRs follow the point data.
std::vector<uint8_t> lasHeader(const LazExportPlan& plan, const std::vector<uint8_t>& laszipVlr,
                               const std::vector<uint8_t>* copcInfo = nullptr, uint64_t evlrStart = 0, uint32_t evlrs = 0) {
    const size_t recordBytes = plan.pointFormat == 7 ? kRecordBytes7 : kRecordBytes6;
    const size_t copcBytes = copcInfo ? kVlrHeaderBytes + copcInfo->size() : 0;
    std::vector<uint8_t> h(kHeaderBytes + copcBytes + kVlrHeaderBytes + laszipVlr.size(), 0);
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
    le::put<uint32_t>(&h[100], copcInfo ? 2 : 1);   // LASzip's VLR, after COPC's
    h[104] = uint8_t(plan.pointFormat | 0x80);      // bit 7: compressed (LASzip's convention)
    le::put<uint16_t>(&h[105], uint16_t(recordBytes));
    for (int a = 0; a < 3; ++a) {
        le::put<double>(&h[131 + 8 * size_t(a)], plan.scale);
        le::put<double>(&h[155 + 8 * size_t(a)], plan.offset[a]);
        le::put<double>(&h[179 + 16 * size_t(a)], plan.points ? plan.bounds.max[a] : 0);
        le::put<double>(&h[187 + 16 * size_t(a)], plan.points ? plan.bounds.min[a] : 0);
    }
    le::put<uint64_t>(&h[235], evlrStart);
    le::put<uint32_t>(&h[243], evlrs);
    le::put<uint64_t>(&h[247], plan.points);
    uint8_t* v = &h[kHeaderBytes];
    if (copcInfo) {
        putVlr(v, "copc", 1, copcInfo->size(), "COPC info");
        std::memcpy(v + kVlrHeaderBytes, copcInfo->data(), copcInfo->size());
        v += copcBytes;
    }
    putVlr(v, "laszip encoded", 22204, laszipVlr.size(), "by surfcast-export (laz crate)");
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
    // One grid for every export of a set, whatever its box, so that boxes
    // exported apart merge exactly: the LAS scale is the power of ten at or
    // below the finest leaf step (exporting loses less than half of it), the
    // offset the whole numbers below the set's bounds, grown by half the
    // coarsest leaf step, which hold every leaf's positions.
    double finest = HUGE_VAL, coarsest = 0;
    for (const NodeRecord& n : set.nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        const double step = positionStep(info, n);
        finest = std::min(finest, step);
        coarsest = std::max(coarsest, step);
    }
    Box3d all = info.bounds;
    all.min = all.min - Vec3d{1, 1, 1} * (coarsest / 2);
    all.max = all.max + Vec3d{1, 1, 1} * (coarsest / 2);
    plan.scale = std::pow(10.0, std::floor(std::log10(std::clamp(finest, 1e-9, 1e9))));
    for (int a = 0; a < 3; ++a) plan.offset[a] = std::floor(all.min[a]);
    auto fits = [&] {  // every coordinate in LAS's 32-bit integers
        for (int a = 0; a < 3; ++a)
            if ((all.max[a] - plan.offset[a]) / plan.scale > 2147483647.0) return false;
        return true;
    };
    while (!fits()) plan.scale *= 10;

    const bool whole = !filter.box && filter.classes.empty();
    if (whole) {
        // Every leaf whole, no decoding (a third of the export's time,
        // bench/BENCHMARKS.md "LAZ export"): the records count the points,
        // and the grown bounds hold them.
        for (size_t i : plan.nodes) plan.points += set.nodes()[i].surfelCount;
        if (plan.points) plan.bounds = all;
    } else {
        SC_TRY(forEachKept(set, filter, plan.nodes, false, stop, [&](const NodeRecord&, const BlockData&, size_t, const Vec3d& p) -> Status {
            plan.bounds.extend(p);
            ++plan.points;
            return {};
        }));
    }
    if (plan.points == 0) return plan;
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
    if (sc_laz_vlr(uint8_t(plan.pointFormat), 0, 0, vlr, sizeof vlr, &vlrBytes) != 0)
        return Status::error("LAZ: no LASzip VLR for point format " + std::to_string(plan.pointFormat));
    const std::vector<uint8_t> header = lasHeader(plan, std::vector<uint8_t>(vlr, vlr + vlrBytes));
    SC_TRY(out(header.data(), header.size()));

    WriteContext context{&out, {}};
    char err[512] = {};
    ScLazWriter* writer = sc_laz_writer_open(&WriteContext::write, &context, header.size(), uint8_t(plan.pointFormat), 0, 0, err, sizeof err);
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
        int32_t q[3];
        if (Status s = fillRecord(&records[at], plan, info, scalars, n, b, i, p, q); !s) return Status::error(set.describe() + ": " + s.message());
        return {};
    });
    if (status.ok() && !records.empty() && sc_laz_writer_write(writer, records.data(), records.size() / recordBytes, err, sizeof err) != 0)
        status = failure("write");
    if (status.ok() && written != plan.points)
        status = Status::error(set.describe() + ": the set changed during the export (fewer points than counted)");
    if (status.ok() && sc_laz_writer_finish(writer, 1, nullptr, nullptr, nullptr, err, sizeof err) != 0) status = failure("finish");
    sc_laz_writer_close(writer);
    return status;
}

namespace {

// COPC's octree cells per axis of a node's grid: a point goes to the
// shallowest node on its path whose cell it falls in is still empty.
constexpr uint32_t kCopcGrid = 128;
constexpr size_t kCopcInfoBytes = 160, kEvlrHeaderBytes = 60;

// Where the leaves lie in a depth-first walk of the octree (children in
// their index order, x first): the Morton code of each one's cube corner at
// the deepest level. Leaves' cubes do not overlap.
uint64_t depthFirstKey(const NodeKey& k) {
    const int shift = kMaxLevel - k.level;
    return mortonCode(k.x << shift, k.y << shift, k.z << shift);
}

struct FileSink {
    std::FILE* f;
    Status failed;
    static int write(void* ctx, const uint8_t* data, uint64_t len) noexcept {
        auto* self = static_cast<FileSink*>(ctx);
        if (std::fwrite(data, 1, size_t(len), self->f) == size_t(len)) return 0;
        self->failed = Status::error(std::string("cannot write: ") + std::strerror(errno));
        return -1;
    }
};

}  // namespace

Result<CopcReport> writeCopcExport(const TilesetReader& set, const PointFilter& filter, std::FILE* f, const StopExport& stop) {
    const TilesetInfo& info = set.info();
    if (!filter.classes.empty() && !info.attribute("classification"))
        return Status::error(set.describe() + ": the set stores no classification to choose classes by");
    // The layout of a whole set's export (no decoding): the records' scale
    // and offset hold any point of the set; the counts and bounds of the
    // points kept go into the header once they are written.
    auto whole = planLazExport(set, PointFilter{});  // no filter: no decoding
    if (!whole) return whole.status();
    LazExportPlan plan = *whole;
    plan.nodes = reachedLeaves(set, filter);
    std::sort(plan.nodes.begin(), plan.nodes.end(),
              [&](size_t a, size_t b) { return depthFirstKey(set.nodes()[a].key) < depthFirstKey(set.nodes()[b].key); });
    uint8_t vlr[1024];
    size_t vlrBytes = 0;
    if (sc_laz_vlr(uint8_t(plan.pointFormat), 0, 1, vlr, sizeof vlr, &vlrBytes) != 0)
        return Status::error("LAZ: no LASzip VLR for point format " + std::to_string(plan.pointFormat));
    const std::vector<uint8_t> laszip(vlr, vlr + vlrBytes);
    std::vector<uint8_t> copcInfo(kCopcInfoBytes, 0);
    const size_t headerBytes = lasHeader(plan, laszip, &copcInfo).size();
    std::vector<uint8_t> zeros(headerBytes, 0);  // the header, written last
    if (std::fwrite(zeros.data(), 1, zeros.size(), f) != zeros.size()) return Status::error(std::string("cannot write: ") + std::strerror(errno));

    FileSink sink{f, {}};
    char err[512] = {};
    ScLazWriter* writer = sc_laz_writer_open(&FileSink::write, &sink, headerBytes, uint8_t(plan.pointFormat), 0, 1, err, sizeof err);
    if (!writer) return Status::error(std::string("LAZ compressor: ") + err);
    const auto failure = [&](const char* what) {
        return sink.failed.ok() ? Status::error(std::string("LAZ compressor: ") + what + ": " + err) : sink.failed;
    };

    // The hierarchy's entries, in the order their chunks were written; the
    // open chunk's entry is the last.
    struct Entry {
        NodeKey key;
        uint64_t offset = 0, bytes = 0;
        uint32_t points = 0;
    };
    std::vector<Entry> entries;
    // The nodes above the current leaf, root first: the cells taken in each
    // one's grid, and the records of the points it holds.
    struct Open {
        NodeKey key;
        std::vector<uint64_t> taken = std::vector<uint64_t>(kCopcGrid * kCopcGrid * kCopcGrid / 64);
        std::vector<uint8_t> records{};
    };
    std::vector<Open> path;
    const LasScalars scalars = lasScalars(info);
    const size_t recordBytes = plan.pointFormat == 7 ? kRecordBytes7 : kRecordBytes6;
    CopcReport report;
    int32_t lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {INT32_MIN, INT32_MIN, INT32_MIN};
    double gpsMin = HUGE_VAL, gpsMax = -HUGE_VAL;

    auto emit = [&](const NodeKey& key, const std::vector<uint8_t>& records) -> Status {
        if (records.empty()) return {};
        if (!entries.empty()) {
            uint64_t first = 0, bytes = 0;
            if (sc_laz_writer_end_chunk(writer, &first, &bytes, err, sizeof err) != 0) return failure("end of chunk");
            entries.back().offset = first;
            entries.back().bytes = bytes;
        }
        if (sc_laz_writer_write(writer, records.data(), records.size() / recordBytes, err, sizeof err) != 0) return failure("write");
        entries.push_back({key, 0, 0, uint32_t(records.size() / recordBytes)});
        return {};
    };
    std::vector<uint8_t> leafRecords;
    Status status;
    for (size_t index : plan.nodes) {
        const NodeRecord& leaf = set.nodes()[index];
        // Close the open nodes that are not above this leaf (deepest first), open those that are.
        size_t common = 0;
        while (common < path.size() && common < leaf.key.level && path[common].key == leaf.key.ancestor(int(common))) ++common;
        while (status.ok() && path.size() > common) {
            status = emit(path.back().key, path.back().records);
            path.pop_back();
        }
        for (int level = int(path.size()); status.ok() && level < leaf.key.level; ++level) path.push_back(Open{leaf.key.ancestor(level)});
        if (!status.ok()) break;
        leafRecords.clear();
        const std::vector<size_t> one{index};
        status = forEachKept(set, filter, one, scalars.any(), stop, [&](const NodeRecord& n, const BlockData& b, size_t i, const Vec3d& p) -> Status {
            std::vector<uint8_t>* into = &leafRecords;
            for (Open& o : path) {
                const Vec3d min = nodeMin(info, o.key);
                const double cell = nodeEdge(info, o.key.level) / kCopcGrid;
                uint32_t c[3];
                for (int a = 0; a < 3; ++a) c[a] = uint32_t(std::clamp((p[a] - min[a]) / cell, 0.0, double(kCopcGrid - 1)));
                const uint64_t bit = (uint64_t(c[0]) * kCopcGrid + c[1]) * kCopcGrid + c[2];
                if (!(o.taken[bit / 64] >> (bit % 64) & 1)) {
                    o.taken[bit / 64] |= uint64_t(1) << (bit % 64);
                    into = &o.records;
                    break;
                }
            }
            const size_t at = into->size();
            into->resize(at + recordBytes, 0);
            int32_t q[3];
            SC_TRY(fillRecord(&(*into)[at], plan, info, scalars, n, b, i, p, q));
            for (int a = 0; a < 3; ++a) {
                lo[a] = std::min(lo[a], q[a]);
                hi[a] = std::max(hi[a], q[a]);
            }
            const double gps = scalarValue(b, scalars.gpsTime, i);
            if (!std::isnan(gps)) {
                gpsMin = std::min(gpsMin, gps);
                gpsMax = std::max(gpsMax, gps);
            }
            ++report.points;
            return {};
        });
        if (status.ok()) status = emit(leaf.key, leafRecords);
        if (!status.ok()) break;
    }
    while (status.ok() && !path.empty()) {
        status = emit(path.back().key, path.back().records);
        path.pop_back();
    }
    uint64_t lastFirst = 0, lastBytes = 0, table = 0;
    if (status.ok() && sc_laz_writer_finish(writer, 0, &lastFirst, &lastBytes, &table, err, sizeof err) != 0) status = failure("finish");
    sc_laz_writer_close(writer);
    if (!status.ok()) return status;
    if (!entries.empty()) {
        entries.back().offset = lastFirst;
        entries.back().bytes = lastBytes;
    }

    // The hierarchy: one page of every node with points, as an EVLR after the chunk table.
    std::vector<uint8_t> page(entries.size() * 32);
    for (size_t k = 0; k < entries.size(); ++k) {
        uint8_t* e = &page[32 * k];
        le::put<int32_t>(e, entries[k].key.level);
        le::put<int32_t>(e + 4, int32_t(entries[k].key.x));
        le::put<int32_t>(e + 8, int32_t(entries[k].key.y));
        le::put<int32_t>(e + 12, int32_t(entries[k].key.z));
        le::put<uint64_t>(e + 16, entries[k].offset);
        le::put<int32_t>(e + 24, int32_t(entries[k].bytes));
        le::put<int32_t>(e + 28, int32_t(entries[k].points));
    }
    if (std::fseek(f, 0, SEEK_END) != 0) return Status::error(std::string("cannot seek: ") + std::strerror(errno));
    const long evlrStart = std::ftell(f);
    std::vector<uint8_t> evlr(kEvlrHeaderBytes, 0);
    putText(&evlr[2], "copc", 16);
    le::put<uint16_t>(&evlr[18], 1000);
    le::put<uint64_t>(&evlr[20], page.size());
    putText(&evlr[28], "COPC hierarchy", 32);
    evlr.insert(evlr.end(), page.begin(), page.end());
    if (evlrStart < 0 || std::fwrite(evlr.data(), 1, evlr.size(), f) != evlr.size())
        return Status::error(std::string("cannot write: ") + std::strerror(errno));

    // The header, now that the counts, bounds and offsets are known.
    const double half = info.rootEdge / 2;
    for (int a = 0; a < 3; ++a) le::put<double>(&copcInfo[8 * size_t(a)], info.rootMin[a] + half);
    le::put<double>(&copcInfo[24], half);
    le::put<double>(&copcInfo[32], info.rootEdge / kCopcGrid);  // the root's spacing
    le::put<uint64_t>(&copcInfo[40], uint64_t(evlrStart) + kEvlrHeaderBytes);
    le::put<uint64_t>(&copcInfo[48], page.size());
    le::put<double>(&copcInfo[56], gpsMin <= gpsMax ? gpsMin : 0);
    le::put<double>(&copcInfo[64], gpsMin <= gpsMax ? gpsMax : 0);
    plan.points = report.points;
    for (int a = 0; a < 3; ++a) {
        plan.bounds.min[a] = plan.offset[a] + lo[a] * plan.scale;
        plan.bounds.max[a] = plan.offset[a] + hi[a] * plan.scale;
    }
    const std::vector<uint8_t> header = lasHeader(plan, laszip, &copcInfo, uint64_t(evlrStart), 1);
    uint8_t offset[8];
    le::put<uint64_t>(offset, table);
    if (std::fseek(f, 0, SEEK_SET) != 0 || std::fwrite(header.data(), 1, header.size(), f) != header.size() ||
        std::fwrite(offset, 1, 8, f) != 8)  // the chunk table's offset, over its -1
        return Status::error(std::string("cannot write: ") + std::strerror(errno));
    report.nodes = entries.size();
    return report;
}

}  // namespace surfcast
