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
#include "http_tile_source.h"
#include "laz_export.h"
#include "object_store.h"
#include "set_publisher.h"
#include "splat_export.h"
#include "tiles3d_export.h"

namespace {

const char* kUsage = R"(usage: surfcast-export SET --format laz|copc [--bbox X0,Y0,Z0,X1,Y1,Z1] [--classes LIST] -o FILE
       surfcast-export SET --format 3dtiles [--as splats|points] [--compression meshopt|none]
                       [--tiling auto|explicit|implicit] -o FOLDER
       surfcast-export SET --format ply|spz [--level N|leaves | --splat-budget N | --camera C [--size WxH] [--lod PX]
                       [--splat-budget N]] -o FILE

Writes a tile set's points as another format. SET is a set's folder or its
http(s) URL.

  --format laz          LAS 1.4 compressed with LASzip (the laz crate): the input
                        points the set's leaves hold (exact duplicates merged at
                        build), point format 6, or 7 with colour; intensity,
                        classification, returns, and GPS time, scan angle, user
                        data and point source id where the set stores them
  --format copc         the same points as a COPC 1.0 file (cloud-optimized point
                        cloud: LAZ chunks in an octree on the set's root cube, each
                        node above the leaves an even sample of what lies under
                        it, the hierarchy in an EVLR), which COPC readers query
                        by box and level
  --format 3dtiles      a 3D Tiles 1.1 tileset for CesiumJS and other 3D Tiles
                        engines: tileset.json and one glb per node (REPLACE
                        refinement, the node's spacing as its geometric error);
                        the whole set, into a folder (docs/EXPORT.md)
  --as splats|points    3dtiles: each surfel a flat Gaussian (default;
                        KHR_gaussian_splatting in SPZ, as CesiumJS reads
                        splats in 3D Tiles), or a glTF point with its LiDAR
                        attributes, which every 3D Tiles engine draws
  --compression meshopt|none
                        3dtiles --as points: the vertex data compressed by
                        meshoptimizer (default; EXT_meshopt_compression, which
                        CesiumJS, three.js and Babylon.js read) or stored as it
                        is, for glTF readers without the extension
  --tiling auto|explicit|implicit
                        3dtiles: every tile in tileset.json (explicit), or the
                        tree in subtree files an engine reads as it descends
                        (3D Tiles 1.1 implicit tiling, each tile's own box and
                        error as tile metadata: engines draw sooner); auto
                        (default): implicit above 10,000 nodes
  --format ply          the 3D Gaussian splatting PLY that splat viewers read:
                        one cut through the tree, each surfel a flat Gaussian,
                        about the centre of the set's bounds (a comment keeps
                        it), in the PLY's y-down axes
  --format spz          the same Gaussians as SPZ 2 (Niantic's compressed
                        splats, y up; at most 10 million)
  --level N|leaves      ply, spz: the nodes of level N and the leaves above it,
                        as surfcast-view --level draws (default: the leaves)
  --splat-budget N      ply, spz: the deepest level whose cut holds at most N
                        surfels (the leaves where they fit); with --camera, at
                        most N surfels of that view, as surfcast-view's budget
  --camera EX,EY,EZ,TX,TY,TZ,UX,UY,UZ,FOV
                        ply, spz: the nodes surfcast-view --lod draws for this
                        camera (as surfcast-view takes it): what it sees, finer
                        where it is nearer
  --size WxH            with --camera: the view's pixels (default 1280x720)
  --lod PX              with --camera: refine while a node's samples lie more
                        than PX pixels apart on screen (default 1)
  --splat-scale S       splats: standard deviation S times the set's kernel
                        scale times the surfel's radius (default 0.75, closest
                        to surfcast-view in CesiumJS and Spark; 1 is Surfcast's
                        own reconstruction kernel)
  --splat-opacity A     splats: opacity A times the surfel's own (default 1)
  --bbox X0,Y0,Z0,X1,Y1,Z1
                        only the points inside this box (world coordinates,
                        bounds included)
  --classes LIST        only these ASPRS classes, e.g. 2,6 (the set must store
                        classification)
  -o, --output FILE     the file (or 3dtiles' folder) to write, replaced atomically;
                        or s3://BUCKET/KEY (a 3dtiles prefix must hold no objects yet)
  --header 'NAME: VALUE', --token-file F, --ca-file F, --insecure,
  --redirect-credentials
                        how to reach a set at a URL, as in surfcast-view
  -q, --quiet           no progress output
  -h, --help            this text
)";

int usageError(const std::string& message) {
    std::fprintf(stderr, "surfcast-export: %s\n(surfcast-export --help for usage)\n", message.c_str());
    return 2;
}

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
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&](std::string* out) {
            if (i + 1 >= argc) return false;
            *out = argv[++i];
            return true;
        };
        std::string v;
        if (a == "-h" || a == "--help") {
            std::fputs(kUsage, stdout);
            return 0;
        } else if (a == "--format") {
            if (!value(&format)) return usageError("--format wants laz, copc, 3dtiles, ply or spz");
        } else if (a == "--as") {
            if (!value(&v) || (v != "points" && v != "splats")) return usageError("--as wants points or splats");
            tiles.as = v == "splats" ? Tiles3dOptions::As::Splats : Tiles3dOptions::As::Points;
            asGiven = true;
        } else if (a == "--compression") {
            if (!value(&v) || (v != "meshopt" && v != "none")) return usageError("--compression wants meshopt or none");
            tiles.compression = v == "meshopt" ? Tiles3dOptions::Compression::Meshopt : Tiles3dOptions::Compression::None;
            compressionGiven = true;
        } else if (a == "--tiling") {
            if (!value(&v) || (v != "auto" && v != "explicit" && v != "implicit")) return usageError("--tiling wants auto, explicit or implicit");
            tiles.tiling = v == "auto"       ? Tiles3dOptions::Tiling::Auto
                           : v == "explicit" ? Tiles3dOptions::Tiling::Explicit
                                             : Tiles3dOptions::Tiling::Implicit;
            tilingGiven = true;
        } else if (a == "--splat-scale" || a == "--splat-opacity") {
            char* end = nullptr;
            const double d = value(&v) ? std::strtod(v.c_str(), &end) : NAN;
            const bool scale = a == "--splat-scale";
            if (!(end && *end == '\0' && d > 0 && d <= (scale ? 100.0 : 1.0)))
                return usageError(a + (scale ? " wants a number in (0, 100]" : " wants a number in (0, 1]"));
            (scale ? tiles.gaussians.sigmaScale : tiles.gaussians.opacity) = d;
            shapeGiven = true;
        } else if (a == "--level") {
            char* end = nullptr;
            const long l = value(&v) && v != "leaves" ? std::strtol(v.c_str(), &end, 10) : -1;
            if (v != "leaves" && !(end && *end == '\0' && !v.empty() && l >= 0 && l <= 64)) return usageError("--level wants a level (0, 1, ...) or leaves");
            cut.level = int(l);
            cutGiven = levelGiven = true;
        } else if (a == "--splat-budget") {
            char* end = nullptr;
            const double d = value(&v) ? std::strtod(v.c_str(), &end) : NAN;
            if (!(end && *end == '\0' && d >= 1 && d <= 1e12)) return usageError("--splat-budget wants a count of surfels (1 or more)");
            cut.budget = uint64_t(d);
            cutGiven = true;
        } else if (a == "--camera") {
            if (!value(&v)) return usageError("--camera wants EX,EY,EZ,TX,TY,TZ,UX,UY,UZ,FOV");
            auto camera = parseCamera(v);
            if (!camera) return usageError("--camera: " + camera.status().message());
            cut.camera = *camera;
            cutGiven = true;
        } else if (a == "--size") {
            auto size = value(&v) ? parseImageSize(v) : Result<std::pair<int, int>>(Status::error("--size wants WxH"));
            if (!size) return usageError("--size wants WxH, 1 to 16384 pixels each");
            cut.width = size->first, cut.height = size->second;
            viewGiven = true;
        } else if (a == "--lod") {
            char* end = nullptr;
            const double d = value(&v) ? std::strtod(v.c_str(), &end) : NAN;
            if (!(end && *end == '\0' && d > 0 && d <= 1000)) return usageError("--lod wants pixels in (0, 1000]");
            cut.lodPixels = d;
            viewGiven = true;
        } else if (a == "-o" || a == "--output") {
            if (!value(&output)) return usageError("-o wants a file");
        } else if (a == "--bbox") {
            if (!value(&v)) return usageError("--bbox wants X0,Y0,Z0,X1,Y1,Z1");
            auto box = parseBox(v);
            if (!box) return usageError("--bbox: " + box.status().message());
            filter.box = *box;
        } else if (a == "--classes") {
            if (!value(&v)) return usageError("--classes wants a list such as 2,6");
            auto classes = parseClasses(v);
            if (!classes) return usageError("--classes: " + classes.status().message());
            filter.classes = *classes;
        } else if (std::string error; parseHttpOption(a, value, http, &error)) {
            if (!error.empty()) return usageError(error);
        } else if (a == "-q" || a == "--quiet") {
            quiet = true;
        } else if (!a.empty() && a[0] == '-') {
            return usageError("unknown option " + a);
        } else if (set.empty()) {
            set = a;
        } else {
            return usageError("one set at a time ('" + set + "' and '" + a + "' given)");
        }
    }
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
