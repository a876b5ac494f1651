// E57 input (the e57 crate behind laz_ffi/): the shared files against the
// counts libE57Format reads from them (../shared/data/e57/PROVENANCE.md), and
// multi-scan files written here with the crate's writer
// (surfcast-write-e57), whose poses, spherical coordinates, limits and
// invalid points the tests know: positions come back in the file's frame,
// attributes scaled by the limits, and normals face each scan's scanner.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "e57_reader.h"
#include "inputs.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace fs = std::filesystem;
using namespace surfcast;

namespace {

struct ReadAll {
    std::vector<InputPoint> points;
    std::vector<double> scalars;
    uint64_t skipped = 0;
};

ReadAll readAll(PointReader& reader) {
    ReadAll r;
    std::vector<InputPoint> batch(5000);
    while (true) {
        auto n = reader.read(batch.data(), batch.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        r.points.insert(r.points.end(), batch.begin(), batch.begin() + long(*n));
        r.scalars.insert(r.scalars.end(), reader.scalarValues().begin(), reader.scalarValues().end());
    }
    r.skipped = reader.skipped();
    return r;
}

// A rotation as a unit quaternion (w, x, y, z): R v, the E57 pose's rotation
// from a scan's own frame into the file's (ASTM E2807 §8.4.6).
struct Pose {
    double w, x, y, z;
    Vec3d t;
    Vec3d rotate(const Vec3d& v) const {
        const double r[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                                {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                                {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
        return {r[0][0] * v.x + r[0][1] * v.y + r[0][2] * v.z, r[1][0] * v.x + r[1][1] * v.y + r[1][2] * v.z,
                r[2][0] * v.x + r[2][1] * v.y + r[2][2] * v.z};
    }
    // The scan's own coordinates of a point of the file's frame: R^T (p - t).
    Vec3d local(const Vec3d& p) const { return Pose{w, -x, -y, -z, {}}.rotate(p - t); }
    std::string spec() const {
        std::ostringstream s;
        s.precision(17);
        s << "pose " << w << ' ' << x << ' ' << y << ' ' << z << ' ' << t.x << ' ' << t.y << ' ' << t.z << '\n';
        return s.str();
    }
};

Pose unitPose(double w, double x, double y, double z, Vec3d t) {
    const double n = std::sqrt(w * w + x * x + y * y + z * z);
    return {w / n, x / n, y / n, z / n, t};
}

// Writes `spec` (surfcast-write-e57's format) as the E57 file `out`.
void writeE57(const test::TempDir& dir, const std::string& spec, const std::string& out) {
    const std::string specFile = out + ".spec";
    test::writeFile(specFile, spec);
    auto w = test::run({"/bin/sh", "-c", std::string("'") + SURFCAST_WRITE_E57 + "' '" + out + "' < '" + specFile + "'"});
    ASSERT_EQ(w.exitCode, 0) << w.output;
    (void)dir;
}

std::string point(const Vec3d& v) {
    std::ostringstream s;
    s.precision(17);
    s << "p " << v.x << ' ' << v.y << ' ' << v.z;
    return s.str();
}

// Range, azimuth and elevation (radians) of a point in a scan's own frame.
Vec3d spherical(const Vec3d& l) {
    const double r = std::sqrt(l.x * l.x + l.y * l.y + l.z * l.z);
    return {r, std::atan2(l.y, l.x), std::asin(l.z / r)};
}

// The inside of a room, x in [0, 8], y in [0, 6], z in [0, 3], sampled every
// `step` on its six faces, and each face's normal into the room.
struct RoomPoint {
    Vec3d p, inward;
};
std::vector<RoomPoint> room(double step) {
    std::vector<RoomPoint> out;
    const double size[3] = {8, 6, 3};
    for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
            const int u = (axis + 1) % 3, v = (axis + 2) % 3;
            for (double a = step / 2; a < size[u]; a += step)
                for (double b = step / 2; b < size[v]; b += step) {
                    RoomPoint r;
                    r.p[axis] = side * size[axis];
                    r.p[u] = a;
                    r.p[v] = b;
                    r.inward[axis] = side ? -1 : 1;
                    out.push_back(r);
                }
        }
    return out;
}

// Two scanners in the room; each point belongs to the nearer one's scan.
// Scan 0 stores spherical coordinates, scan 1 cartesian ones, each in its
// own frame under its pose.
const Pose kScanners[2] = {unitPose(0.9659258, 0, 0, 0.258819, {2.0, 2.5, 1.4}),   // 30° about z
                           unitPose(0.9, 0.1, -0.2, 0.3, {6.0, 3.5, 1.6})};      // a tilted one
int nearerScanner(const Vec3d& p) {
    return length(p - kScanners[0].t) <= length(p - kScanners[1].t) ? 0 : 1;
}
std::string roomSpec(const std::vector<RoomPoint>& points) {
    std::string spec;
    for (int s = 0; s < 2; ++s) {
        spec += "scan station " + std::to_string(s + 1) + "\n" + kScanners[s].spec();
        spec += s == 0 ? "fields spherical\n" : "fields cartesian\n";
        for (const RoomPoint& r : points)
            if (nearerScanner(r.p) == s) {
                const Vec3d l = kScanners[s].local(r.p);
                spec += point(s == 0 ? spherical(l) : l) + "\n";
            }
    }
    return spec;
}

// Leaf surfels of a set of the room away from its edges (0.2 of a wall,
// where a normal's neighbourhood bends round the corner), and how many of
// their normals are their wall's inward one. Leaves keep 1/256 of a cell's
// precision where the input gives none: a wall's points lie within 0.01 of it.
std::pair<size_t, size_t> inwardNormals(const TilesetReader& set) {
    size_t checked = 0, inward = 0;
    const double size[3] = {8, 6, 3};
    for (const NodeRecord& n : set.nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto b = set.readBlock(n);
        EXPECT_TRUE(b.ok()) << b.status().message();
        if (!b.ok()) break;
        for (size_t i = 0; i < b->size(); ++i) {
            const Vec3d p = set.position(n, *b, i);
            int wall = -1, near = 0;
            for (int a = 0; a < 3; ++a) {
                if (std::fabs(p[a]) < 0.01 || std::fabs(p[a] - size[a]) < 0.01) wall = a;
                if (p[a] < 0.2 || p[a] > size[a] - 0.2) ++near;
            }
            if (wall < 0 || near > 1) continue;
            const double inwardSign = p[wall] < 0.01 ? 1 : -1;
            ++checked;
            inward += b->normals[3 * i + size_t(wall)] * inwardSign > 0.9;
        }
    }
    return {checked, inward};
}

TEST(E57, SharedFilesMatchTheirProvenance) {
    REQUIRE_DATA();
    struct Expected {
        const char* file;
        size_t scans;
        uint64_t records;  // all scans', invalid points included
        bool colors, intensity;
    };
    // PROVENANCE.md: what libE57Format reads from each.
    const Expected files[] = {
        {"bunnyDouble.e57", 1, 30571, false, false},        {"bunnyInt19.e57", 1, 30571, false, false},
        {"ColouredCubeDouble.e57", 1, 7680, true, false},   {"tinyCartesianFloatRgb.e57", 1, 2090, true, false},
        {"tiny_spherical.e57", 1, 360, false, false},       {"read_error.e57", 1, 2651, true, true},
        {"integer_intensity.e57", 1, 2, false, true},       {"scaled_integer_intensity.e57", 1, 2, false, true},
        {"float_intensity_without_min_max.e57", 1, 1, false, true},
        {"cartesian_invalid_state_single.e57", 1, 3, false, false},
        {"las2e57_no_images_tag.e57", 1, 153, true, false}, {"ColourRepresentation.e57", 1, 153, true, false},
        {"tiny_pc_and_images.e57", 1, 2, false, false},     {"pdal_A4.e57", 1, 4, true, true},
        {"pdal_A_B.e57", 2, 6, true, true},                 {"pdal_A_B_different_dims.e57", 2, 2, true, true},
        {"empty_pc.e57", 1, 0, false, false},               {"ZeroPoints.e57", 1, 0, false, false},
        {"InvalidCVHeader.e57", 1, 0, false, false},
    };
    for (const Expected& e : files) {
        SCOPED_TRACE(e.file);
        auto r = openE57Reader(test::dataFile(std::string("e57/") + e.file));
        ASSERT_TRUE(r.ok()) << r.status().message();
        const InputDescription& d = (*r)->description();
        EXPECT_EQ(d.format, "e57");
        EXPECT_EQ(d.scanOrigins.size(), e.scans);
        EXPECT_EQ(d.declaredPoints, e.records);
        EXPECT_EQ(d.hasColors, e.colors);
        EXPECT_EQ(d.hasIntensity, e.intensity);
        auto all = readAll(**r);
        EXPECT_EQ(all.points.size() + all.skipped, e.records);
        for (const InputPoint& p : all.points) ASSERT_TRUE(finite(p.position));
    }
    // Invalid states: one of the three points has a return; the spherical
    // file marks half its points.
    auto invalid = openE57Reader(test::dataFile("e57/cartesian_invalid_state_single.e57"));
    ASSERT_TRUE(invalid.ok());
    EXPECT_EQ(readAll(**invalid).points.size(), 1u);
    // The two scans of pdal_A_B, in order, each point with its scan.
    auto ab = openE57Reader(test::dataFile("e57/pdal_A_B.e57"));
    ASSERT_TRUE(ab.ok());
    auto abPoints = readAll(**ab).points;
    ASSERT_EQ(abPoints.size(), 6u);
    for (size_t i = 0; i < 6; ++i) EXPECT_EQ(abPoints[i].scan, i < 2 ? 0 : 1) << i;
}

// The same bunny with double coordinates and with 19-bit scaled integers:
// the same points, within the integers' step (the bunny spans 0.16 units: a
// step of 0.16 / 2^19 = 3.1e-7 at most; the doubles hold the rounded values,
// so they agree exactly).
TEST(E57, ScaledIntegerCoordinatesMatchDoubles) {
    REQUIRE_DATA();
    auto a = openE57Reader(test::dataFile("e57/bunnyDouble.e57"));
    auto b = openE57Reader(test::dataFile("e57/bunnyInt19.e57"));
    ASSERT_TRUE(a.ok() && b.ok());
    auto pa = readAll(**a).points, pb = readAll(**b).points;
    ASSERT_EQ(pa.size(), 30571u);
    ASSERT_EQ(pa.size(), pb.size());
    double worst = 0;
    for (size_t i = 0; i < pa.size(); ++i) worst = std::max(worst, length(pa[i].position - pb[i].position));
    EXPECT_LE(worst, 3.1e-7 * std::sqrt(3.0));
}

// Two scans with poses: spherical coordinates with intensity limits, row and
// column indices and invalid points; cartesian ones with 8-bit colour. Every
// point comes back where it is in the file's frame, in order, with its scan,
// its intensity scaled by the limits and its colour by the colour limits.
TEST(E57, ScansArePosedAndScaledByTheirLimits) {
    test::TempDir dir;
    const std::vector<RoomPoint> pts = room(0.5);
    std::vector<Vec3d> expected[2];
    std::string spec;
    for (int s = 0; s < 2; ++s) {
        spec += "scan station " + std::to_string(s + 1) + "\n" + kScanners[s].spec();
        spec += s == 0 ? "fields spherical intensity rowcolumn invalid\nintensity-limits 0 4095\n" : "fields cartesian color\n";
        size_t k = 0;
        for (const RoomPoint& r : pts) {
            if (nearerScanner(r.p) != s) continue;
            const Vec3d l = kScanners[s].local(r.p);
            if (s == 0) {
                spec += point(spherical(l)) + " " + std::to_string(k * 37 % 4096) + " " + std::to_string(k / 100) + " " +
                        std::to_string(k % 100) + " 0\n";
                if (k % 10 == 0) spec += "p 0 1.5 0.5 7 0 0 2\np 0 1.5 0.5 7 0 0 1\n";  // no return; a direction only
            } else {
                spec += point(l) + " " + std::to_string(k % 256) + " " + std::to_string(k * 7 % 256) + " 255\n";
            }
            expected[s].push_back(r.p);
            ++k;
        }
    }
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, spec, dir.file("room.e57")));

    ScalarSelection rows;
    rows.names = {"row", "column"};
    auto r = openE57Reader(dir.file("room.e57"), rows);
    ASSERT_TRUE(r.ok()) << r.status().message();
    const InputDescription& d = (*r)->description();
    ASSERT_EQ(d.scanOrigins.size(), 2u);
    for (int s = 0; s < 2; ++s) {
        ASSERT_TRUE(d.scanOrigins[size_t(s)].has_value());
        EXPECT_EQ(*d.scanOrigins[size_t(s)], kScanners[s].t);
    }
    ASSERT_EQ(d.scalars.size(), 2u);
    EXPECT_EQ(d.scalars[0].name, "row");
    EXPECT_EQ(d.scalars[1].name, "column");
    auto all = readAll(**r);
    ASSERT_EQ(all.points.size(), expected[0].size() + expected[1].size());
    EXPECT_EQ(all.skipped, 2 * ((expected[0].size() + 9) / 10));
    for (size_t i = 0; i < all.points.size(); ++i) {
        const InputPoint& p = all.points[i];
        const int s = i < expected[0].size() ? 0 : 1;
        const size_t k = s == 0 ? i : i - expected[0].size();
        ASSERT_EQ(p.scan, s) << i;
        ASSERT_LT(length(p.position - expected[s][k]), 1e-9) << i;
        if (s == 0) {
            EXPECT_EQ(p.intensity, std::lround(double(k * 37 % 4096) / 4095 * 65535)) << i;
            EXPECT_EQ(all.scalars[2 * i], double(k / 100)) << i;
            EXPECT_EQ(all.scalars[2 * i + 1], double(k % 100)) << i;
            for (int c = 0; c < 3; ++c) EXPECT_EQ(p.color[c], 65535) << "a scan without colour is white";
        } else {
            EXPECT_EQ(p.intensity, 0);
            EXPECT_EQ(p.color[0], k % 256 * 257) << i;
            EXPECT_EQ(p.color[1], k * 7 % 256 * 257) << i;
            EXPECT_EQ(p.color[2], 65535) << i;
            EXPECT_TRUE(std::isnan(all.scalars[2 * i])) << "the cartesian scan has no rows";
        }
    }
}

// A room scanned from inside by two scanners: every wall's normals face into
// the room, as each scan's scanner saw it. Orienting by the data's centre
// (what a file without scanner positions gets) turns them all outward, and
// "up" only the floor's right (bench/BENCHMARKS.md, "E57: normals toward
// each scanner"). The staged build carries the scans' origins through its
// plan: the same bytes.
TEST(E57, NormalsFaceEachScanner) {
    test::TempDir dir;
    const std::vector<RoomPoint> pts = room(test::kSanitized ? 0.1 : 0.05);  // the same paths, a quarter of the points
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, roomSpec(pts), dir.file("room.e57")));
    const std::vector<std::string> options = {dir.file("room.e57"), "--memory", "56M", "--capacity", "1000"};  // several chunks
    auto build = test::run({test::binary("surfcast-build"), "-q", options[0], options[1], options[2], options[3], options[4], "-o",
                            dir.file("set")});
    ASSERT_EQ(build.exitCode, 0) << build.output;
    auto set = TilesetReader::open(dir.file("set"));
    ASSERT_TRUE(set.ok()) << set.status().message();
    EXPECT_EQ(set->info().normalSource, "estimated-scan-origin");
    EXPECT_EQ(set->info().inputPoints, pts.size());
    const auto [checked, inward] = inwardNormals(*set);
    EXPECT_GT(checked, pts.size() / 2);
    EXPECT_EQ(inward, checked);
    // The same points as text, without their scanners: oriented away from the centre.
    {
        std::ofstream xyz(dir.file("room.xyz"));
        xyz.precision(17);
        for (const RoomPoint& r : pts) xyz << r.p.x << ' ' << r.p.y << ' ' << r.p.z << '\n';
    }
    auto text = test::run({test::binary("surfcast-build"), "-q", dir.file("room.xyz"), "-o", dir.file("text")});
    ASSERT_EQ(text.exitCode, 0) << text.output;
    auto textSet = TilesetReader::open(dir.file("text"));
    ASSERT_TRUE(textSet.ok()) << textSet.status().message();
    EXPECT_EQ(textSet->info().normalSource, "estimated-outward");
    const auto [textChecked, textInward] = inwardNormals(*textSet);
    std::printf("normals facing into the room: %zu of %zu toward each scanner, %zu of %zu away from the centre\n", inward, checked,
                textInward, textChecked);
    EXPECT_LT(textInward, textChecked / 100);

    // Staged: plan (scan and count), distribute, every chunk, merge.
    const std::string work = dir.file("work"), build_ = test::binary("surfcast-build");
    std::vector<std::string> plan = {build_, "plan", "--work", work, "-q"};
    plan.insert(plan.end(), options.begin(), options.end());
    plan.insert(plan.end(), {"-o", dir.file("staged")});
    auto planned = test::run(plan);
    ASSERT_EQ(planned.exitCode, 0) << planned.output;
    const size_t chunks = nlohmann::json::parse(test::readFile(work + "/plan.json"))["chunks"].get<size_t>();
    ASSERT_GE(chunks, 2u);
    auto distributed = test::run({build_, "distribute", "--work", work, "-q"});
    ASSERT_EQ(distributed.exitCode, 0) << distributed.output;
    for (size_t c = 0; c < chunks; ++c) {
        auto chunk = test::run({build_, "chunk", "--work", work, "-q", std::to_string(c)});
        ASSERT_EQ(chunk.exitCode, 0) << chunk.output;
    }
    auto merged = test::run({build_, "merge", "--work", work, "-q"});
    ASSERT_EQ(merged.exitCode, 0) << merged.output;
    EXPECT_EQ(test::readFile(dir.file("staged/blocks.bin")), test::readFile(dir.file("set/blocks.bin")));
    EXPECT_EQ(test::readFile(dir.file("staged/hierarchy.bin")), test::readFile(dir.file("set/hierarchy.bin")));
}

// Intensities without limits (floats, no intensityLimits) stay the raw
// values, rounded and clamped to 16 bits, whatever their size: a value under
// 1 is not taken for a normalized one.
TEST(E57, IntensityWithoutLimitsIsTheRawValue) {
    test::TempDir dir;
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, "scan raw\nfields cartesian floatintensity\np 0 0 0 0.9\np 1 0 0 1.1\np 0 1 0 5\np 1 1 0 300.4\np 2 1 0 70000\n",
                                     dir.file("raw.e57")));
    auto r = openE57Reader(dir.file("raw.e57"));
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE((*r)->description().hasIntensity);
    auto all = readAll(**r);
    ASSERT_EQ(all.points.size(), 5u);
    const uint16_t expected[] = {1, 1, 5, 300, 65535};
    for (size_t i = 0; i < 5; ++i) EXPECT_EQ(all.points[i].intensity, expected[i]) << i;
}

// Georeferenced points with an identity pose: the scanner "at the origin"
// lies a hundred kilometres away, and is ignored (the flat patch faces up);
// the same points in a scan posed where the scanner stood face it.
TEST(E57, AnIdentityPoseFarFromTheDataIsNoScanner) {
    test::TempDir dir;
    std::string far = "scan georeferenced\npose 1 0 0 0 0 0 0\nfields cartesian\n", posed = "scan station\npose 1 0 0 0 100000 5 110\nfields cartesian\n";
    for (int i = 0; i < 60; ++i)
        for (int j = 0; j < 60; ++j) {
            far += point({100000 + i * 0.1, j * 0.1, 100}) + "\n";
            posed += point({i * 0.1, j * 0.1 - 5, -10}) + "\n";  // the same points, 10 below the scanner
        }
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, far, dir.file("far.e57")));
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, posed, dir.file("posed.e57")));
    for (const auto& [file, source] : {std::pair<std::string, std::string>{"far", "estimated-up"}, {"posed", "estimated-scan-origin"}}) {
        auto b = test::run({test::binary("surfcast-build"), "-q", dir.file(file + ".e57"), "-o", dir.file(file)});
        ASSERT_EQ(b.exitCode, 0) << b.output;
        auto set = TilesetReader::open(dir.file(file));
        ASSERT_TRUE(set.ok()) << set.status().message();
        EXPECT_EQ(set->info().normalSource, source) << file;
    }
}

// Bad files: each a clear error naming the file (and the scan where one is
// at fault), a non-zero exit and no set written.
TEST(E57, BadFilesAreClearErrors) {
    REQUIRE_DATA();
    test::TempDir dir;
    const std::string good = "scan a\npose 1 0 0 0 1 2 3\nfields cartesian\np 0 0 0\np 1 0 0\np 0 1 0\n";
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, good, dir.file("good.e57")));
    // A scan that claims 10^9 points in a file of a few hundred bytes, and
    // one that claims 2^61 (times a point's size, the count wraps 64 bits).
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, good + "claim 0 1000000000\n", dir.file("claims.e57")));
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, good + "claim 0 2305843009213693952\n", dir.file("wraps.e57")));
    // A rotation that is not a unit quaternion (it would scale the scan), and
    // a translation that is not finite (every point would be NaN).
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, "scan b\npose 2 0 0 0 0 0 0\nfields cartesian\np 0 0 0\n", dir.file("scaled.e57")));
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, "scan e\npose 1 0 0 0 inf 0 0\nfields cartesian\np 0 0 0\n", dir.file("infinite.e57")));
    // A prototype without coordinates, and one with a field E57 does not define.
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, good + "replace <cartesianX <intensity\nreplace </cartesianX> </intensity>\n",
                                     dir.file("nocoordinates.e57")));
    ASSERT_NO_FATAL_FAILURE(writeE57(dir, good + "replace <cartesianX <cartesianQ\nreplace </cartesianX> </cartesianQ>\n",
                                     dir.file("unknown.e57")));
    // A flipped byte in a scan's data (its second page; the XML is at the
    // end): that page's checksum fails when the scan is read.
    {
        std::string many = "scan c\nfields cartesian\n";
        for (int i = 0; i < 1000; ++i) many += "p " + std::to_string(i) + " 0.5 0.25\n";
        ASSERT_NO_FATAL_FAILURE(writeE57(dir, many, dir.file("many.e57")));
        std::string bytes = test::readFile(dir.file("many.e57"));
        ASSERT_GT(bytes.size(), 4096u);
        bytes[1500] = char(bytes[1500] ^ 0x10);
        test::writeFile(dir.file("flipped.e57"), bytes);
    }
    // Truncated: the good file without its last page.
    {
        std::string bytes = test::readFile(dir.file("good.e57"));
        test::writeFile(dir.file("truncated.e57"), bytes.substr(0, bytes.size() - 1024));
    }
    struct Case {
        std::string path, message;
    };
    const Case cases[] = {
        {test::dataFile("e57/empty.e57"), "no scans"},
        {test::dataFile("e57/corrupt_crc.e57"), "checksum"},
        {test::dataFile("e57/bad-crc.e57"), "checksum"},
        {dir.file("truncated.e57"), "truncated"},
        {dir.file("claims.e57"), "scan 0 ('a')"},
        {dir.file("wraps.e57"), "scan 0 ('a')"},
        {dir.file("nocoordinates.e57"), "scan 0 ('a'): neither cartesian nor spherical coordinates"},
        {dir.file("unknown.e57"), "cartesianQ"},
        {dir.file("flipped.e57"), "scan 0 ('c'): "},
        {dir.file("scaled.e57"), "scan 0 ('b'): the pose's rotation quaternion (2, 0, 0, 0) is not a unit quaternion"},
        {dir.file("infinite.e57"), "scan 0 ('e'): the pose's translation (inf, 0, 0) is not finite"},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.path);
        auto b = test::run({test::binary("surfcast-build"), "-q", c.path, "-o", dir.file("out")});
        EXPECT_EQ(b.exitCode, 1) << b.output;
        EXPECT_NE(b.output.find(c.path + ": "), std::string::npos) << b.output;
        EXPECT_NE(b.output.find(c.message), std::string::npos) << b.output;
        EXPECT_FALSE(fs::exists(dir.file("out")));
        EXPECT_EQ(b.output.find("panicked"), std::string::npos) << b.output;
    }
    // Images are not read, and the build says so once.
    auto images = test::run({test::binary("surfcast-build"), "-q", test::dataFile("e57/tiny_pc_and_images.e57"), "-o", dir.file("images")});
    EXPECT_EQ(images.exitCode, 0) << images.output;
    const std::string note = "images in the file, not read";
    ASSERT_NE(images.output.find(note), std::string::npos) << images.output;
    EXPECT_EQ(images.output.find(note), images.output.rfind(note)) << images.output;
}

}  // namespace
