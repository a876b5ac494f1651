#include "ply_reader.h"

#include <algorithm>
#include <filesystem>
#include <utility>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <sstream>

namespace surfcast {

namespace {

// A header longer than this is not a PLY header but a corrupt or hostile file.
constexpr uint64_t kMaxPlyHeaderBytes = 1 << 20;

bool parseType(const std::string& s, PlyType* t) {
    static const std::pair<const char*, PlyType> kNames[] = {
        {"char", PlyType::Int8},     {"int8", PlyType::Int8},       {"uchar", PlyType::UInt8},
        {"uint8", PlyType::UInt8},   {"short", PlyType::Int16},     {"int16", PlyType::Int16},
        {"ushort", PlyType::UInt16}, {"uint16", PlyType::UInt16},   {"int", PlyType::Int32},
        {"int32", PlyType::Int32},   {"uint", PlyType::UInt32},     {"uint32", PlyType::UInt32},
        {"float", PlyType::Float32}, {"float32", PlyType::Float32}, {"double", PlyType::Float64},
        {"float64", PlyType::Float64}};
    for (auto [name, type] : kNames)
        if (s == name) { *t = type; return true; }
    return false;
}

size_t typeSize(PlyType t) {
    switch (t) {
        case PlyType::Int8: case PlyType::UInt8: return 1;
        case PlyType::Int16: case PlyType::UInt16: return 2;
        case PlyType::Int32: case PlyType::UInt32: case PlyType::Float32: return 4;
        case PlyType::Float64: return 8;
    }
    return 0;
}

// Reads one value of any PLY type, ascii or binary, as a double.
class ValueReader {
public:
    ValueReader(ByteStream& in, PlyHeader::Format format) : in_(in), format_(format) {}

    Status read(PlyType type, double* out) {
        if (format_ == PlyHeader::Format::Ascii) {
            std::string_view tok;
            if (!in_.readToken(&tok)) return Status::error(in_.atLine() + ": unexpected end of file in the data");
            const char* end = tok.data() + tok.size();
            auto [ptr, ec] = std::from_chars(tok.data(), end, *out);
            if (ec != std::errc() || ptr != end) {
                // from_chars rejects "nan"/"inf" spellings some writers use; accept them.
                std::string s(tok);
                char* stop = nullptr;
                *out = std::strtod(s.c_str(), &stop);
                if (stop != s.c_str() + s.size())
                    return Status::error(in_.atLine() + ": '" + s + "' is not a number");
            }
            return {};
        }
        uint8_t bytes[8];
        size_t n = typeSize(type);
        if (!in_.readBytes(bytes, n)) return Status::error(in_.at() + ": file ends inside the binary data");
        bool swap = (format_ == PlyHeader::Format::BinaryBig) != (std::endian::native == std::endian::big);
        if (swap) std::reverse(bytes, bytes + n);
        switch (type) {
            case PlyType::Int8: *out = double(int8_t(bytes[0])); break;
            case PlyType::UInt8: *out = double(bytes[0]); break;
            case PlyType::Int16: { int16_t v; std::memcpy(&v, bytes, 2); *out = v; break; }
            case PlyType::UInt16: { uint16_t v; std::memcpy(&v, bytes, 2); *out = v; break; }
            case PlyType::Int32: { int32_t v; std::memcpy(&v, bytes, 4); *out = v; break; }
            case PlyType::UInt32: { uint32_t v; std::memcpy(&v, bytes, 4); *out = v; break; }
            case PlyType::Float32: { float v; std::memcpy(&v, bytes, 4); *out = v; break; }
            case PlyType::Float64: std::memcpy(out, bytes, 8); break;
        }
        return {};
    }

    // Reads a whole element instance: scalars into `scalars` (one per scalar
    // property, in order), the first list property into `list`.
    // One element instance: its scalar properties in order, and each list
    // property's items in its own vector (lists: one per list property, in order).
    Status readInstance(const PlyElement& e, std::vector<double>* scalars, std::vector<std::vector<double>>* lists) {
        scalars->clear();
        size_t l = 0;
        for (const PlyProperty& p : e.properties) {
            double v = 0;
            if (!p.isList) {
                SC_TRY(read(p.type, &v));
                scalars->push_back(v);
                continue;
            }
            double count = 0;
            SC_TRY(read(p.countType, &count));
            if (!(count >= 0) || count > kMaxListLength)
                return Status::error(in_.at() + ": list length " + std::to_string(count) + " out of range");
            std::vector<double>* list = nullptr;
            if (lists) {
                if (lists->size() <= l) lists->resize(l + 1);
                list = &(*lists)[l++];
                list->clear();
            }
            for (size_t i = 0; i < size_t(count); ++i) {
                SC_TRY(read(p.type, &v));
                if (list) list->push_back(v);
            }
        }
        return {};
    }

private:
    // A face list longer than this is a corrupt count, not a polygon; a strips
    // list is one element and can be long, so the cap is generous.
    static constexpr double kMaxListLength = 1u << 28;
    ByteStream& in_;
    PlyHeader::Format format_;
};

int findProperty(const PlyElement& e, std::initializer_list<const char*> names) {
    for (size_t i = 0; i < e.properties.size(); ++i)
        for (const char* n : names)
            if (!e.properties[i].isList && e.properties[i].name == n) return int(i);
    return -1;
}

// Index of each scalar property within the scalars vector ValueReader fills.
std::vector<int> scalarSlots(const PlyElement& e) {
    std::vector<int> slots(e.properties.size(), -1);
    int next = 0;
    for (size_t i = 0; i < e.properties.size(); ++i)
        if (!e.properties[i].isList) slots[i] = next++;
    return slots;
}

// Scale to the 16-bit channel range: uchar *257, ushort as is, float in [0,1] *65535.
uint16_t toChannel(double v, PlyType t) {
    double scaled = t == PlyType::UInt8 || t == PlyType::Int8 ? v * 257.0
                    : (t == PlyType::Float32 || t == PlyType::Float64) ? v * 65535.0
                                                                       : v;
    return saturate16(scaled);
}

struct VertexLayout {
    int x = -1, y = -1, z = -1, nx = -1, ny = -1, nz = -1, r = -1, g = -1, b = -1, intensity = -1, classification = -1, alpha = -1;
    PlyType colorType = PlyType::UInt8, intensityType = PlyType::UInt16, alphaType = PlyType::UInt8;
    std::vector<int> scalars;  // slots of the selected scalar fields (InputDescription::scalars)
};

Result<VertexLayout> vertexLayout(const PlyElement& e, const std::string& path, const ScalarSelection& selection,
                                  std::vector<ScalarField>* fields) {
    VertexLayout l;
    auto slots = scalarSlots(e);
    auto slot = [&](std::initializer_list<const char*> names) {
        int i = findProperty(e, names);
        return i < 0 ? -1 : slots[i];
    };
    l.x = slot({"x"}); l.y = slot({"y"}); l.z = slot({"z"});
    if (l.x < 0 || l.y < 0 || l.z < 0) return Status::error(path + ": vertex element lacks x, y or z");
    l.nx = slot({"nx", "normal_x"}); l.ny = slot({"ny", "normal_y"}); l.nz = slot({"nz", "normal_z"});
    if (l.nx < 0 || l.ny < 0 || l.nz < 0) l.nx = l.ny = l.nz = -1;
    int ri = findProperty(e, {"red", "r", "diffuse_red"});
    l.r = slot({"red", "r", "diffuse_red"}); l.g = slot({"green", "g", "diffuse_green"}); l.b = slot({"blue", "b", "diffuse_blue"});
    if (l.r < 0 || l.g < 0 || l.b < 0) l.r = l.g = l.b = -1;
    else l.colorType = e.properties[ri].type;
    int ii = findProperty(e, {"intensity", "scalar_intensity"});
    if (ii >= 0) { l.intensity = slots[ii]; l.intensityType = e.properties[ii].type; }
    l.classification = slot({"classification", "scalar_classification", "label", "class"});
    int ai = findProperty(e, {"alpha", "opacity", "diffuse_alpha"});
    if (ai >= 0) { l.alpha = slots[ai]; l.alphaType = e.properties[ai].type; }
    const int taken[] = {l.x, l.y, l.z, l.nx, l.ny, l.nz, l.r, l.g, l.b, l.intensity, l.classification, l.alpha};
    for (size_t i = 0; i < e.properties.size(); ++i) {
        const PlyProperty& p = e.properties[i];
        if (p.isList || std::find(std::begin(taken), std::end(taken), slots[i]) != std::end(taken) || !selection.wants(p.name))
            continue;
        const bool floating = p.type == PlyType::Float32 || p.type == PlyType::Float64;
        fields->push_back({p.name, false, floating ? 0.0 : 1.0});
        l.scalars.push_back(slots[i]);
    }
    return l;
}

const PlyElement* findElement(const PlyHeader& h, const char* name) {
    for (const auto& e : h.elements)
        if (e.name == name) return &e;
    return nullptr;
}

class PlyPointReader final : public PointReader {
public:
    PlyPointReader(ByteStream in, PlyHeader header, VertexLayout layout, const PlyElement* vertex, std::vector<ScalarField> fields)
        : in_(std::move(in)), header_(std::move(header)), layout_(layout), values_(in_, header_.format) {
        desc_.scalars = std::move(fields);
        vertex_ = findElement(header_, vertex->name.c_str());
        desc_.path = in_.path();
        desc_.format = "ply";
        desc_.declaredPoints = vertex_->count;
        desc_.hasNormals = layout_.nx >= 0;
        desc_.hasColors = layout_.r >= 0;
        desc_.hasIntensity = layout_.intensity >= 0;
        desc_.hasClassification = layout_.classification >= 0;
        desc_.colorBits = layout_.colorType == PlyType::UInt8 || layout_.colorType == PlyType::Int8 ? 8 : 16;
        const PlyProperty& px = vertex_->properties[findProperty(*vertex_, {"x"})];
        desc_.float32Coordinates = px.type == PlyType::Float32;
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        if (!started_) {
            started_ = true;
            // Skip elements stored before the vertices.
            for (const auto& e : header_.elements) {
                if (&e == vertex_) break;
                for (uint64_t i = 0; i < e.count; ++i) SC_TRY(values_.readInstance(e, &scalars_, nullptr));
            }
        }
        size_t n = 0;
        const size_t fields = layout_.scalars.size();
        scalarValues_.resize(max * fields);
        while (n < max && index_ < vertex_->count) {
            SC_TRY(values_.readInstance(*vertex_, &scalars_, nullptr));
            ++index_;
            InputPoint& p = out[n];
            p = InputPoint{};
            p.position = {scalars_[layout_.x], scalars_[layout_.y], scalars_[layout_.z]};
            if (!finite(p.position)) { ++skipped_; continue; }
            if (layout_.nx >= 0)
                p.normal = normalizeOrZero(Vec3f{float(scalars_[layout_.nx]), float(scalars_[layout_.ny]), float(scalars_[layout_.nz])});
            if (layout_.r >= 0)
                {
                const int slots[3] = {layout_.r, layout_.g, layout_.b};
                for (int c = 0; c < 3; ++c) p.color[c] = toChannel(scalars_[slots[c]], layout_.colorType);
            }
            if (layout_.intensity >= 0) p.intensity = toChannel(scalars_[layout_.intensity], layout_.intensityType);
            if (layout_.classification >= 0) p.classification = classOf(scalars_[layout_.classification]);
            if (layout_.alpha >= 0) SC_TRY(readAlpha(scalars_[layout_.alpha], &p.alpha));
            for (size_t f = 0; f < fields; ++f) scalarValues_[n * fields + f] = scalars_[size_t(layout_.scalars[f])];
            ++n;
        }
        scalarValues_.resize(n * fields);
        return n;
    }

private:
    // Integer alpha scales by its type's range; floating-point opacity must be
    // in [0, 1]. 3D Gaussian splatting files store a logit under "opacity":
    // those fail here rather than drawing as noise.
    Status readAlpha(double v, uint8_t* alpha) const {
        const bool floating = layout_.alphaType == PlyType::Float32 || layout_.alphaType == PlyType::Float64;
        if (floating && !(v >= 0 && v <= 1))
            return Status::error(desc_.path + ": vertex " + std::to_string(index_ - 1) + ": opacity " + std::to_string(v) +
                                 " is outside [0, 1] (a 3D Gaussian splatting file's logit opacity is not read)");
        const double unit = floating ? v : toChannel(v, layout_.alphaType) / 65535.0;
        *alpha = uint8_t(std::lround(unit * 255));
        return {};
    }

    ByteStream in_;
    PlyHeader header_;
    VertexLayout layout_;
    ValueReader values_;
    const PlyElement* vertex_ = nullptr;
    InputDescription desc_;
    std::vector<double> scalars_;
    uint64_t index_ = 0;
    bool started_ = false;
};

}  // namespace

Result<PlyHeader> parsePlyHeader(ByteStream& in) {
    std::string line;
    auto fail = [&](const std::string& why) { return Status::error(in.path() + ": line " + std::to_string(in.line() - 1) + ": " + why); };
    if (!in.readLine(&line) || line != "ply") return Status::error(in.path() + ": not a PLY file (no 'ply' magic at byte 0)");
    PlyHeader h;
    bool haveFormat = false;
    while (true) {
        if (!in.readLine(&line)) return Status::error(in.path() + ": header has no end_header");
        if (in.offset() > kMaxPlyHeaderBytes) return Status::error(in.path() + ": header longer than 1 MiB");
        std::istringstream words(line);
        std::string word;
        words >> word;
        if (word == "comment") {
            // MeshLab's texture names: "comment TextureFile NAME", in texnumber order.
            std::string key, name;
            if ((words >> key) && key == "TextureFile" && std::getline(words >> std::ws, name)) {
                while (!name.empty() && (name.back() == '\r' || name.back() == ' ')) name.pop_back();
                h.textureFiles.push_back({name, int(in.line() - 1)});
            }
            continue;
        }
        if (word.empty() || word == "obj_info") continue;
        if (word == "end_header") break;
        if (word == "format") {
            std::string f, version;
            words >> f >> version;
            if (f == "ascii") h.format = PlyHeader::Format::Ascii;
            else if (f == "binary_little_endian") h.format = PlyHeader::Format::BinaryLittle;
            else if (f == "binary_big_endian") h.format = PlyHeader::Format::BinaryBig;
            else return fail("unknown format '" + f + "'");
            haveFormat = true;
        } else if (word == "element") {
            PlyElement e;
            long long count = -1;
            words >> e.name >> count;
            if (e.name.empty() || count < 0 || words.fail()) return fail("malformed element line");
            e.count = uint64_t(count);
            h.elements.push_back(e);
        } else if (word == "property") {
            if (h.elements.empty()) return fail("property before any element");
            PlyProperty p;
            std::string type;
            words >> type;
            if (type == "list") {
                std::string countType, itemType;
                words >> countType >> itemType >> p.name;
                p.isList = true;
                if (!parseType(countType, &p.countType) || !parseType(itemType, &p.type))
                    return fail("unknown property type in '" + line + "'");
            } else {
                words >> p.name;
                if (!parseType(type, &p.type)) return fail("unknown property type '" + type + "'");
            }
            if (p.name.empty()) return fail("property without a name");
            h.elements.back().properties.push_back(p);
        } else {
            return fail("unknown header keyword '" + word + "'");
        }
    }
    if (!haveFormat) return Status::error(in.path() + ": header has no format line");
    return h;
}

bool plyHasFaces(const PlyHeader& header) {
    for (const auto& e : header.elements)
        if ((e.name == "face" || e.name == "tristrips") && e.count > 0) return true;
    return false;
}

Result<std::unique_ptr<PointReader>> openPlyReader(const std::string& path, const ScalarSelection& scalars, const HttpOptions& http) {
    auto in = ByteStream::open(path, http);
    if (!in) return in.status();
    auto header = parsePlyHeader(*in);
    if (!header) return header.status();
    const PlyElement* vertex = findElement(*header, "vertex");
    if (!vertex) return Status::error(path + ": no vertex element");
    for (const auto& p : vertex->properties)
        if (p.isList) return Status::error(path + ": vertex element has a list property '" + p.name + "'");
    std::vector<ScalarField> fields;
    auto layout = vertexLayout(*vertex, path, scalars, &fields);
    if (!layout) return layout.status();
    // Binary data must be at least as long as the header promises: a cheap check
    // that names the truncation before hours of work.
    if (header->format != PlyHeader::Format::Ascii && header->elements.front().name == "vertex") {
        uint64_t record = 0;
        for (const auto& p : vertex->properties) record += typeSize(p.type);
        if (in->offset() + record * vertex->count > in->fileSize())
            return Status::error(path + ": file is " + std::to_string(in->fileSize()) + " bytes, the header promises " +
                                 std::to_string(vertex->count) + " vertices of " + std::to_string(record) +
                                 " bytes from byte " + std::to_string(in->offset()));
    }
    PlyHeader h = *header;
    return std::unique_ptr<PointReader>(new PlyPointReader(std::move(*in), std::move(h), *layout, vertex, std::move(fields)));
}

Result<PlyMesh> readPlyMesh(const std::string& path) {
    auto in = ByteStream::open(path);
    if (!in) return in.status();
    auto header = parsePlyHeader(*in);
    if (!header) return header.status();
    ValueReader values(*in, header->format);
    PlyMesh mesh;
    for (const auto& [name, line] : header->textureFiles) mesh.textureFiles.push_back({name, line});
    std::vector<double> scalars;
    std::vector<std::vector<double>> lists;
    bool seenVertices = false;
    for (const PlyElement& e : header->elements) {
        if (e.name == "vertex") {
            // A second vertex element would leave colours and vertices out of
            // step (a heap overflow in the mesh reader: fuzz_read_ply).
            if (std::exchange(seenVertices, true)) return Status::error(path + ": more than one vertex element");
            std::vector<ScalarField> none;
            auto layout = vertexLayout(e, path, {}, &none);
            if (!layout) return layout.status();
            mesh.colorBits = layout->colorType == PlyType::UInt8 ? 8 : 16;
            mesh.vertices.reserve(std::min<uint64_t>(e.count, 1u << 20));  // the header's count is not trusted
            // Per-vertex texture coordinates under any of their usual names.
            const auto slots = scalarSlots(e);
            int u = -1, v = -1;
            for (auto [a, b] : {std::pair{"s", "t"}, {"u", "v"}, {"texture_u", "texture_v"}, {"texture_s", "texture_t"}})
                if (u < 0 && findProperty(e, {a}) >= 0 && findProperty(e, {b}) >= 0) {
                    u = slots[size_t(findProperty(e, {a}))];
                    v = slots[size_t(findProperty(e, {b}))];
                }
            for (uint64_t i = 0; i < e.count; ++i) {
                SC_TRY(values.readInstance(e, &scalars, nullptr));
                mesh.vertices.push_back({scalars[layout->x], scalars[layout->y], scalars[layout->z]});
                if (u >= 0) mesh.vertexUvs.push_back({float(scalars[size_t(u)]), float(scalars[size_t(v)])});
                if (layout->r >= 0)
                    mesh.colors.push_back({toChannel(scalars[layout->r], layout->colorType),
                                           toChannel(scalars[layout->g], layout->colorType),
                                           toChannel(scalars[layout->b], layout->colorType)});
            }
            continue;
        }
        bool faces = e.name == "face", strips = e.name == "tristrips";
        // Which list holds the vertex indices (by name, else the first), and
        // the per-face texture coordinates and texture number, if any.
        int indexList = -1, texcoordList = -1, lists_ = 0;
        for (const PlyProperty& p : e.properties) {
            if (!p.isList) continue;
            if (p.name == "vertex_indices" || p.name == "vertex_index") indexList = lists_;
            if (p.name == "texcoord") texcoordList = lists_;
            ++lists_;
        }
        if (indexList < 0 && lists_ > 0 && texcoordList != 0) indexList = 0;
        const int texnumber = findProperty(e, {"texnumber"}) >= 0 ? scalarSlots(e)[size_t(findProperty(e, {"texnumber"}))] : -1;
        for (uint64_t i = 0; i < e.count; ++i) {
            SC_TRY(values.readInstance(e, &scalars, &lists));
            if (indexList < 0) continue;
            const std::vector<double>& list = lists[size_t(indexList)];
            auto index = [&](double v, uint32_t* out) -> Status {
                if (!(v >= 0) || v >= double(mesh.vertices.size()))
                    return Status::error(in->at() + ": vertex index " + std::to_string(int64_t(v)) + " out of range");
                *out = uint32_t(v);
                return {};
            };
            if (faces) {
                const std::vector<double>* uv = texcoordList >= 0 ? &lists[size_t(texcoordList)] : nullptr;
                if (uv && uv->size() != 2 * list.size())
                    return Status::error(in->at() + ": face " + std::to_string(i) + " has " + std::to_string(uv->size()) +
                                         " texture coordinates for " + std::to_string(list.size()) + " vertices");
                // A polygon becomes a triangle fan. Triangles that repeat a
                // vertex are dropped: OpenMesh's add_face asserts (aborting the
                // process) on one (fuzz_read_ply).
                for (size_t k = 2; k < list.size(); ++k) {
                    std::array<uint32_t, 3> t{};
                    SC_TRY(index(list[0], &t[0]));
                    SC_TRY(index(list[k - 1], &t[1]));
                    SC_TRY(index(list[k], &t[2]));
                    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
                    mesh.triangles.push_back(t);
                    if (uv) {
                        const std::vector<double>& c = *uv;
                        mesh.faceUvs.push_back({float(c[0]), float(c[1]), float(c[2 * k - 2]), float(c[2 * k - 1]), float(c[2 * k]),
                                                float(c[2 * k + 1])});
                    }
                    if (texnumber >= 0) mesh.triangleTexture.push_back(int(std::clamp(scalars[size_t(texnumber)], -1.0, 65535.0)));
                }
            } else if (strips) {
                // -1 restarts a strip; odd triangles flip to keep one orientation.
                size_t start = 0;
                for (size_t k = 0; k <= list.size(); ++k) {
                    if (k < list.size() && list[k] >= 0) continue;
                    for (size_t j = start + 2; j < k; ++j) {
                        std::array<uint32_t, 3> t{};
                        SC_TRY(index(list[j - 2], &t[0]));
                        SC_TRY(index(list[j - 1], &t[1]));
                        SC_TRY(index(list[j], &t[2]));
                        if ((j - start) % 2 == 1) std::swap(t[0], t[1]);
                        if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) mesh.triangles.push_back(t);
                    }
                    start = k + 1;
                }
            }
        }
    }
    if (mesh.vertices.empty()) return Status::error(path + ": mesh has no vertices");
    return mesh;
}

}  // namespace surfcast
