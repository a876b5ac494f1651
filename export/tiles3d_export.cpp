#include "tiles3d_export.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <unordered_map>

#include <meshoptimizer.h>
#include <nlohmann/json.hpp>

#include "byte_io.h"
#include "folder_publish.h"
#include "splat_export.h"
#include "tiles3d_implicit.h"

namespace fs = std::filesystem;
using nlohmann::json;

namespace surfcast {

namespace {

constexpr uint32_t kGlbMagic = 0x46546C67;  // "glTF"
constexpr uint32_t kChunkJson = 0x4E4F534A, kChunkBin = 0x004E4942;
constexpr int kFloat = 5126, kUnsignedShort = 5123, kUnsignedByte = 5121, kByte = 5120;
constexpr int kArrayBuffer = 34962, kPoints = 0;
constexpr const char* kGenerator = "surfcast-export";
// Levels per subtree file of an implicit tileset: the fewest bytes, and the
// least an engine reads before its first tile (BENCHMARKS "3D Tiles export").
constexpr int kSubtreeLevels = 3;
// --tiling auto: implicit above this many nodes, where an explicit
// tileset.json (about 250 bytes a node) passes 2.5 MB, all read before an
// engine draws its first tile (BENCHMARKS "3D Tiles export").
constexpr size_t kImplicitAbove = 10000;

double srgbToLinear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// The set's z-up coordinates as glTF's y-up ones (3D Tiles turns them back at load).
Vec3d toYUp(const Vec3d& v) { return toSplatAxes(v, SplatAxes::YUp); }

// A glb under construction: accessors over one binary buffer, one buffer
// view each. With `meshopt`, vertex views are stored compressed by
// meshoptimizer's vertex codec (EXT_meshopt_compression): the view itself
// then lies in a second, data-less buffer that decoders fill in.
class GlbBuilder {
public:
    explicit GlbBuilder(bool meshopt = false) : meshopt_(meshopt) {}

    // A vertex buffer view of `count` elements of `stride` bytes each (a
    // multiple of 4, as glTF and the codec ask); returns its index.
    // `filter`: the meshopt filter `bytes` are encoded for ("NONE" or
    // "OCTAHEDRAL"); without meshopt they must be the filter's decoded form.
    int view(const std::vector<uint8_t>& bytes, size_t count, int stride, const char* filter = "NONE") {
        assert(bytes.size() == count * size_t(stride) && stride % 4 == 0);
        if (!meshopt_) {
            const int v = blobView(bytes);
            views_[size_t(v)]["target"] = kArrayBuffer;
            views_[size_t(v)]["byteStride"] = stride;
            return v;
        }
        meshopt_encodeVertexVersion(0);  // the one EXT_meshopt_compression allows (later releases default to 1)
        std::vector<uint8_t> packed(meshopt_encodeVertexBufferBound(count, size_t(stride)));
        packed.resize(meshopt_encodeVertexBuffer(packed.data(), packed.size(), bytes.data(), count, size_t(stride)));
        views_.push_back({{"buffer", 1}, {"byteOffset", fallback_}, {"byteLength", bytes.size()}, {"byteStride", stride},
                          {"target", kArrayBuffer},
                          {"extensions", {{"EXT_meshopt_compression", {{"buffer", 0}, {"byteOffset", bin_.size()},
                                                                       {"byteLength", packed.size()}, {"byteStride", stride},
                                                                       {"count", count}, {"mode", "ATTRIBUTES"},
                                                                       {"filter", filter}}}}}});
        append(packed);
        fallback_ += bytes.size();  // a multiple of 4: stride is
        return int(views_.size() - 1);
    }
    int accessor(int view, int componentType, bool normalized, const char* type, size_t count) {
        const int a = accessor(componentType, normalized, type, count);
        accessors_[size_t(a)]["bufferView"] = view;
        return a;
    }
    // A view of opaque bytes an extension decodes (no vertex target), at a
    // multiple of `align` bytes (a property table's values align to their
    // component's size).
    int blobView(const std::vector<uint8_t>& bytes, size_t align = 4) {
        bin_.resize((bin_.size() + align - 1) / align * align, 0);
        views_.push_back({{"buffer", 0}, {"byteOffset", bin_.size()}, {"byteLength", bytes.size()}});
        append(bytes);
        return int(views_.size() - 1);
    }
    // An accessor whose data an extension supplies (no buffer view).
    int accessor(int componentType, bool normalized, const char* type, size_t count) {
        json a = {{"componentType", componentType}, {"count", count}, {"type", type}};
        if (normalized) a["normalized"] = true;
        accessors_.push_back(a);
        return int(accessors_.size() - 1);
    }
    json& lastAccessor() { return accessors_.back(); }

    std::vector<uint8_t> finish(json gltf) const {
        gltf["accessors"] = accessors_;
        gltf["bufferViews"] = views_;
        gltf["buffers"] = json::array({{{"byteLength", bin_.size()}}});
        if (meshopt_)
            gltf["buffers"].push_back({{"byteLength", fallback_}, {"extensions", {{"EXT_meshopt_compression", {{"fallback", true}}}}}});
        std::string text = gltf.dump();
        text.resize((text.size() + 3) & ~size_t(3), ' ');
        std::vector<uint8_t> out(12 + 8 + text.size() + 8 + bin_.size());
        uint8_t* p = out.data();
        le::put<uint32_t>(p, kGlbMagic), le::put<uint32_t>(p + 4, 2), le::put<uint32_t>(p + 8, uint32_t(out.size()));
        le::put<uint32_t>(p + 12, uint32_t(text.size())), le::put<uint32_t>(p + 16, kChunkJson);
        std::memcpy(p + 20, text.data(), text.size());
        p += 20 + text.size();
        le::put<uint32_t>(p, uint32_t(bin_.size())), le::put<uint32_t>(p + 4, kChunkBin);
        if (!bin_.empty()) std::memcpy(p + 8, bin_.data(), bin_.size());
        return out;
    }

private:
    void append(const std::vector<uint8_t>& bytes) {
        bin_.insert(bin_.end(), bytes.begin(), bytes.end());
        bin_.resize((bin_.size() + 3) & ~size_t(3), 0);
    }

    bool meshopt_;
    std::vector<uint8_t> bin_;
    size_t fallback_ = 0;  // bytes of the data-less buffer's views
    json views_ = json::array(), accessors_ = json::array();
};

// A glTF of one node (placed by the column-major `matrix`, into glTF's y-up
// axes: CesiumJS's splat tiles read the matrix) holding one mesh of one
// primitive.
json gltfOf(const NodeRecord& node, const json& matrix, const json& primitive, const std::vector<std::string>& used,
            const std::vector<std::string>& required) {
    json gltf;
    gltf["asset"] = {{"version", "2.0"}, {"generator", std::string(kGenerator) + " 0.1.0"}};
    gltf["extensionsUsed"] = used;
    if (!required.empty()) gltf["extensionsRequired"] = required;
    gltf["scene"] = 0;
    gltf["scenes"] = json::array({{{"nodes", {0}}}});
    gltf["nodes"] = json::array({{{"mesh", 0}, {"matrix", matrix}, {"name", node.key.name()}}});
    gltf["meshes"] = json::array({{{"primitives", json::array({primitive})}}});
    return gltf;
}

// The column-major matrix of a translation by `t`.
json translation(const Vec3d& t) { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, t.x, t.y, t.z, 1}; }

// The matrix taking a glb's coordinates, scaled by `scale`, from the set's
// z-up axes to glTF's y-up ones ((x, y, z) to (x, z, -y)), then moved by `t`.
json yUpMatrix(double scale, const Vec3d& t) { return {scale, 0, 0, 0, 0, 0, -scale, 0, 0, scale, 0, 0, t.x, t.y, t.z, 1}; }

template <typename T>
void put(std::vector<uint8_t>& bytes, size_t at, T value) {
    le::put<T>(bytes.data() + at, value);
}

// One attribute of a block as glTF metadata: a property of the class
// "surfel", its values little-endian, `size` bytes each, as `schema` (the
// class property) declares them.
struct MetadataColumn {
    std::string property;   // the property ID
    const char* attribute;  // points: the vertex attribute holding it; nullptr: a property table column
    json schema;
    size_t size;
    std::vector<uint8_t> values;
};

// 3D Metadata's integer type of `bytes` bytes, signed or not.
std::string integerType(bool isSigned, size_t bytes) { return (isSigned ? "INT" : "UINT") + std::to_string(8 * bytes); }

// A column of values v_i (integers), each clamped to the type's range and
// written in its `bytes` little-endian bytes (two's complement where signed).
MetadataColumn integerColumn(std::string property, const char* attribute, bool isSigned, size_t bytes, size_t n,
                             const std::function<double(size_t)>& value) {
    const double span = std::ldexp(1.0, int(8 * bytes)), lo = isSigned ? -span / 2 : 0, hi = (isSigned ? span / 2 : span) - 1;
    MetadataColumn c{std::move(property), attribute, {{"type", "SCALAR"}, {"componentType", integerType(isSigned, bytes)}}, bytes, {}};
    c.values.resize(n * bytes);
    // The 8-byte types' bounds are not doubles: the largest double below them
    // (a cast of a double past the type's range is undefined; NaN writes 0).
    const double below = std::nextafter(hi + 1, 0.0);
    for (size_t i = 0; i < n; ++i) {
        const double r = std::clamp(std::round(value(i)), lo, std::min(hi, below));
        const uint64_t v = std::isnan(r) ? 0 : isSigned ? uint64_t(int64_t(r)) : uint64_t(r);
        for (size_t k = 0; k < bytes; ++k) c.values[i * bytes + k] = uint8_t(v >> (8 * k));
    }
    return c;
}

// A column of doubles (FLOAT64), v_i each.
MetadataColumn float64Column(std::string property, size_t n, const std::function<double(size_t)>& value) {
    MetadataColumn c{std::move(property), nullptr, {{"type", "SCALAR"}, {"componentType", "FLOAT64"}}, sizeof(double), {}};
    c.values.resize(n * sizeof(double));
    for (size_t i = 0; i < n; ++i) le::put<double>(&c.values[i * sizeof(double)], value(i));
    return c;
}


// A property ID (3D Metadata: [A-Za-z_][A-Za-z0-9_]*, unique in its class)
// for an attribute's name: other characters become '_', and a name taken
// already gets a number.
std::string propertyId(const std::string& name, std::set<std::string>& taken) {
    std::string base = name.empty() || std::isdigit(uint8_t(name[0])) ? "_" + name : name;
    for (char& ch : base)
        if (!std::isalnum(uint8_t(ch)) && ch != '_') ch = '_';
    std::string id = base;
    for (int k = 2; taken.count(id); ++k) id = base + "_" + std::to_string(k);
    taken.insert(id);
    return id;
}

// A block's LiDAR and scalar attributes as metadata: the values, never the
// stored codes (value = stored · scale + offset, AttributeInfo).
// - LiDAR attributes: the value in the LAS type the set keeps them in
//   (intensity UINT16, the others UINT8), as points' vertex attributes. The
//   top intensity step's value can pass 65535 by rounding: it clamps, as the
//   LAS export clamps it.
// - Categorical scalars: the value, in the narrowest integer type holding
//   every value the stored bits can give.
// - Continuous scalars: the stored integer, normalized, with the property's
//   `offset` and `scale` (3D Metadata allows them on normalized integers:
//   value = offset + scale · stored / (2^bits − 1)), so the consumer reads
//   the value the set holds in as few bytes as the set keeps it.
// - A wide field, stored as a top part and "<name>:low" (more than 32
//   bits): one FLOAT64 property of the value, stored · scale + offset +
//   low · low's scale, as the LAS export computes it.
// Points keep scalars in a property table: a 32-bit integer is no vertex attribute.
std::vector<MetadataColumn> metadataColumns(const TilesetInfo& info, const BlockData& b) {
    std::vector<MetadataColumn> out;
    std::set<std::string> taken;
    const size_t n = b.size();
    const auto lidar = [&](const char* property, const char* attribute, const auto& codes) {
        if (codes.empty()) return;
        const AttributeInfo* a = info.attribute(property);
        const double scale = a ? a->scale : 1, offset = a ? a->offset : 0;
        taken.insert(property);
        out.push_back(integerColumn(property, attribute, false, sizeof(codes[0]), n, [&](size_t i) { return codes[i] * scale + offset; }));
    };
    lidar("intensity", "_INTENSITY", b.intensity);
    lidar("classification", "_CLASSIFICATION", b.classification);
    lidar("return_number", "_RETURN_NUMBER", b.returnNumber);
    lidar("number_of_returns", "_NUMBER_OF_RETURNS", b.numberOfReturns);
    const auto scalar = [&](const std::string& name) -> const ScalarAttribute* {
        for (const ScalarAttribute& s : b.scalars)
            if (s.name == name && s.values.size() == n) return &s;  // decodeBlock fills every listed one
        return nullptr;
    };
    const size_t suffix = std::strlen(kLowPartSuffix);
    for (const ScalarAttribute& s : b.scalars) {
        const AttributeInfo* a = info.attribute(s.name);
        const bool lowPart = s.name.ends_with(kLowPartSuffix) && info.attribute(s.name.substr(0, s.name.size() - suffix));
        if (!a || s.values.size() != n || lowPart) continue;  // a low part goes with its top part
        const std::string id = propertyId(s.name, taken);
        const double top = std::ldexp(1.0, s.bits) - 1;  // the largest stored integer
        const AttributeInfo* lowInfo = info.attribute(s.name + kLowPartSuffix);
        if (const ScalarAttribute* low = lowInfo ? scalar(s.name + kLowPartSuffix) : nullptr) {
            out.push_back(float64Column(id, n, [&](size_t i) { return s.values[i] * a->scale + a->offset + low->values[i] * lowInfo->scale; }));
        } else if (a->kind == "categorical") {
            // The values span offset .. offset + scale · top.
            const double lo = std::min(a->offset, a->offset + a->scale * top), hi = std::max(a->offset, a->offset + a->scale * top);
            const auto fits = [&](size_t bytes) {
                const double half = std::ldexp(1.0, int(8 * bytes) - 1);
                return lo < 0 ? lo >= -half && hi < half : hi < 2 * half;
            };
            size_t bytes = 1;
            while (bytes < 8 && !fits(bytes)) bytes *= 2;
            out.push_back(integerColumn(id, nullptr, lo < 0, bytes, n, [&](size_t i) { return s.values[i] * a->scale + a->offset; }));
        } else {
            MetadataColumn c = integerColumn(id, nullptr, false, size_t(s.bits / 8), n, [&](size_t i) { return double(s.values[i]); });
            c.schema["normalized"] = true;
            c.schema["offset"] = a->offset;
            c.schema["scale"] = a->scale * top;
            out.push_back(std::move(c));
        }
        if (id != s.name) out.back().schema["name"] = s.name;
    }
    return out;
}

// EXT_structural_metadata's schema of those columns: the class "surfel".
json surfelSchema(const std::vector<MetadataColumn>& columns) {
    json properties;
    for (const MetadataColumn& c : columns) properties[c.property] = c.schema;
    return {{"id", "surfcast"}, {"classes", {{"surfel", {{"properties", properties}}}}}};
}

// The glTF's EXT_structural_metadata for a primitive of n surfels (null
// without columns): the schema, the columns with a vertex attribute as a
// property attribute (their accessors added to `attributes`, each in 4-byte
// slots: glTF aligns every vertex attribute's elements to 4 bytes, and the
// codec takes the padding out), the others as a property table whose rows
// are the surfels' implicit feature IDs, their vertex indices
// (EXT_mesh_features). Sets the primitive's extensions and adds the glTF
// extensions it uses to `used`.
json surfelMetadata(GlbBuilder& glb, const std::vector<MetadataColumn>& columns, size_t n, json& primitive, json& attributes,
                    std::vector<std::string>& used) {
    if (columns.empty()) return nullptr;
    json metadata = {{"schema", surfelSchema(columns)}}, attributeProperties, tableProperties;
    for (const MetadataColumn& c : columns) {
        if (!c.attribute) {
            tableProperties[c.property] = {{"values", glb.blobView(c.values, c.size)}};
            continue;
        }
        assert(c.size == 1 || c.size == 2);
        std::vector<uint8_t> bytes(4 * n, 0);
        for (size_t i = 0; i < n; ++i) std::memcpy(&bytes[4 * i], &c.values[i * c.size], c.size);
        attributes[c.attribute] = glb.accessor(glb.view(bytes, n, 4), c.size == 2 ? kUnsignedShort : kUnsignedByte, false, "SCALAR", n);
        attributeProperties[c.property] = {{"attribute", c.attribute}};
    }
    if (!attributeProperties.is_null()) {
        metadata["propertyAttributes"] = json::array({{{"class", "surfel"}, {"properties", attributeProperties}}});
        primitive["extensions"]["EXT_structural_metadata"] = {{"propertyAttributes", {0}}};
    }
    if (!tableProperties.is_null()) {
        metadata["propertyTables"] = json::array({{{"class", "surfel"}, {"count", n}, {"properties", tableProperties}}});
        primitive["extensions"]["EXT_mesh_features"] = {{"featureIds", json::array({{{"featureCount", n}, {"propertyTable", 0}}})}};
        used.push_back("EXT_mesh_features");
    }
    used.push_back("EXT_structural_metadata");
    return metadata;
}

// The glTF extensions a point tile's glb uses; all but the unlit material and
// the metadata are required (integer positions, compressed views).
std::vector<std::string> pointExtensions(Tiles3dOptions::Compression compression) {
    std::vector<std::string> e = {"KHR_mesh_quantization"};
    if (compression == Tiles3dOptions::Compression::Meshopt) e.push_back("EXT_meshopt_compression");
    return e;
}

// One node's glb: its surfels as points. Positions are the block's own
// integers where they fit 16 bits (KHR_mesh_quantization: the node's matrix
// scales them by the node's position step and places them at its corner),
// so the tile holds exactly the set's positions; deeper ones are float
// offsets from the corner. Normals are 8-bit (KHR_mesh_quantization); every
// vertex view is compressed as `compression` says.
// Adds the extensions it uses to `usedByAll`.
Result<std::vector<uint8_t>> nodeGlb(const TilesetReader& set, const NodeRecord& node, const BlockData& b, const Vec3d& origin,
                                     Tiles3dOptions::Compression compression, std::set<std::string>* usedByAll) {
    const TilesetInfo& info = set.info();
    const size_t n = b.size();
    GlbBuilder glb(compression == Tiles3dOptions::Compression::Meshopt);
    json attributes;

    const double step = positionStep(info, node);
    const bool integers = node.positionBits <= 16;
    const int positionStride = integers ? 8 : 12;  // 3 uint16 and 2 bytes of padding, or 3 floats
    std::vector<uint8_t> positions(size_t(positionStride) * n, 0);
    std::array<uint32_t, 3> lo{UINT32_MAX, UINT32_MAX, UINT32_MAX}, hi{0, 0, 0};
    for (size_t i = 0; i < n; ++i)
        for (size_t a = 0; a < 3; ++a) {
            const uint32_t q = b.positions[3 * i + a];
            if (q >> node.positionBits)  // a block's integers are not range-checked when decoded
                return Status::error("a position exceeds the node's " + std::to_string(node.positionBits) + " bits");
            lo[a] = std::min(lo[a], q), hi[a] = std::max(hi[a], q);
            if (integers) put<uint16_t>(positions, 8 * i + 2 * a, uint16_t(q));
            else put<float>(positions, 12 * i + 4 * a, float(q * step));
        }
    attributes["POSITION"] =
        glb.accessor(glb.view(positions, n, positionStride), integers ? kUnsignedShort : kFloat, false, "VEC3", n);
    const double unit = integers ? 1.0 : step;  // min and max as the accessor holds them (float: as rounded)
    glb.lastAccessor()["min"] = {float(lo[0] * unit), float(lo[1] * unit), float(lo[2] * unit)};
    glb.lastAccessor()["max"] = {float(hi[0] * unit), float(hi[1] * unit), float(hi[2] * unit)};

    if (b.normals.size() == 3 * n) {
        // Octahedral, 8 bits a coordinate (meshopt's filter): 3 signed bytes
        // and one of padding once decoded.
        std::vector<float> unit(4 * n, 0.0f);
        for (size_t i = 0; i < n; ++i) {
            Vec3d v = normalizeOrZero(Vec3d{b.normals[3 * i], b.normals[3 * i + 1], b.normals[3 * i + 2]});
            if (v == Vec3d{}) v = {0, 0, 1};  // glTF's normals are unit vectors
            for (size_t a = 0; a < 3; ++a) unit[4 * i + a] = float(v[int(a)]);
        }
        std::vector<uint8_t> normals(4 * n);
        meshopt_encodeFilterOct(normals.data(), n, 4, 8, unit.data());
        const bool filtered = compression == Tiles3dOptions::Compression::Meshopt;
        if (!filtered) meshopt_decodeFilterOct(normals.data(), n, 4);
        attributes["NORMAL"] = glb.accessor(glb.view(normals, n, 4, filtered ? "OCTAHEDRAL" : "NONE"), kByte, true, "VEC3", n);
    }
    if (info.colorBits > 0 || !b.opacity.empty()) {
        // Linear RGB (glTF's COLOR_0) from the set's sRGB, and the opacity.
        const double top = info.colorBits > 0 ? double((1u << info.colorBits) - 1) : 1.0;
        std::vector<uint8_t> colors(8 * n);
        for (size_t i = 0; i < n; ++i) {
            for (int c = 0; c < 3; ++c) {
                const double srgb = info.colorBits > 0 ? b.colors[3 * i + size_t(c)] / top : 1.0;
                put<uint16_t>(colors, 8 * i + 2 * size_t(c), uint16_t(std::lround(srgbToLinear(srgb) * 65535.0)));
            }
            put<uint16_t>(colors, 8 * i + 6, uint16_t(b.opacity.empty() ? 65535 : b.opacity[i] * 257));
        }
        attributes["COLOR_0"] = glb.accessor(glb.view(colors, n, 8), kUnsignedShort, true, "VEC4", n);
    }

    json primitive = {{"mode", kPoints}, {"material", 0}};
    const std::vector<std::string> required = pointExtensions(compression);
    std::vector<std::string> used = required;
    used.push_back("KHR_materials_unlit");
    const json metadata = surfelMetadata(glb, metadataColumns(info, b), n, primitive, attributes, used);
    primitive["attributes"] = attributes;

    usedByAll->insert(used.begin(), used.end());
    json gltf = gltfOf(node, yUpMatrix(integers ? step : 1.0, toYUp(nodeMin(info, node.key) - origin)), primitive, used, required);
    if (!metadata.is_null()) gltf["extensions"]["EXT_structural_metadata"] = metadata;
    gltf["materials"] = json::array({{{"pbrMetallicRoughness", {{"baseColorFactor", {1, 1, 1, 1}}, {"metallicFactor", 0}}},
                                      {"extensions", {{"KHR_materials_unlit", json::object()}}}}});
    if (!b.opacity.empty()) gltf["materials"][0]["alphaMode"] = "BLEND";  // COLOR_0's alpha is the surfel's opacity
    return glb.finish(gltf);
}

// The extensions a splat tile's glb uses and requires (the SPZ one: its
// accessors have no data of their own).
const std::vector<std::string> kSplatExtensions = {"KHR_gaussian_splatting", "KHR_gaussian_splatting_compression_spz_2"};

// One node's glb as Gaussians about `centre` (world), in SPZ; `extent`: the
// largest |coordinate| about the centre (the tile's box).
Result<std::vector<uint8_t>> splatGlb(const TilesetReader& set, const NodeRecord& node, const BlockData& b, const Vec3d& centre,
                                      double extent, const Vec3d& origin, const GaussianOptions& options, std::set<std::string>* usedByAll) {
    const size_t n = b.size();
    SpzWriter spzWriter(extent);
    Vec3d lo{HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (size_t i = 0; i < n; ++i) {
        const Gaussian g = surfelGaussian(set, node, b, i, centre, options, SplatAxes::YUp);
        spzWriter.add(g);
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], double(g.position[a]));
            hi[a] = std::max(hi[a], double(g.position[a]));
        }
    }
    auto spz = spzWriter.finish();
    if (!spz) return spz.status();

    GlbBuilder glb;
    const int view = glb.blobView(*spz);
    json attributes;
    attributes["POSITION"] = glb.accessor(kFloat, false, "VEC3", n);
    glb.lastAccessor()["min"] = {lo.x, lo.y, lo.z};
    glb.lastAccessor()["max"] = {hi.x, hi.y, hi.z};
    attributes["COLOR_0"] = glb.accessor(kUnsignedByte, true, "VEC4", n);
    attributes["KHR_gaussian_splatting:SCALE"] = glb.accessor(kFloat, false, "VEC3", n);
    attributes["KHR_gaussian_splatting:ROTATION"] = glb.accessor(kFloat, false, "VEC4", n);
    json primitive = {{"mode", kPoints},
                      {"attributes", attributes},
                      {"extensions",
                       {{"KHR_gaussian_splatting",
                         {{"kernel", "ellipse"},
                          {"colorSpace", "srgb_rec709_display"},
                          {"extensions", {{"KHR_gaussian_splatting_compression_spz_2", {{"bufferView", view}}}}}}}}}};
    // The metadata as a property table, a row per splat: every attribute of
    // an SPZ primitive is read from the SPZ (CesiumJS).
    std::vector<std::string> used = kSplatExtensions;
    std::vector<MetadataColumn> columns = metadataColumns(set.info(), b);
    for (MetadataColumn& c : columns) c.attribute = nullptr;
    const json metadata = surfelMetadata(glb, columns, n, primitive, primitive["attributes"], used);
    usedByAll->insert(used.begin(), used.end());
    json gltf = gltfOf(node, translation(toYUp(centre - origin)), primitive, used, kSplatExtensions);  // the Gaussians are y-up already
    if (!metadata.is_null()) gltf["extensions"]["EXT_structural_metadata"] = metadata;
    return glb.finish(gltf);
}

}  // namespace

bool isTiles3dExport(const std::string& folder) {
    std::ifstream in(fs::path(folder) / "tileset.json");
    if (!in) return false;
    const json j = json::parse(in, nullptr, false);
    const json* generator = j.is_object() && j.contains("asset") && j["asset"].is_object() && j["asset"].contains("generator")
                                ? &j["asset"]["generator"]
                                : nullptr;
    return generator && generator->is_string() && generator->get<std::string>().rfind(kGenerator, 0) == 0;
}

Result<Tiles3dReport> writeTiles3d(const TilesetReader& set, const Tiles3dOptions& options, const std::string& output) {
    const TilesetInfo& info = set.info();
    const std::vector<NodeRecord>& nodes = set.nodes();
    if (nodes.empty()) return Status::error(set.describe() + ": the set holds no nodes");
    std::unordered_map<NodeKey, size_t, NodeKeyHash> index;
    for (size_t i = 0; i < nodes.size(); ++i) index[nodes[i].key] = i;
    auto root = index.find(NodeKey{});
    if (root == index.end()) return Status::error(set.describe() + ": the set has no root node");
    // Only over a previous export (its tileset.json names surfcast-export),
    // never over a Surfcast set or another tool's tileset.
    auto folder = PublishedFolder::create(output, "tileset.json", isTiles3dExport, "a 3D Tiles export of surfcast-export");
    if (!folder) return folder.status();
    const Vec3d origin = (info.bounds.min + info.bounds.max) * 0.5;

    // Each node's box (world): its cube cut to the bounds, grown by its
    // position step (splats: by their reach, 3 sigma, if more) and by its
    // descendants' growth (deepest level first, so children come before
    // their parent).
    std::vector<Box3d> boxes(nodes.size());
    std::vector<double> grow(nodes.size(), 0.0);
    std::vector<size_t> byLevel(nodes.size());
    for (size_t i = 0; i < nodes.size(); ++i) byLevel[i] = i;
    std::stable_sort(byLevel.begin(), byLevel.end(), [&](size_t a, size_t b) { return nodes[a].key.level > nodes[b].key.level; });
    for (size_t i : byLevel) {
        const NodeRecord& n = nodes[i];
        const double edge = nodeEdge(info, n.key.level);
        grow[i] = std::max(grow[i], edge / double((uint64_t(1) << n.positionBits) - 1));
        if (options.as == Tiles3dOptions::As::Splats)  // a surfel's radius is at most its node's h
            grow[i] = std::max(grow[i], 3 * options.gaussians.sigmaScale * info.kernelScale * n.spacing);
        if (n.key.level > 0) {
            auto parent = index.find(n.key.parent());
            if (parent != index.end()) grow[parent->second] = std::max(grow[parent->second], grow[i]);
        }
        const Vec3d lo = nodeMin(info, n.key);
        for (int a = 0; a < 3; ++a) {
            boxes[i].min[a] = std::max(lo[a], info.bounds.min[a]) - grow[i];
            boxes[i].max[a] = std::min(lo[a] + edge, info.bounds.max[a]) + grow[i];
        }
    }

    Tiles3dReport report;
    std::set<std::string> contentUses;  // the glTF extensions the tiles' glbs use
    std::error_code ec;
    if (!fs::create_directory(fs::path((*folder)->path()) / "tiles", ec))
        return Status::error((*folder)->path() + "/tiles: cannot create (" + ec.message() + ")");
    for (size_t i = 0; i < nodes.size(); ++i) {
        const NodeRecord& n = nodes[i];
        if (n.surfelCount > 0) {
            auto block = set.readBlock(n, /*scalars=*/true);
            if (!block) return block.status();
            SC_TRY(checkFiniteSurfels(set, n, *block));
            const Vec3d centre = (boxes[i].min + boxes[i].max) * 0.5;
            const Vec3d half = (boxes[i].max - boxes[i].min) * 0.5;
            auto glb = options.as == Tiles3dOptions::As::Splats
                           ? splatGlb(set, n, *block, centre, std::max({half.x, half.y, half.z}), origin, options.gaussians, &contentUses)
                           : nodeGlb(set, n, *block, origin, options.compression, &contentUses);
            if (!glb) return Status::error(set.describe() + ": node " + n.key.name() + ": " + glb.status().message());
            SC_TRY(writeFileSynced((*folder)->path() + "/tiles/" + n.key.name() + ".glb", glb->data(), glb->size()));
            report.points += n.surfelCount;
            report.bytes += glb->size();
        }
        ++report.tiles;
        if (options.progress) options.progress(i + 1, nodes.size());
    }

    // tileset.json: the tree, in the root's frame (the set's, less `origin`):
    // every tile in it, or (implicit) the root with its subtrees' template.
    const auto boxOf = [&](size_t i) -> std::array<double, 12> {
        const Vec3d c = (boxes[i].min + boxes[i].max) * 0.5 - origin, h = (boxes[i].max - boxes[i].min) * 0.5;
        return {c.x, c.y, c.z, h.x, 0, 0, 0, h.y, 0, 0, 0, h.z};
    };
    const bool implicit = options.tiling == Tiles3dOptions::Tiling::Implicit ||
                          (options.tiling == Tiles3dOptions::Tiling::Auto && nodes.size() > kImplicitAbove);
    report.implicit = implicit;
    json r;
    if (implicit) {
        std::vector<ImplicitTile> tiles(nodes.size());
        int levels = 0;
        for (size_t i = 0; i < nodes.size(); ++i) {
            tiles[i] = {nodes[i].key, nodes[i].surfelCount > 0, boxOf(i), double(nodes[i].spacing)};
            levels = std::max(levels, nodes[i].key.level + 1);
        }
        auto bytes = writeImplicitSubtrees(tiles, kSubtreeLevels, (*folder)->path());
        if (!bytes) return Status::error(set.describe() + ": " + bytes.status().message());
        report.bytes += *bytes;
        // The root cube, which implicit tiling divides (each tile's own box is its metadata).
        const double edge = nodeEdge(info, 0);
        const Vec3d c = nodeMin(info, NodeKey{}) + Vec3d{edge, edge, edge} * 0.5 - origin;
        r = {{"boundingVolume", {{"box", {c.x, c.y, c.z, edge / 2, 0, 0, 0, edge / 2, 0, 0, 0, edge / 2}}}},
             {"geometricError", double(nodes[root->second].spacing)},
             {"content", {{"uri", "tiles/{level}-{x}-{y}-{z}.glb"}}},
             {"implicitTiling", implicitTiling(kSubtreeLevels, levels)}};
    } else {
        bool broken = false;  // a child the hierarchy lists but the set lacks (TilesetReader's checks rule it out)
        const auto tile = [&](auto& self, size_t i) -> json {
            const NodeRecord& n = nodes[i];
            json t = {{"boundingVolume", {{"box", boxOf(i)}}}, {"geometricError", double(n.spacing)}};
            if (n.surfelCount > 0) t["content"] = {{"uri", "tiles/" + n.key.name() + ".glb"}};
            json children = json::array();
            for (int c = 0; c < 8; ++c)
                if (n.childMask & (1u << c)) {
                    auto child = index.find(n.key.child(c));
                    if (child == index.end()) {
                        broken = true;
                        continue;
                    }
                    children.push_back(self(self, child->second));
                }
            if (!children.empty()) t["children"] = children;
            return t;
        };
        r = tile(tile, root->second);
        if (broken) return Status::error(set.describe() + ": the hierarchy lists a child node the set does not hold");
    }
    r["refine"] = "REPLACE";
    r["transform"] = translation(origin);
    const double rootError = nodes[root->second].childMask ? 2.0 * nodes[root->second].spacing : nodes[root->second].spacing;
    json tileset = {{"asset", {{"version", "1.1"}, {"generator", std::string(kGenerator) + " 0.1.0"}}},
                    {"geometricError", std::max(rootError, 0.0)},
                    {"root", r}};
    if (implicit) tileset["schema"] = implicitTileSchema();
    if (!info.constants.empty()) {
        // The set's constants (dimensions of one value over the set, in no
        // block) as 3D Tiles 1.1 tileset metadata: properties of the schema's
        // class "set", FLOAT64 (the set keeps a constant as a number without
        // a type, which FLOAT64 holds as it is).
        json& schema = tileset["schema"];
        if (schema.is_null()) schema = {{"id", kTilesetSchemaId}, {"classes", json::object()}};
        json properties, values;
        std::set<std::string> taken;
        for (const ConstantAttribute& c : info.constants) {
            const std::string id = propertyId(c.name, taken);
            properties[id] = {{"type", "SCALAR"}, {"componentType", "FLOAT64"}};
            if (id != c.name) properties[id]["name"] = c.name;
            values[id] = c.value;
        }
        schema["classes"]["set"] = {{"properties", properties}};
        tileset["metadata"] = {{"class", "set"}, {"properties", values}};
    }
    // The glTF extensions the content needs, where engines look for them.
    const bool splats = options.as == Tiles3dOptions::As::Splats;
    tileset["extensionsUsed"] = tileset["extensionsRequired"] = {"3DTILES_content_gltf"};
    tileset["extensions"]["3DTILES_content_gltf"] = {
        {"extensionsUsed", std::vector<std::string>(contentUses.begin(), contentUses.end())},
        {"extensionsRequired", splats ? kSplatExtensions : pointExtensions(options.compression)}};
    const std::string text = tileset.dump();  // compact: 2.7x smaller than indented at 10^8 points (BENCHMARKS "3D Tiles export")
    SC_TRY(writeFileSynced((*folder)->path() + "/tileset.json", text.data(), text.size()));
    report.bytes += text.size();
    SC_TRY((*folder)->publish());
    return report;
}

}  // namespace surfcast
