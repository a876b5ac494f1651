// Estimated normals (PCA + the outward rule) against the surface normals of the
// shared meshes; the fractions are recorded in docs/ARCHITECTURE.md.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "mesh_reader.h"
#include "normals.h"
#include "test_support.h"

using namespace surfcast;

namespace {
// Agreement: within 30 degrees of the mesh's vertex normal, orientation included.
const double kAgreeCos = std::cos(30.0 * 3.14159265358979 / 180.0);

double agreement(const std::string& file) {
    auto mesh = readMeshVertexNormals(test::dataFile(file));
    EXPECT_TRUE(mesh.ok());
    if (!mesh.ok()) return 0;
    std::vector<Surfel> pts(mesh->positions.size());
    Box3d box;
    for (size_t i = 0; i < pts.size(); ++i) {
        pts[i].position = mesh->positions[i];
        box.extend(mesh->positions[i]);
    }
    NormalContext ctx;
    ctx.rules = {OrientationRule{}};
    ctx.centre = (box.min + box.max) * 0.5;
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    size_t agree = 0, agreeUnoriented = 0, counted = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
        if (length(mesh->normals[i]) < 0.5f) continue;  // isolated vertex: no mesh normal
        ++counted;
        double d = dot(pts[i].normal, mesh->normals[i]);
        if (d >= kAgreeCos) ++agree;
        if (std::fabs(d) >= kAgreeCos) ++agreeUnoriented;
    }
    double fraction = double(agree) / double(counted);
    std::printf("%s: %.1f%% of %zu estimated normals within 30 degrees of the mesh normal (%.1f%% up to orientation)\n",
                file.c_str(), 100 * fraction, counted, 100.0 * double(agreeUnoriented) / double(counted));
    return fraction;
}
}  // namespace

TEST(Normals, AgreeWithMeshNormals) {
    REQUIRE_DATA();
    // Thresholds a few points under the measured values (docs/ARCHITECTURE.md).
    EXPECT_GE(agreement("bunny.ply"), 0.85);
    EXPECT_GE(agreement("horse.ply"), 0.75);  // thin legs defeat the outward rule
    EXPECT_GE(agreement("igea.ply"), 0.95);
}

TEST(Normals, PlaneFacesTheScanOrigin) {
    std::vector<Surfel> pts;
    for (int i = 0; i < 30; ++i)
        for (int j = 0; j < 30; ++j) {
            Surfel s;
            s.position = {i * 0.1, j * 0.1, 0.002 * ((i * 7 + j * 3) % 5)};
            pts.push_back(s);
        }
    NormalContext ctx;
    OrientationRule below;
    below.scanOrigin = Vec3d{1.5, 1.5, -10};
    ctx.rules = {below};
    estimateNormals(pts, {}, ctx);
    for (const Surfel& s : pts) EXPECT_LT(s.normal.z, -0.95f);
    for (Surfel& s : pts) s.normal = {};
    ctx.rules = {OrientationRule{std::nullopt, true}};
    estimateNormals(pts, {}, ctx);
    for (const Surfel& s : pts) EXPECT_GT(s.normal.z, 0.95f);
}
