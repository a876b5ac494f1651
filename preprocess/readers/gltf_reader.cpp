#include "gltf_reader.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <nlohmann/json.hpp>

#include "input_point.h"

namespace surfcast {

// Why not a glTF library: Debian's two both fail here. Its libdraco carries
// its own copy of tinygltf and exports its symbols, which shadow a separate
// libtinygltf's in one process (the two differ in layout: tinygltf's loader
// then ran with Draco's copy and could not read a file). Draco's own glTF
// decoder crashed (a segfault) on a primitive whose indices pass its vertices.
// The JSON goes through nlohmann::json, already a dependency; every index,
// offset and count is checked here.

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// Files and embedded buffers beyond this are refused before they are read.
constexpr uint64_t kMaxBufferBytes = uint64_t(1) << 32;
// The most vertices and triangles a scene's node instances may expand to:
// about 10 GB in OpenMesh's mesh at the bound.
constexpr uint64_t kMaxSceneVertices = uint64_t(1) << 26, kMaxSceneTriangles = uint64_t(1) << 27;

// A 4 x 4 affine transform, column-major as glTF stores it.
using Matrix = std::array<double, 16>;
constexpr Matrix kIdentity{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

Matrix multiply(const Matrix& a, const Matrix& b) {
    Matrix r{};
    for (int c = 0; c < 4; ++c)
        for (int row = 0; row < 4; ++row)
            for (int k = 0; k < 4; ++k) r[c * 4 + row] += a[k * 4 + row] * b[c * 4 + k];
    return r;
}

Vec3d transform(const Matrix& m, const Vec3d& p) {
    return {m[0] * p.x + m[4] * p.y + m[8] * p.z + m[12], m[1] * p.x + m[5] * p.y + m[9] * p.z + m[13],
            m[2] * p.x + m[6] * p.y + m[10] * p.z + m[14]};
}

struct Failure {
    std::string message;
};

class Gltf {
public:
    Gltf(std::string path, json doc, std::vector<uint8_t> glbBin)
        : path_(std::move(path)), doc_(std::move(doc)), glbBin_(std::move(glbBin)) {}
    bool allowOutsidePaths = false;  // external files may lie outside the model's folder

    [[noreturn]] void fail(const std::string& why) const { throw Failure{path_ + ": " + why}; }

    // doc[key] as an array (empty when absent).
    const json& array(const json& object, const char* key) const {
        static const json empty = json::array();
        if (!object.is_object() || !object.contains(key)) return empty;
        if (!object[key].is_array()) fail(std::string("'") + key + "' is not an array");
        return object[key];
    }
    const json& element(const char* key, int64_t index) const {
        const json& a = array(doc_, key);
        if (index < 0 || uint64_t(index) >= a.size() || !a[size_t(index)].is_object())
            fail(std::string("no ") + key + " " + std::to_string(index));
        return a[size_t(index)];
    }
    int64_t integer(const json& object, const char* key, int64_t fallback) const {
        if (!object.contains(key)) return fallback;
        const json& v = object[key];
        if (!v.is_number_integer() && !v.is_number_unsigned()) fail(std::string("'") + key + "' is not an integer");
        return v.get<int64_t>();
    }
    std::vector<double> numbers(const json& object, const char* key, size_t count) const {
        if (!object.contains(key)) return {};
        const json& v = object[key];
        if (!v.is_array() || v.size() != count) fail(std::string("'") + key + "' is not " + std::to_string(count) + " numbers");
        std::vector<double> out;
        for (const json& x : v) {
            if (!x.is_number() || !std::isfinite(x.get<double>())) fail(std::string("'") + key + "' holds a non-number");
            out.push_back(x.get<double>());
        }
        return out;
    }

    // Buffer `index`'s bytes: the .glb's binary chunk, a data URI or a file
    // beside the .gltf. Loaded once each.
    const std::vector<uint8_t>& buffer(int64_t index) {
        auto it = buffers_.find(index);
        if (it != buffers_.end()) return it->second;
        const json& b = element("buffers", index);
        const int64_t length = integer(b, "byteLength", -1);
        if (length < 0 || uint64_t(length) > kMaxBufferBytes) fail("buffer " + std::to_string(index) + ": bad byteLength");
        std::vector<uint8_t> bytes;
        if (!b.contains("uri")) {
            if (index != 0 || glbBin_.empty()) fail("buffer " + std::to_string(index) + " has no uri and no binary chunk");
            bytes = glbBin_;
        } else {
            bytes = resource(b["uri"], "buffer " + std::to_string(index));
        }
        if (bytes.size() < uint64_t(length)) fail("buffer " + std::to_string(index) + " is shorter than its byteLength");
        bytes.resize(size_t(length));
        return buffers_[index] = std::move(bytes);
    }

    // Bytes of buffer view `index`.
    std::span<const uint8_t> view(int64_t index, int64_t* stride = nullptr) {
        const json& v = element("bufferViews", index);
        const std::vector<uint8_t>& data = buffer(integer(v, "buffer", -1));
        const int64_t offset = integer(v, "byteOffset", 0), length = integer(v, "byteLength", -1);
        if (offset < 0 || length < 0 || uint64_t(offset) > data.size() || uint64_t(length) > data.size() - uint64_t(offset))
            fail("buffer view " + std::to_string(index) + " runs past the end of its buffer");
        if (stride) *stride = integer(v, "byteStride", 0);
        return std::span(data).subspan(size_t(offset), size_t(length));
    }

    // A uri's bytes: a base64 data URI, or a file relative to the .gltf.
    std::vector<uint8_t> resource(const json& uri, const std::string& what) {
        if (!uri.is_string()) fail(what + ": uri is not a string");
        const std::string u = uri.get<std::string>();
        if (u.rfind("data:", 0) == 0) {
            const size_t comma = u.find(',');
            if (comma == std::string::npos || !std::string_view(u).substr(0, comma).ends_with(";base64"))
                fail(what + ": a data uri that is not base64");
            return base64(std::string_view(u).substr(comma + 1), what);
        }
        std::string name;  // percent-decoded
        for (size_t i = 0; i < u.size(); ++i) {
            if (u[i] == '%' && i + 2 < u.size() && std::isxdigit(uint8_t(u[i + 1])) && std::isxdigit(uint8_t(u[i + 2]))) {
                name += char(std::stoi(u.substr(i + 1, 2), nullptr, 16));
                i += 2;
            } else {
                name += u[i];
            }
        }
        auto resolved = resolveModelFile(path_, path_, name, allowOutsidePaths);
        if (!resolved) fail(what + ": " + resolved.status().message());
        const std::string& file = *resolved;
        std::error_code ec;
        if (!fs::is_regular_file(file, ec)) fail(what + ": '" + u + "' not found");
        if (fs::file_size(file, ec) > kMaxBufferBytes) fail(what + ": '" + u + "' is over 4 GiB");
        std::ifstream in(file, std::ios::binary);
        return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    }

    std::vector<uint8_t> base64(std::string_view text, const std::string& what) const {
        std::vector<uint8_t> out;
        out.reserve(text.size() / 4 * 3);
        uint32_t bits = 0;
        int count = 0;
        for (char c : text) {
            int v;
            if (c >= 'A' && c <= 'Z') v = c - 'A';
            else if (c >= 'a' && c <= 'z') v = c - 'a' + 26;
            else if (c >= '0' && c <= '9') v = c - '0' + 52;
            else if (c == '+' || c == '-') v = 62;
            else if (c == '/' || c == '_') v = 63;
            else if (c == '=') break;
            else fail(what + ": bad base64 in its data uri");
            bits = (bits << 6) | uint32_t(v);
            if (++count == 4) {
                out.push_back(uint8_t(bits >> 16));
                out.push_back(uint8_t(bits >> 8));
                out.push_back(uint8_t(bits));
                bits = 0;
                count = 0;
            }
        }
        if (count == 3) {
            out.push_back(uint8_t(bits >> 10));
            out.push_back(uint8_t(bits >> 2));
        } else if (count == 2) {
            out.push_back(uint8_t(bits >> 4));
        }
        return out;
    }

    // Accessor `index` as doubles, `components` per element (normalized
    // integers scaled to [0, 1] or [-1, 1]), every byte checked against its view.
    std::vector<double> accessor(int64_t index, int components, const std::string& what) {
        const json& a = element("accessors", index);
        const std::string where = what + " (accessor " + std::to_string(index) + ")";
        if (a.contains("sparse")) fail(where + ": sparse accessors are not supported");
        static const std::map<std::string, int> kComponents{{"SCALAR", 1}, {"VEC2", 2}, {"VEC3", 3}, {"VEC4", 4}};
        const auto type = kComponents.find(a.value("type", std::string()));
        if (type == kComponents.end() || type->second != components)
            fail(where + ": " + std::to_string(components) + " components expected");
        const int64_t componentType = integer(a, "componentType", -1);
        static const std::map<int64_t, int> kSize{{5120, 1}, {5121, 1}, {5122, 2}, {5123, 2}, {5125, 4}, {5126, 4}};
        const auto size = kSize.find(componentType);
        if (size == kSize.end()) fail(where + ": unknown componentType " + std::to_string(componentType));
        const int64_t count = integer(a, "count", -1);
        if (count < 0) fail(where + ": no count");
        const bool normalized = a.value("normalized", false);
        if (count == 0) return {};
        if (!a.contains("bufferView")) fail(where + ": no bufferView");
        int64_t stride = 0;
        const std::span<const uint8_t> bytes = view(integer(a, "bufferView", -1), &stride);
        const uint64_t element = uint64_t(size->second) * uint64_t(components);
        if (stride == 0) stride = int64_t(element);
        const int64_t offset = integer(a, "byteOffset", 0);
        if (stride < int64_t(element) || stride > 252 || offset < 0)
            fail(where + ": bad byteStride or byteOffset");
        if (uint64_t(offset) > bytes.size() || uint64_t(count - 1) > (bytes.size() - uint64_t(offset)) / uint64_t(stride) ||
            uint64_t(offset) + uint64_t(count - 1) * uint64_t(stride) + element > bytes.size())
            fail(where + ": " + std::to_string(count) + " elements do not fit the buffer view");
        std::vector<double> out(size_t(count) * size_t(components));
        for (size_t e = 0; e < size_t(count); ++e)
            for (int c = 0; c < components; ++c) {
                const uint8_t* p = bytes.data() + size_t(offset) + e * size_t(stride) + size_t(c * size->second);
                double v = 0;
                switch (componentType) {
                    case 5126: { float f; std::memcpy(&f, p, 4); v = f; break; }
                    case 5121: v = *p / (normalized ? 255.0 : 1.0); break;
                    case 5120: v = std::max(-1.0, int8_t(*p) / (normalized ? 127.0 : 1.0)); break;
                    case 5123: { uint16_t u; std::memcpy(&u, p, 2); v = u / (normalized ? 65535.0 : 1.0); break; }
                    case 5122: { int16_t i; std::memcpy(&i, p, 2); v = std::max(-1.0, i / (normalized ? 32767.0 : 1.0)); break; }
                    default: { uint32_t u; std::memcpy(&u, p, 4); v = u; break; }
                }
                if (!std::isfinite(v)) fail(where + ": element " + std::to_string(e) + " is NaN or infinite");
                out[e * size_t(components) + size_t(c)] = v;
            }
        return out;
    }

    // The node's local transform: its matrix, or translation · rotation · scale.
    Matrix localTransform(const json& node) const {
        if (auto m = numbers(node, "matrix", 16); !m.empty()) {
            Matrix r;
            std::copy(m.begin(), m.end(), r.begin());
            return r;
        }
        Matrix t = kIdentity, r = kIdentity, s = kIdentity;
        if (auto v = numbers(node, "translation", 3); !v.empty())
            for (int i = 0; i < 3; ++i) t[size_t(12 + i)] = v[size_t(i)];
        if (auto q = numbers(node, "rotation", 4); !q.empty()) {
            const double x = q[0], y = q[1], z = q[2], w = q[3];
            r = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w),     2 * (x * z - y * w),     0,
                 2 * (x * y - z * w),     1 - 2 * (x * x + z * z), 2 * (y * z + x * w),     0,
                 2 * (x * z + y * w),     2 * (y * z - x * w),     1 - 2 * (x * x + y * y), 0,
                 0,                       0,                       0,                       1};
        }
        if (auto v = numbers(node, "scale", 3); !v.empty())
            for (int i = 0; i < 3; ++i) s[size_t(i) * 5] = v[size_t(i)];
        return multiply(t, multiply(r, s));
    }

    const json& doc() const { return doc_; }
    const std::string& path() const { return path_; }

private:
    std::string path_;
    json doc_;
    std::vector<uint8_t> glbBin_;
    std::map<int64_t, std::vector<uint8_t>> buffers_;
};

// The file: JSON, or a .glb's header, JSON chunk and binary chunk.
Gltf open(const std::string& path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) throw Failure{path + ": cannot open"};
    if (fs::file_size(path, ec) > kMaxBufferBytes) throw Failure{path + ": over 4 GiB"};
    std::ifstream in(path, std::ios::binary);
    std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::string text;
    std::vector<uint8_t> bin;
    auto u32 = [&](size_t at) {
        uint32_t v;
        std::memcpy(&v, bytes.data() + at, 4);
        return v;
    };
    if (bytes.size() >= 4 && std::memcmp(bytes.data(), "glTF", 4) == 0) {
        if (bytes.size() < 20) throw Failure{path + ": a .glb shorter than its header"};
        if (u32(4) != 2) throw Failure{path + ": .glb version " + std::to_string(u32(4)) + " (2 is read)"};
        size_t at = 12;
        while (at + 8 <= bytes.size()) {
            const uint64_t length = u32(at);
            const uint32_t kind = u32(at + 4);
            if (length > bytes.size() - at - 8) throw Failure{path + ": .glb chunk at byte " + std::to_string(at) + " runs past the end"};
            const uint8_t* body = bytes.data() + at + 8;
            if (kind == 0x4E4F534A && text.empty()) text.assign(reinterpret_cast<const char*>(body), size_t(length));  // JSON
            else if (kind == 0x004E4942 && bin.empty()) bin.assign(body, body + length);                                // BIN
            at += 8 + size_t(length);
        }
        if (text.empty()) throw Failure{path + ": a .glb without a JSON chunk"};
    } else {
        text.assign(bytes.begin(), bytes.end());
    }
    json doc = json::parse(text, nullptr, false);
    if (doc.is_discarded() || !doc.is_object()) throw Failure{path + ": not glTF (its JSON does not parse to an object)"};
    const json asset = doc.value("asset", json::object());
    if (!asset.is_object() || asset.value("version", std::string()).rfind("2.", 0) != 0)
        throw Failure{path + ": not glTF 2.0 (asset.version)"};
    return Gltf(path, std::move(doc), std::move(bin));
}

}  // namespace

bool isGltfExtension(const std::string& path) {
    const std::string ext = lowerExtension(path);
    return ext == ".gltf" || ext == ".glb";
}

Result<GltfScene> readGltf(const std::string& path, bool allowMissingTextures, bool allowOutsidePaths) try {
    Gltf gltf = open(path);
    gltf.allowOutsidePaths = allowOutsidePaths;
    const json& doc = gltf.doc();
    GltfScene scene;

    // Materials, each base colour texture decoded (with its factor baked in).
    const json& materials = gltf.array(doc, "materials");
    for (size_t i = 0; i < materials.size(); ++i) {
        const json& pbr = materials[i].is_object() ? materials[i].value("pbrMetallicRoughness", json::object()) : json::object();
        GltfMaterial m;
        if (auto f = gltf.numbers(pbr, "baseColorFactor", 4); !f.empty())
            for (int c = 0; c < 3; ++c) m.factor[c] = std::clamp(float(f[size_t(c)]), 0.f, 1.f);
        if (pbr.is_object() && pbr.contains("baseColorTexture")) {
            const std::string what = "material " + std::to_string(i) + " baseColorTexture";
            const json& info = pbr["baseColorTexture"];
            if (!info.is_object()) gltf.fail(what + " is not an object");
            if (gltf.integer(info, "texCoord", 0) != 0)
                scene.warnings.push_back(path + ": " + what + ": uses another TEXCOORD set; TEXCOORD_0 is read");
            const json& texture = gltf.element("textures", gltf.integer(info, "index", -1));
            const int64_t source = gltf.integer(texture, "source", -1);
            const json& image = gltf.element("images", source);
            Result<Texture> decoded = Status::error("no image data");
            try {
                const std::vector<uint8_t> bytes = image.contains("uri") ? gltf.resource(image["uri"], "image " + std::to_string(source))
                                                                         : [&] {
                                                                               auto v = gltf.view(gltf.integer(image, "bufferView", -1));
                                                                               return std::vector<uint8_t>(v.begin(), v.end());
                                                                           }();
                decoded = decodeTexture(bytes, path + ": image " + std::to_string(source));
            } catch (const Failure& f) {
                decoded = Status::error(f.message);
            }
            if (!decoded) {
                if (!allowMissingTextures)
                    gltf.fail(what + ": " + decoded.status().message() +
                              " (with --allow-missing-textures the material keeps its baseColorFactor)");
                scene.warnings.push_back(path + ": " + what + ": " + decoded.status().message() +
                                         "; the material keeps its baseColorFactor");
            } else {
                for (size_t k = 0; k < decoded->rgb.size(); ++k)
                    decoded->rgb[k] = uint8_t(std::lround(decoded->rgb[k] * m.factor[int(k % 3)]));
                m.texture = scene.textures.size();
                scene.textures.push_back(std::move(*decoded));
            }
        }
        scene.materials.push_back(m);
    }
    const uint32_t defaultMaterial = uint32_t(scene.materials.size());
    scene.materials.push_back({});  // primitives without a material: white
    std::map<uint32_t, uint32_t> untexturedOf;  // a textured material's factor-only copy, for primitives without coordinates

    // One primitive in world space.
    auto addPrimitive = [&](const json& prim, const Matrix& world, const std::string& what) {
        if (!prim.is_object()) gltf.fail(what + " is not an object");
        if (gltf.integer(prim, "mode", 4) != 4) {
            scene.warnings.push_back(path + ": " + what + ": not triangles, skipped");
            return;
        }
        const json attributes = prim.value("attributes", json::object());
        if (!attributes.is_object() || !attributes.contains("POSITION")) gltf.fail(what + " has no POSITION");
        const std::vector<double> p = gltf.accessor(gltf.integer(attributes, "POSITION", -1), 3, what + " POSITION");
        const size_t count = p.size() / 3, first = scene.positions.size();
        std::vector<double> uv;
        if (attributes.contains("TEXCOORD_0")) {
            uv = gltf.accessor(gltf.integer(attributes, "TEXCOORD_0", -1), 2, what + " TEXCOORD_0");
            if (uv.size() / 2 != count) gltf.fail(what + ": TEXCOORD_0 and POSITION differ in count");
        }
        uint32_t material = defaultMaterial;
        if (prim.contains("material")) {
            const int64_t m = gltf.integer(prim, "material", -1);
            if (m < 0 || uint64_t(m) >= defaultMaterial) gltf.fail(what + ": no material " + std::to_string(m));
            material = uint32_t(m);
            if (uv.empty() && scene.materials[material].texture) {
                auto [it, added] = untexturedOf.try_emplace(material, uint32_t(scene.materials.size()));
                if (added) scene.materials.push_back({std::nullopt, scene.materials[material].factor});
                material = it->second;
            }
        }
        std::vector<double> indices;
        if (prim.contains("indices")) indices = gltf.accessor(gltf.integer(prim, "indices", -1), 1, what + " indices");
        else
            for (size_t v = 0; v < count; ++v) indices.push_back(double(v));
        for (size_t v = 0; v < count; ++v) {
            scene.positions.push_back(transform(world, {p[3 * v], p[3 * v + 1], p[3 * v + 2]}));
            // glTF's v runs down the image; ours runs up.
            scene.uvs.push_back(uv.empty() ? std::array<float, 2>{0, 0} : std::array<float, 2>{float(uv[2 * v]), float(1 - uv[2 * v + 1])});
        }
        for (size_t k = 0; k + 2 < indices.size(); k += 3) {
            std::array<uint32_t, 3> tri;
            for (int c = 0; c < 3; ++c) {
                const double i = indices[k + size_t(c)];
                if (!(i >= 0 && i < double(count))) {
                    char index[32];
                    std::snprintf(index, sizeof index, "%.0f", i);
                    gltf.fail(what + ": index " + index + " past its " + std::to_string(count) + " vertices");
                }
                tri[size_t(c)] = uint32_t(first + size_t(i));
            }
            if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) continue;  // OpenMesh's add_face asserts on these
            scene.triangles.push_back(tri);
            scene.triangleMaterial.push_back(material);
        }
    };

    // The default scene's nodes, depth first, `each` called on every primitive
    // of every node instance. A node met twice on one path (a cycle) is an
    // error; nodes shared by several parents are instanced each time, up to a
    // bound that keeps a small file from expanding without end.
    constexpr size_t kMaxNodeInstances = 1'000'000;
    using Each = std::function<void(const json& primitive, const Matrix& world, const std::string& what)>;
    const json& nodes = gltf.array(doc, "nodes");
    auto walk = [&](const Each& each) {
        size_t instances = 0;
        std::vector<bool> onPath(nodes.size(), false);
        std::function<void(int64_t, const Matrix&, int)> visit = [&](int64_t n, const Matrix& parent, int depth) {
            const json& node = gltf.element("nodes", n);
            if (onPath[size_t(n)]) gltf.fail("node " + std::to_string(n) + " is its own ancestor");
            if (depth > 256) gltf.fail("nodes nested deeper than 256");
            if (++instances > kMaxNodeInstances) gltf.fail("more than " + std::to_string(kMaxNodeInstances) + " node instances");
            const Matrix world = multiply(parent, gltf.localTransform(node));
            if (node.contains("mesh")) {
                const int64_t m = gltf.integer(node, "mesh", -1);
                const json& primitives = gltf.array(gltf.element("meshes", m), "primitives");
                for (size_t i = 0; i < primitives.size(); ++i)
                    each(primitives[i], world, "mesh " + std::to_string(m) + " primitive " + std::to_string(i));
            }
            onPath[size_t(n)] = true;
            for (const json& child : gltf.array(node, "children")) {
                if (!child.is_number_integer()) gltf.fail("node " + std::to_string(n) + ": a child that is not an index");
                visit(child.get<int64_t>(), world, depth + 1);
            }
            onPath[size_t(n)] = false;
        };
        const json& scenes = gltf.array(doc, "scenes");
        const int64_t sceneIndex = gltf.integer(doc, "scene", 0);
        if (!scenes.empty()) {
            for (const json& root : gltf.array(gltf.element("scenes", sceneIndex), "nodes")) {
                if (!root.is_number_integer()) gltf.fail("scene " + std::to_string(sceneIndex) + ": a node that is not an index");
                visit(root.get<int64_t>(), kIdentity, 0);
            }
        } else {
            for (size_t i = 0; i < nodes.size(); ++i) visit(int64_t(i), kIdentity, 0);  // no scene: every node, as a root
        }
    };
    // What the instances expand to, from the accessors' declared counts,
    // before anything is decoded: about 1 MB of shared nodes can ask for
    // 70 GB. Each vertex takes 32 bytes here and about 150 in OpenMesh's mesh.
    // Checked as it adds up (under the bound, one more count cannot wrap).
    uint64_t vertices = 0, triangles = 0;
    auto declared = [&](int64_t accessor) {
        return uint64_t(std::max<int64_t>(0, gltf.integer(gltf.element("accessors", accessor), "count", 0)));
    };
    walk([&](const json& prim, const Matrix&, const std::string&) {
        if (!prim.is_object() || gltf.integer(prim, "mode", 4) != 4) return;  // addPrimitive says what is wrong
        const json attributes = prim.value("attributes", json::object());
        if (!attributes.is_object() || !attributes.contains("POSITION")) return;
        const uint64_t count = declared(gltf.integer(attributes, "POSITION", -1));
        vertices += count;
        triangles += (prim.contains("indices") ? declared(gltf.integer(prim, "indices", -1)) : count) / 3;
        if (vertices > kMaxSceneVertices || triangles > kMaxSceneTriangles)
            gltf.fail("the scene's node instances expand to over " + std::to_string(kMaxSceneVertices) + " vertices or " +
                      std::to_string(kMaxSceneTriangles) + " triangles, more than a mesh may have");
    });
    walk(addPrimitive);
    if (scene.triangles.empty()) gltf.fail("the scene has no triangles");
    return scene;
} catch (const Failure& f) {
    return Status::error(f.message);
} catch (const json::exception& e) {
    return Status::error(path + ": malformed glTF (" + e.what() + ")");
} catch (const std::exception& e) {  // a check missed above: still an error, never an abort
    return Status::error(path + ": malformed glTF (" + e.what() + ")");
}

}  // namespace surfcast
