#include "mesh_reader.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>

#include "ply_reader.h"
#include "random.h"

namespace surfcast {

namespace {

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
    uint64_t rejectedFaces = 0;  // faces OpenMesh refused (non-manifold)
    // Faces wound clockwise (negative signed volume): OpenMesh's normals point
    // inward and are flipped, so surfels face out of the object.
    double normalSign = 1;
};


// OpenMesh's OBJ reader asserts (aborting the process) on a face none of
// whose vertices has an index ("f /2/1 //3", found by fuzz_read_obj). Faces
// are checked first: every vertex of a face starts with a non-zero integer
// index, and a face has at least three.
Status checkObjFaces(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) return Status::error(path + ": cannot open");
    std::string line;
    for (uint64_t number = 1; std::getline(in, line); ++number) {
        size_t at = line.find_first_not_of(" \t");
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

Result<std::unique_ptr<LoadedMesh>> loadMesh(const std::string& path) {
    auto loaded = std::make_unique<LoadedMesh>();
    TriMesh& mesh = loaded->mesh;
    mesh.request_vertex_colors();
    if (lowerExtension(path) == ".ply") {
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
        for (const auto& t : ply->triangles)
            if (!mesh.add_face(handles[t[0]], handles[t[1]], handles[t[2]]).is_valid()) ++loaded->rejectedFaces;
    } else {
        if (lowerExtension(path) == ".obj") SC_TRY(checkObjFaces(path));
        OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexColor;
        if (!OpenMesh::IO::read_mesh(mesh, path, options)) return Status::error(path + ": OpenMesh could not read the mesh");
        loaded->hasColors = options.check(OpenMesh::IO::Options::VertexColor) && mesh.has_vertex_colors();
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
    MeshReader(std::unique_ptr<LoadedMesh> mesh, const std::string& path, const MeshSampling& sampling)
        : mesh_(std::move(mesh)), rng_(sampling.seed), spacing_(sampling.spacing) {
        const TriMesh& m = mesh_->mesh;
        if (!(spacing_ > 0)) {
            std::vector<double> lengths;
            for (auto e : m.edges()) lengths.push_back(m.calc_edge_length(e));
            if (!lengths.empty()) {
                std::nth_element(lengths.begin(), lengths.begin() + lengths.size() / 2, lengths.end());
                spacing_ = 0.5 * lengths[lengths.size() / 2];
            }
            double area = 0;
            for (auto f : m.faces()) area += m.calc_face_area(f);
            const double cap = double(std::max<uint64_t>(1, sampling.maxSurfels));
            if (spacing_ > 0 && area / (spacing_ * spacing_) > cap) {
                const double coarser = std::sqrt(area / cap);
                // Once per file, though each pass of the build opens it again.
                static std::mutex mutex;
                static std::set<std::string> warned;
                std::lock_guard lock(mutex);
                if (warned.insert(path).second)
                    std::fprintf(stderr, "warning: %s: half the median edge (%g) would sample %.3g surfels; spacing %g "
                                 "keeps them to --mesh-max-surfels %llu\n", path.c_str(), spacing_,
                                 area / (spacing_ * spacing_), coarser, (unsigned long long)sampling.maxSurfels);
                spacing_ = coarser;
            }
        }
        desc_.path = path;
        desc_.format = "mesh";
        desc_.hasNormals = true;
        desc_.hasColors = mesh_->hasColors;
        desc_.colorBits = 8;
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        const TriMesh& m = mesh_->mesh;
        size_t n = 0;
        // Meshes without faces (or with faces too small to sample) still give their vertices.
        if (m.n_faces() == 0 || !(spacing_ > 0)) {
            for (; n < max && vertex_ < m.n_vertices(); ++vertex_, ++n) {
                TriMesh::VertexHandle v{int(vertex_)};
                out[n] = makePoint(m.point(v), m.normal(v) * mesh_->normalSign, v, v, v, 1, 0, 0);
            }
            return n;
        }
        while (n < max) {
            if (pending_ == 0) {
                if (face_ >= m.n_faces()) break;
                TriMesh::FaceHandle f{int(face_++)};
                auto fv = m.cfv_iter(f);
                v_[0] = *fv; ++fv; v_[1] = *fv; ++fv; v_[2] = *fv;
                double area = 0.5 * ((m.point(v_[1]) - m.point(v_[0])) % (m.point(v_[2]) - m.point(v_[0]))).norm();
                double expected = area / (spacing_ * spacing_);
                pending_ = uint64_t(std::floor(expected + rng_.uniform()));  // unbiased count
                continue;
            }
            --pending_;
            // Uniform point in the triangle (Osada et al. 2002).
            double r1 = std::sqrt(rng_.uniform()), r2 = rng_.uniform();
            double a = 1 - r1, b = r1 * (1 - r2), c = r1 * r2;
            auto p = m.point(v_[0]) * a + m.point(v_[1]) * b + m.point(v_[2]) * c;
            auto normal = (m.normal(v_[0]) * a + m.normal(v_[1]) * b + m.normal(v_[2]) * c) * mesh_->normalSign;
            out[n++] = makePoint(p, normal, v_[0], v_[1], v_[2], a, b, c);
        }
        return n;
    }

private:
    InputPoint makePoint(const OpenMesh::Vec3d& p, const OpenMesh::Vec3d& normal, TriMesh::VertexHandle v0,
                         TriMesh::VertexHandle v1, TriMesh::VertexHandle v2, double a, double b, double c) const {
        const TriMesh& m = mesh_->mesh;
        InputPoint q;
        q.position = {p[0], p[1], p[2]};
        q.normal = normalizeOrZero(Vec3f{float(normal[0]), float(normal[1]), float(normal[2])});
        if (mesh_->hasColors)
            for (int k = 0; k < 3; ++k) {
                const double unit = m.color(v0)[k] * a + m.color(v1)[k] * b + m.color(v2)[k] * c;
                q.color[k] = unit > 0 ? (unit < 1 ? uint16_t(std::lround(unit * 65535.0)) : uint16_t(65535)) : 0;  // NaN: 0
            }
        return q;
    }

    std::unique_ptr<LoadedMesh> mesh_;
    SplitMix64 rng_;
    double spacing_;
    InputDescription desc_;
    size_t face_ = 0, vertex_ = 0;
    uint64_t pending_ = 0;
    TriMesh::VertexHandle v_[3];
};

}  // namespace

bool isMeshExtension(const std::string& path) {
    std::string ext = lowerExtension(path);
    return ext == ".obj" || ext == ".off" || ext == ".stl";
}

Result<std::unique_ptr<PointReader>> openMeshReader(const std::string& path, const MeshSampling& sampling) {
    auto mesh = loadMesh(path);
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
    auto mesh = loadMesh(path);
    if (!mesh) return mesh.status();
    return vertexNormals(**mesh);
}

Result<MeshTriangles> readMeshTriangles(const std::string& path) {
    auto mesh = loadMesh(path);
    if (!mesh) return mesh.status();
    const TriMesh& m = (*mesh)->mesh;
    MeshTriangles out{vertexNormals(**mesh), {}};
    for (auto f : m.faces())
        for (auto v : m.fv_range(f)) out.triangles.push_back(uint32_t(v.idx()));
    return out;
}

}  // namespace surfcast
