// Every reader on every shared file of its format (counts and bounds from
// ../shared/data/PROVENANCE.md), and on generated files covering the variants
// the shared files lack.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "default_scene.h"
#include "inputs.h"
#include "las_reader.h"
#include "mesh_reader.h"
#include "ply_reader.h"
#include "test_support.h"
#include "text_reader.h"

using namespace surfcast;
using surfcast::test::TempDir;

namespace {

struct ReadAll {
    uint64_t points = 0, skipped = 0;
    Box3d bounds;
    std::vector<InputPoint> all;
};

ReadAll readAll(PointReader& reader, bool keep = false) {
    ReadAll r;
    std::vector<InputPoint> batch(10000);
    while (true) {
        auto n = reader.read(batch.data(), batch.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        for (size_t i = 0; i < *n; ++i) {
            r.bounds.extend(batch[i].position);
            if (keep) r.all.push_back(batch[i]);
        }
        r.points += *n;
    }
    r.skipped = reader.skipped();
    return r;
}

void expectBounds(const Box3d& b, Vec3d lo, Vec3d hi, double tol) {
    for (int a = 0; a < 3; ++a) {
        EXPECT_NEAR(b.min[a], lo[a], tol) << "axis " << a;
        EXPECT_NEAR(b.max[a], hi[a], tol) << "axis " << a;
    }
}

// PROVENANCE.md gives coordinates to 6 decimals.
constexpr double kProvenanceTolerance = 1e-6;

}  // namespace

TEST(PlyReader, BunnyAsciiMatchesProvenance) {
    REQUIRE_DATA();
    auto r = openPlyReader(test::dataFile("bunny.ply"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_FALSE((*r)->description().hasColors);
    EXPECT_TRUE((*r)->description().hasIntensity);
    auto all = readAll(**r);
    EXPECT_EQ(all.points, 35947u);
    expectBounds(all.bounds, {-0.094690, 0.032987, -0.061874}, {0.061009, 0.187321, 0.058800}, kProvenanceTolerance);
}

TEST(PlyReader, HorseBigEndianMatchesProvenance) {
    REQUIRE_DATA();
    auto r = openPlyReader(test::dataFile("horse.ply"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE((*r)->description().hasColors);
    auto all = readAll(**r, true);
    EXPECT_EQ(all.points, 48485u);
    expectBounds(all.bounds, {-0.042003, -0.091670, -0.076418}, {0.042003, 0.091671, 0.076418}, kProvenanceTolerance);
    // Every colour is 255 (white): uchar 255 scales to 65535.
    EXPECT_EQ(all.all[0].color[0], 65535);
    EXPECT_EQ(all.all[48484].color[2], 65535);
}

TEST(PlyReader, IgeaLittleEndianMatchesProvenance) {
    REQUIRE_DATA();
    auto r = openPlyReader(test::dataFile("igea.ply"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    auto all = readAll(**r);
    EXPECT_EQ(all.points, 134345u);
    expectBounds(all.bounds, {-0.034556, -0.049669, -0.049538}, {0.034556, 0.049669, 0.049538}, kProvenanceTolerance);
}

TEST(PlyReader, NanAndOutOfRangeColoursAndIntensitiesSaturate) {
    // A float colour or intensity of nan was cast to an integer (undefined:
    // fuzz_read_ply, fuzz/regressions/read_ply). NaN gives 0; values beyond
    // the range give its ends.
    test::TempDir dir;
    test::writeFile(dir.file("c.ply"), "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                                       "property float z\nproperty float red\nproperty float green\nproperty float blue\n"
                                       "property float intensity\nend_header\n0 0 0 nan 2 -1 nan\n1 0 0 0.5 inf -inf 70000\n");
    auto r = openPlyReader(dir.file("c.ply"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    auto all = readAll(**r, true);
    ASSERT_EQ(all.points, 2u);
    EXPECT_EQ(all.all[0].color[0], 0);
    EXPECT_EQ(all.all[0].color[1], 65535);
    EXPECT_EQ(all.all[0].color[2], 0);
    EXPECT_EQ(all.all[0].intensity, 0);
    EXPECT_EQ(all.all[1].color[0], 32768);  // lround(0.5 * 65535 = 32767.5)
    EXPECT_EQ(all.all[1].color[1], 65535);
    EXPECT_EQ(all.all[1].color[2], 0);
    EXPECT_EQ(all.all[1].intensity, 65535);
}

TEST(PlyReader, ASecondVertexElementIsAnError) {
    // Colours from one vertex element and vertices from two fell out of step
    // and the mesh reader read past the colours (heap overflow: fuzz_read_ply,
    // fuzz/regressions/read_ply).
    test::TempDir dir;
    test::writeFile(dir.file("two.ply"), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                         "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                                         "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                                         "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                         "0 0 0 1 2 3\n1 0 0 1 2 3\n0 1 0 1 2 3\n5 0 0\n6 0 0\n5 1 0\n3 3 4 5\n");
    auto r = openMeshReader(dir.file("two.ply"), MeshSampling{});
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("more than one vertex element"), std::string::npos) << r.status().message();
}

TEST(PlyReader, FaceTrianglesRepeatingAVertexAreDropped) {
    // OpenMesh's add_face asserts (aborting the process) on a triangle such as
    // (0, 1, 0) (fuzz_read_ply: fuzz/regressions/read_ply/face-repeating-a-vertex.ply).
    // Such triangles have no area and are dropped; the others are sampled.
    test::TempDir dir;
    test::writeFile(dir.file("dup.ply"), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                         "property float z\nelement face 3\nproperty list uchar int vertex_indices\nend_header\n"
                                         "0 0 0\n1 0 0\n0 1 0\n3 0 1 0\n4 0 1 1 2\n3 0 1 2\n");
    auto mesh = readPlyMesh(dir.file("dup.ply"));
    ASSERT_TRUE(mesh.ok()) << mesh.status().message();
    ASSERT_EQ(mesh->triangles.size(), 2u);  // the quad's fan (0,1,1) is dropped, (0,1,2) kept twice
    auto r = openMeshReader(dir.file("dup.ply"), MeshSampling{0.01});
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_GT(readAll(**r).points, 0u);
}

TEST(PlyReader, MeshElementsAreDetected) {
    REQUIRE_DATA();
    for (const char* name : {"bunny.ply", "horse.ply", "igea.ply"}) {
        auto in = ByteStream::open(test::dataFile(name));
        ASSERT_TRUE(in.ok());
        auto h = parsePlyHeader(*in);
        ASSERT_TRUE(h.ok()) << h.status().message();
        EXPECT_TRUE(plyHasFaces(*h)) << name;
    }
}

TEST(PlyReader, IgeaTriangleStrips) {
    REQUIRE_DATA();
    auto mesh = readPlyMesh(test::dataFile("igea.ply"));
    ASSERT_TRUE(mesh.ok()) << mesh.status().message();
    EXPECT_EQ(mesh->vertices.size(), 134345u);
    // PROVENANCE: 373,830 indices, 35,048 restarts, about 268,686 strip
    // triangles with degenerate ones; degenerate ones are dropped.
    EXPECT_GT(mesh->triangles.size(), 260000u);
    EXPECT_LE(mesh->triangles.size(), 268686u);
}

TEST(PlyReader, GeneratedVariants) {
    TempDir dir;
    // ASCII with normals, float colours and double coordinates.
    test::writeFile(dir.file("a.ply"),
                    "ply\nformat ascii 1.0\ncomment hi\nelement vertex 3\nproperty double x\nproperty double y\n"
                    "property double z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                    "property float red\nproperty float green\nproperty float blue\nend_header\n"
                    "1 2 3 0 0 2 1 0.5 0\n4 5 6 0 0 1 0 0 1\nnan 0 0 0 0 1 1 1 1\n");
    auto a = openPlyReader(dir.file("a.ply"));
    ASSERT_TRUE(a.ok()) << a.status().message();
    auto ra = readAll(**a, true);
    EXPECT_EQ(ra.points, 2u);
    EXPECT_EQ(ra.skipped, 1u);
    EXPECT_EQ(ra.all[0].normal, (Vec3f{0, 0, 1}));  // normalized
    EXPECT_EQ(ra.all[0].color[0], 65535);
    EXPECT_EQ(ra.all[0].color[1], 32768);  // 0.5 * 65535 rounded
    // Binary big endian, ushort colours, an element before the vertices.
    std::string bin = "ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty uchar id\nelement vertex 2\n"
                      "property float x\nproperty float y\nproperty float z\nproperty ushort red\nproperty ushort green\n"
                      "property ushort blue\nend_header\n";
    bin.push_back(char(9));  // camera id
    auto be32 = [&](float f) { uint32_t u; std::memcpy(&u, &f, 4); for (int s = 24; s >= 0; s -= 8) bin.push_back(char(u >> s)); };
    auto be16 = [&](uint16_t v) { bin.push_back(char(v >> 8)); bin.push_back(char(v)); };
    be32(1.5f); be32(-2.f); be32(3.25f); be16(1000); be16(2000); be16(65535);
    be32(0.f); be32(0.f); be32(0.f); be16(0); be16(0); be16(0);
    test::writeFile(dir.file("b.ply"), bin);
    auto b = openPlyReader(dir.file("b.ply"));
    ASSERT_TRUE(b.ok()) << b.status().message();
    auto rb = readAll(**b, true);
    ASSERT_EQ(rb.points, 2u);
    EXPECT_EQ(rb.all[0].position, (Vec3d{1.5, -2, 3.25}));
    EXPECT_EQ(rb.all[0].color[1], 2000);
    EXPECT_EQ((*b)->description().colorBits, 16);
}

namespace {
// A LAS file with `count` points of format `format`, version 1.minor.
std::string makeLas(int minor, int format, uint32_t count, bool use64BitCount, size_t recordLength, double scale,
                    double offset) {
    size_t headerSize = minor >= 4 ? 375 : 227;
    std::string h(headerSize, '\0');
    std::memcpy(h.data(), "LASF", 4);
    h[24] = 1;
    h[25] = char(minor);
    auto put16 = [&](size_t at, uint16_t v) { std::memcpy(h.data() + at, &v, 2); };
    auto put32 = [&](size_t at, uint32_t v) { std::memcpy(h.data() + at, &v, 4); };
    auto put64 = [&](size_t at, uint64_t v) { std::memcpy(h.data() + at, &v, 8); };
    auto putD = [&](size_t at, double v) { std::memcpy(h.data() + at, &v, 8); };
    put16(94, uint16_t(headerSize));
    put32(96, uint32_t(headerSize));
    h[104] = char(format);
    put16(105, uint16_t(recordLength));
    put32(107, use64BitCount ? 0 : count);
    for (int a = 0; a < 3; ++a) { putD(131 + 8 * a, scale); putD(155 + 8 * a, offset); }
    if (minor >= 4) put64(247, count);
    std::string data(count * recordLength, '\0');
    for (uint32_t i = 0; i < count; ++i) {
        int32_t xyz[3] = {int32_t(i), int32_t(2 * i), -int32_t(i)};
        std::memcpy(data.data() + i * recordLength, xyz, 12);
        uint16_t intensity = uint16_t(100 + i);
        std::memcpy(data.data() + i * recordLength + 12, &intensity, 2);
    }
    return h + data;
}
}  // namespace

TEST(LasReader, AutzenMatchesProvenance) {
    REQUIRE_DATA();
    auto r = openLasReader(test::dataFile("autzen_trim.las"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE((*r)->description().hasColors);
    EXPECT_DOUBLE_EQ((*r)->description().precision, 0.01);
    auto all = readAll(**r, true);
    EXPECT_EQ(all.points, 110000u);
    expectBounds(all.bounds, {636001.76, 848935.2, 406.26}, {637179.22, 849497.9, 520.51}, kProvenanceTolerance);
    // PROVENANCE: red [40..236] stored raw in the 16-bit field.
    uint16_t lo = 65535, hi = 0;
    for (const auto& p : all.all) { lo = std::min(lo, p.color[0]); hi = std::max(hi, p.color[0]); }
    EXPECT_EQ(lo, 40);
    EXPECT_EQ(hi, 236);
}

// The coordinate system a file declares (PROVENANCE.md, read there by
// laspy and pyproj): autzen's WKT VLR, before its GeoTIFF keys; lone-star's
// GeoTIFF keys alone (model type 2, raster type 3, geographic WGS 84).
TEST(LasReader, CoordinateSystemsMatchProvenance) {
    REQUIRE_DATA();
    auto autzen = openLasReader(test::dataFile("autzen_trim.las"));
    ASSERT_TRUE(autzen.ok()) << autzen.status().message();
    EXPECT_EQ((*autzen)->description().crs.rfind("PROJCS[\"NAD_1983_HARN_Lambert_Conformal_Conic\"", 0), 0u) << (*autzen)->description().crs;
    EXPECT_EQ(crsName((*autzen)->description().crs), "NAD_1983_HARN_Lambert_Conformal_Conic");
    auto lone = openLasReader(test::dataFile("lone-star.laz"));
    ASSERT_TRUE(lone.ok()) << lone.status().message();
    EXPECT_EQ((*lone)->description().crs, "GeoTIFF keys: 1025=2 1024=3 2048=4326");
    EXPECT_EQ(crsName((*lone)->description().crs), "EPSG:4326");
    // One code in WKT (WKT1's closing AUTHORITY, WKT2's ID) and GeoTIFF keys
    // is one coordinate system; a code within the WKT (its datum's) is not the root's.
    const std::string wkt1 = "GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\",SPHEROID[\"WGS 84\",6378137,298.257223563,AUTHORITY[\"EPSG\",\"7030\"]],"
                             "AUTHORITY[\"EPSG\",\"6326\"]],PRIMEM[\"Greenwich\",0],UNIT[\"degree\",0.0174532925199433],AUTHORITY[\"EPSG\",\"4326\"]]";
    const std::string wkt2 = "GEOGCRS[\"WGS 84\",DATUM[\"World Geodetic System 1984\",ELLIPSOID[\"WGS 84\",6378137,298.257223563]],"
                             "CS[ellipsoidal,2],ID[\"EPSG\",4326]]";
    EXPECT_EQ(crsIdentity(wkt1), "EPSG:4326");
    EXPECT_EQ(crsIdentity(wkt2), "EPSG:4326");
    EXPECT_EQ(crsIdentity((*lone)->description().crs), "EPSG:4326");
    EXPECT_NE(crsIdentity((*autzen)->description().crs), "EPSG:4326");
    auto lion = openLasReader(test::dataFile("lion_takanawa.copc.laz"));
    ASSERT_TRUE(lion.ok()) << lion.status().message();
    EXPECT_EQ((*lion)->description().crs, "") << "PROVENANCE: no CRS";
}

TEST(LasReader, EveryPointFormatAndVersion) {
    TempDir dir;
    const size_t minLength[11] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
    for (int format = 0; format <= 10; ++format) {
        int minor = format >= 6 ? 4 : (format >= 4 ? 3 : 2);
        std::string path = dir.file("f" + std::to_string(format) + ".las");
        test::writeFile(path, makeLas(minor, format, 5, format >= 6, minLength[format] + 3 /* extra bytes */, 0.5, 100));
        auto r = openLasReader(path);
        ASSERT_TRUE(r.ok()) << "format " << format << ": " << r.status().message();
        auto all = readAll(**r, true);
        ASSERT_EQ(all.points, 5u) << "format " << format;
        EXPECT_EQ(all.all[4].position, (Vec3d{102, 104, 98})) << "format " << format;
        EXPECT_EQ(all.all[4].intensity, 104);
        EXPECT_EQ((*r)->description().hasColors, format == 2 || format == 3 || format == 5 || format == 7 || format == 8 || format == 10);
    }
}

TEST(LasReader, TruncatedAndCompressedGiveClearErrors) {
    TempDir dir;
    std::string las = makeLas(2, 0, 100, false, 20, 0.01, 0);
    test::writeFile(dir.file("t.las"), las.substr(0, las.size() - 30));
    auto r = openLasReader(dir.file("t.las"));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("declares 100 points"), std::string::npos) << r.status().message();
    las[104] = char(0x80);  // format 0, compressed, but no LASzip VLR
    las.resize(227 + 100 * 28);
    test::writeFile(dir.file("c.las"), las);
    auto c = openLasReader(dir.file("c.las"));
    ASSERT_FALSE(c.ok());
    EXPECT_NE(c.status().message().find("LASzip VLR"), std::string::npos) << c.status().message();
}

TEST(TextReader, LayoutsDetectedAndGiven) {
    TempDir dir;
    test::writeFile(dir.file("a.xyz"), "# comment\n1 2 3 255 0 10\n4,5,6,0,0,0\n\n7 8 9 1 1 1\n");
    auto a = openTextReader(dir.file("a.xyz"), "");
    ASSERT_TRUE(a.ok()) << a.status().message();
    EXPECT_TRUE((*a)->description().hasColors);
    auto ra = readAll(**a, true);
    ASSERT_EQ(ra.points, 3u);
    EXPECT_EQ(ra.all[0].color[0], 65535);
    EXPECT_EQ(ra.all[0].color[2], 10 * 257);
    // Normals: non-integer columns 4-6.
    test::writeFile(dir.file("n.xyz"), "0 0 0 0 0.5 0\n1 1 1 0.1 0.2 0.3\n");
    auto n = openTextReader(dir.file("n.xyz"), "");
    ASSERT_TRUE(n.ok());
    EXPECT_TRUE((*n)->description().hasNormals);
    EXPECT_EQ(readAll(**n, true).all[0].normal, (Vec3f{0, 1, 0}));
    // PTS: a count line, then x y z i r g b.
    test::writeFile(dir.file("p.pts"), "2\n1 2 3 -5 10 20 30\n4 5 6 7 1 2 3\n");
    auto p = openTextReader(dir.file("p.pts"), "");
    ASSERT_TRUE(p.ok());
    auto rp = readAll(**p, true);
    ASSERT_EQ(rp.points, 2u);
    EXPECT_EQ(rp.all[0].color[1], 20 * 257);
    // Given layout with an ignored column.
    auto g = openTextReader(dir.file("p.pts"), "x,y,z,_,r,g,b");
    ASSERT_TRUE(g.ok());
    EXPECT_FALSE((*g)->description().hasIntensity);
    // Errors name the line.
    test::writeFile(dir.file("bad.xyz"), "1 2 3\n4 five 6\n");
    auto bad = openTextReader(dir.file("bad.xyz"), "");
    ASSERT_TRUE(bad.ok());
    std::vector<InputPoint> buf(10);
    auto res = (*bad)->read(buf.data(), buf.size());
    ASSERT_FALSE(res.ok());
    EXPECT_NE(res.status().message().find("line 2"), std::string::npos) << res.status().message();
    EXPECT_FALSE(openTextReader(dir.file("a.xyz"), "x,y,q").ok());
}

TEST(MeshReader, SamplesShareMeshesAtTargetSpacing) {
    REQUIRE_DATA();
    MeshSampling sampling;
    sampling.spacing = 0.001;  // 1 mm on the bunny
    auto r = openMeshReader(test::dataFile("bunny.ply"), sampling);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE((*r)->description().hasNormals);
    auto all = readAll(**r, true);
    // Expected count = area / spacing²; the bunny's area is about 0.057 m².
    EXPECT_GT(all.points, 45000u);
    EXPECT_LT(all.points, 70000u);
    for (size_t i = 0; i < all.all.size(); i += 997) EXPECT_NEAR(length(all.all[i].normal), 1.0f, 1e-4);
    // Samples lie within the vertex bounds.
    expectBounds(all.bounds, {-0.094690, 0.032987, -0.061874}, {0.061009, 0.187321, 0.058800}, 2e-3);
}

TEST(MeshReader, ObjThroughOpenMesh) {
    REQUIRE_DATA();
    std::string path = test::dataFile("fg_spkMgDragon/fg_spkMgDragon.obj");
    auto normals = readMeshVertexNormals(path);
    ASSERT_TRUE(normals.ok()) << normals.status().message();
    EXPECT_EQ(normals->positions.size(), 4996u);  // PROVENANCE: 4,996 vertices
    auto r = openMeshReader(path, MeshSampling{});
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_GT(readAll(**r).points, 4996u);
}

TEST(MeshReader, ObjColoursOutsideTheUnitRangeAreClamped) {
    // OBJ vertex colours are floats of any value; OpenMesh cast them to bytes
    // unchecked (undefined behaviour for -74.3, found by fuzz_read_obj:
    // fuzz/regressions/read_obj). They are clamped to [0, 1]: a triangle whose
    // corners all read (-74.3, 2, 0.5) samples red 0, green full,
    // blue half, wherever it is sampled.
    test::TempDir dir;
    test::writeFile(dir.file("c.obj"), "v 0 0 0 -74.3 2 0.5\nv 1 0 0 -74.3 2 0.5\nv 0 1 0 -74.3 2 0.5\nf 1 2 3\n");
    auto r = openMeshReader(dir.file("c.obj"), MeshSampling{0.05});
    ASSERT_TRUE(r.ok()) << r.status().message();
    ASSERT_TRUE((*r)->description().hasColors);
    auto all = readAll(**r, true);
    ASSERT_GT(all.points, 10u);
    for (const InputPoint& p : all.all) {
        EXPECT_EQ(p.color[0], 0);
        EXPECT_EQ(p.color[1], 65535);
        // 0.5 · 65535 = 32767.5: the barycentric weights sum to 1 only up to
        // rounding, so either neighbour.
        EXPECT_NEAR(p.color[2], 32767.5, 0.5);
    }
}

TEST(MeshReader, DefaultSpacingIsCappedAtMaxSurfels) {
    // One huge triangle beside many tiny ones (fuzz_read_obj found a 3 KB OBJ
    // like it that sampled without end): half the median edge, 0.0005, would
    // sample the big one's 5e5 area with 2e12 surfels. The default spacing is
    // coarsened to the cap, with a warning (the count per face is random:
    // 20,000 ± 1 %); an explicit spacing is taken as given.
    test::TempDir dir;
    std::string obj = "v 0 0 0\nv 1000 0 0\nv 0 1000 0\nf 1 2 3\n";
    for (int i = 0; i < 100; ++i) {
        const double x = 2000 + i;
        obj += "v " + std::to_string(x) + " 0 0\nv " + std::to_string(x + 0.001) + " 0 0\nv " + std::to_string(x) +
               " 0.001 0\nf " + std::to_string(4 + 3 * i) + " " + std::to_string(5 + 3 * i) + " " +
               std::to_string(6 + 3 * i) + "\n";
    }
    test::writeFile(dir.file("huge.obj"), obj);
    auto r = test::run({test::binary("surfcast-build"), dir.file("huge.obj"), "--mesh-max-surfels", "20000", "-o",
                        dir.file("out")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("keeps them to --mesh-max-surfels 20000"), std::string::npos) << r.output;
    size_t at = r.output.find("points in: ");
    ASSERT_NE(at, std::string::npos) << r.output;
    const long points = std::atol(r.output.c_str() + at + 11);
    EXPECT_NEAR(double(points), 20000.0, 200.0) << r.output;
    MeshSampling explicitSpacing{5.0};
    explicitSpacing.maxSurfels = 10;
    auto reader = openMeshReader(dir.file("huge.obj"), explicitSpacing);
    ASSERT_TRUE(reader.ok()) << reader.status().message();
    EXPECT_NEAR(double(readAll(**reader).points), 5e5 / 25, 500) << "an explicit spacing is not capped";
}

TEST(MeshReader, ObjFacesWithoutVertexIndicesAreErrors) {
    // OpenMesh's OBJ reader aborted the process (an assertion) on a face none
    // of whose vertices has an index (fuzz/regressions/read_obj). Such faces,
    // and faces of fewer than three vertices, are errors naming the line.
    test::TempDir dir;
    for (auto [face, message] : {std::pair{"f /2/1 //3//1 /1", "face vertex '/2/1' has no vertex index"},
                                 std::pair{"f 1 2 0", "face vertex '0' has no vertex index"},
                                 std::pair{"f 1 2", "a face needs three vertices"}}) {
        test::writeFile(dir.file("bad.obj"), std::string("v 0 0 0\nv 1 0 0\nv 0 1 0\n") + face + "\n");
        auto r = openMeshReader(dir.file("bad.obj"), MeshSampling{});
        ASSERT_FALSE(r.ok()) << face;
        EXPECT_NE(r.status().message().find(std::string("line 4: ") + message), std::string::npos) << r.status().message();
    }
    auto crash = test::run({test::binary("surfcast-build"), SURFCAST_FUZZ_REGRESSIONS "/read_obj/face-without-vertex-index.obj",
                            "-o", dir.file("out")});
    EXPECT_EQ(crash.exitCode, 1) << crash.output;
    EXPECT_NE(crash.output.find("has no vertex index"), std::string::npos) << crash.output;
}

TEST(Inputs, ScanMergesFilesAndScalesLasColours) {
    REQUIRE_DATA();
    InputOptions opt;
    opt.paths = {test::dataFile("autzen_trim.las"), test::dataFile("igea.ply")};
    opt.verticesOnly = true;
    auto stats = scanInputs(opt, [](uint64_t) {});
    ASSERT_TRUE(stats.ok()) << stats.status().message();
    EXPECT_EQ(stats->points, 110000u + 134345u);
    EXPECT_EQ(stats->sources[0].colorScale, 257);  // 8-bit values in LAS's 16-bit fields
    EXPECT_EQ(stats->colorBits, 8);
}

TEST(DefaultScene, DeterministicIrregularAndColoured) {
    auto read = [](uint64_t seed) {
        SceneOptions o;
        o.seed = seed;
        o.targetPoints = 60000;
        std::vector<InputPoint> all;
        for (auto& r : openDefaultScene(o)) {
            EXPECT_TRUE(r->description().hasColors);
            EXPECT_FALSE(r->description().hasNormals);
            EXPECT_TRUE(r->description().scanOrigins.size() == 1 && r->description().scanOrigins[0].has_value());
            auto part = readAll(*r, true);
            all.insert(all.end(), part.all.begin(), part.all.end());
        }
        return all;
    };
    auto a = read(7), b = read(7), c = read(8);
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(a[i].position, b[i].position) << i;
    EXPECT_NE(a[100].position, c[100].position);
    // About the requested size.
    EXPECT_GT(a.size(), 45000u);
    EXPECT_LT(a.size(), 75000u);
    // Density falls with distance from the scanners: points per m² of ground
    // within 3 m of scanner 1's foot far exceed those 9-12 m away.
    size_t nearCount = 0, farCount = 0;
    for (const auto& p : a) {
        if (std::fabs(p.position.z) > 0.02) continue;
        double r = std::hypot(p.position.x - 7.0, p.position.y + 6.0);
        if (r < 3) ++nearCount;
        else if (r > 9 && r < 12) ++farCount;
    }
    double nearDensity = nearCount / (M_PI * 9), farDensity = farCount / (M_PI * (144 - 81));
    EXPECT_GT(nearDensity, 5 * farDensity);
}
