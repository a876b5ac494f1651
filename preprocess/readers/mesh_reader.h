// Meshes (PLY with faces or triangle strips, OBJ, OFF, STL, glTF 2.0) through
// OpenMesh, sampled into surfels: uniform random samples on every triangle at
// a target spacing, normals interpolated from OpenMesh's vertex normals
// (flipped when the faces wind inward, i.e. the signed volume is negative).
// Colours come from the face's diffuse texture where it has one (an OBJ's
// map_Kd, a glTF material's baseColorTexture times its baseColorFactor): the
// texture's bilinear reconstruction at the sample's interpolated texture
// coordinates, a point sample. Else from vertex colours, else, on a textured
// mesh, from the material's Kd (glTF: baseColorFactor). The mesh and its
// textures are held in memory; the samples are streamed.
#pragma once

#include <array>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "input_point.h"
#include "texture.h"

namespace surfcast {

// Surfels a mesh gives at most with the default spacing (about this many;
// the count per face is random). A few faces can ask for any density: one
// huge triangle beside many tiny ones made a 3 KB OBJ sample without end
// (fuzz_read_obj). An explicit spacing is taken as given.
inline constexpr uint64_t kDefaultMeshMaxSurfels = 5'000'000;

struct MeshSampling {
    // World units. 0: on a textured mesh, one surfel per texel of the texture
    // area its faces use; otherwise half the median edge length. Either is
    // coarsened to maxSurfels.
    double spacing = 0;
    uint64_t seed = 1;
    uint64_t maxSurfels = kDefaultMeshMaxSurfels;
    // A diffuse texture that cannot be loaded is a warning, and its faces take
    // vertex colours (or Kd), instead of an error.
    bool allowMissingTextures = false;
    // Files the model names may lie outside its folder (resolveModelFile).
    bool allowOutsidePaths = false;
};

// A mesh as read (OpenMesh's topology and attributes, and its textures).
struct LoadedMesh;
// Its bytes in memory: OpenMesh's items and properties, and the textures.
uint64_t meshBytes(const LoadedMesh& mesh);

// Meshes read once and shared by a build's passes over its inputs (scan,
// count, distribute) and its texture fields, instead of read by each. Holds
// meshes up to `capacity` bytes, dropping the least recently used beyond it:
// a mesh dropped is read again when asked for, and a reader still using it
// keeps it. A mesh held costs its topology and the textures nothing else
// holds (a texture field's are counted there). One MeshSampling's file
// options per store. Thread-safe (the read-ahead threads open inputs).
class MeshStore {
public:
    explicit MeshStore(uint64_t capacity) : capacity_(capacity) {}
    Result<std::shared_ptr<const LoadedMesh>> load(const std::string& path, const MeshSampling& options);
    void setCapacity(uint64_t capacity);  // drops meshes beyond it
    uint64_t bytes() const;               // what the meshes held cost
    uint64_t largestBytes() const;        // the most one read of a mesh took so far (its bytes and decoding buffers)
    uint64_t reads() const;               // meshes read from their files so far

private:
    uint64_t heldBytes() const;  // with mutex_ held
    void trim();                 // with mutex_ held
    struct Held {
        std::shared_ptr<const LoadedMesh> mesh;
        uint64_t lastUsed = 0;
    };
    mutable std::mutex mutex_;
    uint64_t capacity_, largest_ = 0, reads_ = 0, clock_ = 0;
    std::map<std::string, Held> held_;
};

// `store`: where the mesh is read once for every pass (null: read here).
Result<std::unique_ptr<PointReader>> openMeshReader(const std::string& path, const MeshSampling& sampling,
                                                    MeshStore* store = nullptr);

// The mesh's vertices with OpenMesh's vertex normals (oriented out of the
// object by the sign of the mesh's volume), to measure estimated normals against.
struct MeshVertexNormals {
    std::vector<Vec3d> positions;
    std::vector<Vec3f> normals;
};
Result<MeshVertexNormals> readMeshVertexNormals(const std::string& path);

// The whole triangle mesh (vertices with outward normals as above, and
// triangles as vertex index triples), for reference renders of the mesh. With
// `textures`, also what the sampler colours surfels from: each triangle's
// diffuse texture (an index into `textures`, -1 for none) and texture
// coordinates (v up), else its colour (vertex colours averaged, or Kd).
struct MeshTriangles {
    MeshVertexNormals vertices;
    std::vector<uint32_t> triangles;  // 3 per triangle
    std::vector<std::shared_ptr<const Texture>> textures;  // null: one that could not be loaded
    std::vector<int> triangleTexture;             // per triangle; empty without `textures`
    std::vector<std::array<float, 6>> cornerUvs;  // per triangle: (u, v) of its 3 corners
    std::vector<Vec3f> triangleColor;             // per triangle, where it has no texture (grey 0.5 without colours)
};
// `options`: what to allow (allowMissingTextures, allowOutsidePaths); `store`:
// the build's meshes (null: read here), whose textures the result shares.
Result<MeshTriangles> readMeshTriangles(const std::string& path, bool textures = false, const MeshSampling& options = {},
                                        MeshStore* store = nullptr);

// True for file names the mesh path reads (.obj .off .stl .gltf .glb; PLY decides by content).
bool isMeshExtension(const std::string& path);

}  // namespace surfcast
