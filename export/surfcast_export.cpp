// surfcast-export: a tile set's points out to other tools. main() parses
// arguments and writes the file atomically; the export is laz_export.h's.
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <string>

#include "camera.h"
#include "command_line.h"
#include "http_tile_source.h"
#include "laz_export.h"
#include "object_store.h"
#include "set_publisher.h"
#include "splat_export.h"
#include "tiles3d_export.h"

namespace {

constexpr const char* kUsage = R"(surfcast-export SET --format laz|copc [--bbox X0,Y0,Z0,X1,Y1,Z1] [--classes LIST] -o FILE
       surfcast-export SET --format 3dtiles [--as splats|points] [--compression meshopt|none]
                       [--tiling auto|explicit|implicit] -o FOLDER
       surfcast-export SET --format ply|spz [--level N|leaves | --splat-budget N | --camera C [--size WxH] [--lod PX]
                       [--splat-budget N]] -o FILE)";

constexpr const char* kDescription = R"(Writes a tile set's points as another format. SET is a set's folder or its
http(s) URL.)";

constexpr const char* kFormats = R"(Formats (--format):
  laz      LAS 1.4 compressed with LASzip (the laz crate): the input points the
           set's leaves hold (exact duplicates merged at build), point format 6,
           or 7 with colour; intensity, classification, returns, and GPS time,
           scan angle, user data and point source id where the set stores them
  copc     the same points as a COPC 1.0 file (cloud-optimized point cloud: LAZ
           chunks in an octree on the set's root cube, each node above the
           leaves an even sample of what lies under it, the hierarchy in an
           EVLR), which COPC readers query by box and level
  3dtiles  a 3D Tiles 1.1 tileset for CesiumJS and other 3D Tiles engines:
           tileset.json and one glb per node (REPLACE refinement, the node's
           spacing as its geometric error); the whole set, into a folder
           (docs/EXPORT.md)
  ply      the 3D Gaussian splatting PLY that splat viewers read: one cut
           through the tree, each surfel a flat Gaussian, about the centre of
           the set's bounds (a comment keeps it), in the PLY's y-down axes
  spz      the same Gaussians as SPZ 2 (Niantic's compressed splats, y up; at
           most 10 million))";

int usageError(const std::string& message) { return surfcast::cli::usageError("surfcast-export", message); }

// The summary's lines on what a LAS export carries and what it leaves out.
std::string dimensionSummary(const std::vector<std::string>& carried, const std::vector<std::string>& leftOut) {
    auto list = [](const std::vector<std::string>& names) {
        std::string out;
        for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
        return out.empty() ? std::string("none") : out;
    };
    std::string out = "dimensions: x, y, z, " + list(carried) + "\n";
    if (!leftOut.empty()) out += "left out (the set or the point format does not keep them): " + list(leftOut) + "\n";
    return out;
}

// Progress on stderr, a line each twentieth of the work: "  DONE of ALL UNIT".
std::function<void(size_t, size_t)> progressLines(const char* unit) {
    return [unit, last = size_t(0)](size_t done, size_t all) mutable {
        if (done != all && done - last < std::max<size_t>(1, all / 20)) return;
        last = done;
        std::fprintf(stderr, "  %zu of %zu %s\n", done, all, unit);
    };
}

}  // namespace

int main(int argc, char** argv) {
    using namespace surfcast;
    std::string set, format, output;
    PointFilter filter;
    HttpOptions http;
    bool quiet = false;
    Tiles3dOptions tiles;
    bool asGiven = false, compressionGiven = false, tilingGiven = false, shapeGiven = false, cutGiven = false, viewGiven = false,
         levelGiven = false;  // options only some formats take
    SplatCut cut;
    using cli::UsageError;
    CLI::App app{kDescription, "surfcast-export"};
    cli::configure(app)->usage(&app, kUsage);
    app.footer(kFormats);
    app.add_option("SET", set, "the set's folder, or its http(s) or s3:// URL");
    auto option = [&](const std::string& spec, const std::string& type, const std::string& help, std::function<void(const std::string&)> f) {
        cli::option(app, spec, type, help, std::move(f));
    };
    // A number in (0, most], whole text, else `message`.
    auto positive = [](const std::string& v, double most, const std::string& message) {
        char* end = nullptr;
        const double d = std::strtod(v.c_str(), &end);
        if (!(*end == '\0' && !v.empty() && d > 0 && d <= most)) throw UsageError(message);
        return d;
    };
    option("--format", "FORMAT", "laz, copc, 3dtiles, ply or spz (below)", [&](const std::string& v) { format = v; });
    option("-o,--output", "FILE", "the file (or 3dtiles' folder) to write, replaced atomically; or s3://BUCKET/KEY (a 3dtiles prefix must hold no objects yet)",
           [&](const std::string& v) { output = v; });
    option("--bbox", "X0,Y0,Z0,X1,Y1,Z1", "laz, copc: only the points inside this box (world coordinates, bounds included)",
           [&](const std::string& v) {
               auto box = parseBox(v);
               if (!box) throw UsageError("--bbox: " + box.status().message());
               filter.box = *box;
           });
    option("--classes", "LIST", "laz, copc: only these ASPRS classes, e.g. 2,6 (the set must store classification)", [&](const std::string& v) {
        auto classes = parseClasses(v);
        if (!classes) throw UsageError("--classes: " + classes.status().message());
        filter.classes = *classes;
    });
    option("--as", "splats|points",
           "3dtiles: each surfel a flat Gaussian (default; KHR_gaussian_splatting in SPZ, as CesiumJS reads splats in 3D Tiles), or a "
           "glTF point with its LiDAR attributes, which every 3D Tiles engine draws",
           [&](const std::string& v) {
               if (v != "points" && v != "splats") throw UsageError("--as wants points or splats");
               tiles.as = v == "splats" ? Tiles3dOptions::As::Splats : Tiles3dOptions::As::Points;
               asGiven = true;
           });
    option("--compression", "meshopt|none",
           "3dtiles --as points: the vertex data compressed by meshoptimizer (default; EXT_meshopt_compression, which CesiumJS, "
           "three.js and Babylon.js read) or stored as it is, for glTF readers without the extension",
           [&](const std::string& v) {
               if (v != "meshopt" && v != "none") throw UsageError("--compression wants meshopt or none");
               tiles.compression = v == "meshopt" ? Tiles3dOptions::Compression::Meshopt : Tiles3dOptions::Compression::None;
               compressionGiven = true;
           });
    option("--tiling", "auto|explicit|implicit",
           "3dtiles: every tile in tileset.json (explicit), or the tree in subtree files an engine reads as it descends (3D Tiles 1.1 "
           "implicit tiling, each tile's own box and error as tile metadata: engines draw sooner); auto (default): implicit above "
           "10,000 nodes",
           [&](const std::string& v) {
               if (v != "auto" && v != "explicit" && v != "implicit") throw UsageError("--tiling wants auto, explicit or implicit");
               tiles.tiling = v == "auto" ? Tiles3dOptions::Tiling::Auto
                              : v == "explicit" ? Tiles3dOptions::Tiling::Explicit
                                                : Tiles3dOptions::Tiling::Implicit;
               tilingGiven = true;
           });
    option("--level", "N|leaves", "ply, spz: the nodes of level N and the leaves above it, as surfcast-view --level draws (default: the leaves)",
           [&](const std::string& v) {
               char* end = nullptr;
               const long l = v != "leaves" ? std::strtol(v.c_str(), &end, 10) : -1;
               if (v != "leaves" && !(*end == '\0' && !v.empty() && l >= 0 && l <= 64))
                   throw UsageError("--level wants a level (0, 1, ...) or leaves");
               cut.level = int(l);
               cutGiven = levelGiven = true;
           });
    option("--splat-budget", "N",
           "ply, spz: the deepest level whose cut holds at most N surfels (the leaves where they fit); with --camera, at most N "
           "surfels of that view, as surfcast-view's budget",
           [&](const std::string& v) {
               char* end = nullptr;
               const double d = std::strtod(v.c_str(), &end);
               if (!(*end == '\0' && d >= 1 && d <= 1e12)) throw UsageError("--splat-budget wants a count of surfels (1 or more)");
               cut.budget = uint64_t(d);
               cutGiven = true;
           });
    option("--camera", "EX,EY,EZ,TX,TY,TZ,UX,UY,UZ,FOV",
           "ply, spz: the nodes surfcast-view --lod draws for this camera (as surfcast-view takes it): what it sees, finer where it "
           "is nearer",
           [&](const std::string& v) {
               auto camera = parseCamera(v);
               if (!camera) throw UsageError("--camera: " + camera.status().message());
               cut.camera = *camera;
               cutGiven = true;
           });
    option("--size", "WxH", "with --camera: the view's pixels (default 1280x720)", [&](const std::string& v) {
        auto size = parseImageSize(v);
        if (!size) throw UsageError("--size wants WxH, 1 to 16384 pixels each");
        cut.width = size->first, cut.height = size->second;
        viewGiven = true;
    });
    option("--lod", "PX", "with --camera: refine while a node's samples lie more than PX pixels apart on screen (default 1)",
           [&](const std::string& v) {
               cut.lodPixels = positive(v, 1000, "--lod wants pixels in (0, 1000]");
               viewGiven = true;
           });
    option("--splat-scale", "S",
           "splats: standard deviation S times the set's kernel scale times the surfel's radius (default 0.75, closest to "
           "surfcast-view in CesiumJS and Spark; 1 is Surfcast's own reconstruction kernel)",
           [&](const std::string& v) {
               tiles.gaussians.sigmaScale = positive(v, 100, "--splat-scale wants a number in (0, 100]");
               shapeGiven = true;
           });
    option("--splat-opacity", "A", "splats: opacity A times the surfel's own (default 1)", [&](const std::string& v) {
        tiles.gaussians.opacity = positive(v, 1, "--splat-opacity wants a number in (0, 1]");
        shapeGiven = true;
    });
    cli::addHttpOptions(app, http, "Reaching a set at a URL (as surfcast-view does)");
    cli::flag(app, "-q,--quiet", "no progress output", [&] { quiet = true; });
    if (int status = cli::parse(app, std::vector<std::string>(argv + 1, argv + argc), nullptr,
                                [&set](const CLI::App&, const std::string& arg) {
                                    return !arg.empty() && arg[0] == '-' ? "unknown option " + arg
                                                                         : "one set at a time ('" + set + "' and '" + arg + "' given)";
                                });
        status >= 0)
        return status;
    if (set.empty()) return usageError("no set given");
    if (format.empty()) return usageError("--format is required (laz, copc, 3dtiles, ply or spz)");
    const bool splatFile = format == "ply" || format == "spz";
    if (format != "laz" && format != "copc" && format != "3dtiles" && !splatFile)
        return usageError("--format " + format + ": the formats are laz, copc, 3dtiles, ply and spz");
    if (format != "laz" && format != "copc" && (filter.box || !filter.classes.empty()))
        return usageError("--format " + format + " exports the whole set (--bbox and --classes are for laz and copc)");
    if ((asGiven || tilingGiven) && format != "3dtiles") return usageError(std::string(asGiven ? "--as" : "--tiling") + " is for --format 3dtiles");
    if (compressionGiven && (format != "3dtiles" || tiles.as != Tiles3dOptions::As::Points))
        return usageError("--compression is for --format 3dtiles --as points (splats are always SPZ)");
    if (shapeGiven && ((format == "3dtiles" && tiles.as == Tiles3dOptions::As::Points) || (format != "3dtiles" && !splatFile)))
        return usageError("--splat-scale and --splat-opacity are for splats (3dtiles --as splats, ply, spz)");
    if ((cutGiven || viewGiven) && !splatFile) return usageError("--level, --splat-budget and --camera are for --format ply and spz");
    if (levelGiven && (cut.budget > 0 || cut.camera)) return usageError(cut.camera ? "--level or --camera, not both" : "--level or --splat-budget, not both");
    if (viewGiven && !cut.camera) return usageError("--size and --lod are for --camera");
    if (output.empty()) return usageError("-o FILE is required");
    // An export to an object store is written in a local folder, then
    // uploaded: a file as one object (a PUT replaces an object whole, as the
    // rename replaces a file), a 3D Tiles folder by publishFolder.
    const std::string publishTo = isS3Url(output) ? output : "";
    std::unique_ptr<PublishStaging> staging;
    if (!publishTo.empty()) {
        auto url = parseS3Url(publishTo);
        if (!url) return usageError(url.status().message());
        if (url->key.empty() || url->key.back() == '/') return usageError(publishTo + ": name the object (or 3D Tiles prefix) to write");
        auto created = PublishStaging::create();
        if (!created) {
            std::fprintf(stderr, "surfcast-export: %s\n", created.status().message().c_str());
            return 1;
        }
        staging = std::move(*created);
        output = staging->dir() + "/" + std::filesystem::path(url->key).filename().string();
    }
    // Uploads the finished output where -o named an object store.
    auto publish = [&]() -> int {
        if (publishTo.empty()) return 0;
        Status st;
        if (format == "3dtiles") {
            auto report = publishFolder(output, publishTo);
            if (!report) st = report.status();
            else if (!quiet) std::fprintf(stderr, "uploaded %s: %llu objects\n", publishTo.c_str(), (unsigned long long)report->objects);
        } else {
            auto store = ObjectStore::shared();
            auto put = store ? (*store)->putFile(*parseS3Url(publishTo), output) : Result<std::optional<ObjectInfo>>(store.status());
            if (!put) st = put.status();
            else if (!quiet) std::fprintf(stderr, "uploaded %s\n", publishTo.c_str());
        }
        if (st.ok()) return 0;
        std::fprintf(stderr, "surfcast-export: %s\n", st.message().c_str());
        return 1;
    };

    auto reader = openTileset(set, http);
    if (!reader) {
        std::fprintf(stderr, "surfcast-export: %s\n", reader.status().message().c_str());
        return 1;
    }
    if (format == "3dtiles") {
        if (!quiet) tiles.progress = progressLines("tiles");
        auto report = writeTiles3d(*reader, tiles, output);
        if (!report) {
            std::fprintf(stderr, "surfcast-export: %s\n", report.status().message().c_str());
            return 1;
        }
        if (!quiet)
            std::fprintf(stderr, "wrote %s: %zu tiles (%s tiling), %llu points, %llu bytes (%.2f per point)\n", output.c_str(),
                         report->tiles, report->implicit ? "implicit" : "explicit", (unsigned long long)report->points,
                         (unsigned long long)report->bytes, report->points ? double(report->bytes) / double(report->points) : 0.0);
        return publish();
    }
    Result<LazExportPlan> plan = LazExportPlan{};
    if (format == "laz") {
        plan = planLazExport(*reader, filter);
        if (!plan) {
            std::fprintf(stderr, "surfcast-export: %s\n", plan.status().message().c_str());
            return 1;
        }
        if (!quiet)
            std::fprintf(stderr, "%llu points from %zu leaves; LAS point format %d, scale %g %g %g\n%s", (unsigned long long)plan->points,
                         plan->nodes.size(), plan->pointFormat, plan->scale.x, plan->scale.y, plan->scale.z,
                         dimensionSummary(plan->dimensions, plan->leftOut).c_str());
    }

    // Written beside the output, then renamed over it: a reader finds the old file or the whole new one.
    const std::string partial = output + ".partial-" + std::to_string(::getpid());
    std::FILE* f = std::fopen(partial.c_str(), "wb");
    if (!f) {
        std::fprintf(stderr, "surfcast-export: %s: %s\n", partial.c_str(), std::strerror(errno));
        return 1;
    }
    uint64_t bytes = 0, reported = 0;
    Status status;
    if (splatFile) {
        auto report = writeSplatFile(*reader, format == "ply" ? SplatFormat::Ply : SplatFormat::Spz, cut, tiles.gaussians, f,
                                     quiet ? std::function<void(size_t, size_t)>() : progressLines("nodes"));
        if (!report) status = Status::error(partial + ": " + report.status().message());
        else plan->points = report->splats;
        if (report && !quiet) std::fprintf(stderr, "%llu splats from %zu nodes (%s)\n", (unsigned long long)report->splats, report->nodes, report->cut.c_str());
        if (report && std::fseek(f, 0, SEEK_END) == 0) bytes = uint64_t(std::ftell(f));
    } else if (format == "copc") {
        auto copc = writeCopcExport(*reader, filter, f);
        if (!copc) status = Status::error(partial + ": " + copc.status().message());
        else plan->points = copc->points;
        if (copc && !quiet)
            std::fprintf(stderr, "%llu points in %zu octree nodes; LAS point format %d\n%s", (unsigned long long)copc->points, copc->nodes,
                         copc->pointFormat, dimensionSummary(copc->dimensions, copc->leftOut).c_str());
        if (copc && std::fseek(f, 0, SEEK_END) == 0) bytes = uint64_t(std::ftell(f));
    } else {
        status = writeLazExport(*reader, filter, *plan, [&](const uint8_t* data, size_t n) -> Status {
            if (std::fwrite(data, 1, n, f) != n) return Status::error(partial + ": " + std::strerror(errno));
            bytes += n;
            if (!quiet && bytes - reported >= (64u << 20)) {
                std::fprintf(stderr, "  %llu MiB written\n", (unsigned long long)(bytes >> 20));
                reported = bytes;
            }
            return {};
        });
    }
    if (status.ok() && (std::fflush(f) != 0 || ::fsync(::fileno(f)) != 0)) status = Status::error(partial + ": " + std::strerror(errno));
    if (std::fclose(f) != 0 && status.ok()) status = Status::error(partial + ": " + std::strerror(errno));
    std::error_code ec;
    if (status.ok()) {
        std::filesystem::rename(partial, output, ec);
        if (ec) status = Status::error(output + ": " + ec.message());
    }
    if (!status.ok()) {
        std::filesystem::remove(partial, ec);
        std::fprintf(stderr, "surfcast-export: %s\n", status.message().c_str());
        return 1;
    }
    if (!quiet)
        std::fprintf(stderr, "wrote %s: %llu points, %llu bytes (%.2f per point)\n", output.c_str(), (unsigned long long)plan->points,
                     (unsigned long long)bytes, plan->points ? double(bytes) / double(plan->points) : 0.0);
    return publish();
}
