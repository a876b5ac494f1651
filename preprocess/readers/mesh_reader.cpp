#include "mesh_reader.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>

#include "gltf_reader.h"
#include "ply_reader.h"
#include "random.h"
#include "texture.h"

namespace surfcast {

struct MeshTraits : public OpenMesh::DefaultTraits {
    using Point = OpenMesh::Vec3d;
    using Normal = OpenMesh::Vec3d;
    // Floats in [0, 1] nominally: OpenMesh reads OBJ colours as floats of any
    // value and would cast them to bytes unchecked (undefined behaviour outside
    // 0..255, found by fuzz_read_obj); makePoint clamps instead.
    using Color = OpenMesh::Vec3f;
};
using TriMesh = OpenMesh::TriMesh_ArrayKernelT<MeshTraits>;

struct LoadedMesh {
    TriMesh mesh;
    bool hasColors = false;
    // Diffuse textures by OpenMesh's face texture index (0: none; null: none,
    // or one that could not be loaded, with --allow-missing-textures).
    std::vector<std::shared_ptr<const Texture>> textures;
    bool textured = false;    // some face has a loaded texture
    // The materials name diffuse maps, and gave faces their Kd: the colour of
    // faces whose texture could not be loaded and which have no vertex colours.
    bool faceColors = false;
    uint64_t rejectedFaces = 0;  // faces OpenMesh refused (non-manifold)
    // Faces wound clockwise (negative signed volume): OpenMesh's normals point
    // inward and are flipped, so surfels face out of the object.
    double normalSign = 1;
};

namespace {




// OpenMesh's OBJ reader asserts (aborting the process) on a face none of
// whose vertices has an index ("f /2/1 //3", found by fuzz_read_obj). Faces
// are checked first: every vertex of a face starts with a non-zero integer
// index, and a face has at least three. Texture coordinates (vt) must be
// finite numbers (OpenMesh refuses "nan" with no word of where). Also
// collects the material libraries the file names (mtllib), resolved against
// its folder, which they must lie in unless allowOutside (OpenMesh reads them
// next, so this comes first). A statement is found as OpenMesh 9 finds it:
// the line trimmed of " \t\r\n", its first word; OpenMesh opens the rest of
// the line as one name, the texture loader each word of it, so both are checked.
Status scanObj(const std::string& path, bool allowOutside, std::vector<std::string>* libraries) {
    std::ifstream in(path, std::ios::binary);
    if (!in) return Status::error(path + ": cannot open");
    std::string line;
    for (uint64_t number = 1; std::getline(in, line); ++number) {
        size_t at = line.find_first_not_of(" \t");
        {
            std::istringstream words(line);
            std::string keyword;
            if (words >> keyword && keyword == "mtllib") {
                std::string rest;
                std::getline(words, rest);
                const size_t first = rest.find_first_not_of(" \t\r\n"), last = rest.find_last_not_of(" \t\r\n");
                rest = first == std::string::npos ? "" : rest.substr(first, last - first + 1);
                std::istringstream names(rest);
                std::vector<std::string> each;
                for (std::string name; names >> name;) each.push_back(name);
                if (each.size() > 1)  // OpenMesh's reading: one name, spaces and all
                    if (auto whole = resolveModelFile(path, path, rest, allowOutside); !whole)
                        return Status::error(path + ": line " + std::to_string(number) + ": mtllib " + whole.status().message());
                for (const std::string& name : each) {
                    auto library = resolveModelFile(path, path, name, allowOutside);
                    if (!library) return Status::error(path + ": line " + std::to_string(number) + ": mtllib " + library.status().message());
                    libraries->push_back(*library);
                }
                continue;
            }
        }
        if (at != std::string::npos && line.compare(at, 3, "vt ") == 0) {
            std::istringstream words(line.substr(at + 3));
            for (std::string word; words >> word;) {
                char* end = nullptr;
                const double v = std::strtod(word.c_str(), &end);
                if (*end != '\0' || !std::isfinite(v))
                    return Status::error(path + ": line " + std::to_string(number) + ": texture coordinate '" + word +
                                         "' is not a finite number");
            }
            continue;
        }
        if (at == std::string::npos || line[at] != 'f' || at + 1 >= line.size() || (line[at + 1] != ' ' && line[at + 1] != '\t'))
            continue;
        std::istringstream words(line.substr(at + 1));
        int vertices = 0;
        for (std::string word; words >> word; ++vertices) {
            const std::string index = word.substr(0, word.find('/'));
            char* end = nullptr;
            const long v = std::strtol(index.c_str(), &end, 10);
            if (index.empty() || *end != '\0' || v == 0)
                return Status::error(path + ": line " + std::to_string(number) + ": face vertex '" + word +
                                     "' has no vertex index");
        }
        if (vertices < 3)
            return Status::error(path + ": line " + std::to_string(number) + ": a face needs three vertices");
    }
    return {};
}

// A map statement's file name: its last word (options such as "-s 1 1 1" come first).
std::string lastWord(const std::string& s) {
    std::istringstream words(s);
    std::string last;
    for (std::string w; words >> w;) last = w;
    return last;
}

// The diffuse textures OpenMesh's OBJ reader found (its "TextureMapping": texture
// index to the text after map_Kd), loaded through our own reading of the
// libraries, so that errors name the library's line.
Status loadObjTextures(const std::string& path, const std::vector<std::string>& libraries, bool allowMissing,
                       bool allowOutside, LoadedMesh& loaded) {
    TriMesh& mesh = loaded.mesh;
    OpenMesh::MPropHandleT<std::map<int, std::string>> mapping;
    if (!mesh.has_halfedge_texcoords2D() || !mesh.get_property_handle(mapping, "TextureMapping")) return {};
    std::vector<MtlLibrary> libs;
    for (const std::string& name : libraries) {
        auto lib = readMtl(name, path, allowOutside);
        if (!lib) return Status::error(path + ": " + lib.status().message());
        for (const std::string& w : lib->missingUnusedMaps) warnOnce(w);
        libs.push_back(std::move(*lib));
    }
    for (const auto& [index, text] : mesh.property(mapping)) {
        if (index <= 0 || index > 65535) continue;
        const MtlLibrary* owner = nullptr;
        const MtlMaterial* material = nullptr;
        for (const MtlLibrary& lib : libs)
            for (const MtlMaterial& m : lib.materials)
                if (!material && !m.diffusePath.empty() && m.diffuseMap == lastWord(text)) {
                    owner = &lib;
                    material = &m;
                }
        if (!material) return Status::error(path + ": map_Kd '" + text + "' is in no material library the file names");
        if (loaded.textures.size() <= size_t(index)) loaded.textures.resize(size_t(index) + 1);
        auto texture = loadTexture(material->diffusePath);
        if (!texture) {
            const std::string why = owner->path + ": line " + std::to_string(material->diffuseLine) + ": map_Kd '" +
                                    material->diffuseMap + "': " + texture.status().message();
            if (!allowMissing) return Status::error(why + " (with --allow-missing-textures its faces take vertex colours, else the material's Kd)");
            warnOnce(why + "; its faces take vertex colours, else the material's Kd");
            continue;
        }
        loaded.textures[size_t(index)] = std::make_shared<const Texture>(std::move(*texture));
        loaded.textured = true;
    }
    if (!loaded.textured) return {};
    for (auto f : mesh.faces()) {
        const int t = mesh.texture_index(f);
        if (t <= 0 || size_t(t) >= loaded.textures.size() || !loaded.textures[size_t(t)]) continue;
        for (auto h : mesh.fh_range(f)) {
            const auto uv = mesh.texcoord2D(h);
            if (!std::isfinite(uv[0]) || !std::isfinite(uv[1]))
                return Status::error(path + ": face " + std::to_string(f.idx()) + " has a NaN or infinite texture coordinate");
        }
    }
    return {};
}

struct LoadOptions {
    bool textures = true;  // load diffuse textures (only sampling needs them)
    bool allowMissingTextures = false;
    bool allowOutsidePaths = false;
};

Result<std::unique_ptr<LoadedMesh>> loadMesh(const std::string& path, const LoadOptions& load = {}) {
    auto loaded = std::make_unique<LoadedMesh>();
    TriMesh& mesh = loaded->mesh;
    mesh.request_vertex_colors();
    if (isGltfExtension(path)) {
        auto gltf = readGltf(path, load.allowMissingTextures, load.allowOutsidePaths);
        if (!gltf) return gltf.status();
        for (const std::string& w : gltf->warnings) warnOnce(w);
        mesh.request_halfedge_texcoords2D();
        mesh.request_face_texture_index();
        mesh.request_face_colors();
        std::vector<TriMesh::VertexHandle> handles;
        handles.reserve(gltf->positions.size());
        for (const Vec3d& v : gltf->positions) handles.push_back(mesh.add_vertex({v.x, v.y, v.z}));
        // Texture index t + 1 is scene texture t (0: none), as OpenMesh numbers an OBJ's.
        loaded->textures.resize(gltf->textures.size() + 1);
        for (size_t t = 0; t < gltf->textures.size(); ++t)
            loaded->textures[t + 1] = std::make_shared<const Texture>(std::move(gltf->textures[t]));
        loaded->textured = !gltf->textures.empty();
        loaded->faceColors = true;
        for (size_t i = 0; i < gltf->triangles.size(); ++i) {
            const auto& t = gltf->triangles[i];
            auto f = mesh.add_face(handles[t[0]], handles[t[1]], handles[t[2]]);
            if (!f.is_valid()) {
                ++loaded->rejectedFaces;
                continue;
            }
            const GltfMaterial& material = gltf->materials[gltf->triangleMaterial[i]];
            mesh.set_texture_index(f, material.texture ? int(*material.texture + 1) : 0);
            mesh.set_color(f, {material.factor[0], material.factor[1], material.factor[2]});
            for (auto h : mesh.fh_range(f)) {
                const auto& uv = gltf->uvs[size_t(mesh.to_vertex_handle(h).idx())];
                mesh.set_texcoord2D(h, {uv[0], uv[1]});
            }
        }
    } else if (lowerExtension(path) == ".ply") {
        // Our PLY parser handles triangle strips and big-endian files, which
        // OpenMesh's PLY reader does not; OpenMesh then owns the topology.
        auto ply = readPlyMesh(path);
        if (!ply) return ply.status();
        std::vector<TriMesh::VertexHandle> handles;
        handles.reserve(ply->vertices.size());
        for (size_t i = 0; i < ply->vertices.size(); ++i) {
            const Vec3d& v = ply->vertices[i];
            handles.push_back(mesh.add_vertex({v.x, v.y, v.z}));
            if (!ply->colors.empty())
                mesh.set_color(handles.back(), {float(ply->colors[i][0] >> 8) / 255.f, float(ply->colors[i][1] >> 8) / 255.f,
                                                float(ply->colors[i][2] >> 8) / 255.f});
        }
        loaded->hasColors = !ply->colors.empty();
        const bool uvs = !ply->vertexUvs.empty() || !ply->faceUvs.empty();
        if (load.textures && uvs && !ply->textureFiles.empty()) {
            mesh.request_halfedge_texcoords2D();
            mesh.request_face_texture_index();
            loaded->textures.resize(ply->textureFiles.size() + 1);  // texture index t + 1 is TextureFile t
            for (size_t t = 0; t < ply->textureFiles.size(); ++t) {
                const PlyMesh::TextureFile& file = ply->textureFiles[t];
                auto resolved = resolveModelFile(path, path, file.name, load.allowOutsidePaths);
                if (!resolved)
                    return Status::error(path + ": line " + std::to_string(file.line) + ": comment TextureFile " +
                                         resolved.status().message());
                auto texture = loadTexture(*resolved);
                if (!texture) {
                    const std::string why = path + ": line " + std::to_string(file.line) + ": comment TextureFile '" + file.name +
                                            "': " + texture.status().message();
                    if (!load.allowMissingTextures)
                        return Status::error(why + " (with --allow-missing-textures its faces take vertex colours)");
                    warnOnce(why + "; its faces take vertex colours");
                    continue;
                }
                loaded->textures[t + 1] = std::make_shared<const Texture>(std::move(*texture));
                loaded->textured = true;
            }
        }
        for (size_t i = 0; i < ply->triangles.size(); ++i) {
            const auto& t = ply->triangles[i];
            auto f = mesh.add_face(handles[t[0]], handles[t[1]], handles[t[2]]);
            if (!f.is_valid()) {
                ++loaded->rejectedFaces;
                continue;
            }
            if (!loaded->textured) continue;
            const int texture = ply->triangleTexture.empty() ? 0 : ply->triangleTexture[i];
            mesh.set_texture_index(f, texture >= 0 && size_t(texture) + 1 < loaded->textures.size() ? texture + 1 : 0);
            for (auto h : mesh.fh_range(f)) {
                const uint32_t v = uint32_t(mesh.to_vertex_handle(h).idx());
                std::array<float, 2> uv{0, 0};
                if (!ply->faceUvs.empty()) {
                    const int corner = v == t[0] ? 0 : v == t[1] ? 1 : 2;
                    uv = {ply->faceUvs[i][size_t(2 * corner)], ply->faceUvs[i][size_t(2 * corner + 1)]};
                } else {
                    uv = ply->vertexUvs[v];
                }
                if (!std::isfinite(uv[0]) || !std::isfinite(uv[1]))
                    return Status::error(path + ": face " + std::to_string(i) + " has a NaN or infinite texture coordinate");
                mesh.set_texcoord2D(h, {uv[0], uv[1]});
            }
        }
    } else {
        const bool obj = lowerExtension(path) == ".obj";
        std::vector<std::string> libraries;
        if (obj) SC_TRY(scanObj(path, load.allowOutsidePaths, &libraries));
        OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexColor;
        if (obj && load.textures && !libraries.empty()) {
            mesh.request_halfedge_texcoords2D();
            mesh.request_face_texture_index();
            mesh.request_face_colors();
            options += OpenMesh::IO::Options::FaceTexCoord;
            options += OpenMesh::IO::Options::FaceColor;
        }
        if (!OpenMesh::IO::read_mesh(mesh, path, options)) return Status::error(path + ": OpenMesh could not read the mesh");
        loaded->hasColors = options.check(OpenMesh::IO::Options::VertexColor) && mesh.has_vertex_colors();
        if (options.check(OpenMesh::IO::Options::FaceTexCoord))
            SC_TRY(loadObjTextures(path, libraries, load.allowMissingTextures, load.allowOutsidePaths, *loaded));
        OpenMesh::MPropHandleT<std::map<int, std::string>> maps;
        loaded->faceColors = options.check(OpenMesh::IO::Options::FaceColor) && mesh.has_face_colors() &&
                             mesh.get_property_handle(maps, "TextureMapping") && !mesh.property(maps).empty();
    }
    if (mesh.n_vertices() == 0) return Status::error(path + ": mesh has no vertices");
    for (auto v : mesh.vertices()) {
        auto p = mesh.point(v);
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
            return Status::error(path + ": vertex " + std::to_string(v.idx()) + " has a NaN or infinite coordinate");
    }
    mesh.request_face_normals();
    mesh.request_vertex_normals();
    mesh.update_normals();
    // Signed volume by the divergence theorem, about the centroid so that
    // large coordinates do not cancel.
    OpenMesh::Vec3d centroid(0, 0, 0);
    for (auto v : mesh.vertices()) centroid += mesh.point(v);
    centroid /= double(mesh.n_vertices());
    double volume = 0;
    for (auto f : mesh.faces()) {
        auto fv = mesh.cfv_iter(f);
        auto a = mesh.point(*fv) - centroid;
        ++fv;
        auto b = mesh.point(*fv) - centroid;
        ++fv;
        auto c = mesh.point(*fv) - centroid;
        volume += (a | (b % c)) / 6.0;
    }
    loaded->normalSign = volume < 0 ? -1 : 1;
    return loaded;
}

class MeshReader final : public PointReader {
public:
    MeshReader(std::shared_ptr<const LoadedMesh> mesh, const std::string& path, const MeshSampling& sampling)
        : mesh_(std::move(mesh)), rng_(sampling.seed), spacing_(sampling.spacing) {
        const TriMesh& m = mesh_->mesh;
        if (!(spacing_ > 0)) {
            const char* rule = "half the median edge";
            if (mesh_->textured) {
                // One surfel per texel: the textured faces' area over the texels
                // their texture coordinates cover.
                double area = 0, texels = 0;
                for (auto f : m.faces()) {
                    const Texture* t = texture(f);
                    if (!t) continue;
                    OpenMesh::Vec2f uv[3];
                    int k = 0;
                    for (auto h : m.fh_range(f)) uv[k++] = m.texcoord2D(h);
                    const auto e1 = uv[1] - uv[0], e2 = uv[2] - uv[0];
                    const double uvArea = 0.5 * std::abs(double(e1[0]) * e2[1] - double(e1[1]) * e2[0]);
                    area += m.calc_face_area(f);
                    texels += uvArea * t->width * t->height;
                }
                if (texels > 0 && area > 0) {
                    spacing_ = std::sqrt(area / texels);
                    rule = "one surfel per texel";
                }
            }
            if (!(spacing_ > 0)) {
                std::vector<double> lengths;
                for (auto e : m.edges()) lengths.push_back(m.calc_edge_length(e));
                if (!lengths.empty()) {
                    std::nth_element(lengths.begin(), lengths.begin() + lengths.size() / 2, lengths.end());
                    spacing_ = 0.5 * lengths[lengths.size() / 2];
                }
            }
            double area = 0;
            for (auto f : m.faces()) area += m.calc_face_area(f);
            const double cap = double(std::max<uint64_t>(1, sampling.maxSurfels));
            if (spacing_ > 0 && area / (spacing_ * spacing_) > cap) {
                const double coarser = std::sqrt(area / cap);
                char message[512];
                std::snprintf(message, sizeof message, "%s: %s (spacing %g) would sample %.3g surfels; spacing %g keeps them "
                              "to --mesh-max-surfels %llu", path.c_str(), rule, spacing_, area / (spacing_ * spacing_), coarser,
                              (unsigned long long)sampling.maxSurfels);
                warnOnce(message);
                spacing_ = coarser;
            }
        }
        desc_.path = path;
        desc_.format = "mesh";
        desc_.hasNormals = true;
        desc_.hasColors = mesh_->hasColors || mesh_->textured || mesh_->faceColors;
        desc_.textured = mesh_->textured;
        desc_.colorBits = 8;
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        const TriMesh& m = mesh_->mesh;
        size_t n = 0;
        // Meshes without faces (or with faces too small to sample) still give their vertices.
        if (m.n_faces() == 0 || !(spacing_ > 0)) {
            for (; n < max && vertex_ < m.n_vertices(); ++vertex_, ++n) {
                Corners at;
                at.v[0] = at.v[1] = at.v[2] = TriMesh::VertexHandle{int(vertex_)};
                out[n] = makePoint(m.point(at.v[0]), m.normal(at.v[0]) * mesh_->normalSign, at, 1, 0, 0);
            }
            return n;
        }
        while (n < max) {
            if (pending_ == 0) {
                if (face_ >= m.n_faces()) break;
                corners_.face = TriMesh::FaceHandle{int(face_++)};
                int k = 0;
                for (auto h : m.fh_range(corners_.face)) {
                    corners_.v[k] = m.to_vertex_handle(h);
                    corners_.h[k++] = h;
                }
                const auto& p = corners_.v;
                double area = 0.5 * ((m.point(p[1]) - m.point(p[0])) % (m.point(p[2]) - m.point(p[0]))).norm();
                double expected = area / (spacing_ * spacing_);
                pending_ = uint64_t(std::floor(expected + rng_.uniform()));  // unbiased count
                continue;
            }
            --pending_;
            // Uniform point in the triangle (Osada et al. 2002).
            double r1 = std::sqrt(rng_.uniform()), r2 = rng_.uniform();
            double a = 1 - r1, b = r1 * (1 - r2), c = r1 * r2;
            const auto& v = corners_.v;
            auto p = m.point(v[0]) * a + m.point(v[1]) * b + m.point(v[2]) * c;
            auto normal = (m.normal(v[0]) * a + m.normal(v[1]) * b + m.normal(v[2]) * c) * mesh_->normalSign;
            out[n++] = makePoint(p, normal, corners_, a, b, c);
        }
        return n;
    }

private:
    // A face's three corners: vertices and the halfedges into them (which
    // carry the face's texture coordinates).
    struct Corners {
        TriMesh::FaceHandle face;
        TriMesh::VertexHandle v[3];
        TriMesh::HalfedgeHandle h[3];
    };

    const Texture* texture(TriMesh::FaceHandle f) const {
        if (!mesh_->textured || !f.is_valid()) return nullptr;
        const int t = mesh_->mesh.texture_index(f);
        if (t <= 0 || size_t(t) >= mesh_->textures.size()) return nullptr;
        return mesh_->textures[size_t(t)].get();
    }

    InputPoint makePoint(const OpenMesh::Vec3d& p, const OpenMesh::Vec3d& normal, const Corners& at, double a, double b,
                         double c) const {
        const TriMesh& m = mesh_->mesh;
        InputPoint q;
        q.position = {p[0], p[1], p[2]};
        q.normal = normalizeOrZero(Vec3f{float(normal[0]), float(normal[1]), float(normal[2])});
        if (!desc_.hasColors) return q;
        Vec3f unit{0.5f, 0.5f, 0.5f};
        if (const Texture* t = texture(at.face)) {
            const auto uv = m.texcoord2D(at.h[0]) * float(a) + m.texcoord2D(at.h[1]) * float(b) + m.texcoord2D(at.h[2]) * float(c);
            const Vec3f texel = t->sample(uv[0], uv[1]);
            // Rounded to the texture's 8 bits (stored as c·257), so that a
            // textured set stores 8-bit colour.
            for (int k = 0; k < 3; ++k) q.color[k] = uint16_t(std::lround(std::clamp(texel[k], 0.f, 1.f) * 255.f) * 257);
            return q;
        } else if (mesh_->hasColors) {
            for (int k = 0; k < 3; ++k)
                unit[k] = float(m.color(at.v[0])[k] * a + m.color(at.v[1])[k] * b + m.color(at.v[2])[k] * c);
        } else if (mesh_->faceColors && at.face.is_valid()) {
            for (int k = 0; k < 3; ++k) unit[k] = m.color(at.face)[k];
        }
        for (int k = 0; k < 3; ++k)
            q.color[k] = unit[k] > 0 ? (unit[k] < 1 ? uint16_t(std::lround(unit[k] * 65535.0)) : uint16_t(65535)) : 0;  // NaN: 0
        return q;
    }

    std::shared_ptr<const LoadedMesh> mesh_;
    SplitMix64 rng_;
    double spacing_;
    InputDescription desc_;
    size_t face_ = 0, vertex_ = 0;
    uint64_t pending_ = 0;
    Corners corners_;
};

}  // namespace

bool isMeshExtension(const std::string& path) {
    std::string ext = lowerExtension(path);
    return ext == ".obj" || ext == ".off" || ext == ".stl" || isGltfExtension(path);
}

namespace {
// OpenMesh's items and properties.
uint64_t topologyBytes(const LoadedMesh& loaded) {
    const TriMesh& m = loaded.mesh;
    uint64_t sum = sizeof loaded + m.n_vertices() * sizeof(OpenMesh::ArrayItems::Vertex) +
                   m.n_edges() * sizeof(OpenMesh::ArrayItems::Edge) + m.n_faces() * sizeof(OpenMesh::ArrayItems::Face);
    auto properties = [&](auto begin, auto end) {
        for (auto p = begin; p != end; ++p)
            if (*p) sum += (*p)->size_of();
    };
    properties(m.vprops_begin(), m.vprops_end());
    properties(m.hprops_begin(), m.hprops_end());
    properties(m.eprops_begin(), m.eprops_end());
    properties(m.fprops_begin(), m.fprops_end());
    return sum;
}

// Its textures that nothing else holds (`sharedToo`: all of them).
uint64_t textureBytes(const LoadedMesh& loaded, bool sharedToo) {
    uint64_t sum = 0;
    for (const auto& t : loaded.textures)
        if (t && (sharedToo || t.use_count() == 1)) sum += t->bytes();
    return sum;
}
}  // namespace

uint64_t meshBytes(const LoadedMesh& loaded) { return topologyBytes(loaded) + textureBytes(loaded, true); }

Result<std::shared_ptr<const LoadedMesh>> MeshStore::load(const std::string& path, const MeshSampling& options) {
    std::lock_guard lock(mutex_);
    ++clock_;
    if (auto it = held_.find(path); it != held_.end()) {
        it->second.lastUsed = clock_;
        return it->second.mesh;
    }
    // Read under the lock: a mesh other threads want meanwhile is read once.
    auto loaded = loadMesh(path, {true, options.allowMissingTextures, options.allowOutsidePaths});
    if (!loaded) return loaded.status();
    std::shared_ptr<const LoadedMesh> mesh = std::move(*loaded);
    const uint64_t size = meshBytes(*mesh);
    // While a texture is read, its file's bytes and stb_image's buffer
    // (then copied into it) are held too: the largest of those on top.
    uint64_t decoding = 0;
    for (const auto& t : mesh->textures) {
        if (!t) continue;
        std::error_code ec;
        const uint64_t file = std::filesystem::file_size(t->path, ec);
        decoding = std::max(decoding, t->bytes() + (ec ? 0 : file));
    }
    largest_ = std::max(largest_, size + decoding);
    ++reads_;
    held_[path] = {mesh, clock_};
    trim();
    return mesh;
}

uint64_t MeshStore::heldBytes() const {
    uint64_t sum = 0;
    for (const auto& [path, h] : held_) sum += topologyBytes(*h.mesh) + textureBytes(*h.mesh, false);
    return sum;
}

void MeshStore::trim() {
    while (!held_.empty() && heldBytes() > capacity_) {
        auto oldest = std::min_element(held_.begin(), held_.end(),
                                       [](const auto& a, const auto& b) { return a.second.lastUsed < b.second.lastUsed; });
        held_.erase(oldest);
    }
}

void MeshStore::setCapacity(uint64_t capacity) {
    std::lock_guard lock(mutex_);
    capacity_ = capacity;
    trim();
}

uint64_t MeshStore::bytes() const {
    std::lock_guard lock(mutex_);
    return heldBytes();
}

uint64_t MeshStore::largestBytes() const {
    std::lock_guard lock(mutex_);
    return largest_;
}

uint64_t MeshStore::reads() const {
    std::lock_guard lock(mutex_);
    return reads_;
}

namespace {
// The mesh at `path` from `store`, or read here without one.
Result<std::shared_ptr<const LoadedMesh>> sharedMesh(const std::string& path, bool textures, const MeshSampling& options,
                                                     MeshStore* store) {
    if (store) return store->load(path, options);
    auto loaded = loadMesh(path, {textures, options.allowMissingTextures, options.allowOutsidePaths});
    if (!loaded) return loaded.status();
    return std::shared_ptr<const LoadedMesh>(std::move(*loaded));
}
}  // namespace

Result<std::unique_ptr<PointReader>> openMeshReader(const std::string& path, const MeshSampling& sampling, MeshStore* store) {
    auto mesh = sharedMesh(path, true, sampling, store);
    if (!mesh) return mesh.status();
    return std::unique_ptr<PointReader>(new MeshReader(std::move(*mesh), path, sampling));
}

namespace {
MeshVertexNormals vertexNormals(const LoadedMesh& loaded) {
    const TriMesh& m = loaded.mesh;
    MeshVertexNormals out;
    for (auto v : m.vertices()) {
        auto p = m.point(v);
        auto n = m.normal(v) * loaded.normalSign;
        out.positions.push_back({p[0], p[1], p[2]});
        out.normals.push_back(Vec3f{float(n[0]), float(n[1]), float(n[2])});
    }
    return out;
}
}  // namespace

Result<MeshVertexNormals> readMeshVertexNormals(const std::string& path) {
    auto mesh = loadMesh(path, {false, false});
    if (!mesh) return mesh.status();
    return vertexNormals(**mesh);
}

Result<MeshTriangles> readMeshTriangles(const std::string& path, bool textures, const MeshSampling& options, MeshStore* store) {
    auto mesh = sharedMesh(path, textures, options, store);
    if (!mesh) return mesh.status();
    const LoadedMesh& loaded = **mesh;
    const TriMesh& m = loaded.mesh;
    MeshTriangles out{vertexNormals(loaded), {}, {}, {}, {}, {}};
    for (auto f : m.faces()) {
        for (auto h : m.fh_range(f)) out.triangles.push_back(uint32_t(m.to_vertex_handle(h).idx()));
        if (!textures) continue;
        const int t = loaded.textured ? m.texture_index(f) : 0;
        const bool hasTexture = t > 0 && size_t(t) < loaded.textures.size() && loaded.textures[size_t(t)];
        out.triangleTexture.push_back(hasTexture ? t - 1 : -1);
        std::array<float, 6> uv{};
        Vec3f color{0.5f, 0.5f, 0.5f};
        int k = 0;
        if (loaded.hasColors) color = {};
        for (auto h : m.fh_range(f)) {
            if (hasTexture) {
                uv[size_t(2 * k)] = m.texcoord2D(h)[0];
                uv[size_t(2 * k + 1)] = m.texcoord2D(h)[1];
            }
            if (loaded.hasColors)
                for (int c = 0; c < 3; ++c) color[c] += m.color(m.to_vertex_handle(h))[c] / 3;
            ++k;
        }
        if (!loaded.hasColors && loaded.faceColors) color = {m.color(f)[0], m.color(f)[1], m.color(f)[2]};
        out.cornerUvs.push_back(uv);
        out.triangleColor.push_back(color);
    }
    if (textures) {
        // Texture index t + 1 is out.textures[t], shared, not copied.
        if (loaded.textures.size() > 1) out.textures.assign(loaded.textures.begin() + 1, loaded.textures.end());
    }
    return out;
}

}  // namespace surfcast
