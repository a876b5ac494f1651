#include "build_cli.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <set>
#include <sstream>

#include "command_line.h"
#include "input_point.h"
#include "octree_key.h"

namespace surfcast {

namespace {

using cli::UsageError;

constexpr const char* kProgram = "surfcast-build";

constexpr const char* kUsage = R"(surfcast-build [options] INPUT... -o OUT      (INPUT: a file, a folder, or @LIST)
       surfcast-build --default-scene -o OUT
       surfcast-build --add INPUT... | --remove NAME... | --replace OLD NEW  --to SET
       surfcast-build --compact SET
       surfcast-build --merge SET1 SET2... [options] -o OUT
       surfcast-build --info SET            (SET: a folder, an http(s) or s3:// URL)
       surfcast-build scan|count --work W --part P/N [options] INPUT... -o OUT
       surfcast-build plan --work W [--parts N] [options] INPUT... -o OUT
       surfcast-build distribute --work W [--part P] [--header ...]
       surfcast-build chunk --work W I...
       surfcast-build merge --work W        (a build in stages: see below)
       surfcast-build update-plan --work W --add INPUT... | --remove NAME... | --replace OLD NEW  --to SET
       surfcast-build update-merge --work W (an update in stages: chunk between them))";

constexpr const char* kDescription = R"(Builds a level-of-detail tile set (tileset.json, hierarchy.bin, blocks.bin)
from point clouds and meshes. Inputs: PLY (points, or meshes with faces or
triangle strips), LAS 1.0-1.4 and LAZ (COPC too), E57 (every scan, posed; its
normals face each scan's scanner), PCD, text columns (.xyz .txt .pts .csv),
meshes in OBJ/OFF/STL through OpenMesh, and glTF. Several inputs merge into one
tile set. A folder stands for every readable file under it; @LIST for the paths
listed in the text file LIST, one per line. A point file may be an http(s) URL,
read by ranges from any host that honours Range (a presigned URL's query string
is never shown or stored), or an s3:// object; s3://BUCKET/PREFIX/ stands for
every readable object under the prefix. Meshes are read from local files.
S3 credentials, region and endpoint come from the standard AWS variables and
files (docs/STORAGE.md).)";

constexpr const char* kFooter = R"(A build in stages runs as separate commands, each its own process, on any
machines that see the inputs and the work folder W; the set is the same bytes
as one surfcast-build. plan takes the inputs and options and writes W/plan.bin
and W/plan.json (the chunk count and each chunk's points); distribute, chunk
and merge read them, and take only --work, --threads and -q (distribute also
--part). chunk builds the chunks named (0 to the count less one), in any order
and any grouping; merge writes the set at plan's -o, then removes the parts'
and chunks' files from W. plan scans and counts the inputs itself, or, with
--parts N, reduces what scan and count wrote for parts 0/N to N-1/N (runs of
consecutive inputs of about equal bytes; count runs once every scan is done);
distribute --part P then reads part P alone. How to reach URL inputs
(--header, --token-file, --ca-file, --insecure) is never stored in the plan:
give it to each stage that reads inputs (scan, count, plan, distribute).

An update in stages: update-plan does all that precedes the chunks' builds
(the scan and count of the added inputs, the removed points found, the set's
points near the change and the added ones distributed) and writes W/plan.json
with "build", the chunks to build; chunk builds them; update-merge builds the
levels above and switches the set, as --add, --remove and --replace do in one
process, with the same bytes. It fails, leaving the set as it is, where the
set changed after update-plan.)";

bool parseSize(const std::string& s, uint64_t* out) {
    char* end = nullptr;
    double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || !(v > 0)) return false;
    std::string unit(end);
    double mult = unit.empty() || unit == "B" ? 1
                  : unit == "K" || unit == "KiB" ? 1024.0
                  : unit == "M" || unit == "MiB" ? 1024.0 * 1024
                  : unit == "G" || unit == "GiB" ? 1024.0 * 1024 * 1024
                                                 : 0;
    if (mult == 0) return false;
    *out = uint64_t(v * mult);
    return true;
}

// What the kept arguments are made of: each option name, whether it takes a
// value, and whether the stored command line keeps it.
struct OptionNames {
    std::map<std::string, bool> takesValue;
    std::set<std::string> kept;
};

// Declares options on one app or subcommand, in a help group, each read by
// its callback as the parser meets it (so that a later one wins, as given).
class Declare {
public:
    Declare(CLI::App& app, OptionNames& names) : app_(app), names_(names) {}
    void group(std::string g) { group_ = std::move(g); }

    void flag(const std::string& spec, const std::string& help, std::function<void()> set, bool keep = true) {
        note(spec, false, keep);
        cli::flag(app_, spec, help, std::move(set))->group(group_);
    }
    void value(const std::string& spec, const std::string& type, const std::string& help, std::function<void(const std::string&)> set,
               bool keep = true) {
        note(spec, true, keep);
        cli::option(app_, spec, type, help, std::move(set))->group(group_);
    }
    // A number in [lo, hi] (a whole one where `whole`), else a usage error saying `message`.
    void number(const std::string& spec, const std::string& type, const std::string& help, double lo, double hi, bool whole,
                const std::string& message, std::function<void(double)> set, bool keep = true) {
        value(spec, type, help, [=](const std::string& v) {
            double d = 0;
            if (!cli::parseNumber(v, &d) || !(d >= lo && d <= hi) || (whole && d != std::floor(d))) throw UsageError(message);
            set(d);
        }, keep);
    }

private:
    void note(const std::string& spec, bool takesValue, bool keep) {
        std::stringstream names(spec);
        for (std::string name; std::getline(names, name, ',');) {
            names_.takesValue[name] = takesValue;
            if (keep) names_.kept.insert(name);
        }
    }
    CLI::App& app_;
    OptionNames& names_;
    std::string group_ = "Options";
};

// -o; the inputs are the positional arguments (parseAs).
void addOutput(Declare& d, BuildArgs& a) {
    d.group("Inputs and output");
    d.value("-o,--output", "DIR",
            "tile set folder to write (replaced atomically), or s3://BUCKET/PREFIX: a new prefix of an S3 bucket (built in $TMPDIR, "
            "then uploaded; docs/STORAGE.md)",
            [&a](const std::string& v) { a.opt.output = v; }, false);
}

// How to reach inputs and sets at URLs: never stored (it may hold a token).
void addReach(CLI::App& app, OptionNames& names, BuildArgs& a) {
    cli::addHttpOptions(app, a.opt.inputs.http, "Reaching URLs (as surfcast-view does; never stored in a plan or a record)");
    for (const char* name : {"--header", "--token-file", "--ca-file"}) names.takesValue[name] = true;
    for (const char* name : {"--insecure", "--redirect-credentials"}) names.takesValue[name] = false;
}

void addThreadsAndQuiet(Declare& d, BuildArgs& a) {
    d.number("--threads", "N", "worker threads (default: all cores)", 1, 1024, false, "--threads needs a value in [1, 1024]",
             [&a](double v) { a.opt.threads = int(v); });
    d.flag("-q,--quiet", "no progress output", [&a] { a.opt.progress = false; });
}

// The options a plan and a build record keep.
void addBuildOptions(Declare& d, BuildArgs& a) {
    BuildOptions& o = a.opt;
    d.group("Inputs and output");
    d.flag("--default-scene", "add the built-in scanned scene (about 1.5 M points)", [&o] { o.inputs.defaultScene = true; });
    d.number("--scene-points", "N", "points of the built-in scene (default 1500000)", 1, 1e10, false,
             "--scene-points needs a positive count", [&o](double v) { o.inputs.scene.targetPoints = uint64_t(v); });
    d.number("--seed", "N", "seed of the built-in scene and mesh sampling (default 1)", 0, 1e18, false,
             "--seed needs a non-negative integer", [&o](double v) { o.inputs.scene.seed = o.inputs.mesh.seed = uint64_t(v); });

    d.group("Octree and sampling");
    d.number("--grid", "G", "cells per axis of a node's finest sampling grid (default 128)", 4, 1024, false,
             "--grid needs a value in [4, 1024]", [&o](double v) { o.grid = int(v); });
    d.number("--page-depth", "D", "levels per hierarchy page, which a viewer fetches as it reaches them (default 5)", 2, kMaxLevel + 1,
             false, "--page-depth needs a value in [2, 21]", [&o](double v) { o.pageDepth = uint32_t(v); });
    const std::string capacity = "[16, " + std::to_string(kMaxBlockPoints) + "]";
    d.number("--capacity", "N", "surfels above which a node splits (default 20000, at most " + std::to_string(kMaxBlockPoints) + ")", 16,
             kMaxBlockPoints, false, "--capacity needs a value in " + capacity, [&o](double v) { o.capacity = uint32_t(v); });
    d.value("--memory", "SIZE", "peak memory budget, e.g. 512M, 2G (default 2G)", [&o](const std::string& v) {
        if (!parseSize(v, &o.memoryBytes)) throw UsageError("--memory needs a size such as 512M or 2G");
    });
    d.number("--position-fraction", "F", "resampled levels: quantization step = cell / F (default 8)", 1, 1 << 16, false,
             "--position-fraction needs a value in [1, 65536]", [&o](double v) { o.positionFraction = v; });

    d.group("Normals, spacing and weights");
    d.number("--normal-k", "K", "neighbours for normal estimation (default 16)", 3, 256, false, "--normal-k needs a value in [3, 256]",
             [&o](double v) { o.normalK = int(v); });
    d.number("--spacing-k", "K", "k of the k-th-neighbour spacing h (default 8)", 1, 64, false, "--spacing-k needs a value in [1, 64]",
             [&o](double v) { o.spacingK = int(v); });
    d.number("--normal-bits", "N",
             "Draco's quantization of normals: bits of each of their two octahedral coordinates (default 8, chosen by "
             "measurement: bench/BENCHMARKS.md; with --codec draco, of each of their three components)", 4, 16, false,
             "--normal-bits needs a value in [4, 16]", [&o](double v) { o.normalBits = int(v); });
    d.value("--codec", "C",
            "how blocks are coded: draco-columns (default: the positions in a kd-tree, the other attributes column by column) "
            "or draco (one kd-tree of every attribute, as sets were coded before draco-columns; larger, and read by older viewers)",
            [&o](const std::string& c) {
                auto codec = parseBlockCodec(c);
                if (!codec) throw UsageError("--codec needs draco-columns or draco");
                o.blockCodec = *codec;
            });
    d.flag("--no-radius", "no per-surfel radius, even where a node's sampling is irregular", [&o] { o.radii = false; });
    d.value("--isolation", "T",
            "isolated surfels (a stray return, a leaf hit by a few points) are drawn at their level's spacing rho (2 sampling "
            "cells), not as discs reaching their far neighbours: those whose k-th neighbour (--spacing-k) lies beyond T rho, or "
            "beyond rho among neighbours scattered off a plane (default 6, measured: see bench/BENCHMARKS.md; 0: off, as "
            "--no-radius makes it)",
            [&o](const std::string& v) {
                double d = 0;
                if (!cli::parseNumber(v, &d) || !(d >= 0 && d <= 1000) || (d > 0 && d < 1))
                    throw UsageError("--isolation needs 0 or a value in [1, 1000]");
                o.isolation = d;
            });
    d.number("--remove-outliers", "M",
             "removes stray input points: those whose k-th neighbour (--spacing-k) lies farther than the mean over their "
             "chunk's points by M standard deviations, and than twice the mean (statistical outlier removal, like PCL's and "
             "PDAL's filters, which take the mean distance to the k nearest; 2 is usual; a surface sampled far more sparsely "
             "than the chunk's average goes too). 0 (the default): off, a set keeps every point it reads",
             0, 100, false, "--remove-outliers needs a value in [0, 100]", [&o](double v) { o.removeOutliers = v; });
    d.number("--kernel-scale", "K", "reconstruction kernel V^r = (K h)^2 I the weights assume (default 0.5, measured: see bench/BENCHMARKS.md)",
             0.05, 10, false, "--kernel-scale needs a value in [0.05, 10]", [&o](double v) { o.kernelScale = v; });
    d.value("--weights", "MODE",
            "none (default: ewa-pixel, the default renderer mode, reads no weights), analytic (for ewa-surfel), or capture (rendered "
            "on Vulkan, Ren 2002 §7.2; see surfcast-weights)",
            [&a](const std::string& v) {
                if (v != "analytic" && v != "none" && v != "capture") throw UsageError("--weights is capture, analytic or none");
                // Capture starts from analytic weights: they stay for surfels no view sees.
                a.opt.weights = v != "none";
                a.captureWeights = v == "capture";
            });

    d.group("Attributes");
    d.value("--attributes", "LIST",
            "attributes to store: a comma-separated list of names; all; or none. Default: intensity, classification, return_number "
            "and number_of_returns, each where some input carries it and it varies across the set (LAS/LAZ: all four; PLY/PCD/text: "
            "intensity, classification where a field holds them). On request: LAS/LAZ scan_angle, user_data, point_source_id, "
            "gps_time, nir and Extra Bytes dimensions by name; PLY and PCD properties by name; E57 row and column",
            [&o](const std::string& v) {
                std::vector<std::string> names;
                if (v == "all") {
                    names.assign(std::begin(kLidarAttributes), std::end(kLidarAttributes));
                    o.inputs.scalars.all = true;
                } else if (v != "none") {
                    std::stringstream list(v);
                    for (std::string name; std::getline(list, name, ',');) {
                        if (name.empty()) throw UsageError("--attributes: an empty name in '" + v + "'");
                        names.push_back(name);
                    }
                }
                o.attributes = names;
            });
    d.number("--opacity", "A",
             "multiply every point's opacity by A in [0, 1] (all inputs); the set stores opacity only where some point is translucent "
             "(PLY alpha/opacity properties; see --read-alpha)",
             0, 1, false, "--opacity needs a value in [0, 1]", [&o](double v) { o.inputs.opacity = v; });
    d.flag("--read-alpha", "PCD: take the packed colour's top byte (rgba's alpha) as opacity; off by default, as many PCD files leave junk there",
           [&o] { o.inputs.readAlpha = true; });
    d.value("--columns", "LAYOUT", "text layout, e.g. x,y,z,r,g,b or x,y,z,_,nx,ny,nz", [&o](const std::string& v) { o.inputs.columns = v; });

    d.group("Meshes");
    d.number("--mesh-spacing", "S",
             "mesh sampling spacing (default: one surfel per texel on a textured mesh, else half the median edge; coarsened where "
             "that would exceed --mesh-max-surfels)",
             1e-12, 1e12, false, "--mesh-spacing needs a positive length", [&o](double v) { o.inputs.mesh.spacing = v; });
    d.number("--mesh-max-surfels", "N", "most surfels a mesh gives at its default spacing (5000000)", 1, 1e12, true,
             "--mesh-max-surfels needs a whole number >= 1", [&o](double v) { o.inputs.mesh.maxSurfels = uint64_t(v); });
    d.value("--texture-filter", "F",
            "colours of textured meshes' surfels, on every level: optimal (least-squares coefficients for the renderer's kernels; "
            "default), ewa (the texture filtered with each surfel's kernel: faster to build, blurrier) or nearest (the texture at "
            "each leaf's centre, averaged above)",
            [&o](const std::string& f) {
                if (f != "ewa" && f != "nearest" && f != "optimal") throw UsageError("--texture-filter needs ewa, optimal or nearest");
                using Filter = BuildOptions::TextureFilter;
                o.textureFilter = f == "ewa" ? Filter::Ewa : f == "optimal" ? Filter::Optimal : Filter::Nearest;
            });
    d.flag("--allow-missing-textures",
           "a diffuse texture (OBJ map_Kd) that is missing or unreadable is a warning, its faces take vertex colours (default: error)",
           [&o] { o.inputs.mesh.allowMissingTextures = true; });
    d.flag("--allow-outside-paths",
           "let a mesh's external files (glTF buffers and images, OBJ material libraries and maps, PLY TextureFile) lie outside its "
           "folder (default: an error naming the file, so that a model from elsewhere cannot read any file you can)",
           [&o] { o.inputs.mesh.allowOutsidePaths = true; });
    d.flag("--vertices-only", "read a mesh file's vertices as points, no sampling", [&o] { o.inputs.verticesOnly = true; });

    d.group("Options");
    addThreadsAndQuiet(d, a);
}

// --add, --remove, --replace and --to.
void addUpdate(Declare& d, BuildArgs& a) {
    d.group("Updating a set in place (README, \"Updating a set\")");
    auto mode = [&a](const std::string& m) {
        return [&a, m] {
            if (!a.update.empty() && a.update != m) throw UsageError(a.update + " and " + m + " are separate updates");
            a.update = m;
        };
    };
    d.flag("--add", "add the INPUTs to the set --to names: only the chunks the new points reach and the levels above them are built "
                    "again; every other node keeps its bytes and byte range, the new blocks are appended and tileset.json switched "
                    "last, so readers see the old set or the new one. The options are the set's own (its build record); only "
                    "--threads and -q may be given. SET may be s3://BUCKET/PREFIX: the new version is uploaded, then tileset.json "
                    "switched only if no other update did first (docs/STORAGE.md, \"Updates\")",
           mode("--add"), false);
    d.flag("--remove", "remove the points of the set's inputs NAME... (a path, or a file name only one input has), in place alike",
           mode("--remove"), false);
    d.flag("--replace", "remove input OLD's points and add NEW's, in one update", mode("--replace"), false);
    d.value("--to", "SET", "the set an update changes", [&a](const std::string& v) { a.to = v; }, false);
}

CLI::App* stage(CLI::App& app, const char* name, const char* help) {
    CLI::App* sub = app.add_subcommand(name, help);
    sub->group("Stages of a build in stages (see below)");
    sub->set_version_flag("--version", cli::versionText(kProgram), "the program's version and the tile-set formats it reads and writes");
    return sub;
}

void addWork(Declare& d, BuildArgs& a) {
    d.group("Options");
    d.value("--work", "W", "the work folder every stage's process sees (or s3://BUCKET/PREFIX)", [&a](const std::string& v) { a.work = v; },
            false);
}

// --part P/N (scan, count) or P (distribute).
void addStandIns(Declare& d, BuildArgs& a, const std::string& help) {
    d.number("--stand-ins", "N", help, 1, 4294967295.0, true, "--stand-ins needs a stride in [1, 2^32)",
             [&a](double v) { a.standIns = uint32_t(v); }, false);
}

void addPart(Declare& d, BuildArgs& a, bool fraction) {
    d.value("--part", fraction ? "P/N" : "P", fraction ? "part P of N parts (0 <= P < N)" : "part P of the plan's parts alone",
            [&a, fraction](const std::string& v) {
                const size_t slash = v.find('/');
                double p = -1, n = 1e6;
                bool ok = fraction ? slash != std::string::npos && cli::parseNumber(v.substr(0, slash), &p) &&
                                         cli::parseNumber(v.substr(slash + 1), &n)
                                   : slash == std::string::npos && cli::parseNumber(v, &p);
                ok = ok && p >= 0 && p == std::floor(p) && n >= 1 && n <= 1e6 && n == std::floor(n) && p < n;
                if (!ok) throw UsageError(fraction ? "--part needs P/N, part P of N parts (0 <= P < N)" : "--part needs a part number (0, 1, ...)");
                a.part = size_t(p);
                a.parts = fraction ? size_t(n) : 0;
                a.partGiven = true;
            }, false);
}

// The whole command line: the modes, and a subcommand for each stage.
struct BuildApp {
    CLI::App app{kDescription, kProgram};
    OptionNames names;

    explicit BuildApp(BuildArgs& a) {
        cli::configure(app)->usage(&app, kUsage);
        app.footer(kFooter);
        app.require_subcommand(0, 1);  // one stage at most: a second stage's name is an argument of the first
        Declare d(app, names);
        addOutput(d, a);
        addBuildOptions(d, a);
        addUpdate(d, a);
        d.group("Other modes");
        d.flag("--merge", "join tile sets built apart (the INPUTs) into one at -o OUT: a build from their points (each set's leaves: "
                          "positions, normals, colours, attributes), with SET1's build options (its build record) and then the command "
                          "line's; each set is one input of the joined set (--remove takes it out again). A tile set's folder (or s3:// "
                          "prefix) is an input anywhere",
               [&a] { a.merge = true; }, false);
        d.value("--compact", "SET",
                "write the set anew without the blocks its updates replaced (replaced atomically, as a rebuild is: byte ranges change, "
                "node ETags do not); a set in a bucket gets the compacted blocks as its next version",
                [&a](const std::string& v) { a.compact = v; }, false);
        d.value("--info", "SET", "print a tile set's summary and verify every checksum (SET: a folder, an http(s) or s3:// URL)",
                [&a](const std::string& v) { a.info = v; }, false);
        d.group("Previews");
        d.flag("--preview", "first publish a preview to OUT, unless OUT holds a set (whose viewers keep it until the build replaces "
                            "it): a set of every Nth point of each input, about 200,000 points, marked \"preview\" in its tileset.json, "
                            "for viewers to open and follow (surfcast-view --follow, ?follow=) while the build goes on; then, as "
                            "chunks are built, versions with those chunks at full detail and the others from every Nth point; "
                            "the build then replaces them. The build's own bytes are those it writes without --preview",
               [&a] { a.preview = true; }, false);
        d.number("--preview-points", "N", "--preview of about N points (default 200000)", 1000, 1e9, false,
                 "--preview-points needs a count in [1000, 10^9]", [&a](double v) {
                     a.preview = true;
                     a.previewPoints = uint64_t(v);
                 }, false);
        d.number("--preview-interval", "S",
                 "--preview with versions at least S seconds apart, and further apart where publishing one takes over a 20th of "
                 "that (default 2; 0: after every chunk)",
                 0, 3600, false, "--preview-interval needs seconds in [0, 3600]", [&a](double v) {
                     a.preview = true;
                     a.previewInterval = v;
                 }, false);
        addReach(app, names, a);

        // The stages that take the inputs and the options: preview, scan, count and plan.
        for (const char* name : {"preview", "scan", "count", "plan"}) {
            const std::string n = name;
            CLI::App* sub = stage(app, name,
                                  n == "plan"      ? "plan the build: the chunk layout, W/plan.bin and W/plan.json"
                                  : n == "scan"    ? "scan part P of the inputs"
                                  : n == "preview" ? "publish --preview's set at -o (a folder), unless it holds a set"
                                                   : "count part P's points on the counting grid");
            Declare s(*sub, names);
            addOutput(s, a);
            addBuildOptions(s, a);
            addReach(*sub, names, a);
            addWork(s, a);
            if (n == "plan")
                s.number("--parts", "N", "reduce what scan and count wrote for parts 0/N to N-1/N", 1, 1e6, true,
                         "--parts needs the count of scan and count parts", [&a](double v) { a.parts = size_t(v); }, false);
            else if (n == "preview")
                s.number("--preview-points", "N", "about N points (default 200000)", 1000, 1e9, false,
                         "--preview-points needs a count in [1000, 10^9]", [&a](double v) { a.previewPoints = uint64_t(v); }, false);
            else
                addPart(s, a, true);
        }
        CLI::App* updatePlan = stage(app, "update-plan", "an update's plan and distribution: chunk, then update-merge");
        Declare u(*updatePlan, names);
        addOutput(u, a);
        addBuildOptions(u, a);
        addUpdate(u, a);
        addReach(*updatePlan, names, a);
        addWork(u, a);

        // The later stages read the rest from the plan.
        CLI::App* distribute = stage(app, "distribute", "the points of every part, or of --part P, to their chunks' files");
        Declare ds(*distribute, names);
        addWork(ds, a);
        addThreadsAndQuiet(ds, a);
        addPart(ds, a, false);
        addStandIns(ds, a, "also every Nth point of the part to the stand-ins' files, for refine");
        addReach(*distribute, names, a);
        CLI::App* refine = stage(app, "refine",
                                 "publish a version of the build in progress at the plan's -o (a folder): the chunks built so far, "
                                 "the others' stand-ins (distribute --stand-ins N)");
        Declare r(*refine, names);
        addWork(r, a);
        addThreadsAndQuiet(r, a);
        addStandIns(r, a, "the stand-ins' stride, as distribute was given it (required)");
        CLI::App* chunk = stage(app, "chunk", "build the chunks I... (0 to the plan's count less one)");
        Declare c(*chunk, names);
        addWork(c, a);
        addThreadsAndQuiet(c, a);
        for (const char* name : {"merge", "update-merge"}) {
            CLI::App* sub = stage(app, name, std::string(name) == "merge" ? "the levels above the chunks, then the set at plan's -o"
                                                                           : "an update's levels above its chunks, then the set switched");
            Declare m(*sub, names);
            addWork(m, a);
            addThreadsAndQuiet(m, a);
        }
    }

    // The build options among `args`, in the order given (BuildArgs::kept),
    // each as "--name" and its value apart, however given ("--name=value":
    // the form the stored command lines have always had).
    std::vector<std::string> kept(const std::vector<std::string>& args) const {
        std::vector<std::string> out;
        for (size_t i = 0; i < args.size(); ++i) {
            const size_t eq = args[i].rfind("--", 0) == 0 ? args[i].find('=') : std::string::npos;
            const std::string name = args[i].substr(0, eq);
            auto it = names.takesValue.find(name);
            if (it == names.takesValue.end()) continue;
            std::string value;
            // "--name=" is no value: the parser took the next argument.
            const bool inline_ = eq != std::string::npos && eq + 1 < args[i].size();
            if (inline_) value = args[i].substr(eq + 1);
            else if (it->second && i + 1 < args.size()) value = args[++i];
            if (names.kept.count(name)) {
                out.push_back(name);
                if (it->second) out.push_back(value);
            }
        }
        return out;
    }
};

bool laterStage(const std::string& stage) {
    return stage == "distribute" || stage == "chunk" || stage == "refine" || stage == "merge" || stage == "update-merge";
}

// What a later stage says of an argument it does not take.
std::string notFromThePlan(const std::string& stage, const std::string& arg) {
    return stage + " takes --work DIR, --threads N and -q" +
           (stage == "chunk"        ? " and chunk numbers"
            : stage == "distribute" ? ", --part P, --stand-ins N and how to reach URL inputs (--header, ...)"
            : stage == "refine"     ? " and --stand-ins N"
                                    : "") +
           "; the other options come from the plan (not " + arg + ")";
}

int parseAs(const std::vector<std::string>& args, BuildArgs* out) {
    BuildArgs& a = *out;
    BuildApp build(a);
    // A stage is named first, or not at all: a later argument of that name is
    // an input (and --help lists every stage).
    const bool help = std::find(args.begin(), args.end(), "--help") != args.end() || std::find(args.begin(), args.end(), "-h") != args.end();
    const bool staged = !args.empty() && cli::subcommand(build.app, args[0]) != nullptr;
    for (CLI::App* sub : build.app.get_subcommands({}))
        if (staged ? sub->get_name() != args[0] : !help) sub->disabled();
    std::vector<std::string> positionals;
    const int status = cli::parse(build.app, args, &positionals, [](const CLI::App& where, const std::string& arg) -> std::string {
        if (laterStage(where.get_name())) return notFromThePlan(where.get_name(), arg);
        return "unknown option " + arg;
    });
    if (status >= 0) return status;
    for (const CLI::App* sub : build.app.get_subcommands()) a.stage = sub->get_name();
    if (a.stage == "chunk") {
        for (const std::string& i : positionals) {
            double d = 0;
            if (!cli::parseNumber(i, &d) || d < 0 || d > 1e9 || d != std::floor(d))
                return cli::usageError(kProgram, "chunk wants chunk numbers (0, 1, ...), not " + i);
            a.chunks.push_back(size_t(d));
        }
    } else if (laterStage(a.stage) && !positionals.empty()) {
        return cli::usageError(kProgram, notFromThePlan(a.stage, positionals[0]));
    } else {
        a.opt.inputs.paths.insert(a.opt.inputs.paths.end(), positionals.begin(), positionals.end());
    }
    // Outlier removal judges a point by its --spacing-k-th neighbour among
    // the --normal-k its normal's search finds, itself among them.
    if (a.opt.removeOutliers > 0 && a.opt.normalK <= a.opt.spacingK)
        return cli::usageError(kProgram, "--remove-outliers needs --normal-k above --spacing-k (" + std::to_string(a.opt.normalK) +
                                             " is not above " + std::to_string(a.opt.spacingK) + ")");
    a.kept = build.kept(args);
    return -1;
}

}  // namespace

int parseBuildCommandLine(const std::vector<std::string>& args, BuildArgs* out) { return parseAs(args, out); }

int parseStoredCommandLine(const std::vector<std::string>& args, BuildArgs* out) {
    std::vector<std::string> plan = {"plan"};
    plan.insert(plan.end(), args.begin(), args.end());
    const int status = parseAs(plan, out);
    out->stage.clear();
    return status;
}

std::vector<std::string> storedCommandLine(const BuildArgs& a) {
    std::vector<std::string> stored;
    for (size_t i = 0; i < a.kept.size(); ++i) {
        if (a.kept[i] == "--threads") ++i;
        else if (a.kept[i] != "-q" && a.kept[i] != "--quiet") stored.push_back(a.kept[i]);
    }
    stored.insert(stored.end(), {"-o", a.opt.output});
    stored.insert(stored.end(), a.opt.inputs.paths.begin(), a.opt.inputs.paths.end());
    return stored;
}

}  // namespace surfcast
