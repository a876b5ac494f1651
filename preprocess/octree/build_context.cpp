#include "build_context.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <thread>
#include <tuple>

#include "block_codec.h"
#include "las_format.h"
#include "set_reader.h"

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// Leaves of inputs whose precision is unknown (doubles, text) are quantized to
// this fraction of the leaf's cell size.
constexpr double kUnknownPrecisionFraction = 256;
// Float32 coordinates: 24 significant bits.
constexpr double kFloat32Epsilon = 0x1.0p-24;
// A default scan origin farther from the data than this many data extents is ignored.
constexpr double kFarOrigin = 10;
// Data whose height is under this fraction of its width is terrain: normals up.
constexpr double kFlatRatio = 0.25;
// Most bits of a stored scalar field (Draco's integer attributes are 32-bit),
// and of a field stored exactly in two (a double's significand).
constexpr int kMaxScalarBits = 32, kMaxWideScalarBits = 53;

double distanceToBox(const Vec3d& p, const Box3d& b) {
    Vec3d d;
    for (int a = 0; a < 3; ++a) d[a] = std::max({b.min[a] - p[a], 0.0, p[a] - b.max[a]});
    return length(d);
}

}  // namespace

BuildOptions normalizeOptions(BuildOptions o) {
    if (o.threads <= 0) o.threads = int(std::max(1u, std::thread::hardware_concurrency()));
    o.inputs.threads = o.threads;
    // Scalar fields are decoded only when asked for by name.
    if (o.attributes)
        for (const std::string& name : *o.attributes)
            if (lidarIndex(name) < 0 && !o.inputs.scalars.wants(name)) o.inputs.scalars.names.push_back(name);
    // Meshes are read once: the scan keeps them for the passes after it,
    // within half the budget until the plan knows what else it holds.
    if (!o.inputs.meshes) o.inputs.meshes = std::make_shared<MeshStore>((o.memoryBytes - std::min(o.memoryBytes, kBaselineBytes)) / 2);
    return o;
}

Result<std::shared_ptr<const BuildContext>> BuildContext::derive(const BuildOptions& options, InputStats stats, bool report,
                                                                 const BuildContext* set, bool keepLayout) {
    std::shared_ptr<BuildContext> c(new BuildContext);
    c->report_ = report;
    c->opt_ = normalizeOptions(options);
    c->threads_ = c->opt_.threads;
    c->stats_ = std::move(stats);
    if (c->stats_.points == 0)
        return Status::error("the inputs hold no valid points (" + std::to_string(c->stats_.skipped) + " skipped: NaN/Inf or no return)");
    c->chooseRootBox();
    if (set) {
        const Box3d& b = c->stats_.bounds;
        const Vec3d lo = set->rootMin_, hi = lo + Vec3d{1, 1, 1} * set->rootEdge_;
        for (int a = 0; a < 3; ++a)
            if (!(b.min[a] >= lo[a] && b.max[a] < hi[a]))
                return Status::error("internal: the inputs reach beyond the set's root cube on axis " + std::string(1, "xyz"[a]) + " (" +
                                     std::to_string(b.min[a]) + " to " + std::to_string(b.max[a]) + ", the cube " + std::to_string(lo[a]) +
                                     " to " + std::to_string(hi[a]) + "): an update grows the cube before it derives its context");
        c->rootMin_ = set->rootMin_;
        c->rootEdge_ = set->rootEdge_;
    }
    SC_TRY(c->chooseOrientationRules());
    SC_TRY(c->chooseAttributes());
    if (set && keepLayout) {
        // The set's layout, and the provenance attribute where these inputs
        // need it and the set, of one input, has none (update.cpp).
        std::optional<ScalarQuantization> provenance;
        for (const ScalarQuantization& q : c->stored_)
            if (q.provenance && std::none_of(set->stored_.begin(), set->stored_.end(), [](const ScalarQuantization& s) { return s.provenance; }))
                provenance = q;
        c->leafStep_ = set->leafStep_;
        std::copy(std::begin(set->store_), std::end(set->store_), std::begin(c->store_));
        c->storeOpacity_ = set->storeOpacity_;
        c->stored_ = set->stored_;
        c->attributeNames_ = set->attributeNames_;
        c->intensityOffset_ = set->intensityOffset_;
        c->intensityStep_ = set->intensityStep_;
        // The set's constants and its dimensions left out stay; a constant
        // of the inputs the set neither stores nor holds is left out too (one
        // that differs from the set's varies: update.cpp refuses the
        // attribute the set lacks). What the LAS headers agree on is the
        // inputs' own, old and added.
        c->duplicatesKept_ = set->duplicatesKept_;
        auto holds = [&](const std::string& name) {
            const int lidar = lidarIndex(name);
            return lidar >= 0 ? set->store_[lidar]
                              : std::any_of(set->stored_.begin(), set->stored_.end(), [&](const ScalarQuantization& q) { return q.name == name; }) ||
                                    std::any_of(set->constants_.begin(), set->constants_.end(), [&](const ConstantAttribute& o) { return o.name == name; });
        };
        for (const ConstantAttribute& k : c->constants_)
            if (!holds(k.name)) c->leftOut_.push_back(k.name);
        c->constants_ = set->constants_;
        for (const std::string& name : set->leftOut_)
            if (std::find(c->leftOut_.begin(), c->leftOut_.end(), name) == c->leftOut_.end()) c->leftOut_.push_back(name);
        if (provenance) {
            c->stored_.push_back(*provenance);
            c->attributeNames_.push_back(provenance->name);
        }
    }
    c->normals_.mergesCopies = !c->duplicatesKept_;  // (decided by the attributes, the set's where it keeps its layout)
    return std::shared_ptr<const BuildContext>(std::move(c));
}

std::shared_ptr<const BuildContext> BuildContext::rerooted(const BuildContext& c, const Vec3d& rootMin, double rootEdge) {
    std::shared_ptr<BuildContext> r(new BuildContext(c));
    r->rootMin_ = rootMin;
    r->rootEdge_ = rootEdge;
    return r;
}

std::shared_ptr<const BuildContext> BuildContext::withLayoutOf(const BuildContext& c, const TilesetInfo& set) {
    std::shared_ptr<BuildContext> r(new BuildContext(c));
    r->rootMin_ = set.rootMin;
    r->rootEdge_ = set.rootEdge;
    r->attributeNames_.clear();
    for (int i = 0; i < kLidarCount; ++i) {
        r->store_[i] = set.attribute(kLidarAttributes[i]) != nullptr;
        if (r->store_[i]) r->attributeNames_.push_back(kLidarAttributes[i]);
    }
    if (const AttributeInfo* a = set.attribute(kLidarAttributes[kLidarIntensity])) {
        r->intensityOffset_ = int(std::lround(a->offset));
        r->intensityStep_ = std::max(1, int(std::lround(a->scale)));
    }
    r->duplicatesKept_ = set.duplicatesKept;
    r->normals_.mergesCopies = !r->duplicatesKept_;
    r->constants_ = set.constants;
    r->leftOut_ = set.leftOut;
    r->storeOpacity_ = set.attribute(kOpacityAttribute) != nullptr;
    if (r->storeOpacity_) r->attributeNames_.push_back(kOpacityAttribute);
    r->stored_.clear();
    for (const AttributeInfo& a : set.attributes) {
        if (std::find(std::begin(kFixedAttributes), std::end(kFixedAttributes), a.name) != std::end(kFixedAttributes) ||
            lidarIndex(a.name) >= 0 || a.name == kOpacityAttribute)
            continue;
        ScalarQuantization q;
        q.name = a.name;
        q.categorical = a.kind == "categorical";
        q.provenance = a.name == kProvenanceAttribute;
        q.offset = a.offset;
        q.step = a.scale;
        q.bits = a.type == "uint8" ? 8 : a.type == "uint16" ? 16 : 32;
        // A wide field's low part follows its top part (chooseAttributes): a
        // uint32 top part, the low part's offset 0, and a ratio of steps that
        // is 2^1 to 2^21 (53 bits in all). Else the two are fields apart.
        if (!r->stored_.empty() && q.name == r->stored_.back().name + kLowPartSuffix && q.offset == 0 &&
            r->stored_.back().bits == kMaxScalarBits) {
            int exponent = 0;
            const double ratio = std::frexp(r->stored_.back().step / q.step, &exponent);
            if (ratio == 0.5 && exponent - 1 >= 1 && exponent - 1 <= kMaxWideScalarBits - kMaxScalarBits) {
                q.lowPart = true;
                r->stored_.back().lowBits = q.bits = exponent - 1;
            }
        }
        r->stored_.push_back(q);
        r->attributeNames_.push_back(q.name);
    }
    return r;
}

ScalarTable BuildContext::emptyTable() const {
    ScalarTable t;
    for (const ScalarQuantization& q : stored_) t.categorical.push_back(q.categorical);
    return t;
}

uint16_t BuildContext::storedIntensity(uint16_t intensity) const {
    // Clamped: an input without intensity (beside ones with it) reads as 0,
    // below the range of those that carry it.
    return uint16_t(std::clamp(std::lround(double(intensity - intensityOffset_) / intensityStep_), 0l,
                               long(1 << intensityCodeBits(intensityStep_)) - 1));
}

bool BuildContext::anyTexture() const {
    return std::any_of(textureFields_.begin(), textureFields_.end(), [](const auto& f) { return f != nullptr; });
}

bool BuildContext::fitting() const { return opt_.textureFilter == BuildOptions::TextureFilter::Optimal && anyTexture(); }

uint64_t BuildContext::bytesPerChunkPoint() const {
    return kBytesPerChunkPoint + kBytesPerChunkScalar * stored_.size() + (fitting() ? kFitBytesPerChunkPoint : 0);
}

int BuildContext::positionBits(const NodeKey& key, double cell) const {
    const double e = edge(key.level);
    const double step = cell > 0      ? cell / opt_.positionFraction
                        : leafStep_ > 0 ? leafStep_
                                        : e / opt_.grid / kUnknownPrecisionFraction;
    const int bits = int(std::ceil(std::log2(e / step) - 1e-9));
    return std::clamp(bits, 1, kMaxPositionBits);
}

LevelParams BuildContext::levelParams(int level, double fallbackSpacing, int threads) const {
    LevelParams p;
    p.spacingK = opt_.spacingK;
    p.fetchK = opt_.fetchK;
    p.cutoff = opt_.cutoff;
    p.kernelScale = opt_.kernelScale;
    p.radii = opt_.radii;
    p.isolation = opt_.isolation;
    p.levelCell = edge(level) / opt_.grid;
    p.leafCell = std::max(p.levelCell, edge(level) / std::sqrt(double(opt_.capacity)));
    p.fallbackSpacing = fallbackSpacing;
    p.weights = opt_.weights;
    p.threads = threads;
    return p;
}

TilesetInfo BuildContext::tilesetInfo() const {
    TilesetInfo info;
    info.generator = "surfcast-build 0.1.0";
    info.previewStride = opt_.preview;
    info.blockCodec = opt_.blockCodec;
    info.inputPoints = stats_.points;
    info.grid = opt_.grid;
    info.pageDepth = opt_.pageDepth;
    info.rootMin = rootMin_;
    info.rootEdge = rootEdge_;
    info.bounds = stats_.bounds;
    info.colorBits = stats_.colorBits;
    if (inputNames_.size() > 1) info.inputs = inputNames_;
    info.attributes.push_back({"position", "uint32", 3, 0});
    info.attributes.push_back({"normal", "float32", 3, opt_.normalBits});
    if (stats_.colorBits) info.attributes.push_back({"color", stats_.colorBits == 8 ? "uint8" : "uint16", 3, 0});
    if (opt_.weights) info.attributes.push_back({"weight", "float32", 1, BlockCodecOptions{}.weightBits});
    info.attributes.push_back({"radius", "float32", 1, BlockCodecOptions{}.radiusBits});  // only in nodes flagged kFlagHasRadius
    const char* const types[kLidarCount] = {"uint16", "uint8", "uint8", "uint8"};
    for (int i = 0; i < kLidarCount; ++i)
        if (store_[i])
            info.attributes.push_back({kLidarAttributes[i], types[i], 1, 0, i == kLidarIntensity ? "continuous" : "categorical",
                                       i == kLidarIntensity ? double(intensityStep_) : 1.0,
                                       i == kLidarIntensity ? double(intensityOffset_) : 0.0});
    if (storeOpacity_) info.attributes.push_back({kOpacityAttribute, "uint8", 1, 0, "continuous", 1.0 / 255, 0.0});
    for (const ScalarQuantization& q : stored_)
        info.attributes.push_back({q.name, scalarType(q.bits), 1, 0, q.categorical ? "categorical" : "continuous", q.step, q.offset});
    info.constants = constants_;
    info.leftOut = leftOut_;
    info.las = las_;
    info.duplicatesKept = duplicatesKept_;
    info.statistics = statistics();
    info.normalSource = normalSource_;
    info.weights = opt_.weights ? "analytic" : "none";
    info.textureFilter = textureFilter_;
    info.kernelScale = opt_.kernelScale;
    return info;
}

void BuildContext::describe(BuildSummary* summary) const {
    summary->colorBits = stats_.colorBits;
    summary->normalSource = normalSource_;
    summary->textureFilter = textureFilter_;
    summary->attributes = attributeNames_;
    summary->textureBytes = textureBytes_;
}

TilesetStatistics BuildContext::statistics() const {
    TilesetStatistics st;
    st.elevationMin = stats_.bounds.min.z;
    st.elevationMax = stats_.bounds.max.z;
    const AttributeStats& a = stats_.attributes;
    if (store_[kLidarIntensity]) {
        st.intensity = true;
        // The value below which a fraction p of the points lie (the lowest such).
        auto percentile = [&](double p) {
            const uint64_t rank = uint64_t(std::ceil(p * double(a.intensityPoints)));
            uint64_t seen = 0;
            for (size_t v = 0; v < a.intensityHistogram.size(); ++v)
                if ((seen += a.intensityHistogram[v]) >= std::max<uint64_t>(rank, 1)) return double(v);
            return 65535.0;
        };
        st.intensityMin = percentile(0);
        st.intensityMax = percentile(1);
        st.intensityP2 = percentile(0.02);
        st.intensityP98 = percentile(0.98);
    }
    if (store_[kLidarClassification])
        for (int c = 0; c < 256; ++c)
            if (a.classCounts[size_t(c)]) st.classCounts.push_back({c, a.classCounts[size_t(c)]});
    return st;
}

// Which LiDAR attributes the set stores (BuildOptions::attributes), and how
// the intensity is quantized.
Status BuildContext::chooseAttributes() {
    const AttributeStats& a = stats_.attributes;
    auto distinct = [](const std::vector<uint64_t>& histogram, auto key) {
        std::set<int> values;
        for (size_t v = 0; v < histogram.size(); ++v)
            if (histogram[v]) values.insert(key(int(v)));
        return values.size();
    };
    auto self = [](int v) { return v; };
    const bool carried[kLidarCount] = {a.intensityPoints > 0, a.classifiedPoints > 0, a.returnPoints > 0, a.returnPoints > 0};
    // The return number and the number of returns go together (one means
    // little without the other): both are stored where either varies.
    const size_t values[kLidarCount] = {distinct(a.intensityHistogram, self), distinct(a.classCounts, self),
                                        distinct(a.returnsHistogram, self), distinct(a.returnsHistogram, self)};
    for (int i = 0; i < kLidarCount; ++i) store_[i] = carried[i] && (opt_.attributes || values[i] > 1);
    constants_.clear();
    leftOut_.clear();
    // Every dimension asked for (--attributes all): every point too, so the set can stand in for its inputs.
    duplicatesKept_ = opt_.inputs.scalars.all;
    if (opt_.attributes) {
        for (const std::string& name : *opt_.attributes) {
            int i = lidarIndex(name);
            if (i >= 0 && !carried[i] && report_) std::fprintf(stderr, "warning: --attributes %s: no input carries it; not stored\n", name.c_str());
            auto isField = [&](const ScalarStats& f) { return f.field.name == name; };
            if (i < 0 && std::none_of(stats_.scalars.begin(), stats_.scalars.end(), isField))
                return Status::error("--attributes: no input has an attribute '" + name +
                                     "' (LAS/LAZ: intensity, classification, return_number, number_of_returns, scan_angle, "
                                     "user_data, point_source_id, gps_time, nir and the Extra Bytes dimensions; PLY and PCD: "
                                     "their property names)");
        }
        for (int i = 0; i < kLidarCount; ++i)
            store_[i] = store_[i] && std::find(opt_.attributes->begin(), opt_.attributes->end(), kLidarAttributes[i]) !=
                                         opt_.attributes->end();
    }
    // One of the return pair asked for brings the other.
    store_[kLidarReturnNumber] = store_[kLidarNumberOfReturns] = store_[kLidarReturnNumber] || store_[kLidarNumberOfReturns];
    for (int i = 0; i < kLidarCount; ++i)
        if (store_[i]) attributeNames_.push_back(kLidarAttributes[i]);
    // What is carried and not stored: its one value where it has one (the
    // exports write it), else a dimension the set leaves out.
    auto only = [](const std::vector<uint64_t>& histogram) {
        return double(std::find_if(histogram.begin(), histogram.end(), [](uint64_t n) { return n > 0; }) - histogram.begin());
    };
    const double one[kLidarCount] = {only(a.intensityHistogram), only(a.classCounts), double(int(only(a.returnsHistogram)) & 15),
                                     double(int(only(a.returnsHistogram)) >> 4)};
    for (int i = 0; i < kLidarCount; ++i)
        if (carried[i] && !store_[i]) {
            if (values[i] == 1) constants_.push_back({kLidarAttributes[i], one[i]});
            else leftOut_.push_back(kLidarAttributes[i]);
        }
    // Opacity only where some point is translucent: an opaque set carries none.
    storeOpacity_ = a.translucentPoints > 0;
    if (storeOpacity_) attributeNames_.push_back(kOpacityAttribute);
    // Scalar fields (selected by name or with "all": every one found that
    // varies is stored): exact where the range fits a double's significand
    // at the file's own resolution, or for floating-point fields at the
    // finest bit any value sets; else in the finest power-of-two step that
    // fits. Past 32 bits, in two attributes (ScalarQuantization).
    for (const ScalarStats& f : stats_.scalars) {
        // A constant field carries no information per point; stored, it still
        // costs Draco's kd-tree coder, whose cost grows with the dimensions
        // (bench/BENCHMARKS.md, "Attribute bytes"). The set records its value
        // once instead.
        if (!(f.max > f.min)) {
            if (f.points) constants_.push_back({f.field.name, f.min});
            else if (report_) std::fprintf(stderr, "warning: --attributes %s: no valid value across the set; not stored\n", f.field.name.c_str());
            continue;
        }
        ScalarQuantization q;
        q.name = f.field.name;
        q.categorical = f.field.categorical;
        const double range = f.max - f.min;
        const double maxSteps = std::ldexp(1.0, kMaxWideScalarBits) - 1;
        q.offset = f.min;
        q.step = f.field.resolution > 0 ? f.field.resolution : f.finestBit != INT_MAX ? std::ldexp(1.0, f.finestBit) : 0;
        // Steps counted rounded: a range of whole steps of a decimal scale divides to a hair past its count.
        if (!(q.step > 0) || std::round(range / q.step) > maxSteps) q.step = std::exp2(std::ceil(std::log2(range / maxSteps)));
        while (std::round(range / q.step) > maxSteps) q.step *= 2;  // log2 of a hair over a power of two rounds down to it
        const int bits = std::max(1, int(std::ceil(std::log2(std::round(range / q.step) + 1))));
        q.bits = std::min(bits, kMaxScalarBits);
        if (bits > kMaxScalarBits) {
            q.lowBits = bits - kMaxScalarBits;
            ScalarQuantization low = q;
            low.name += kLowPartSuffix;
            low.offset = 0;
            low.bits = q.lowBits;
            low.lowBits = 0;
            low.lowPart = true;
            q.step = std::ldexp(q.step, q.lowBits);
            stored_.push_back(q);
            attributeNames_.push_back(q.name);
            q = low;
        }
        stored_.push_back(q);
        attributeNames_.push_back(q.name);
    }
    // Provenance: where the set holds more than one input, each point's input,
    // in as many bits as their count needs, so that an update can remove an
    // input's points (docs/FORMAT.md, "Provenance").
    inputOfSource_.clear();
    inputNames_.clear();
    for (const SourceStats& src : stats_.sources) {
        const bool scene = src.description.format == "scene";
        if (!scene || inputNames_.empty() || inputNames_[0] != "default scene")
            inputNames_.push_back(scene ? "default scene" : inputName(src.description.path));
        inputOfSource_.push_back(scene ? 0 : uint32_t(inputNames_.size() - 1));
    }
    if (inputNames_.size() > 1) {
        if (std::any_of(stored_.begin(), stored_.end(), [](const ScalarQuantization& q) { return q.name == kProvenanceAttribute; }))
            return Status::error(std::string("--attributes: an input's field '") + kProvenanceAttribute +
                                 "' has the name of the set's provenance attribute; leave it out");
        ScalarQuantization q;
        q.name = kProvenanceAttribute;
        q.categorical = true;
        q.provenance = true;
        q.bits = std::max(1, int(std::ceil(std::log2(double(inputNames_.size())))));
        stored_.push_back(q);
        attributeNames_.push_back(q.name);
    }
    // Intensity as (value - min) / step with the smallest power-of-two step
    // that fits the set's range in kIntensityBits: exact for ranges up to 4096
    // values (Megaplot, autzen, lone-star); a 16-bit range keeps 1/4096 of it,
    // finer than any display maps it (docs/FORMAT.md).
    if (store_[kLidarIntensity]) {
        const TilesetStatistics st = statistics();
        intensityOffset_ = int(st.intensityMin);
        intensityStep_ = 1;
        // Asked for by name (or all): the values themselves.
        const bool exact = opt_.attributes.has_value();
        while (!exact && (st.intensityMax - st.intensityMin) / intensityStep_ >= double(1 << kIntensityBits)) intensityStep_ *= 2;
    }
    // The files' fields the readers did not decode (asked for by no --attributes).
    for (const SourceStats& src : stats_.sources)
        for (const std::string& name : src.description.otherScalars)
            if (std::find(leftOut_.begin(), leftOut_.end(), name) == leftOut_.end()) leftOut_.push_back(name);
    chooseLasSource();
    return {};
}

// What the LAS inputs' headers agree on (LasSourceInfo): a field where they
// differ is left unknown.
void BuildContext::chooseLasSource() {
    las_ = {};
    bool otherInputs = false;
    for (const SourceStats& src : stats_.sources) {
        const LasSourceInfo& l = src.description.las;
        if (!l.present) {
            otherInputs = otherInputs || src.points > 0;
            continue;
        }
        const int multiplier = src.colorMax <= 255 ? 1 : src.colorsTimes256 ? 256 : 257;
        if (!las_.present) {
            las_ = l;
            las_.extraBytes.clear();
            las_.colorMultiplier = multiplier;
        } else {
            if (las_.colorMultiplier != multiplier) las_.colorMultiplier = 257;
            if (las_.pointFormat != l.pointFormat) las_.pointFormat = -1;
            if (las_.gpsTimeType != l.gpsTimeType) las_.gpsTimeType = -1;
            if (las_.systemIdentifier != l.systemIdentifier) las_.systemIdentifier.clear();
            if (las_.generatingSoftware != l.generatingSoftware) las_.generatingSoftware.clear();
            if (las_.creationDay != l.creationDay || las_.creationYear != l.creationYear) las_.creationDay = las_.creationYear = -1;
            if (las_.scale != l.scale || las_.offset != l.offset) las_.scale = las_.offset = {};
            if (las_.crsVlrs != l.crsVlrs) las_.crsVlrs.clear();
        }
        // Each named dimension's first descriptor (the one whose name, type and scale the export writes).
        for (const std::vector<uint8_t>& d : l.extraBytes) {
            const std::string name = las::descriptorName(d.data());
            if (std::none_of(las_.extraBytes.begin(), las_.extraBytes.end(), [&](const auto& e) { return las::descriptorName(e.data()) == name; }))
                las_.extraBytes.push_back(d);
        }
    }
    // Points of other inputs lie on no LAS lattice, nor in a LAS point format.
    if (otherInputs) {
        las_.scale = las_.offset = {};
        las_.pointFormat = -1;
    }
}

// The cubic root box around the points' bounds, and the leaves' quantization step.
void BuildContext::chooseRootBox() {
    // A hair larger than the bounds, so the maximum lies inside.
    const Box3d& b = stats_.bounds;
    double extent = std::max({b.max.x - b.min.x, b.max.y - b.min.y, b.max.z - b.min.z});
    double magnitude = std::max({std::fabs(b.min.x), std::fabs(b.min.y), std::fabs(b.min.z), std::fabs(b.max.x),
                                 std::fabs(b.max.y), std::fabs(b.max.z), 1.0});
    // Identical points have no extent: give them a box a million times their
    // coordinates' resolution.
    rootEdge_ = std::max(extent * (1 + 1e-6), magnitude * 1e-9);
    Vec3d centre = (b.min + b.max) * 0.5;
    rootMin_ = centre - Vec3d{rootEdge_, rootEdge_, rootEdge_} * 0.5;

    bool unknown = false;
    double step = HUGE_VAL;
    for (const SourceStats& s : stats_.sources) {
        const InputDescription& d = s.description;
        double mag = std::max({std::fabs(s.bounds.min.x), std::fabs(s.bounds.min.y), std::fabs(s.bounds.min.z),
                               std::fabs(s.bounds.max.x), std::fabs(s.bounds.max.y), std::fabs(s.bounds.max.z)});
        if (d.precision > 0) step = std::min(step, d.precision);
        else if (d.float32Coordinates) step = std::min(step, mag * kFloat32Epsilon);
        else unknown = true;
    }
    leafStep_ = unknown || !(step > 0) || !std::isfinite(step) ? 0 : step;
}

// The normal-orientation policy of each input (normals.h), deduplicated: inputs
// that orient alike share a rule, so Surfel::source stays 16-bit however many
// inputs there are. An input of several scans (E57) gets a rule per scan,
// consecutive from sourceIds_[input], each toward its own scanner.
Status BuildContext::chooseOrientationRules() {
    const Box3d& b = stats_.bounds;
    normals_.centre = (b.min + b.max) * 0.5 - rootMin_;
    normals_.k = opt_.normalK;
    normals_.spacingK = opt_.spacingK;
    normals_.measure = opt_.radii && opt_.isolation > 0;
    normals_.rules.clear();
    sourceIds_.clear();
    std::map<std::tuple<bool, double, double, double, bool, long>, uint16_t> ruleIds;
    std::vector<std::string> sources;
    for (const SourceStats& s : stats_.sources) {
        const InputDescription& d = s.description;
        const Box3d& sb = s.bounds;
        double sourceExtent = std::max({sb.max.x - sb.min.x, sb.max.y - sb.min.y, sb.max.z - sb.min.z});
        // Airborne LiDAR, and any data much flatter than wide (terrain), face up.
        bool flat = sb.max.z - sb.min.z < kFlatRatio * std::max(sb.max.x - sb.min.x, sb.max.y - sb.min.y);
        const size_t scans = std::max<size_t>(1, d.scanOrigins.size());
        for (size_t scan = 0; scan < scans; ++scan) {
            OrientationRule rule;
            const std::optional<Vec3d> origin = scan < d.scanOrigins.size() ? d.scanOrigins[scan] : std::nullopt;
            // A default scan origin (PCD's 0,0,0) far from the data is no origin.
            bool originUsable = origin && !(d.scanOriginIsDefault && distanceToBox(*origin, sb) > kFarOrigin * sourceExtent);
            if (originUsable) rule.scanOrigin = *origin - rootMin_;
            rule.up = d.airborne || (!originUsable && flat);
            Vec3d o = rule.scanOrigin.value_or(Vec3d{});
            // A textured mesh has a rule of its own: its surfels find their
            // texture by it; so do the scans of a file of several, which
            // find theirs by their order.
            const bool ownRule = (d.textured && opt_.textureFilter != BuildOptions::TextureFilter::Nearest) || scans > 1;
            auto [it, added] = ruleIds.try_emplace({rule.scanOrigin.has_value(), o.x, o.y, o.z, rule.up,
                                                    ownRule ? long(normals_.rules.size()) : -1L},
                                                   uint16_t(normals_.rules.size()));
            if (added) {
                if (normals_.rules.size() > 0xFFFF)
                    return Status::error(d.path + ": more than 65,536 distinct scan origins among the inputs");
                normals_.rules.push_back(rule);
            }
            if (scan == 0) sourceIds_.push_back(it->second);
            std::string name = d.hasNormals ? "input" : orientationName(rule);
            if (std::find(sources.begin(), sources.end(), name) == sources.end()) sources.push_back(name);
        }
    }
    for (size_t i = 0; i < sources.size(); ++i) normalSource_ += (i ? "+" : "") + sources[i];
    // The textured meshes' fields, from the meshes the scan read (whose
    // textures they share).
    textureFields_.assign(normals_.rules.size(), nullptr);
    for (size_t i = 0; i < stats_.sources.size(); ++i) {
        const InputDescription& d = stats_.sources[i].description;
        if (!d.textured) continue;
        textureFilter_ = textureFilterName(opt_.textureFilter);
        if (opt_.textureFilter == BuildOptions::TextureFilter::Nearest) continue;
        auto mesh = readMeshTriangles(d.path, true, opt_.inputs.mesh, opt_.inputs.meshes.get());
        if (!mesh) return mesh.status();
        textureFields_[sourceIds_[i]] = std::make_shared<const TextureField>(*mesh, rootMin_);
        textureBytes_ += textureFields_[sourceIds_[i]]->bytes();
    }
    return {};
}

SampleGrid BuildContext::nodeGrid(const NodeKey& k, std::span<const Surfel> below) const {
    const size_t target = std::max<size_t>(1, below.size() / kLevelReduction);
    // Step j has floor(G / kGridCoarsening^j) cells per axis (one at least), so
    // its cells tile the node and line up with those of the level's other
    // nodes on the same step.
    auto grid = [&](int j) {
        const uint32_t cells = uint32_t(std::max(1.0, std::floor(opt_.grid * std::pow(kGridCoarsening, -j) + 1e-9)));
        return SampleGrid{nodeMinRel(k), edge(k.level) / cells, cells};
    };
    int j = 0;
    for (SampleGrid g = grid(0); g.cells > 1 && occupiedCells(below, g) > target; g = grid(++j)) {
    }
    return grid(j);
}

}  // namespace surfcast
