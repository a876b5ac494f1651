// glTF 2.0 scenes (.gltf with its buffers and images, or .glb): the
// triangles of the default scene in world space (every node's transform
// applied), with their texture coordinates and base colours, for the mesh
// reader to sample. gltf_reader.cpp says why no glTF library reads them.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "status.h"
#include "texture.h"
#include "vec3.h"

namespace surfcast {

struct GltfMaterial {
    // baseColorTexture: an index into GltfScene::textures, whose texels are
    // already multiplied by baseColorFactor. Without one, the factor is the
    // material's colour.
    std::optional<size_t> texture;
    Vec3f factor{1, 1, 1};
};

struct GltfScene {
    std::vector<Vec3d> positions;           // world space: every node's transform applied
    std::vector<std::array<float, 2>> uvs;  // per vertex, v up from the image's bottom (the OBJ convention)
    std::vector<std::array<uint32_t, 3>> triangles;  // indices into positions, never one repeated
    std::vector<uint32_t> triangleMaterial;  // index into materials, per triangle
    std::vector<GltfMaterial> materials;
    std::vector<Texture> textures;
    std::vector<std::string> warnings;  // what was not read as asked (other texture sets, missing textures allowed)
};

// Errors name the file and what is wrong (a bad accessor, an index past its
// vertices, a node cycle, ...). A base colour texture that cannot be decoded
// is an error, or with allowMissingTextures a warning, its material keeping
// only its factor. Sparse accessors and texture sets other than TEXCOORD_0
// are not read; primitives other than triangles are skipped with a warning.
// External buffers and images must lie in the model's folder unless
// allowOutsidePaths (resolveModelFile).
Result<GltfScene> readGltf(const std::string& path, bool allowMissingTextures, bool allowOutsidePaths = false);

bool isGltfExtension(const std::string& path);  // .gltf, .glb

}  // namespace surfcast
