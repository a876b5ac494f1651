// Texture acquisition from textured meshes (Zwicker et al. 2001, §5): image
// textures decoded and reconstructed bilinearly, OBJ material libraries,
// one leaf surfel per texel, and the errors of bad textures.
#include <gtest/gtest.h>
#include <stb_image.h>
#include <stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>

#include "mesh_reader.h"
#include "test_support.h"
#include "texture.h"
#include "texture_field.h"
#include "tileset_reader.h"

using namespace surfcast;

namespace {

// A W x H RGB texture whose texel (i, j) (column i, row j from the top) is f(i, j).
void writePng(const std::string& path, int w, int h, const std::function<Vec3f(int, int)>& f) {
    std::vector<uint8_t> rgb;
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            Vec3f c = f(i, j);
            for (int k = 0; k < 3; ++k) rgb.push_back(uint8_t(c[k]));
        }
    ASSERT_TRUE(stbi_write_png(path.c_str(), w, h, 3, rgb.data(), w * 3));
}

// A quad of 2 x 1 world units in the z = 0 plane, (x, y) = (2 u, v) for
// texture coordinates (u, v) in [0, uvScale]², with material `material`.
std::string quadObj(const std::string& mtl, const std::string& material, double uvScale = 1) {
    const std::string s = std::to_string(uvScale);
    return "mtllib " + mtl + "\nv 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nvt 0 0\nvt " + s + " 0\nvt " + s + " " + s + "\nvt 0 " + s +
           "\nusemtl " + material + "\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
}

std::vector<InputPoint> readAll(PointReader& reader) {
    std::vector<InputPoint> all;
    std::vector<InputPoint> batch(4096);
    while (true) {
        auto n = reader.read(batch.data(), batch.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        all.insert(all.end(), batch.begin(), batch.begin() + long(*n));
    }
    return all;
}

}  // namespace

TEST(Texture, BilinearReconstructionAndRepeatMatchHandDerivedValues) {
    test::TempDir dir;
    // 2 x 2 texels: top row (10, 20), bottom row (30, 40) in red.
    writePng(dir.file("t.png"), 2, 2, [](int i, int j) { return Vec3f{float(10 + 10 * i + 20 * j), 0, 255}; });
    auto t = loadTexture(dir.file("t.png"));
    ASSERT_TRUE(t.ok()) << t.status().message();
    EXPECT_EQ(t->width, 2);
    EXPECT_EQ(t->height, 2);
    // Texel centres: u = 0.25, 0.75; v = 0.75 (top row), 0.25 (bottom row).
    EXPECT_FLOAT_EQ(t->sample(0.25, 0.75)[0] * 255, 10);
    EXPECT_FLOAT_EQ(t->sample(0.75, 0.75)[0] * 255, 20);
    EXPECT_FLOAT_EQ(t->sample(0.25, 0.25)[0] * 255, 30);
    EXPECT_FLOAT_EQ(t->sample(0.75, 0.25)[0] * 255, 40);
    EXPECT_FLOAT_EQ(t->sample(0.5, 0.5)[0] * 255, 25);    // the four texels' mean
    EXPECT_FLOAT_EQ(t->sample(0.5, 0.75)[0] * 255, 15);   // halfway along the top row
    // Repeat: u = 0 lies halfway between the last column and the first.
    EXPECT_FLOAT_EQ(t->sample(0.0, 0.75)[0] * 255, 15);
    EXPECT_FLOAT_EQ(t->sample(3.25, -1.25)[0] * 255, 10);
    EXPECT_FLOAT_EQ(t->sample(0.25, 0.75)[2], 1.f);
    EXPECT_FLOAT_EQ(t->sample(NAN, 0.5)[0] * 255, 25);  // as (0, 0): the corner, all four texels' mean
}

// A mesh without textures asked for its textures (surfcast-mesh-reference
// --colors on any mesh): none (an empty list, not one indexed past its end),
// and its triangles with their colours.
TEST(TexturedMesh, AMeshWithoutTexturesHasNone) {
    test::TempDir dir;
    test::writeFile(dir.file("t.off"), "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
    auto mesh = readMeshTriangles(dir.file("t.off"), true);
    ASSERT_TRUE(mesh) << mesh.status().message();
    EXPECT_TRUE(mesh->textures.empty());
    EXPECT_EQ(mesh->triangles.size(), 6u);
    ASSERT_EQ(mesh->triangleTexture.size(), 2u);
    EXPECT_EQ(mesh->triangleTexture[0], -1);
    EXPECT_FLOAT_EQ(mesh->triangleColor[1][0], 0.5f);
}

// A ramp texture reconstructed bilinearly is linear between texel centres, so
// every leaf sample's colour follows from its position alone: on the quad,
// u = x / 2 and v = y, and red = 4 (64 u - 0.5), green = 4 (63.5 - 64 v)
// (texel column i has red 4 i, row j from the top green 4 j). Stored colours
// are rounded to 8 bits: within 0.5 of that.
TEST(TexturedMesh, LeafColoursAreTheTextureAtEachSampledPoint) {
    test::TempDir dir;
    writePng(dir.file("ramp.png"), 64, 64, [](int i, int j) { return Vec3f{float(4 * i), float(4 * j), 77}; });
    test::writeFile(dir.file("m.mtl"), "newmtl ramp\nKd 1 1 1\nmap_Kd ramp.png\n");
    test::writeFile(dir.file("quad.obj"), quadObj("m.mtl", "ramp"));
    auto r = openMeshReader(dir.file("quad.obj"), MeshSampling{});
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE((*r)->description().hasColors);
    const auto all = readAll(**r);
    // One surfel per texel: 4,096 texels over the area 2, each of the two
    // faces sampled floor(2048 + U) times, U uniform in [0, 1).
    EXPECT_GE(all.size(), 4096u);
    EXPECT_LE(all.size(), 4098u);
    size_t checked = 0;
    for (const InputPoint& p : all) {
        const double u = p.position.x / 2, v = p.position.y;
        // Within half a texel of the border the reconstruction wraps around.
        if (u < 0.5 / 64 || u > 63.5 / 64 || v < 0.5 / 64 || v > 63.5 / 64) continue;
        ++checked;
        EXPECT_NEAR(p.color[0] / 257.0, 4 * (64 * u - 0.5), 0.5 + 1e-3) << u << " " << v;
        EXPECT_NEAR(p.color[1] / 257.0, 4 * (63.5 - 64 * v), 0.5 + 1e-3) << u << " " << v;
        EXPECT_EQ(p.color[2], 77 * 257);
        EXPECT_EQ(p.color[0] % 257, 0) << "8-bit colour, stored as c * 257";
    }
    EXPECT_GT(checked, 3800u);
}

// Texture coordinates in [0, 3]: the texture repeats 3 x 3 times, so the
// quad uses 9 times the texels, and colours repeat with period 2/3 in x.
TEST(TexturedMesh, CoordinatesOutsideTheUnitSquareRepeat) {
    test::TempDir dir;
    writePng(dir.file("ramp.png"), 16, 16, [](int i, int) { return Vec3f{float(16 * i), 0, 0}; });
    test::writeFile(dir.file("m.mtl"), "newmtl ramp\nmap_Kd ramp.png\n");
    test::writeFile(dir.file("quad.obj"), quadObj("m.mtl", "ramp", 3));
    auto r = openMeshReader(dir.file("quad.obj"), MeshSampling{});
    ASSERT_TRUE(r.ok()) << r.status().message();
    const auto all = readAll(**r);
    EXPECT_GE(all.size(), 9u * 256);
    EXPECT_LE(all.size(), 9u * 256 + 2);
    for (const InputPoint& p : all) {
        const double u = 3 * p.position.x / 2, frac = u - std::floor(u);
        if (frac < 0.5 / 16 || frac > 15.5 / 16) continue;
        EXPECT_NEAR(p.color[0] / 257.0, 16 * (16 * frac - 0.5), 0.5 + 1e-3) << u;
    }
}

// Several materials in one file: two textures and a material without a map,
// whose faces take its Kd.
TEST(TexturedMesh, SeveralMaterialsEachColourTheirFaces) {
    test::TempDir dir;
    writePng(dir.file("red.png"), 4, 4, [](int, int) { return Vec3f{255, 0, 0}; });
    std::filesystem::create_directories(dir.file("maps"));
    writePng(dir.file("maps/blue.png"), 4, 4, [](int, int) { return Vec3f{0, 0, 255}; });
    test::writeFile(dir.file("m.mtl"),
                    "newmtl red\nmap_Kd red.png\nnewmtl blue\nmap_Kd -s 1 1 1 maps/blue.png\nnewmtl green\nKd 0 1 0\n");
    test::writeFile(dir.file("three.obj"),
                    "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 2 0 0\nv 2 1 0\nv 3 0 0\nv 3 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n"
                    "usemtl red\nf 1/1 2/2 3/3\nusemtl blue\nf 2/1 4/2 5/3\nusemtl green\nf 4/1 6/2 7/3\n");
    auto r = openMeshReader(dir.file("three.obj"), MeshSampling{0.02});
    ASSERT_TRUE(r.ok()) << r.status().message();
    size_t seen[3] = {};
    for (const InputPoint& p : readAll(**r)) {
        const int face = std::clamp(int(p.position.x), 0, 2);
        const uint16_t expected[3][3] = {{65535, 0, 0}, {0, 0, 65535}, {0, 65535, 0}};
        ++seen[face];
        for (int k = 0; k < 3; ++k) ASSERT_EQ(p.color[k], expected[face][k]) << "face " << face << " at x " << p.position.x;
    }
    for (size_t s : seen) EXPECT_GT(s, 1000u);
}

TEST(TexturedMesh, BadTexturesAreClearErrors) {
    test::TempDir dir;
    auto openWith = [&](const std::string& mtl, bool allowMissing = false) {
        test::writeFile(dir.file("m.mtl"), mtl);
        test::writeFile(dir.file("quad.obj"), quadObj("m.mtl", "a"));
        MeshSampling sampling{0.05};
        sampling.allowMissingTextures = allowMissing;
        return openMeshReader(dir.file("quad.obj"), sampling);
    };
    auto expectError = [&](const Result<std::unique_ptr<PointReader>>& r, const std::string& what) {
        ASSERT_FALSE(r.ok()) << what;
        EXPECT_NE(r.status().message().find(what), std::string::npos) << r.status().message();
    };
    // A missing diffuse map: an error naming the library's line.
    expectError(openWith("newmtl a\nKd 0 1 0\nmap_Kd missing.png\n"), "m.mtl: line 3: map_Kd 'missing.png': ");
    expectError(openWith("newmtl a\nmap_Kd missing.png\n"), "texture not found");
    // ... or, when allowed, a warning, and the faces take Kd.
    auto allowed = openWith("newmtl a\nKd 0 1 0\nmap_Kd missing.png\n", true);
    ASSERT_TRUE(allowed.ok()) << allowed.status().message();
    for (const InputPoint& p : readAll(**allowed)) EXPECT_EQ(p.color[1], 65535);
    // A missing map Surfcast does not use is no error.
    writePng(dir.file("ok.png"), 2, 2, [](int, int) { return Vec3f{1, 2, 3}; });
    EXPECT_TRUE(openWith("newmtl a\nmap_Kd ok.png\nmap_Ks nowhere.jpg\n").ok());
    // A corrupt JPEG (a real header, then garbage) and an image of 0 x 0.
    test::writeFile(dir.file("bad.jpg"), std::string("\xFF\xD8\xFF\xE0\x00\x10JFIF\x00", 11) + std::string(200, '\x55'));
    expectError(openWith("newmtl a\nmap_Kd bad.jpg\n"), "m.mtl: line 2: map_Kd 'bad.jpg': ");
    auto png = [](uint32_t w, uint32_t h) {
        std::string s("\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR", 16);
        for (uint32_t v : {w, h}) s += std::string{char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
        return s + std::string("\x08\x02\x00\x00\x00\x00\x00\x00\x00", 9);
    };
    test::writeFile(dir.file("empty.png"), png(0, 0));
    expectError(openWith("newmtl a\nmap_Kd empty.png\n"), "m.mtl: line 2: map_Kd 'empty.png': ");
    // A header claiming 100,000 x 100,000 texels is refused before decoding.
    test::writeFile(dir.file("huge.png"), png(100000, 100000));
    expectError(openWith("newmtl a\nmap_Kd huge.png\n"), "huge.png");
    // Texture coordinates of NaN or beyond a double.
    test::writeFile(dir.file("m.mtl"), "newmtl a\nmap_Kd ok.png\n");
    for (const std::string vt : {"nan nan", "0 1e999"}) {
        test::writeFile(dir.file("nan.obj"),
                        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt " + vt + "\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3\n");
        expectError(openMeshReader(dir.file("nan.obj"), MeshSampling{}), "nan.obj: line 6: texture coordinate '");
    }
    // The build itself: exit 1, the message, no set written.
    test::writeFile(dir.file("m.mtl"), "newmtl a\nmap_Kd missing.png\n");
    auto build = test::run({test::binary("surfcast-build"), dir.file("quad.obj"), "-o", dir.file("out")});
    EXPECT_EQ(build.exitCode, 1) << build.output;
    EXPECT_NE(build.output.find("map_Kd 'missing.png'"), std::string::npos) << build.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("out")));
}


// PLY textures in MeshLab's conventions: "comment TextureFile", per-corner
// "texcoord" lists beside the vertex indices, per-vertex s/t, and polygons.
// A face's lists are read apart: read as one, corners.ply's texture
// coordinates would become vertex indices of extra triangles (1.5 times the
// quad's area sampled), which the surfel count below catches. Each carries the ramp quad of
// LeafColoursAreTheTextureAtEachSampledPoint, so the same colours follow.
TEST(TexturedMesh, PlyTextureCoordinatesPerCornerOrPerVertex) {
    test::TempDir dir;
    writePng(dir.file("ramp.png"), 64, 64, [](int i, int j) { return Vec3f{float(4 * i), float(4 * j), 77}; });
    const std::string head = "ply\nformat ascii 1.0\ncomment made by hand\ncomment TextureFile ramp.png\n";
    const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
    const std::map<std::string, std::string> files{
        {"corners.ply", head + "element vertex 4\n" + xyz +
                            "element face 2\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\n"
                            "end_header\n0 0 0\n2 0 0\n2 1 0\n0 1 0\n3 0 1 2 6 0 0 1 0 1 1\n3 0 2 3 6 0 0 1 1 0 1\n"},
        {"polygon.ply", head + "element vertex 4\n" + xyz +
                            "element face 1\nproperty list uchar float texcoord\nproperty list uchar int vertex_indices\n"
                            "property int texnumber\nend_header\n0 0 0\n2 0 0\n2 1 0\n0 1 0\n8 0 0 1 0 1 1 0 1 4 0 1 2 3 0\n"},
        {"vertices.ply", head + "element vertex 4\n" + xyz +
                             "property float s\nproperty float t\nelement face 2\nproperty list uchar int vertex_indices\n"
                             "end_header\n0 0 0 0 0\n2 0 0 1 0\n2 1 0 1 1\n0 1 0 0 1\n3 0 1 2\n3 0 2 3\n"}};
    for (const auto& [name, text] : files) {
        test::writeFile(dir.file(name), text);
        auto r = openMeshReader(dir.file(name), MeshSampling{});
        ASSERT_TRUE(r.ok()) << name << ": " << r.status().message();
        const auto all = readAll(**r);
        EXPECT_GE(all.size(), 4096u) << name;
        EXPECT_LE(all.size(), 4098u) << name;
        for (const InputPoint& p : all) {
            const double u = p.position.x / 2, v = p.position.y;
            if (u < 0.5 / 64 || u > 63.5 / 64 || v < 0.5 / 64 || v > 63.5 / 64) continue;
            ASSERT_NEAR(p.color[0] / 257.0, 4 * (64 * u - 0.5), 0.5 + 1e-3) << name << " " << u << " " << v;
            ASSERT_NEAR(p.color[1] / 257.0, 4 * (63.5 - 64 * v), 0.5 + 1e-3) << name << " " << u << " " << v;
        }
    }
    // A missing texture names the header line.
    test::writeFile(dir.file("missing.ply"), "ply\nformat ascii 1.0\ncomment TextureFile gone.png\nelement vertex 3\n" + xyz +
                                                 "property float s\nproperty float t\nelement face 1\n"
                                                 "property list uchar int vertex_indices\nend_header\n0 0 0 0 0\n1 0 0 1 0\n"
                                                 "0 1 0 0 1\n3 0 1 2\n");
    auto missing = openMeshReader(dir.file("missing.ply"), MeshSampling{});
    ASSERT_FALSE(missing.ok());
    EXPECT_NE(missing.status().message().find("missing.ply: line 3: comment TextureFile 'gone.png'"), std::string::npos)
        << missing.status().message();
    // Texture coordinates that do not pair with the vertices.
    test::writeFile(dir.file("short.ply"), head + "element vertex 3\n" + xyz +
                                               "element face 1\nproperty list uchar int vertex_indices\n"
                                               "property list uchar float texcoord\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 4 0 0 1 0\n");
    auto uneven = openMeshReader(dir.file("short.ply"), MeshSampling{});
    ASSERT_FALSE(uneven.ok());
    EXPECT_NE(uneven.status().message().find("has 4 texture coordinates for 3 vertices"), std::string::npos)
        << uneven.status().message();
}

namespace {

// A glTF scene: a textured unit quad (the 64 x 64 ramp times baseColorFactor
// (0.5, 1, 1)) placed by a node translated by (10, 0, 0) and scaled by 2, and
// an untextured unit quad of baseColorFactor (0, 1, 0) translated by (0, 5, 0).
// glTF's texture coordinates run down the image: the vertex at y = 0 has v = 1.
struct GltfFixture {
    std::string bin;   // positions, texture coordinates, indices
    std::string json;  // with "BUFFER" and "IMAGE" left for the caller
    GltfFixture() {
        auto put = [&](auto v) { bin.append(reinterpret_cast<const char*>(&v), sizeof v); };
        for (float p : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 1.f, 1.f, 0.f, 0.f, 1.f, 0.f}) put(p);  // 48 bytes
        for (float t : {0.f, 1.f, 1.f, 1.f, 1.f, 0.f, 0.f, 0.f}) put(t);                      // 32 bytes
        for (uint16_t i : {0, 1, 2, 0, 2, 3}) put(i);                                          // 12 bytes
        json = R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
  "nodes": [{"mesh": 0, "translation": [10, 0, 0], "scale": [2, 2, 2]}, {"mesh": 1, "translation": [0, 5, 0]}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]},
             {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2, "material": 1}]}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "baseColorFactor": [0.5, 1, 1, 1]}},
                {"pbrMetallicRoughness": {"baseColorFactor": [0, 1, 0, 1]}}],
  "textures": [{"source": 0}],
  "images": [IMAGE],
  "buffers": [BUFFER],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                  {"buffer": 0, "byteOffset": 80, "byteLength": 12}IMAGEVIEW],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
                {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]})";
    }
    static std::string replace(std::string s, const std::string& from, const std::string& to) {
        s.replace(s.find(from), from.size(), to);
        return s;
    }
};

void expectGltfScene(PointReader& reader) {
    size_t textured = 0, plain = 0;
    for (const InputPoint& p : readAll(reader)) {
        if (p.position.y >= 5) {  // the untextured quad
            ++plain;
            EXPECT_EQ(p.color[0], 0);
            EXPECT_EQ(p.color[1], 65535);
            EXPECT_EQ(p.color[2], 0);
            continue;
        }
        ++textured;
        const double u = (p.position.x - 10) / 2, v = p.position.y / 2;
        EXPECT_GE(u, -1e-9);
        if (u < 0.5 / 64 || u > 63.5 / 64 || v < 0.5 / 64 || v > 63.5 / 64) continue;
        // Texel column i: red 4 i times the factor 0.5, i.e. 2 i, exactly.
        EXPECT_NEAR(p.color[0] / 257.0, 2 * (64 * u - 0.5), 0.5 + 1e-3) << u << " " << v;
        EXPECT_NEAR(p.color[1] / 257.0, 4 * (63.5 - 64 * v), 0.5 + 1e-3) << u << " " << v;
    }
    // One surfel per texel: 4,096 texels over the textured quad's area 4 (so
    // 1,024 on the unit quad), each face sampled floor(expected + U) times.
    EXPECT_GE(textured, 4096u);
    EXPECT_LE(textured, 4098u);
    EXPECT_GE(plain, 1024u);
    EXPECT_LE(plain, 1026u);
}

}  // namespace

TEST(TexturedMesh, GltfScenesCarryTransformsTexturesAndBaseColours) {
    test::TempDir dir;
    writePng(dir.file("ramp.png"), 64, 64, [](int i, int j) { return Vec3f{float(4 * i), float(4 * j), 77}; });
    GltfFixture f;
    test::writeFile(dir.file("scene.bin"), f.bin);
    std::string json = GltfFixture::replace(f.json, "BUFFER", R"({"uri": "scene.bin", "byteLength": 92})");
    json = GltfFixture::replace(json, "IMAGE", R"({"uri": "ramp.png"})");
    test::writeFile(dir.file("scene.gltf"), GltfFixture::replace(json, "IMAGEVIEW", ""));
    auto r = openMeshReader(dir.file("scene.gltf"), MeshSampling{});
    ASSERT_TRUE(r.ok()) << r.status().message();
    expectGltfScene(**r);

    // The same as one .glb: the PNG inside the binary chunk.
    std::ifstream png(dir.file("ramp.png"), std::ios::binary);
    const std::string image((std::istreambuf_iterator<char>(png)), std::istreambuf_iterator<char>());
    std::string bin = f.bin + image;
    while (bin.size() % 4) bin += '\0';
    json = GltfFixture::replace(f.json, "BUFFER", R"({"byteLength": )" + std::to_string(bin.size()) + "}");
    json = GltfFixture::replace(json, "IMAGE", R"({"bufferView": 3, "mimeType": "image/png"})");
    json = GltfFixture::replace(json, "IMAGEVIEW",
                                R"(, {"buffer": 0, "byteOffset": 92, "byteLength": )" + std::to_string(image.size()) + "}");
    while (json.size() % 4) json += ' ';
    auto u32 = [](uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
    const std::string glb = "glTF" + u32(2) + u32(uint32_t(12 + 8 + json.size() + 8 + bin.size())) + u32(uint32_t(json.size())) +
                            "JSON" + json + u32(uint32_t(bin.size())) + std::string("BIN\0", 4) + bin;
    test::writeFile(dir.file("scene.glb"), glb);
    auto b = openMeshReader(dir.file("scene.glb"), MeshSampling{});
    ASSERT_TRUE(b.ok()) << b.status().message();
    expectGltfScene(**b);

    // Bad scenes are clear errors.
    auto expectError = [&](const std::string& text, const std::string& what) {
        test::writeFile(dir.file("bad.gltf"), text);
        auto bad = openMeshReader(dir.file("bad.gltf"), MeshSampling{});
        ASSERT_FALSE(bad.ok()) << what;
        EXPECT_NE(bad.status().message().find(what), std::string::npos) << bad.status().message();
    };
    std::string good = GltfFixture::replace(f.json, "BUFFER", R"({"uri": "scene.bin", "byteLength": 92})");
    good = GltfFixture::replace(GltfFixture::replace(good, "IMAGE", R"({"uri": "ramp.png"})"), "IMAGEVIEW", "");
    expectError(GltfFixture::replace(good, R"("count": 6)", R"("count": 600)"), "600 elements do not fit the buffer view");
    expectError(GltfFixture::replace(good, R"("translation": [0, 5, 0]})", R"("translation": [0, 5, 0], "children": [1]})"),
                "is its own ancestor");
    expectError(GltfFixture::replace(good, R"({"uri": "ramp.png"})", R"({"uri": "nowhere.png"})"), "baseColorTexture");
    expectError("{ not json", "not glTF (its JSON does not parse to an object)");
    // A data uri with its comma before where ";base64" would end (fuzz_read_gltf:
    // std::string::compare threw out of range, uncaught, and the process aborted).
    expectError(GltfFixture::replace(good, R"("uri": "scene.bin")", R"("uri": "data:,AAAA")"), "a data uri that is not base64");
    // Indices past the quad's four vertices.
    test::writeFile(dir.file("far.bin"), f.bin.substr(0, 80) + std::string("\x00\x00\x01\x00\x09\x00\x00\x00\x02\x00\x03\x00", 12));
    expectError(GltfFixture::replace(good, "scene.bin", "far.bin"), "index 9 past its 4 vertices");
    // A triangle repeating a vertex (OpenMesh's add_face asserts on one) is dropped.
    test::writeFile(dir.file("dup.bin"), f.bin.substr(0, 80) + std::string("\x00\x00\x01\x00\x00\x00\x00\x00\x02\x00\x03\x00", 12));
    test::writeFile(dir.file("dup.gltf"), GltfFixture::replace(good, "scene.bin", "dup.bin"));
    auto dup = openMeshReader(dir.file("dup.gltf"), MeshSampling{0.05});
    ASSERT_TRUE(dup.ok()) << dup.status().message();
    EXPECT_GT(readAll(**dup).size(), 0u);
    // A missing texture, allowed: the material keeps its factor (0.5, 1, 1).
    test::writeFile(dir.file("bad.gltf"), GltfFixture::replace(good, R"({"uri": "ramp.png"})", R"({"uri": "nowhere.png"})"));
    MeshSampling allow;
    allow.allowMissingTextures = true;
    auto allowed = openMeshReader(dir.file("bad.gltf"), allow);
    ASSERT_TRUE(allowed.ok()) << allowed.status().message();
    for (const InputPoint& p : readAll(**allowed)) {
        if (p.position.y < 5) {
            EXPECT_EQ(p.color[0], 32768) << "0.5 of 65535, rounded";
        }
    }
}

// Nodes shared by many parents are instanced each time: 1 x 1,000 x 68 paths
// to a mesh of 1,000 unindexed vertices in a file of a few kilobytes expand
// to 68,000 x 1,000 = 68 M vertices (2.2 GB here, about 10 in OpenMesh; a
// megabyte of such nodes can ask for 70 GB). Counted from the accessors
// before anything is decoded, and refused once past 2^26 = 67,108,864.
TEST(TexturedMesh, GltfInstancesAreCountedBeforeTheyExpand) {
    test::TempDir dir;
    std::string bin;
    for (int v = 0; v < 1000; ++v)
        for (float c : {float(v % 10), float(v / 10), 0.f}) bin.append(reinterpret_cast<const char*>(&c), 4);
    test::writeFile(dir.file("many.bin"), bin);
    auto children = [](int node, int n) {
        std::string s = "[";
        for (int i = 0; i < n; ++i) {
            if (i) s += ',';
            s += std::to_string(node);
        }
        return s + "]";
    };
    test::writeFile(dir.file("many.gltf"),
                    R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
  "nodes": [{"children": )" + children(1, 1000) + R"(}, {"children": )" + children(2, 68) + R"(}, {"mesh": 0}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
  "buffers": [{"uri": "many.bin", "byteLength": 12000}], "bufferViews": [{"buffer": 0, "byteLength": 12000}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 1000, "type": "VEC3"}]})");
    auto r = openMeshReader(dir.file("many.gltf"), MeshSampling{});
    ASSERT_FALSE(r.ok());
    const std::string refused = "the scene's node instances expand to over 67108864 vertices or 134217728 triangles";
    EXPECT_NE(r.status().message().find("many.gltf: " + refused), std::string::npos) << r.status().message();
    // Counts that lie: four primitives of 2^62 vertices each would sum to 0
    // in 64 bits; the sum is checked as it grows.
    std::string lying = test::readFile(dir.file("many.gltf"));
    auto swap = [&](const std::string& from, const std::string& to) {
        ASSERT_NE(lying.find(from), std::string::npos) << from;
        lying.replace(lying.find(from), from.size(), to);
    };
    const std::string primitive = R"({"attributes": {"POSITION": 0}})";
    swap(R"("nodes": [0]}])", R"("nodes": [2]}])");  // the mesh's node alone
    swap(primitive, primitive + ", " + primitive + ", " + primitive + ", " + primitive);
    swap(R"("count": 1000)", R"("count": 4611686018427387904)");
    test::writeFile(dir.file("lying.gltf"), lying);
    auto l = openMeshReader(dir.file("lying.gltf"), MeshSampling{});
    ASSERT_FALSE(l.ok());
    EXPECT_NE(l.status().message().find("lying.gltf: " + refused), std::string::npos) << l.status().message();
}

// A model's external files resolve inside its folder, so that a model from
// elsewhere cannot make the build read any file the user can ("../" or an
// absolute path in a glTF uri, an OBJ mtllib or map_Kd, a PLY TextureFile). Each is an
// error naming it; --allow-outside-paths reads them. A library in a subfolder
// may still name a map beside the model.
TEST(TexturedMesh, ExternalFilesStayInsideTheModelsFolder) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("model/mats"));
    std::filesystem::create_directories(dir.file("elsewhere"));
    auto ramp = [](int i, int j) { return Vec3f{float(4 * i), float(4 * j), 77}; };
    writePng(dir.file("elsewhere/secret.png"), 64, 64, ramp);
    writePng(dir.file("model/ramp.png"), 64, 64, ramp);
    GltfFixture f;
    test::writeFile(dir.file("elsewhere/scene.bin"), f.bin);
    test::writeFile(dir.file("model/scene.bin"), f.bin);
    auto gltf = [&](const std::string& buffer, const std::string& image) {
        std::string json = GltfFixture::replace(f.json, "BUFFER", R"({"uri": ")" + buffer + R"(", "byteLength": 92})");
        return GltfFixture::replace(GltfFixture::replace(json, "IMAGE", R"({"uri": ")" + image + R"("})"), "IMAGEVIEW", "");
    };
    const std::string secret = dir.file("elsewhere/secret.png");
    test::writeFile(dir.file("elsewhere/x.mtl"), "newmtl a\nmap_Kd secret.png\n");
    test::writeFile(dir.file("model/map.mtl"), "newmtl a\nmap_Kd ../elsewhere/secret.png\n");
    test::writeFile(dir.file("model/mats/sub.mtl"), "newmtl a\nmap_Kd ../ramp.png\n");
    const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
    const std::vector<std::pair<std::string, std::string>> escapes = {
        {"up.gltf", "up.gltf: buffer 0: '../elsewhere/scene.bin' lies outside the model's folder"},
        {"absolute.gltf", "absolute.gltf: image 0: '" + secret + "' lies outside the model's folder"},
        {"up.obj", "up.obj: line 1: mtllib '../elsewhere/x.mtl' lies outside the model's folder"},
        // Separators OpenMesh takes too: a tab after the keyword, a carriage return before it.
        {"tab.obj", "tab.obj: line 1: mtllib '../elsewhere/x.mtl' lies outside the model's folder"},
        {"cr.obj", "cr.obj: line 1: mtllib '../elsewhere/x.mtl' lies outside the model's folder"},
        {"map.obj", "map.mtl: line 2: map_Kd '../elsewhere/secret.png' lies outside the model's folder"},
        {"up.ply", "up.ply: line 3: comment TextureFile '../elsewhere/secret.png' lies outside the model's folder"}};
    test::writeFile(dir.file("model/up.gltf"), gltf("../elsewhere/scene.bin", "ramp.png"));
    test::writeFile(dir.file("model/absolute.gltf"), gltf("scene.bin", secret));
    test::writeFile(dir.file("model/up.obj"), quadObj("../elsewhere/x.mtl", "a"));
    const std::string quad = quadObj("../elsewhere/x.mtl", "a");
    test::writeFile(dir.file("model/tab.obj"), "mtllib\t" + quad.substr(7));
    test::writeFile(dir.file("model/cr.obj"), "\r" + quad);
    test::writeFile(dir.file("model/map.obj"), quadObj("map.mtl", "a"));
    test::writeFile(dir.file("model/up.ply"), "ply\nformat ascii 1.0\ncomment TextureFile ../elsewhere/secret.png\n"
                                              "element vertex 3\n" + xyz + "property float s\nproperty float t\n"
                                              "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                              "0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n");
    MeshSampling allowed;
    allowed.allowOutsidePaths = true;
    for (const auto& [name, message] : escapes) {
        auto refused = openMeshReader(dir.file("model/" + name), MeshSampling{});
        ASSERT_FALSE(refused.ok()) << name;
        EXPECT_NE(refused.status().message().find(message), std::string::npos) << refused.status().message();
        EXPECT_NE(refused.status().message().find("(--allow-outside-paths reads it)"), std::string::npos)
            << refused.status().message();
        auto read = openMeshReader(dir.file("model/" + name), allowed);
        ASSERT_TRUE(read.ok()) << name << ": " << read.status().message();
        EXPECT_GT(readAll(**read).size(), 0u) << name;
    }
    test::writeFile(dir.file("model/sub.obj"), quadObj("mats/sub.mtl", "a"));
    auto sub = openMeshReader(dir.file("model/sub.obj"), MeshSampling{});
    ASSERT_TRUE(sub.ok()) << sub.status().message();
    // surfcast-build says so, writes nothing, and takes the option.
    auto build = test::run({test::binary("surfcast-build"), dir.file("model/map.obj"), "-o", dir.file("out")});
    EXPECT_EQ(build.exitCode, 1) << build.output;
    EXPECT_NE(build.output.find("map_Kd '../elsewhere/secret.png' lies outside"), std::string::npos) << build.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("out")));
    auto opted = test::run({test::binary("surfcast-build"), "-q", dir.file("model/map.obj"), "--allow-outside-paths", "-o",
                            dir.file("out")});
    EXPECT_EQ(opted.exitCode, 0) << opted.output;
}

namespace {
struct Rgb {
    int width = 0, height = 0;
    std::vector<uint8_t> pixels;
    const uint8_t* at(int x, int y) const { return &pixels[3 * (size_t(y) * size_t(width) + size_t(x))]; }
    bool background(int x, int y) const { return at(x, y)[0] == 255 && at(x, y)[1] == 255 && at(x, y)[2] == 255; }
};
Rgb readPng(const std::string& path) {
    Rgb img;
    int n = 0;
    uint8_t* p = stbi_load(path.c_str(), &img.width, &img.height, &n, 3);
    EXPECT_NE(p, nullptr) << path;
    if (p) img.pixels.assign(p, p + size_t(img.width) * size_t(img.height) * 3);
    stbi_image_free(p);
    return img;
}
}  // namespace

// The texture fields (decoded texels, mip levels, triangles) count against
// --memory, and the mesh is read once, not once a pass. An 8192 x 8192
// texture is 192 MiB of texels and 64 MiB of mip levels above them (each a
// quarter of the one below: 192 x (1/4 + 1/16 + ...) = 64), so the field
// holds 256 MiB whatever the chunks: under --memory 256M the build stops with
// an error that names them. Under 768M it fits (the minimum is the 48 MiB
// baseline, the field's 256 MiB and the mesh while it is read, its 192 MiB
// texture twice while decoding, and the JPEG file: about 700 MiB): peak RSS
// within the budget (+10 %, as out_of_core_test) and the mesh read once
// (uncounted fields would let the build pass at about 885 MiB, measured on an
// 8192² PPM of the same size). Under the sanitizers, where RSS is not
// checked, a 4096² texture: 64 MiB held, so 64M is too small, and 256M enough
// (the minimum: 48 + 64 + 2 x 48 MiB and the file, about 210).
TEST(TexturedMesh, LargeTexturesCountAgainstTheMemoryBudget) {
    test::TempDir dir;
    const size_t side = test::kSanitized ? 4096 : 8192;
    const int heldMiB = int(side * side * 4 >> 20);  // 3 bytes a texel, and a third more for the mip levels
    {
        std::vector<uint8_t> rgb(side * side * 3);
        for (size_t j = 0; j < side; ++j)
            for (size_t i = 0; i < side; ++i) {
                uint8_t* p = &rgb[3 * (j * side + i)];
                p[0] = uint8_t(i / 32), p[1] = uint8_t(j / 32), p[2] = uint8_t((i / 512 + j / 512) % 2 * 255);
            }
        ASSERT_TRUE(stbi_write_jpg(dir.file("big.jpg").c_str(), int(side), int(side), 3, rgb.data(), 90));
    }
    test::writeFile(dir.file("m.mtl"), "newmtl big\nmap_Kd big.jpg\n");
    test::writeFile(dir.file("quad.obj"), quadObj("m.mtl", "big"));
    auto build = [&](const std::string& memory) {
        return test::run({test::binary("surfcast-build"), dir.file("quad.obj"), "--mesh-spacing", "0.005", "--texture-filter", "ewa",
                          "--threads", "2", "--memory", memory, "-o", dir.file("set-" + memory)});
    };
    const int budgetMiB = test::kSanitized ? 256 : 768;
    const std::string tightBudget = std::to_string(heldMiB) + "M", budget = std::to_string(budgetMiB) + "M";
    auto tight = build(tightBudget);
    EXPECT_NE(tight.exitCode, 0) << tight.output;
    EXPECT_NE(tight.output.find("--memory " + std::to_string(heldMiB) + " MiB is too small"), std::string::npos) << tight.output;
    const std::string named = "the textured meshes' textures, mip levels and triangles take ";
    const size_t at = tight.output.find(named);
    ASSERT_NE(at, std::string::npos) << tight.output;
    const int held = std::atoi(tight.output.c_str() + at + named.size());
    EXPECT_GE(held, heldMiB) << tight.output;  // the texels and mip levels, and the two triangles' few bytes
    EXPECT_LE(held, heldMiB + 1) << tight.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("set-" + tightBudget))) << "a half-written set";

    auto fits = build(budget);
    ASSERT_EQ(fits.exitCode, 0) << fits.output;
    EXPECT_NE(fits.output.find("meshes read: 1)"), std::string::npos) << fits.output;
    if (test::kRssMeaningful) {
        EXPECT_LE(double(fits.peakRss), 1.10 * double(uint64_t(budgetMiB) << 20)) << "peak RSS " << (fits.peakRss >> 20) << " MiB";
    }
}

// The shared textured dragon, built with its 2048² texture and rendered by the
// streaming client's renderer, against the mesh itself rendered with its
// texture by surfcast-mesh-reference (16 samples per pixel, trilinear mip
// filtering), both unlit from the same camera. Compared over the pixels both
// cover whose neighbours they also cover (silhouette pixels are partial in
// different ways).
//
// Mean colour: both images are linear filters of the same texture over the
// same surface, so their per-pixel difference has mean zero up to rounding
// (the surfels' 8-bit colours and both 8-bit images: at most 1.5/255 in all)
// and a random part from the surfels' random positions, whose mean over N
// pixels has standard deviation sigma/sqrt(N) (measured: sigma 5.4/255 in
// luminance, N 30,649, so 0.03/255). Bound: 2/255 per channel; measured
// differences 0.4-0.6/255. A grey dragon (the texture ignored) is 90/255 off.
// The dragon is built at 1 M input points (--mesh-max-surfels), not one per
// texel: still about 40 surfels per covered pixel, and a quarter of the build
// (bench/RELIABILITY.md, "CI stages").
//
// Histogram of luminance in 16 bins of 16 levels: a per-pixel difference of
// RMS 5.4 levels can carry the pixels within 5.4 levels of a bin edge, about
// a third of them, into the next bin; were all those moves one way, the L1
// distance of the normalized histograms would be 0.7, while moves both ways
// cancel (measured: 0.083; 0.076 at the default spacing; 0.034 with
// --texture-filter ewa and 0.061 with nearest, at the default spacing).
// Bound: 0.25. A grey dragon gives 2 (no bin in common).
TEST(TexturedMesh, DragonRendersLikeItsTexturedMesh) {
    REQUIRE_DATA();
    test::TempDir dir;
    const std::string obj = test::dataFile("fg_spkMgDragon/fg_spkMgDragon.obj");
    auto build = test::run({test::binary("surfcast-build"), "-q", obj, "--mesh-max-surfels", "1000000", "-o", dir.file("dragon")});
    ASSERT_EQ(build.exitCode, 0) << build.output;
    EXPECT_NE(build.output.find("map_Ks 'fg_spkMgDragon_specular.jpg' not found (unused)"), std::string::npos) << build.output;
    const std::string camera = "--camera=0.0,0.05,0.15,0.005,0.04,0,0,1,0,40";
    auto view = test::run({test::binary("surfcast-view"), "--headless", dir.file("dragon"), camera, "--size", "400x300", "--out",
                           dir.file("surfels.png")});
    ASSERT_EQ(view.exitCode, 0) << view.output;
    auto ref = test::run({test::binary("surfcast-mesh-reference"), obj, camera, "--size", "400x300", "--shading", "unlit",
                          "--colors", "--out", dir.file("mesh.png")});
    ASSERT_EQ(ref.exitCode, 0) << ref.output;
    const Rgb a = readPng(dir.file("surfels.png")), b = readPng(dir.file("mesh.png"));
    ASSERT_EQ(a.width, b.width);
    ASSERT_EQ(a.height, b.height);
    double sum[2][3] = {}, diff2 = 0;
    std::vector<double> hist[2] = {std::vector<double>(16), std::vector<double>(16)};
    size_t n = 0;
    for (int y = 1; y + 1 < a.height; ++y)
        for (int x = 1; x + 1 < a.width; ++x) {
            bool inside = true;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) inside = inside && !a.background(x + dx, y + dy) && !b.background(x + dx, y + dy);
            if (!inside) continue;
            ++n;
            const Rgb* img[2] = {&a, &b};
            for (int i = 0; i < 2; ++i) {
                const uint8_t* p = img[i]->at(x, y);
                for (int c = 0; c < 3; ++c) sum[i][c] += p[c];
                const double luminance = 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
                hist[i][std::min(15, int(luminance / 16))] += 1;
            }
            diff2 += std::pow(0.2126 * (a.at(x, y)[0] - b.at(x, y)[0]) + 0.7152 * (a.at(x, y)[1] - b.at(x, y)[1]) +
                                  0.0722 * (a.at(x, y)[2] - b.at(x, y)[2]), 2);
        }
    ASSERT_GT(n, 10000u) << "the dragon covers too few pixels";
    double l1 = 0;
    for (int k = 0; k < 16; ++k) l1 += std::fabs(hist[0][size_t(k)] - hist[1][size_t(k)]) / double(n);
    std::printf("pixels %zu, mean surfels (%.2f %.2f %.2f), mesh (%.2f %.2f %.2f), per-pixel luminance rms difference %.2f, "
                "histogram L1 %.3f\n", n, sum[0][0] / n, sum[0][1] / n, sum[0][2] / n, sum[1][0] / n, sum[1][1] / n, sum[1][2] / n,
                std::sqrt(diff2 / n), l1);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(sum[0][c] / double(n), sum[1][c] / double(n), 2.0) << "channel " << c;
    EXPECT_LT(l1, 0.25);
}

namespace {
// A rectangle of 256 x 64 world units in z = 0 carrying a 256 x 64 texture,
// one texel per unit: texel column i covers x in [i, i + 1].
MeshTriangles texturedRectangle(const std::function<Vec3f(int, int)>& texel) {
    MeshTriangles m;
    m.vertices.positions = {{0, 0, 0}, {256, 0, 0}, {256, 64, 0}, {0, 64, 0}};
    m.vertices.normals.assign(4, Vec3f{0, 0, 1});
    m.triangles = {0, 1, 2, 0, 2, 3};
    Texture t;
    t.width = 256;
    t.height = 64;
    for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 256; ++i) {
            const Vec3f c = texel(i, j);
            for (int k = 0; k < 3; ++k) t.rgb.push_back(uint8_t(c[k]));
        }
    m.textures.push_back(std::make_shared<const Texture>(t));
    m.triangleTexture = {0, 0};
    m.cornerUvs = {{0, 0, 1, 0, 1, 1}, {0, 0, 1, 1, 0, 1}};
    m.triangleColor.assign(2, Vec3f{});
    return m;
}

// The same rectangle as rect.obj in `dir`, its texture rect.png.
void writeTexturedRectangle(const test::TempDir& dir, const std::function<Vec3f(int, int)>& texel) {
    writePng(dir.file("rect.png"), 256, 64, texel);
    test::writeFile(dir.file("m.mtl"), "newmtl t\nmap_Kd rect.png\n");
    test::writeFile(dir.file("rect.obj"), "mtllib m.mtl\nv 0 0 0\nv 256 0 0\nv 256 64 0\nv 0 64 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                                          "usemtl t\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n");
}

// rect.obj in `dir` built with --texture-filter `filter` and --capacity 4000
// (several nodes) into dir/filter, and opened; its tileset.json must say
// which filter made it.
Result<TilesetReader> buildRectangle(const test::TempDir& dir, const std::string& filter) {
    auto build = test::run({test::binary("surfcast-build"), "-q", dir.file("rect.obj"), "--capacity", "4000", "--texture-filter",
                            filter, "-o", dir.file(filter)});
    if (build.exitCode != 0) return Status::error("surfcast-build failed: " + build.output);
    auto set = TilesetReader::open(dir.file(filter));
    if (set.ok()) {
        EXPECT_EQ(set->info().textureFilter, filter);
    }
    return set;
}

// The Gaussian-weighted average of the texel values at the texel centres
// (i + 0.5, j + 0.5) within 3 sigma of (x, y), for the 256 x 64 texture black
// for i < 128 and white beyond.
double stepAverage(double x, double y, double sigma) {
    double sum = 0, weight = 0;
    for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 256; ++i) {
            const double d2 = std::pow(i + 0.5 - x, 2) + std::pow(j + 0.5 - y, 2);
            if (d2 > 9 * sigma * sigma) continue;
            const double g = std::exp(-d2 / (2 * sigma * sigma));
            sum += g * (i < 128 ? 0 : 1);
            weight += g;
        }
    return sum / weight;
}
}  // namespace

// The view-independent EWA coefficient of a surfel (Zwicker et al. 2001, §5),
// w = Σ_i c_i ⟨r, n_i⟩ / Σ_i ⟨r, n_i⟩, derived here independently as the
// Gaussian-weighted average of the texel values at the texel centres within
// the kernel's support (3 sigma): for a texture black for x < 128 and white
// beyond, w(x, y) = Σ c_ij g(x_ij - p) / Σ g(x_ij - p) over centres x_ij =
// (i + 0.5, j + 0.5) within 3 sigma of p = (x, y). Up to sigma = 2 texels
// the field sums exactly these terms (bar rounding); above, it sums the
// texels of the mip level at most sigma/2 wide, m x m texel averages whose
// variance (at most sigma²/48) the Gaussian gives up: the filter keeps its
// variance, not quite its shape, which moves the step's blurred profile by
// at most 1 % (measured: 2.2/255 at sigma = 8). Bound: 2.5/255. The point
// sample at the centre (nearest) misses by up to half the step.
TEST(TextureField, EwaCoefficientsAreTheGaussianWeightedTexelAverage) {
    const MeshTriangles rect = texturedRectangle([](int i, int) { return Vec3f{i < 128 ? 0.f : 255.f, 0, 0}; });
    const TextureField field(rect, Vec3d{});
    double worstNearest = 0, worstEwa = 0;
    for (double sigma : {1.0, 2.0, 4.0, 8.0})
        for (double x = 128 - 2.5 * sigma; x <= 128 + 2.5 * sigma; x += sigma / 4) {
            const double y = 32.25;
            const double expected = stepAverage(x, y, sigma);
            Vec3f c;
            ASSERT_TRUE(field.filter({x, y, 0}, {0, 0, 1}, sigma, &c));
            EXPECT_NEAR(c[0] * 255, expected * 255, sigma <= 2 ? 0.01 : 2.5) << "sigma " << sigma << " x " << x;
            worstEwa = std::max(worstEwa, std::fabs(c[0] - expected) * 255);
            worstNearest = std::max(worstNearest, std::fabs(rect.textures[0]->sample(x / 256, y / 64)[0] - expected) * 255);
        }
    std::printf("worst difference from the texel average: ewa %.2f/255, nearest %.2f/255\n", worstEwa, worstNearest);
    EXPECT_GT(worstNearest, 50) << "the step blurred by the kernel is what nearest sampling misses";
    // The other side of the surface, and no surface in reach, give nothing.
    Vec3f c;
    EXPECT_FALSE(field.filter({128, 32, 0}, {0, 0, -1}, 4, &c));
    EXPECT_FALSE(field.filter({128, 32, 50}, {0, 0, 1}, 4, &c));

    // Texture coordinates stretched a million-fold (a hostile or broken file):
    // the footprint would cover 10^12 texel visits. The texture repeats so
    // often under it that its mean (the 1 x 1 mip level) stands in.
    MeshTriangles stretched = texturedRectangle([](int i, int j) { return Vec3f{(i + j) % 2 ? 200.f : 100.f, 0, 0}; });
    stretched.cornerUvs = {{0, 0, 1e6, 0, 1e6, 1e6}, {0, 0, 1e6, 1e6, 0, 1e6}};
    const TextureField many(stretched, Vec3d{});
    ASSERT_TRUE(many.filter({100, 30, 0}, {0, 0, 1}, 4, &c));
    EXPECT_NEAR(c[0] * 255, 150, 1.0);
}

// Every level of a built set carries the texture filtered with its own kernel:
// each surfel's colour is the step's texel average at its position with
// sigma = kernel_scale times its node's h (or its own radius). Tolerance per
// surfel: the field's 2.5/255 (above), 0.5 for the 8-bit colour, and the
// colour's change over the position's quantization error (half a step of the
// node's position bits along each axis): the blurred step's slope is at most
// 255 / (sigma sqrt(2 pi)) per unit. Under --texture-filter nearest the
// coarse levels average the leaves' point samples instead, which this
// misses by far more.
TEST(TexturedMesh, EveryLevelCarriesTheTextureFilteredWithItsKernel) {
    test::TempDir dir;
    writeTexturedRectangle(dir, [](int i, int) { return Vec3f{i < 128 ? 0.f : 255.f, 0, 0}; });
    auto check = [&](const std::string& filter, double* worstExcess, size_t* coarse) {
        auto set = buildRectangle(dir, filter);
        ASSERT_TRUE(set.ok()) << set.status().message();
        *worstExcess = -1e9;
        *coarse = 0;
        for (const NodeRecord& node : set->nodes()) {
            auto block = set->readBlock(node);
            ASSERT_TRUE(block.ok()) << block.status().message();
            const double edge = nodeEdge(set->info(), node.key.level);
            const double quantum = edge / double((uint64_t(1) << node.positionBits) - 1) / 2;
            for (size_t i = 0; i < block->size(); ++i) {
                const Vec3d p = set->position(node, *block, i);
                const double sigma = set->info().kernelScale * (block->radii.empty() ? node.spacing : block->radii[i]);
                // Away from the rectangle's ends, where the texture repeats.
                if (p.x < 3 * sigma + 1 || p.x > 256 - 3 * sigma - 1 || p.y < 3 * sigma + 1 || p.y > 64 - 3 * sigma - 1) continue;
                const double expected = 255 * stepAverage(p.x, p.y, sigma);
                const double tolerance = 2.5 + 0.5 + 255 / (sigma * std::sqrt(2 * M_PI)) * quantum * std::sqrt(3.0);
                *worstExcess = std::max(*worstExcess, std::fabs(block->colors[3 * i] - expected) - tolerance);
                if (!(node.flags & kFlagInputPoints)) ++*coarse;
            }
        }
    };
    double ewaExcess = 0, nearestExcess = 0;
    size_t coarse = 0, coarseNearest = 0;
    check("ewa", &ewaExcess, &coarse);
    check("nearest", &nearestExcess, &coarseNearest);
    std::printf("largest excess over the tolerance: ewa %.2f, nearest %.2f (%zu resampled surfels checked)\n", ewaExcess, nearestExcess,
                coarse);
    EXPECT_GT(coarse, 1000u);
    EXPECT_LE(ewaExcess, 0);
    EXPECT_GT(nearestExcess, 10);
}

namespace {
// The L2 distance, over x in [20, 236] x [12, 52] sampled every 0.1 units,
// between the bilinear texture of `rect` and what the renderer reconstructs
// from the surfels (where any kernel reaches): Σ w_k g_k(x) / Σ g_k(x) with g_k the Gaussian of
// standard deviation sigma_k cut off at |x - p_k|² <= 2 sigma_k² (c = 1).
// Red channel only. Surfels are bucketed in 4 x 4 cells; every kernel here
// reaches less than 4 units.
double reconstructionError(const MeshTriangles& rect, const std::vector<FitSurfel>& surfels) {
    std::map<std::pair<int, int>, std::vector<size_t>> cells;
    for (size_t k = 0; k < surfels.size(); ++k)
        cells[{int(std::floor(surfels[k].position.x / 4)), int(std::floor(surfels[k].position.y / 4))}].push_back(k);
    double sum2 = 0;
    size_t n = 0;
    for (double y = 12; y <= 52; y += 0.1)
        for (double x = 20; x <= 236; x += 0.1) {
            double num = 0, den = 0;
            const int cx = int(std::floor(x / 4)), cy = int(std::floor(y / 4));
            for (int i = cx - 1; i <= cx + 1; ++i)
                for (int j = cy - 1; j <= cy + 1; ++j) {
                    auto it = cells.find({i, j});
                    if (it == cells.end()) continue;
                    for (size_t k : it->second) {
                        const FitSurfel& s = surfels[k];
                        const double d2 = std::pow(x - s.position.x, 2) + std::pow(y - s.position.y, 2);
                        if (d2 > 2 * s.sigma * s.sigma) continue;
                        const double g = std::exp(-d2 / (2 * s.sigma * s.sigma));
                        num += g * s.color[0];
                        den += g;
                    }
                }
            if (!(den > 0)) continue;  // a hole, which the renderer leaves too
            const double truth = rect.textures[0]->sample(x / 256, y / 64)[0];
            sum2 += std::pow(num / den - truth, 2);
            ++n;
        }
    return std::sqrt(sum2 / double(n));
}
}  // namespace

// --texture-filter optimal (Zwicker et al. 2001, eq. 10-11): the coefficients
// minimize the L2 distance between the texture and the normalized
// reconstruction the renderer draws, so no other coefficients on the same
// surfels do better: not the ewa prefilter, not the point samples. Measured
// here independently of the fit's own quadrature (reconstructionError), on a
// jittered grid of surfels 2 units apart (jitter +-0.4, sigma 1.5: no point of
// the plane lies beyond a kernel's cutoff) over a checkerboard of 3-texel
// squares, finer than the surfels can carry: the regime of magnification,
// where the paper's Figure 6 shows the difference. The fit is solved in four
// groups (four nodes) with their halos; it is within 2 % of the one-group
// solution (the active set for the [0, 1] bounds makes neither exactly the
// constrained optimum). A constant texture stays exactly constant: the
// normalized kernels sum to 1, so the constant fits with no residual, and the
// ridge pulls towards the starting guess, the ewa coefficients, which are
// that constant too. Bound: CG's relative residual 1e-4, well under 1e-3.
TEST(TextureField, OptimalCoefficientsBeatEwaAndNearestInL2) {
    const MeshTriangles rect = texturedRectangle([](int i, int j) {
        return Vec3f{(i / 3 + j / 3) % 2 ? 230.f : 25.f, 0, 0};
    });
    const TextureField field(rect, Vec3d{});
    std::vector<FitSurfel> nearest, ewa;
    uint32_t state = 12345;
    auto jitter = [&] {
        state = state * 1664525u + 1013904223u;
        return (double(state >> 8) / double(1u << 24) - 0.5) * 0.8;
    };
    for (double x = 1; x < 256; x += 2)
        for (double y = 1; y < 64; y += 2) {
            FitSurfel s{{x + jitter(), y + jitter(), 0}, {0, 0, 1}, 1.5, {}};
            s.color = rect.textures[0]->sample(s.position.x / 256, s.position.y / 64);
            nearest.push_back(s);
            ASSERT_TRUE(field.filter(s.position, s.normal, s.sigma, &s.color));
            ewa.push_back(s);
        }
    // Four groups along x (the surfels were generated column by column).
    std::vector<FitSurfel> optimal = ewa, single = ewa;
    const uint32_t n = uint32_t(ewa.size());
    std::vector<std::pair<uint32_t, uint32_t>> four = {{0, n / 4}, {n / 4, n / 2}, {n / 2, 3 * n / 4}, {3 * n / 4, n}};
    std::vector<std::pair<uint32_t, uint32_t>> one = {{0, n}};
    const FitReport report = field.fitOptimal(optimal, four, FitParams{});
    field.fitOptimal(single, one, FitParams{});
    EXPECT_EQ(report.groups, 4u);
    EXPECT_GT(report.unknowns, size_t(n)) << "each group's halo adds unknowns";
    EXPECT_LE(report.maxResidual, 1e-4);
    const double eNearest = reconstructionError(rect, nearest), eEwa = reconstructionError(rect, ewa);
    const double eOptimal = reconstructionError(rect, optimal), eSingle = reconstructionError(rect, single);
    std::printf("L2 error: nearest %.4f, ewa %.4f, optimal %.4f (one group %.4f); CG iterations mean %.1f max %d\n", eNearest, eEwa,
                eOptimal, eSingle, double(report.iterations) / double(report.groups), report.maxIterations);
    EXPECT_LT(eOptimal, eEwa);
    EXPECT_LT(eOptimal, eNearest);
    EXPECT_NEAR(eOptimal, eSingle, 0.02 * eSingle);

    // A constant texture: every coefficient is the constant.
    const MeshTriangles flat = texturedRectangle([](int, int) { return Vec3f{153, 0, 0}; });
    const TextureField flatField(flat, Vec3d{});
    std::vector<FitSurfel> constant = nearest;
    for (FitSurfel& s : constant) ASSERT_TRUE(flatField.filter(s.position, s.normal, s.sigma, &s.color));
    flatField.fitOptimal(constant, four, FitParams{});
    double worst = 0;
    for (const FitSurfel& s : constant) worst = std::max(worst, std::fabs(s.color[0] - 0.6));
    EXPECT_LT(worst, 1e-3);
}

// The same through surfcast-build: the leaves of a set built with
// --texture-filter optimal (several nodes, so groups with halos) reconstruct
// the texture better in L2 than those of ewa and nearest builds, which have
// the same surfels (the sampling is seeded) and only other colours. The
// checkerboard of 3-texel squares against one surfel per texel (the default
// spacing): detail at the surfels' own scale. tileset.json says "optimal".
TEST(TexturedMesh, OptimalBuildReconstructsTheTextureBest) {
    test::TempDir dir;
    auto texel = [](int i, int j) { return Vec3f{(i / 3 + j / 3) % 2 ? 230.f : 25.f, 0, 0}; };
    writeTexturedRectangle(dir, texel);
    const MeshTriangles rect = texturedRectangle(texel);
    std::map<std::string, double> error;
    size_t leaves = 0;
    for (const char* filter : {"nearest", "ewa", "optimal"}) {
        auto set = buildRectangle(dir, filter);
        ASSERT_TRUE(set.ok()) << set.status().message();
        std::vector<FitSurfel> surfels;
        size_t leafNodes = 0;
        for (const NodeRecord& node : set->nodes()) {
            if (!(node.flags & kFlagInputPoints)) continue;
            ++leafNodes;
            auto block = set->readBlock(node);
            ASSERT_TRUE(block.ok()) << block.status().message();
            for (size_t i = 0; i < block->size(); ++i) {
                const double sigma = set->info().kernelScale * (block->radii.empty() ? node.spacing : block->radii[i]);
                surfels.push_back({set->position(node, *block, i), {0, 0, 1}, sigma, Vec3f{block->colors[3 * i] / 255.f, 0, 0}});
            }
        }
        EXPECT_GT(leafNodes, 2u) << "several nodes, so that groups meet";
        leaves = surfels.size();
        error[filter] = reconstructionError(rect, surfels);
    }
    std::printf("L2 error of the built leaves (%zu): nearest %.4f, ewa %.4f, optimal %.4f\n", leaves, error["nearest"], error["ewa"],
                error["optimal"]);
    EXPECT_LT(error["optimal"], error["nearest"]);
    EXPECT_LT(error["optimal"], error["ewa"]);
}
