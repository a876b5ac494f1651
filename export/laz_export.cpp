#include "laz_export.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <ctime>
#include <sstream>

#include "byte_io.h"
#include "las_format.h"
#include "surfcast_laz.h"

namespace surfcast {

namespace {

// LAS 1.4 (ASPRS R15): the header, a VLR's header.
constexpr size_t kHeaderBytes = 375, kVlrHeaderBytes = 54;
// Scan angle's unit in point formats 6-10 (degrees).
constexpr double kScanAngleUnit = 0.006;
// As many Extra Bytes descriptors as a VLR's 16-bit payload size holds; a
// field of the inputs with no descriptor is written as a double.
constexpr size_t kMaxExtraBytesDescriptors = 65535 / las::kDescriptorBytes;
constexpr int kExtraF64 = 10;

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

// The LAS dimensions beyond position and colour, as the LAS reader names them
// (las_reader.h), in this order.
enum Dim {
    kIntensity, kClassification, kReturnNumber, kNumberOfReturns, kScanAngle, kUserData, kPointSourceId, kGpsTime,
    kClassFlags, kScanChannel, kScanDirection, kEdgeOfFlightLine, kNir,
    kWaveIndex, kWaveOffset, kWaveSize, kWaveLocation, kWaveX, kWaveY, kWaveZ, kDimCount
};
constexpr const char* kDimNames[kDimCount] = {
    "intensity", "classification", "return_number", "number_of_returns", "scan_angle", "user_data", "point_source_id", "gps_time",
    "classification_flags", "scan_channel", "scan_direction_flag", "edge_of_flight_line", "nir",
    "wavepacket_index", "wavepacket_offset", "wavepacket_size", "return_point_wave_location", "x_t", "y_t", "z_t"};

// Where a dimension's values come from: a stored attribute (value = stored ·
// scale + offset), the set's constant, or nowhere (the export writes 0).
struct DimSource {
    const AttributeInfo* attribute = nullptr;
    int lidar = -1;       // a LiDAR attribute's index (kLidarAttributes), else a scalar attribute
    int scalar = -1;      // the scalar attribute's index among a block's scalars
    const AttributeInfo* low = nullptr;  // a wide field's low part (docs/FORMAT.md), added
    int lowScalar = -1;
    double constant = 0;
    bool known = false;   // stored or constant
};

// A scalar attribute's index among a block's scalars, which blocks list in tileset.json's order.
int scalarIndexOf(const TilesetInfo& info, const AttributeInfo* a) {
    int k = 0;
    for (const AttributeInfo& b : info.attributes) {
        if (&b == a) break;
        if (!b.kind.empty() && lidarIndex(b.name) < 0 && b.name != kOpacityAttribute) ++k;
    }
    return k;
}

// The values a set gives for the LAS dimensions and its extra bytes.
struct Dimensions {
    DimSource dims[kDimCount];
    std::vector<DimSource> extra;                    // per extra-bytes descriptor
    std::vector<std::vector<uint8_t>> descriptors;   // the Extra Bytes VLR's, in record order
    std::vector<std::string> dropped;                // fields no descriptor could hold
    bool scalars = false;                            // some value comes from a scalar attribute

    bool has(Dim d) const { return dims[d].known; }
    bool anyWave() const { return has(kWaveIndex) || has(kWaveOffset) || has(kWaveSize) || has(kWaveLocation); }
};

std::string descriptorName(const std::vector<uint8_t>& d) { return las::descriptorName(d.data()); }

DimSource sourceOf(const TilesetInfo& info, const std::string& name) {
    DimSource s;
    if (const AttributeInfo* a = info.attribute(name)) {
        s.attribute = a;
        s.lidar = lidarIndex(name);
        s.known = true;
        if (s.lidar < 0) {
            s.scalar = scalarIndexOf(info, a);
            s.low = info.attribute(name + kLowPartSuffix);
            if (s.low) s.lowScalar = scalarIndexOf(info, s.low);
        }
    } else if (const ConstantAttribute* c = info.constant(name)) {
        s.constant = c->value;
        s.known = true;
    }
    return s;
}

Dimensions dimensionsOf(const TilesetInfo& info) {
    Dimensions d;
    for (int k = 0; k < kDimCount; ++k) d.dims[k] = sourceOf(info, kDimNames[k]);
    auto standard = [&](const std::string& name) {
        const bool lowPart = name.ends_with(kLowPartSuffix) && info.attribute(name.substr(0, name.size() - std::strlen(kLowPartSuffix)));
        return lowPart || name == kProvenanceAttribute || name == kOpacityAttribute ||
               std::find_if(std::begin(kDimNames), std::end(kDimNames), [&](const char* n) { return name == n; }) != std::end(kDimNames);
    };
    // The inputs' extra-bytes dimensions the set keeps, as they described them...
    for (const std::vector<uint8_t>& e : info.las.extraBytes) {
        const DimSource s = sourceOf(info, descriptorName(e));
        if (!s.known || standard(descriptorName(e))) continue;
        if (d.descriptors.size() == kMaxExtraBytesDescriptors) {
            d.dropped.push_back(descriptorName(e));
            continue;
        }
        d.descriptors.push_back(e);
        d.extra.push_back(s);
    }
    // ...and any other field of the inputs (PLY, PCD, E57) as a double.
    std::vector<std::string> names;
    for (const AttributeInfo& a : info.attributes)
        if (!a.kind.empty()) names.push_back(a.name);
    for (const ConstantAttribute& c : info.constants) names.push_back(c.name);
    for (const std::string& name : names) {
        const bool described = std::any_of(d.descriptors.begin(), d.descriptors.end(), [&](const auto& e) { return descriptorName(e) == name; });
        if (standard(name) || described) continue;
        // A descriptor names a dimension in 32 bytes; the VLR holds 341 of them.
        if (name.size() > 32 || d.descriptors.size() == kMaxExtraBytesDescriptors) {
            d.dropped.push_back(name);
            continue;
        }
        std::vector<uint8_t> e(las::kDescriptorBytes, 0);
        e[2] = kExtraF64;
        std::memcpy(&e[4], name.data(), name.size());
        d.descriptors.push_back(e);
        d.extra.push_back(sourceOf(info, name));
    }
    for (const DimSource& s : d.dims) d.scalars = d.scalars || s.scalar >= 0;
    for (const DimSource& s : d.extra) d.scalars = d.scalars || s.scalar >= 0;
    return d;
}

// A dimension's value for surfel i of block b.
double valueOf(const DimSource& s, const BlockData& b, size_t i) {
    if (!s.attribute) return s.constant;
    double stored = 0;
    switch (s.lidar) {
    case kLidarIntensity: stored = b.intensity.empty() ? 0 : b.intensity[i]; break;
    case kLidarClassification: stored = b.classification.empty() ? 0 : b.classification[i]; break;
    case kLidarReturnNumber: stored = b.returnNumber.empty() ? 0 : b.returnNumber[i]; break;
    case kLidarNumberOfReturns: stored = b.numberOfReturns.empty() ? 0 : b.numberOfReturns[i]; break;
    default: stored = size_t(s.scalar) < b.scalars.size() ? b.scalars[size_t(s.scalar)].values[i] : 0;
    }
    const double low = s.low && size_t(s.lowScalar) < b.scalars.size() ? b.scalars[size_t(s.lowScalar)].values[i] * s.low->scale : 0;
    return stored * s.attribute->scale + s.attribute->offset + low;
}

// The point format that holds the set's dimensions: the inputs' own where
// they agree on one (so legacy records come back as they were), else the
// LAS 1.4 format of what is stored (COPC: 6, 7 or 8 only, its spec's).
int pointFormatOf(const TilesetInfo& info, const Dimensions& d, bool copc) {
    const bool rgb = info.colorBits != 0, nir = d.has(kNir), wave = d.anyWave();
    const int own = info.las.pointFormat;
    if (!copc && own >= 0) {
        const las::FormatLayout& l = las::kFormats[own];
        if ((l.rgb != 0) == rgb && (l.nir != 0 || !nir) && (l.wave != 0 || !wave)) return own;
    }
    if (copc) return nir ? 8 : rgb ? 7 : 6;
    return wave ? (rgb || nir ? 10 : 9) : nir ? 8 : rgb ? 7 : 6;
}

// What a record at `format` plus the extra bytes holds of the dimensions
// (the export's summary), and what it cannot.
void describeDimensions(const TilesetInfo& info, const Dimensions& d, LazExportPlan* plan) {
    const int f = plan->pointFormat;
    const las::FormatLayout& l = las::kFormats[f];
    for (int k = 0; k < kDimCount; ++k) {
        if (!d.has(Dim(k))) continue;
        const bool held = (k != kGpsTime || l.gps) && (k != kNir || l.nir) && (k != kScanChannel || f >= 6) && (k < kWaveIndex || l.wave);
        (held ? plan->dimensions : plan->leftOut).push_back(kDimNames[k]);
    }
    if (info.colorBits) plan->dimensions.push_back("rgb");
    for (const std::vector<uint8_t>& e : d.descriptors) plan->dimensions.push_back(descriptorName(e));
    for (const std::string& name : d.dropped) plan->leftOut.push_back(name);
    for (const std::string& name : info.leftOut) plan->leftOut.push_back(name);
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

// A value rounded into T's range (a hostile tileset.json's offset may put it
// anywhere: a cast of a double out of range is undefined).
template <class T>
T clamped(double v) {
    if (std::isnan(v)) return T(0);
    return T(std::clamp(std::round(v), double(std::numeric_limits<T>::min()), double(std::numeric_limits<T>::max())));
}
float clampedFloat(double v) { return std::isnan(v) ? NAN : float(std::clamp(v, -double(FLT_MAX), double(FLT_MAX))); }
// uint64's bound is no double: the largest below it is 2^64 - 2048.
uint64_t clampedU64(double v) { return v > 0 ? (v < 0x1p64 ? uint64_t(std::round(v)) : UINT64_MAX) : 0; }  // NaN: 0

// An extra-bytes value as its descriptor stores it: raw = (value - offset) / scale.
void putExtra(uint8_t* at, const std::vector<uint8_t>& e, double v) {
    const int type = e[2], options = e[3];
    if (options & 16) v -= le::get<double>(&e[136]);
    if (options & 8) v /= le::get<double>(&e[112]);
    switch (type) {
    case 1: *at = clamped<uint8_t>(v); break;
    case 2: *at = uint8_t(clamped<int8_t>(v)); break;
    case 3: le::put<uint16_t>(at, clamped<uint16_t>(v)); break;
    case 4: le::put<int16_t>(at, clamped<int16_t>(v)); break;
    case 5: le::put<uint32_t>(at, clamped<uint32_t>(v)); break;
    case 6: le::put<int32_t>(at, clamped<int32_t>(v)); break;
    case 7: le::put<uint64_t>(at, clampedU64(v)); break;
    case 8: le::put<int64_t>(at, v > -0x1p63 ? (v < 0x1p63 ? int64_t(std::round(v)) : INT64_MAX) : INT64_MIN); break;
    case 9: le::put<float>(at, clampedFloat(v)); break;
    default: le::put<double>(at, v); break;
    }
}

// The record of surfel i of block b at p into `r` (zeroed, plan.recordBytes
// long), in the plan's point format (tables 7-17) and extra bytes; its
// coordinates' integers in q.
Status fillRecord(uint8_t* r, const LazExportPlan& plan, const TilesetInfo& info, const Dimensions& d, const NodeRecord& n,
                  const BlockData& b, size_t i, const Vec3d& p, int32_t q[3]) {
    for (int a = 0; a < 3; ++a) {
        const double v = std::round((p[a] - plan.offset[a]) / plan.scale[a]);
        if (!(v >= -2147483648.0 && v <= 2147483647.0))
            return Status::error("node " + n.key.name() + ": a point outside the bounds the export planned");
        q[a] = int32_t(v);
        le::put<int32_t>(r + 4 * a, q[a]);
    }
    auto value = [&](Dim k) { return valueOf(d.dims[k], b, i); };
    auto bit = [&](Dim k, int bits) { return uint8_t(clamped<uint8_t>(value(k)) & ((1 << bits) - 1)); };
    const int f = plan.pointFormat;
    le::put<uint16_t>(r + 12, clamped<uint16_t>(value(kIntensity)));
    // A point of no known return is its pulse's only one.
    const int ret = d.has(kReturnNumber) ? clamped<uint8_t>(value(kReturnNumber)) : 1;
    const int count = d.has(kNumberOfReturns) ? clamped<uint8_t>(value(kNumberOfReturns)) : 1;
    const uint8_t flags = bit(kClassFlags, 4), direction = bit(kScanDirection, 1), edge = bit(kEdgeOfFlightLine, 1);
    if (f < 6) {
        r[14] = uint8_t((ret & 7) | (count & 7) << 3 | direction << 6 | edge << 7);
        r[15] = uint8_t((clamped<uint8_t>(value(kClassification)) & 31) | (flags & 7) << 5);
        r[16] = uint8_t(clamped<int8_t>(value(kScanAngle)));
        r[17] = clamped<uint8_t>(value(kUserData));
        le::put<uint16_t>(r + 18, clamped<uint16_t>(value(kPointSourceId)));
    } else {
        r[14] = uint8_t((ret & 15) | (count & 15) << 4);
        r[15] = uint8_t(flags | bit(kScanChannel, 2) << 4 | direction << 6 | edge << 7);
        r[16] = clamped<uint8_t>(value(kClassification));
        r[17] = clamped<uint8_t>(value(kUserData));
        le::put<int16_t>(r + 18, clamped<int16_t>(value(kScanAngle) / kScanAngleUnit));
        le::put<uint16_t>(r + 20, clamped<uint16_t>(value(kPointSourceId)));
    }
    const las::FormatLayout& l = las::kFormats[f];
    if (l.gps) le::put<double>(r + l.gps, value(kGpsTime));
    if (l.rgb && !b.colors.empty())
        for (int c = 0; c < 3; ++c) {
            const uint16_t v = b.colors[3 * i + size_t(c)];
            le::put<uint16_t>(r + l.rgb + 2 * size_t(c), info.colorBits == 8 ? uint16_t(v * info.las.colorMultiplier) : v);
        }
    if (l.nir) le::put<uint16_t>(r + l.nir, clamped<uint16_t>(value(kNir)));
    if (const size_t w = l.wave) {
        r[w] = clamped<uint8_t>(value(kWaveIndex));
        le::put<uint64_t>(r + w + 1, clampedU64(value(kWaveOffset)));
        le::put<uint32_t>(r + w + 9, clamped<uint32_t>(value(kWaveSize)));
        le::put<float>(r + w + 13, clampedFloat(value(kWaveLocation)));
        le::put<float>(r + w + 17, clampedFloat(value(kWaveX)));
        le::put<float>(r + w + 21, clampedFloat(value(kWaveY)));
        le::put<float>(r + w + 25, clampedFloat(value(kWaveZ)));
    }
    size_t at = l.bytes;
    for (size_t k = 0; k < d.descriptors.size(); ++k) {
        putExtra(r + at, d.descriptors[k], valueOf(d.extra[k], b, i));
        at += las::kTypeBytes[d.descriptors[k][2]];
    }
    return {};
}

void putText(uint8_t* at, const std::string& text, size_t size) {
    std::memset(at, 0, size);
    std::memcpy(at, text.data(), std::min(text.size(), size));
}

// The LAS 1.4 header and its VLRs: COPC's info VLR first where given (COPC
// wants it there), the LASzip VLR, the coordinate system's VLRs and the Extra
// Bytes VLR; `evlrStart` and `evlrs` say where extended VLRs follow the point
// data. The inputs' header fields where the set kept them (LasSourceInfo).
std::vector<uint8_t> lasHeader(const LazExportPlan& plan, const LasSourceInfo& las, const std::vector<uint8_t>& laszipVlr,
                               const std::vector<uint8_t>* copcInfo = nullptr, uint64_t evlrStart = 0, uint32_t evlrs = 0) {
    bool wkt = false, geoTiff = false;
    for (const auto& vlr : las.crsVlrs) (vlr.first == las::kWktRecord ? wkt : geoTiff) = true;
    std::vector<uint8_t> extraBytes;
    for (const std::vector<uint8_t>& e : plan.extraBytes) extraBytes.insert(extraBytes.end(), e.begin(), e.end());
    std::vector<uint8_t> h(kHeaderBytes, 0);
    uint32_t vlrs = 0;
    auto addVlr = [&](const char* user, uint16_t record, const std::vector<uint8_t>& payload, const char* description) {
        const size_t at = h.size();
        h.resize(at + kVlrHeaderBytes + payload.size(), 0);
        putText(&h[at + 2], user, 16);
        le::put<uint16_t>(&h[at + 18], record);
        le::put<uint16_t>(&h[at + 20], uint16_t(payload.size()));
        putText(&h[at + 22], description, 32);
        std::copy(payload.begin(), payload.end(), h.begin() + ptrdiff_t(at + kVlrHeaderBytes));
        ++vlrs;
    };
    if (copcInfo) addVlr("copc", 1, *copcInfo, "COPC info");
    addVlr("laszip encoded", 22204, laszipVlr, "by surfcast-export (laz crate)");
    for (const auto& [record, payload] : las.crsVlrs) addVlr(las::kProjectionUser, record, payload, "coordinate system");
    if (!extraBytes.empty()) addVlr(las::kSpecUser, las::kExtraBytesRecord, extraBytes, "Extra Bytes");

    std::memcpy(h.data(), "LASF", 4);
    // Global encoding: bit 0 the GPS time's type, bit 4 a WKT coordinate
    // system (required for formats 6-10, unless the inputs' is GeoTIFF's).
    const bool wktBit = wkt || (plan.pointFormat >= 6 && !geoTiff);
    le::put<uint16_t>(&h[6], uint16_t((las.gpsTimeType == 1 ? 1u : 0u) | (wktBit ? 1u << 4 : 0u)));
    h[24] = 1;
    h[25] = 4;
    putText(&h[26], las.systemIdentifier.empty() ? "surfcast" : las.systemIdentifier, 32);
    putText(&h[58], "surfcast-export", 32);
    if (las.creationYear >= 0) {
        le::put<uint16_t>(&h[90], uint16_t(las.creationDay));
        le::put<uint16_t>(&h[92], uint16_t(las.creationYear));
    } else {
        const std::time_t now = std::time(nullptr);
        std::tm utc{};
        gmtime_r(&now, &utc);
        le::put<uint16_t>(&h[90], uint16_t(utc.tm_yday + 1));
        le::put<uint16_t>(&h[92], uint16_t(utc.tm_year + 1900));
    }
    le::put<uint16_t>(&h[94], uint16_t(kHeaderBytes));
    le::put<uint32_t>(&h[96], uint32_t(h.size()));  // offset to the point data
    le::put<uint32_t>(&h[100], vlrs);
    h[104] = uint8_t(plan.pointFormat | 0x80);      // bit 7: compressed (LASzip's convention)
    le::put<uint16_t>(&h[105], uint16_t(plan.recordBytes));
    // Formats 0-5 fill the legacy counts too, where they fit (R15, 2.4).
    if (plan.pointFormat < 6 && plan.points <= UINT32_MAX) {
        le::put<uint32_t>(&h[107], uint32_t(plan.points));
        for (size_t k = 0; k < 5; ++k) le::put<uint32_t>(&h[111 + 4 * k], uint32_t(plan.pointsByReturn[k]));
    }
    for (int a = 0; a < 3; ++a) {
        le::put<double>(&h[131 + 8 * size_t(a)], plan.scale[a]);
        le::put<double>(&h[155 + 8 * size_t(a)], plan.offset[a]);
        le::put<double>(&h[179 + 16 * size_t(a)], plan.points ? plan.bounds.max[a] : 0);
        le::put<double>(&h[187 + 16 * size_t(a)], plan.points ? plan.bounds.min[a] : 0);
    }
    le::put<uint64_t>(&h[235], evlrStart);
    le::put<uint32_t>(&h[243], evlrs);
    le::put<uint64_t>(&h[247], plan.points);
    for (size_t k = 0; k < 15; ++k) le::put<uint64_t>(&h[255 + 8 * k], plan.pointsByReturn[k]);
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

namespace {

// The plan of a LAZ export, or (`copc`) the layout alone of a COPC export,
// whose writer counts the points as it goes.
Result<LazExportPlan> planExport(const TilesetReader& set, const PointFilter& filter, bool copc, const StopExport& stop) {
    const TilesetInfo& info = set.info();
    if (!filter.classes.empty() && !info.attribute("classification"))
        return Status::error(set.describe() + ": the set stores no classification to choose classes by");
    LazExportPlan plan;
    plan.nodes = reachedLeaves(set, filter);
    const Dimensions d = dimensionsOf(info);
    plan.pointFormat = pointFormatOf(info, d, copc);
    plan.extraBytes = d.descriptors;
    plan.recordBytes = las::kFormats[plan.pointFormat].bytes;
    for (const std::vector<uint8_t>& e : d.descriptors) plan.recordBytes += las::kTypeBytes[e[2]];
    describeDimensions(info, d, &plan);
    // One grid for every export of a set, whatever its box, so that boxes
    // exported apart merge exactly: the inputs' own LAS lattice where they
    // agree on one (the very coordinates come back), else the power of ten at
    // or below the finest leaf step (exporting loses less than half of it)
    // and the whole numbers below the set's bounds, grown by half the
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
    auto fits = [&] {  // every coordinate in LAS's 32-bit integers
        for (int a = 0; a < 3; ++a)
            if ((all.max[a] - plan.offset[a]) / plan.scale[a] > 2147483647.0 || (all.min[a] - plan.offset[a]) / plan.scale[a] < -2147483648.0)
                return false;
        return true;
    };
    plan.scale = info.las.scale;
    plan.offset = info.las.offset;
    if (!(info.las.scale.x > 0) || !fits()) {
        const double scale = std::pow(10.0, std::floor(std::log10(std::clamp(finest, 1e-9, 1e9))));
        plan.scale = {scale, scale, scale};
        for (int a = 0; a < 3; ++a) plan.offset[a] = std::floor(all.min[a]);
        while (!fits()) plan.scale = plan.scale * 10.0;
    }
    if (copc) return plan;

    // Every leaf whole, no decoding (a third of the export's time,
    // bench/BENCHMARKS.md "LAZ export"), unless the header's counts by
    // return need the points' returns: the records count the points, and the
    // grown bounds hold them.
    const DimSource& returns = d.dims[kReturnNumber];
    const bool whole = !filter.box && filter.classes.empty() && !returns.attribute;
    if (whole) {
        for (size_t i : plan.nodes) plan.points += set.nodes()[i].surfelCount;
        if (plan.points) plan.bounds = all;
        const int only = returns.known ? clamped<uint8_t>(returns.constant) : 1;
        if (only >= 1 && only <= 15) plan.pointsByReturn[only - 1] = plan.points;
    } else {
        SC_TRY(forEachKept(set, filter, plan.nodes, false, stop, [&](const NodeRecord&, const BlockData& b, size_t i, const Vec3d& p) -> Status {
            plan.bounds.extend(p);
            ++plan.points;
            const int r = returns.known ? clamped<uint8_t>(valueOf(returns, b, i)) : 1;
            if (r >= 1 && r <= 15) ++plan.pointsByReturn[r - 1];
            return {};
        }));
    }
    if (plan.points == 0) return plan;
    // The bounds of the integers the records hold: rounding is monotonic, so
    // the points' own bounds round to theirs; grown bounds round outward.
    for (int a = 0; a < 3; ++a) {
        const double lo = (plan.bounds.min[a] - plan.offset[a]) / plan.scale[a], hi = (plan.bounds.max[a] - plan.offset[a]) / plan.scale[a];
        plan.bounds.min[a] = plan.offset[a] + (whole ? std::floor(lo) : double(std::llround(lo))) * plan.scale[a];
        plan.bounds.max[a] = plan.offset[a] + (whole ? std::ceil(hi) : double(std::llround(hi))) * plan.scale[a];
    }
    return plan;
}

}  // namespace

Result<LazExportPlan> planLazExport(const TilesetReader& set, const PointFilter& filter, const StopExport& stop) {
    return planExport(set, filter, false, stop);
}

Status writeLazExport(const TilesetReader& set, const PointFilter& filter, const LazExportPlan& plan,
                      const std::function<Status(const uint8_t*, size_t)>& out, const StopExport& stop) {
    const uint16_t extra = uint16_t(plan.recordBytes - las::kFormats[plan.pointFormat].bytes);
    uint8_t vlr[1024];
    size_t vlrBytes = 0;
    if (sc_laz_vlr(uint8_t(plan.pointFormat), extra, 0, vlr, sizeof vlr, &vlrBytes) != 0)
        return Status::error("LAZ: no LASzip VLR for point format " + std::to_string(plan.pointFormat));
    const TilesetInfo& info = set.info();
    const std::vector<uint8_t> header = lasHeader(plan, info.las, std::vector<uint8_t>(vlr, vlr + vlrBytes));
    SC_TRY(out(header.data(), header.size()));

    WriteContext context{&out, {}};
    char err[512] = {};
    ScLazWriter* writer = sc_laz_writer_open(&WriteContext::write, &context, header.size(), uint8_t(plan.pointFormat), extra, 0, err, sizeof err);
    if (!writer) return Status::error(std::string("LAZ compressor: ") + err);
    const auto failure = [&](const char* what) {
        return context.failed.ok() ? Status::error(std::string("LAZ compressor: ") + what + ": " + err) : context.failed;
    };
    const Dimensions d = dimensionsOf(info);
    const size_t recordBytes = plan.recordBytes;
    std::vector<uint8_t> records;
    uint64_t written = 0;
    const NodeRecord* current = nullptr;
    Status status = forEachKept(set, filter, plan.nodes, d.scalars, stop, [&](const NodeRecord& n, const BlockData& b, size_t i, const Vec3d& p) -> Status {
        if (current != &n && !records.empty()) {  // a block's records at a time
            if (sc_laz_writer_write(writer, records.data(), records.size() / recordBytes, err, sizeof err) != 0) return failure("write");
            records.clear();
        }
        current = &n;
        if (++written > plan.points) return Status::error(set.describe() + ": the set changed during the export (more points than counted)");
        const size_t at = records.size();
        records.resize(at + recordBytes, 0);
        int32_t q[3];
        if (Status s = fillRecord(&records[at], plan, info, d, n, b, i, p, q); !s) return Status::error(set.describe() + ": " + s.message());
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
    // The layout (no decoding): the records' scale and offset hold any point
    // of the set; the counts and bounds of the points kept go into the header
    // once they are written.
    auto layout = planExport(set, filter, true, stop);
    if (!layout) return layout.status();
    LazExportPlan plan = *layout;
    std::sort(plan.nodes.begin(), plan.nodes.end(),
              [&](size_t a, size_t b) { return depthFirstKey(set.nodes()[a].key) < depthFirstKey(set.nodes()[b].key); });
    const uint16_t extra = uint16_t(plan.recordBytes - las::kFormats[plan.pointFormat].bytes);
    uint8_t vlr[1024];
    size_t vlrBytes = 0;
    if (sc_laz_vlr(uint8_t(plan.pointFormat), extra, 1, vlr, sizeof vlr, &vlrBytes) != 0)
        return Status::error("LAZ: no LASzip VLR for point format " + std::to_string(plan.pointFormat));
    const std::vector<uint8_t> laszip(vlr, vlr + vlrBytes);
    std::vector<uint8_t> copcInfo(kCopcInfoBytes, 0);
    const size_t headerBytes = lasHeader(plan, info.las, laszip, &copcInfo).size();
    std::vector<uint8_t> zeros(headerBytes, 0);  // the header, written last
    if (std::fwrite(zeros.data(), 1, zeros.size(), f) != zeros.size()) return Status::error(std::string("cannot write: ") + std::strerror(errno));

    FileSink sink{f, {}};
    char err[512] = {};
    ScLazWriter* writer = sc_laz_writer_open(&FileSink::write, &sink, headerBytes, uint8_t(plan.pointFormat), extra, 1, err, sizeof err);
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
    const Dimensions d = dimensionsOf(info);
    const size_t recordBytes = plan.recordBytes;
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
        status = forEachKept(set, filter, one, d.scalars, stop, [&](const NodeRecord& n, const BlockData& b, size_t i, const Vec3d& p) -> Status {
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
            SC_TRY(fillRecord(&(*into)[at], plan, info, d, n, b, i, p, q));
            for (int a = 0; a < 3; ++a) {
                lo[a] = std::min(lo[a], q[a]);
                hi[a] = std::max(hi[a], q[a]);
            }
            if (d.has(kGpsTime)) {
                const double gps = valueOf(d.dims[kGpsTime], b, i);
                gpsMin = std::min(gpsMin, gps);
                gpsMax = std::max(gpsMax, gps);
            }
            const int r = d.has(kReturnNumber) ? clamped<uint8_t>(valueOf(d.dims[kReturnNumber], b, i)) : 1;
            if (r >= 1 && r <= 15) ++plan.pointsByReturn[r - 1];
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
        plan.bounds.min[a] = plan.offset[a] + lo[a] * plan.scale[a];
        plan.bounds.max[a] = plan.offset[a] + hi[a] * plan.scale[a];
    }
    const std::vector<uint8_t> header = lasHeader(plan, info.las, laszip, &copcInfo, uint64_t(evlrStart), 1);
    uint8_t offset[8];
    le::put<uint64_t>(offset, table);
    if (std::fseek(f, 0, SEEK_SET) != 0 || std::fwrite(header.data(), 1, header.size(), f) != header.size() ||
        std::fwrite(offset, 1, 8, f) != 8)  // the chunk table's offset, over its -1
        return Status::error(std::string("cannot write: ") + std::strerror(errno));
    report.nodes = entries.size();
    report.pointFormat = plan.pointFormat;
    report.dimensions = plan.dimensions;
    report.leftOut = plan.leftOut;
    return report;
}

}  // namespace surfcast
