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
#include <memory>
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

Result<std::unique_ptr<PointReader>> openMeshReader(const std::string& path, const MeshSampling& sampling);

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
    std::vector<Texture> textures;
    std::vector<int> triangleTexture;             // per triangle; empty without `textures`
    std::vector<std::array<float, 6>> cornerUvs;  // per triangle: (u, v) of its 3 corners
    std::vector<Vec3f> triangleColor;             // per triangle, where it has no texture (grey 0.5 without colours)
};
// `options`: what to allow (allowMissingTextures, allowOutsidePaths).
Result<MeshTriangles> readMeshTriangles(const std::string& path, bool textures = false, const MeshSampling& options = {});

// True for file names the mesh path reads (.obj .off .stl .gltf .glb; PLY decides by content).
bool isMeshExtension(const std::string& path);

}  // namespace surfcast
