// PLY (Turk 1994): ascii, binary_little_endian, binary_big_endian. Streams the
// vertex element as points; files with faces or triangle strips are meshes and
// go through mesh_reader instead (plyHasFaces tells which).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "byte_stream.h"
#include "input_point.h"
#include "tile_source.h"

namespace surfcast {

enum class PlyType { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

struct PlyProperty {
    std::string name;
    PlyType type = PlyType::Float32;
    bool isList = false;
    PlyType countType = PlyType::UInt8;
};

struct PlyElement {
    std::string name;
    uint64_t count = 0;
    std::vector<PlyProperty> properties;
};

struct PlyHeader {
    enum class Format { Ascii, BinaryLittle, BinaryBig } format = Format::Ascii;
    std::vector<PlyElement> elements;
    std::vector<std::pair<std::string, int>> textureFiles;  // "comment TextureFile NAME": name and header line
};

Result<PlyHeader> parsePlyHeader(ByteStream& in);
// True when the file holds a non-empty face or tristrips element.
bool plyHasFaces(const PlyHeader& header);

// Vertex properties that no fixed attribute takes are scalar fields under
// their own names (integer types at resolution 1); `scalars` selects those decoded.
Result<std::unique_ptr<PointReader>> openPlyReader(const std::string& path, const ScalarSelection& scalars = {},
                                                   const HttpOptions& http = {});

// Whole-file read of a PLY mesh: vertex positions and colours (16-bit scale,
// empty when absent), texture coordinates and texture names, and triangles
// from faces (fans of polygons) or strips, none repeating a vertex.
struct PlyMesh {
    std::vector<Vec3d> vertices;
    std::vector<std::array<uint16_t, 3>> colors;
    std::vector<std::array<uint32_t, 3>> triangles;
    int colorBits = 8;
    // Texture coordinates (MeshLab's conventions): per vertex (s/t, u/v,
    // texture_u/texture_v) or per triangle corner (a face's "texcoord" list),
    // each empty when absent; per triangle its texture ("texnumber"), empty
    // when absent (texture 0); the textures from "comment TextureFile".
    std::vector<std::array<float, 2>> vertexUvs;
    std::vector<std::array<float, 6>> faceUvs;
    std::vector<int> triangleTexture;
    struct TextureFile {
        std::string name;  // as written (resolveModelFile resolves it)
        int line = 0;      // header line
    };
    std::vector<TextureFile> textureFiles;
};
Result<PlyMesh> readPlyMesh(const std::string& path);

}  // namespace surfcast
