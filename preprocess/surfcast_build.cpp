// surfcast-build: scans → tile set. main() only parses arguments and wires the
// builder (octree_builder.h) and the verifier (tileset_reader.h) together.
// Weight capture renders, so it runs as its own program (surfcast-weights, next
// to this one): the build itself needs no Vulkan.
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "block_codec.h"
#include "compact.h"
#include "crc32.h"
#include "octree_builder.h"
#include "preview.h"
#include "refine.h"
#include "set_lock.h"
#include "stages.h"
#include "store_work.h"
#include "update.h"
#include "work_files.h"
#include "http_tile_source.h"
#include "input_file.h"
#include "object_store.h"
#include "set_publisher.h"
#include "build_cli.h"
#include "command_line.h"
#include "set_reader.h"
#include "tileset_reader.h"

extern char** environ;

namespace {

// Runs surfcast-weights from this program's folder on `set`; its exit status,
// or -1 when it cannot be started.
int runWeightCapture(const std::string& set, bool quiet) {
    std::error_code ec;
    std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
    std::string program = ec ? std::string("surfcast-weights") : (self.parent_path() / "surfcast-weights").string();
    std::vector<std::string> args = {program};
    if (quiet) args.push_back("-q");
    const char* env = std::getenv("SURFCAST_VALIDATION");
    if (env && std::string(env) == "1") args.push_back("--validation");
    args.push_back(set);
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    pid_t pid = 0;
    if (posix_spawnp(&pid, program.c_str(), nullptr, nullptr, argv.data(), environ) != 0) return -1;
    int status = 0;
    while (waitpid(pid, &status, 0) < 0)
        if (errno != EINTR) return -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int usageError(const std::string& message) { return surfcast::cli::usageError("surfcast-build", message); }

using Args = surfcast::BuildArgs;

using surfcast::parseBuildCommandLine;

int fail(const surfcast::Status& status) {
    std::fprintf(stderr, "surfcast-build: %s\n", status.message().c_str());
    return 1;
}

// Prints what a build wrote and runs the weight capture where asked.
int finishBuild(const Args& a, const surfcast::BuildSummary& summary, bool staged = false) {
    std::printf("%s %s\n%s", staged ? "built" : "wrote", a.opt.output.c_str(), summary.text().c_str());
    if (a.captureWeights) {
        // The capture writes the set again, under the lock of the folder the
        // build swapped in (the build's own is on the one it replaced).
        surfcast::SetLock lock;
        if (auto st = surfcast::lockOutput(a.opt.output, &lock); !st.ok()) return fail(st);
        std::fflush(stdout);
        int status = runWeightCapture(a.opt.output, !a.opt.progress);
        if (status != 0) {
            std::fprintf(stderr, "surfcast-build: weight capture (surfcast-weights) %s; the set keeps its analytic weights\n",
                         status < 0 ? "could not be started" : ("failed with status " + std::to_string(status)).c_str());
            return 1;
        }
    }
    return 0;
}

// The inputs, expanded (folders, @LIST) and absolute, so that every stage's
// process reads the same files wherever it runs.
surfcast::Result<std::vector<std::string>> absoluteInputs(const std::vector<std::string>& given) {
    auto paths = surfcast::expandInputPaths(given);
    if (!paths) return paths.status();
    for (std::string& p : *paths)
        if (!surfcast::isRemoteInput(p)) p = std::filesystem::absolute(p).lexically_normal().string();
    return paths;
}

// Each chunk's points, from the plan's counts.
std::vector<uint64_t> plannedChunkPoints(const surfcast::BuildPlan& plan, const surfcast::BuildContext& c) {
    surfcast::ChunkLayout layout = plan.layout(c);
    std::vector<uint64_t> points(layout.chunks().size(), 0);
    if (plan.counts.empty()) points[0] = c.stats().points;  // one chunk, not counted
    const double cell = c.rootEdge() / (1 << surfcast::kCountLevel);
    for (auto [index, n] : plan.counts) {
        const uint32_t side = 1u << surfcast::kCountLevel;
        const surfcast::Vec3d centre{(index / side / side + 0.5) * cell, (index / side % side + 0.5) * cell, (index % side + 0.5) * cell};
        points[size_t(layout.chunkOf(centre))] += n;
    }
    return points;
}

// plan.json: what a driver schedules by (docs/ARCHITECTURE.md, "Stages"):
// the chunks' points and nodes, the parts, and an update's chunks to build
// (`build`).
surfcast::Status writePlanJson(const surfcast::WorkFolder& work, const surfcast::BuildPlan& plan, const surfcast::ChunkLayout& layout,
                               const std::vector<uint64_t>& points, const std::vector<size_t>* build = nullptr) {
    std::ostringstream json;
    json << "{\n  \"format\": \"surfcast-plan\",\n  \"points\": " << plan.stats.points << ",\n  \"chunks\": " << points.size()
         << ",\n  \"chunk_points\": [";
    for (size_t i = 0; i < points.size(); ++i) json << (i ? ", " : "") << points[i];
    // Each chunk's node (level-x-y-z, as docs/FORMAT.md names nodes).
    json << "],\n  \"chunk_nodes\": [";
    for (size_t i = 0; i < layout.chunks().size(); ++i) json << (i ? ", " : "") << '"' << layout.chunks()[i].key.name() << '"';
    if (build) {
        json << "],\n  \"build\": [";
        for (size_t i = 0; i < build->size(); ++i) json << (i ? ", " : "") << (*build)[i];
    }
    // Each part from input `first`'s record `begin` to input `last`'s record `end` (0: up to input `last`).
    json << "],\n  \"parts\": [";
    for (size_t i = 0; i < plan.parts.size(); ++i) {
        const surfcast::InputPart& p = plan.parts[i];
        json << (i ? ",\n    " : "\n    ") << "{\"first\": " << p.first << ", \"begin\": " << p.begin << ", \"last\": " << p.last
             << ", \"end\": " << p.end << ", \"points\": " << p.points << "}";
    }
    json << "\n  ]\n}\n";
    const std::string path = work.dir + "/plan.json", partial = surfcast::partialName(path);
    std::FILE* f = std::fopen(partial.c_str(), "wb");
    if (!f) return surfcast::Status::error(partial + ": cannot create");
    const std::string text = json.str();
    bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
    ok = std::fclose(f) == 0 && ok;
    std::error_code ec;
    if (ok) std::filesystem::rename(partial, path, ec);
    return ok && !ec ? surfcast::Status{} : surfcast::Status::error(path + ": could not be written");
}

// What the budget leaves the meshes' store while the inputs are read again
// (as plan_stage.cpp sets it in one process; docs/ARCHITECTURE.md, "Memory").
uint64_t meshCapacity(const surfcast::BuildContext& c) {
    const surfcast::BuildOptions& o = c.options();
    const uint64_t held = surfcast::kBaselineBytes + c.textureBytes() + c.stats().largestMeshBytes;
    return o.memoryBytes > held ? o.memoryBytes - held : 0;
}

// The scans of `parts` parts (scan --part P/N), reduced: the statistics of
// every input and each part's inputs and sources.
surfcast::Result<std::pair<surfcast::InputStats, std::vector<surfcast::InputPart>>> reducedScans(const surfcast::WorkFolder& work,
                                                                                                const surfcast::InputOptions& inputs,
                                                                                                size_t parts, uint32_t job) {
    std::vector<surfcast::InputStats> stats(parts);
    std::vector<surfcast::InputPart> ranges(parts);
    for (size_t p = 0; p < parts; ++p) {
        auto scanned = surfcast::readScan(work.scan(p), &ranges[p], job);
        if (!scanned) return scanned.status();
        stats[p] = std::move(*scanned);
    }
    const size_t inputCount = inputs.paths.size() + (inputs.defaultScene ? 1 : 0);
    auto reduced = surfcast::reduceScans(std::move(stats), ranges, [&](size_t p) { return work.scan(p); });
    if (!reduced) return reduced.status();
    if (ranges.empty() || ranges.back().last != inputCount || ranges.back().end != 0)
        return surfcast::Status::error(work.dir + "/scan: the parts cover " + std::to_string(ranges.empty() ? 0 : ranges.back().last) +
                                       " of the " + std::to_string(inputCount) + " inputs");
    return std::make_pair(std::move(*reduced), std::move(ranges));
}

using surfcast::storedCommandLine;

// The input of a set's build record that NAME names: its path as given
// (made absolute), or its file name where only one input has it; -1 with
// `error` set otherwise.
long findInput(const std::vector<std::string>& paths, size_t first, const std::string& name, std::string* error) {
    std::string absolute = surfcast::isRemoteInput(name) ? name : std::filesystem::absolute(name).lexically_normal().string();
    while (absolute.size() > 1 && absolute.back() == '/') absolute.pop_back();  // a set's folder given as "team_b/"
    long found = -1;
    for (size_t i = 0; i < paths.size(); ++i)
        if (paths[i] == absolute || (surfcast::isSetInput(paths[i]) && paths[i] == absolute + "/tileset.json")) return long(first + i);
    for (size_t i = 0; i < paths.size(); ++i)
        if (surfcast::inputName(paths[i]) == name) {
            if (found >= 0) {
                *error = name + " names several of the set's inputs; give its path";
                return -1;
            }
            found = long(first + i);
        }
    if (found < 0) *error = name + " is not one of the set's inputs (surfcast-build --info lists them)";
    return found;
}

// The build record of the set in folder `set` (update.h): its plan, and its
// command line parsed into `planned`. `purpose`: what the record is for, in
// the error where the set keeps none; with `found`, a set without a record is
// no error (*found says whether it had one).
surfcast::Status readRecord(const std::string& set, surfcast::BuildPlan* record, Args* planned, const std::string& purpose,
                            bool* found = nullptr, const std::string& name = {}) {
    const std::string& shown = name.empty() ? set : name;  // a set in a store, whose metadata `set` mirrors
    std::string json;
    {
        std::ifstream in(set + "/tileset.json", std::ios::binary);
        if (!in) return surfcast::Status::error(shown + ": not a tile set (no tileset.json)");
        json.assign(std::istreambuf_iterator<char>(in), {});
    }
    auto info = surfcast::readTilesetJson(json, set + "/tileset.json");
    if (!info) return info.status();
    const std::string recordPath = set + "/" + surfcast::buildRecordFile(info->hierarchyFile);
    if (found) *found = std::filesystem::exists(recordPath);
    if (found && !*found) return {};
    if (!std::filesystem::exists(recordPath))
        return surfcast::Status::error(shown + ": keeps no build record (" + surfcast::buildRecordFile(info->hierarchyFile) +
                                       "): it was built before updates existed; build it anew to " + purpose);
    std::vector<std::string> stored;
    auto read = surfcast::readPlan(recordPath, &stored, true);
    if (!read) return read.status();
    *record = std::move(*read);
    if (surfcast::parseStoredCommandLine(stored, planned) >= 0) return surfcast::Status::error(recordPath + ": its command line does not parse");
    return {};
}

// surfcast-build --add INPUT... | --remove NAME... | --replace OLD NEW, --to
// SET: the update in place (update.h), with the options of the set's build
// record.
int runUpdate(const Args& a) {
    const std::string& mode = a.update;
    if (a.to.empty()) return usageError(mode + " needs the set to update (--to SET)");
    if (!a.opt.output.empty()) return usageError(mode + " updates the set --to names in place; it takes no -o");
    if (a.opt.inputs.defaultScene || a.opt.inputs.paths.empty())
        return usageError(mode == "--add" ? "--add needs input files to add" : mode == "--remove" ? "--remove needs the inputs to remove" : "--replace needs OLD and NEW");
    if (mode == "--replace" && a.opt.inputs.paths.size() != 2) return usageError("--replace takes two inputs: OLD (in the set) and NEW");
    for (size_t i = 0; i < a.kept.size(); ++i) {
        if (a.kept[i] == "--threads") ++i;
        else if (a.kept[i] != "-q" && a.kept[i] != "--quiet")
            return usageError(mode + " takes the set's own build options from its build record, not " + a.kept[i] + " (only --threads and -q)");
    }
    // A set in a store is updated in a local folder holding its metadata,
    // then published as its next version (set_publisher.h): the store's
    // conditional write, not a lock, keeps two updaters apart.
    const bool stored = surfcast::isS3Url(a.to);
    if (stored && !a.work.empty())
        return usageError("update-plan writes to folders; update a set in a store in one process (--to s3://... without stages)");
    std::unique_ptr<surfcast::PublishStaging> staging;
    std::optional<surfcast::StoredVersion> base;
    std::string set;
    surfcast::SetLock lock;
    if (stored) {
        auto created = surfcast::PublishStaging::create();
        if (!created) return fail(created.status());
        staging = std::move(*created);
        set = staging->dir() + "/set";
        std::error_code ec;
        std::filesystem::create_directories(set, ec);
        if (ec) return fail(surfcast::Status::error(set + ": cannot create (" + ec.message() + ")"));
        auto mirrored = surfcast::mirrorSetMetadata(a.to, set);
        if (!mirrored) return fail(mirrored.status());
        base = std::move(*mirrored);
    } else {
        set = std::filesystem::absolute(a.to).lexically_normal().string();
        if (auto st = surfcast::lockSet(set, &lock); !st.ok()) return fail(st);
    }
    const std::string shown = stored ? base->url : set;
    surfcast::BuildPlan record;
    Args planned;
    if (auto st = readRecord(set, &record, &planned, "update it", nullptr, shown); !st.ok()) return fail(st);
    planned.opt.threads = a.opt.threads;
    planned.opt.progress = a.opt.progress;
    planned.opt.inputs.http = a.opt.inputs.http;  // how to reach the added inputs: never in a record
    if (!stored) planned.opt.output = set;  // (a set in a store keeps the URL it was built to)

    surfcast::UpdateRequest request;
    if (stored) request.store = base->url;
    std::vector<std::string> toAdd, toRemove;
    if (mode == "--add") toAdd = a.opt.inputs.paths;
    else if (mode == "--remove") toRemove = a.opt.inputs.paths;
    else toRemove = {a.opt.inputs.paths[0]}, toAdd = {a.opt.inputs.paths[1]};
    const size_t first = planned.opt.inputs.defaultScene ? 1 : 0;  // the scene is input 0
    for (const std::string& name : toRemove) {
        std::string error;
        const long k = findInput(planned.opt.inputs.paths, first, name, &error);
        if (k < 0) return fail(surfcast::Status::error(shown + ": " + error));
        request.removed.push_back(uint32_t(k));
    }
    if (!toAdd.empty()) {
        auto added = absoluteInputs(toAdd);
        if (!added) return fail(added.status());
        request.added = added->size();
        planned.opt.inputs.paths.insert(planned.opt.inputs.paths.end(), added->begin(), added->end());
    }
    if (!a.work.empty()) {
        // update-plan: the first stage of an update in stages (update.h).
        const surfcast::WorkFolder work{std::filesystem::absolute(a.work).lexically_normal().string()};
        std::error_code ec;
        std::filesystem::create_directories(work.dir, ec);
        if (ec) return fail(surfcast::Status::error(work.dir + ": cannot create (" + ec.message() + ")"));
        auto staged = surfcast::updatePlanStage(planned.opt, request, set, record, storedCommandLine(planned), work);
        if (!staged) return fail(staged.status());
        if (auto st = writePlanJson(work, staged->plan, staged->layout, staged->chunkPoints, &staged->build); !st.ok()) return fail(st);
        std::printf("planned the update of %s: %zu of %zu chunks to build, in %s\n", set.c_str(), staged->build.size(),
                    staged->chunkPoints.size(), work.dir.c_str());
        return 0;
    }
    auto summary = surfcast::updateTileset(planned.opt, request, set, record, storedCommandLine(planned));
    if (!summary) return fail(summary.status());
    if (stored) {
        auto published = surfcast::publishVersion(set, *base);
        if (!published) return fail(published.status());
        if (!published->warning.empty()) std::fprintf(stderr, "surfcast-build: warning: %s\n", published->warning.c_str());
        std::printf("published %s: %llu objects, %llu bytes, %llu requests; %llu objects no kept version names deleted\n",
                    shown.c_str(), (unsigned long long)published->objects, (unsigned long long)published->bytes,
                    (unsigned long long)published->requests, (unsigned long long)published->removed);
    }
    std::printf("updated %s (%zu inputs added, %zu removed; %zu chunks built again)\n%s", shown.c_str(), request.added,
                request.removed.size(), summary->chunks, summary->text().c_str());
    return 0;
}

// surfcast-build --compact SET: the set written anew without the blocks its
// updates replaced, its nodes' bytes (and so their ETags) as they were.
int runCompact(const std::string& set) {
    auto report = surfcast::compactSet(set);
    if (!report) return fail(report.status());
    if (report->already) {
        std::printf("%s is compact already: its one block file holds every node's bytes and no others\n", set.c_str());
        return 0;
    }
    std::printf("compacted %s: blocks %llu bytes, was %llu in its block files\n", set.c_str(), (unsigned long long)report->blocksBytes,
                (unsigned long long)report->before);
    if (surfcast::isS3Url(set))
        std::printf("(%llu requests; %llu objects no kept version names deleted)\n", (unsigned long long)report->requests,
                    (unsigned long long)report->removed);
    return 0;
}

int runStageOn(const std::string& stage, Args& a, const surfcast::WorkFolder& work);

// A stage: on the work folder --work names, or on a local copy of the files
// it reads from a work prefix in a store, whose outputs it then uploads
// (store_work.h).
int runStage(Args& a) {
    const std::string& stage = a.stage;
    if (a.work.empty()) return usageError(stage + " needs --work DIR, a folder every stage's process sees (or s3://BUCKET/PREFIX)");
    if (!surfcast::isS3Url(a.work)) return runStageOn(stage, a, surfcast::WorkFolder{a.work});
    if (stage == "update-merge") return usageError("an update in stages works in a folder; --work s3://... is for builds");
    if (stage == "preview" || stage == "refine" || a.standIns > 0)
        return usageError("previews and versions while building publish to a folder; --work s3://... builds a set in a store whole");
    auto staging = surfcast::PublishStaging::create();
    if (!staging) return fail(staging.status());
    auto storeWork = surfcast::StoreWork::open(a.work, stage, a.chunks, (*staging)->dir() + "/work");
    if (!storeWork) return fail(storeWork.status());
    const surfcast::StoreWork& w = **storeWork;
    // A new plan makes the earlier one's later outputs stale (as it removes
    // them from a folder); a merged set leaves only the plan, a record.
    if (stage == "plan")
        if (auto st = w.remove({"chunks/", "nodes/", "update.bin"}); !st.ok()) return fail(st);
    const int status = runStageOn(stage, a, surfcast::WorkFolder{w.dir()});
    if (status != 0) return status;
    if (auto st = w.upload(); !st.ok()) return fail(st);
    if (stage == "merge")
        if (auto st = w.remove({"scan/", "count/", "chunks/", "nodes/"}); !st.ok()) return fail(st);
    return 0;
}

// One stage of a staged build (stages.h): scan, count and plan take the inputs
// and options of a whole build, and plan stores them; the later stages read
// them from the plan.
int runStageOn(const std::string& stage, Args& a, const surfcast::WorkFolder& work) {
    surfcast::BuildSummary summary;
    std::shared_ptr<const surfcast::BuildContext> context;
    if (stage == "preview") {
        if (a.opt.output.empty()) return usageError("no output folder (-o OUT)");
        if (surfcast::isS3Url(a.opt.output)) return usageError("--preview publishes to a folder (-o DIR); a set in a store is published whole");
        if (a.opt.inputs.paths.empty() && !a.opt.inputs.defaultScene) return usageError("no inputs (give files or --default-scene)");
        auto paths = absoluteInputs(a.opt.inputs.paths);
        if (!paths) return fail(paths.status());
        a.opt.inputs.paths = *paths;
        auto written = surfcast::publishPreview(a.opt, a.previewPoints);
        if (!written) return fail(written.status());
        std::printf("%s %s\n", *written ? "published a preview at" : "no preview: a set is at", a.opt.output.c_str());
        return 0;
    }
    if (stage == "scan" || stage == "count" || stage == "plan") {
        if (a.opt.output.empty()) return usageError("no output folder (-o OUT)");
        if (a.opt.inputs.paths.empty() && !a.opt.inputs.defaultScene) return usageError("no inputs (give files or --default-scene)");
        if (stage != "plan" && !a.partGiven) return usageError(stage + " needs --part P/N");
        auto paths = absoluteInputs(a.opt.inputs.paths);
        if (!paths) return fail(paths.status());
        a.opt.inputs.paths = *paths;
        if (!surfcast::isS3Url(a.opt.output)) a.opt.output = std::filesystem::absolute(a.opt.output).lexically_normal().string();
        else if (auto url = surfcast::parseS3Url(a.opt.output); !url) return fail(url.status());
        std::error_code ec;
        std::filesystem::create_directories(work.dir + "/" + (stage == "plan" ? "" : stage), ec);
        if (ec) return fail(surfcast::Status::error(work.dir + ": cannot create (" + ec.message() + ")"));
        const surfcast::BuildOptions opt = surfcast::normalizeOptions(a.opt);
        surfcast::Progress progress(opt.progress);
        // The command line the plan stores (but -q and --threads N, which
        // change no byte and which each stage gives its own), and the job it
        // names: the scans and counts of one job reduce together, never
        // another's.
        const std::vector<std::string> stored = storedCommandLine(a);
        std::string joined;
        for (const std::string& arg : stored) joined += arg + '\0';
        const uint32_t job = surfcast::crc32(joined.data(), joined.size());
        if (stage == "scan") {
            surfcast::InputPart part = surfcast::inputPart(opt.inputs, a.part, a.parts);
            progress.begin("scan", 0);
            auto stats = surfcast::scanStage(opt, part, progress);
            if (!stats) return fail(stats.status());
            progress.end();
            part.sources = stats->sources.size();
            part.points = stats->points;
            if (auto st = surfcast::writeScan(work.scan(a.part), *stats, part, job); !st.ok()) return fail(st);
            std::printf("scanned part %zu of %zu: from input %zu record %llu to input %zu record %llu, %llu points\n", a.part, a.parts,
                        part.first, (unsigned long long)part.begin, part.last, (unsigned long long)part.end,
                        (unsigned long long)stats->points);
            return 0;
        }
        surfcast::BuildPlan plan;
        if (stage == "plan" && a.parts == 0) {
            auto planned = surfcast::planStage(opt, 1, progress, &context, &summary);  // one part: the same plan whatever --threads
            if (!planned) return fail(planned.status());
            plan = std::move(*planned);
        } else {
            auto scans = reducedScans(work, opt.inputs, a.parts, job);
            if (!scans) return fail(scans.status());
            auto derived = surfcast::BuildContext::derive(opt, std::move(scans->first), stage == "plan");
            if (!derived) return fail(derived.status());
            context = *derived;
            context->options().inputs.meshes->setCapacity(meshCapacity(*context));
            auto most = surfcast::chunkPoints(*context);
            if (!most) return fail(most.status());
            if (stage == "count") {
                std::vector<std::pair<uint32_t, uint32_t>> counts;  // none where one chunk takes every point
                if (*most > 0) {
                    progress.begin("count", 0);
                    auto counted = surfcast::countStage(*context, scans->second.at(a.part), progress);
                    if (!counted) return fail(counted.status());
                    progress.end();
                    counts = std::move(*counted);
                }
                if (auto st = surfcast::writeCount(work.count(a.part), counts, job); !st.ok()) return fail(st);
                return 0;
            }
            plan.stats = context->stats();
            plan.parts = std::move(scans->second);
            plan.maxChunkPoints = *most;
            if (*most > 0) {
                std::vector<std::vector<std::pair<uint32_t, uint32_t>>> counts;
                for (size_t p = 0; p < a.parts; ++p) {
                    auto counted = surfcast::readCount(work.count(p), job);
                    if (!counted) return fail(counted.status());
                    counts.push_back(std::move(*counted));
                }
                plan.counts = surfcast::addCounts(counts);
            }
        }
        // A new plan: what earlier plans distributed and built goes (their
        // files name their plan, and the later stages would refuse them).
        for (const char* folder : {"chunks", "nodes", "stand-ins"}) std::filesystem::remove_all(work.dir + "/" + folder, ec);
        std::filesystem::remove(work.update(), ec);
        if (auto st = surfcast::writePlan(work.plan(), plan, stored); !st.ok()) return fail(st);
        if (auto st = writePlanJson(work, plan, plan.layout(*context), plannedChunkPoints(plan, *context)); !st.ok()) return fail(st);
        std::printf("planned %zu chunks for %llu points in %s\n", plan.layout(*context).chunks().size(),
                    (unsigned long long)context->stats().points, work.dir.c_str());
        return 0;
    }

    std::vector<std::string> stored;
    auto plan = surfcast::readPlan(work.plan(), &stored);
    if (!plan) return fail(plan.status());
    Args planned;
    if (surfcast::parseStoredCommandLine(stored, &planned) >= 0) return fail(surfcast::Status::error(work.plan() + ": its command line does not parse"));
    planned.opt.threads = a.opt.threads;
    planned.opt.progress = a.opt.progress;
    planned.opt.inputs.http = a.opt.inputs.http;  // how to reach URL inputs: never in a plan
    const size_t inputCount = planned.opt.inputs.paths.size() + (planned.opt.inputs.defaultScene ? 1 : 0);
    if (plan->parts.back().last != inputCount)
        return fail(surfcast::Status::error(work.plan() + ": its parts do not cover its " + std::to_string(inputCount) + " inputs"));
    // A staged update's plan (update.bin beside plan.bin) is distributed by
    // update-plan, and merged into its set by update-merge.
    const bool update = std::filesystem::exists(work.update());
    if (update && (stage == "distribute" || stage == "merge" || stage == "refine"))
        return usageError(work.dir + " holds an update's plan, which update-plan distributed; run chunk, then update-merge");
    if (!update && stage == "update-merge") return usageError(work.dir + " holds no update's plan (update.bin): run update-plan first");
    if (update && (stage == "chunk" || stage == "update-merge")) {
        // A task run again after the switch (a worker lost after it, a
        // driver started again): the set holds this update already.
        auto applied = surfcast::updateApplied(planned.opt, work);
        if (!applied) return fail(applied.status());
        if (*applied) {
            std::printf("%s holds this update already (its build record is %s)\n", planned.opt.output.c_str(), work.plan().c_str());
            return 0;
        }
    }
    if (stage == "update-merge") {
        const std::string& set = planned.opt.output;
        surfcast::SetLock lock;
        if (auto st = surfcast::lockSet(set, &lock); !st.ok()) return fail(st);
        auto summary = surfcast::updateMergeStage(planned.opt, *plan, stored, work);
        if (!summary) return fail(summary.status());
        std::error_code ec;
        for (const char* folder : {"chunks", "nodes"}) std::filesystem::remove_all(work.dir + "/" + folder, ec);
        std::printf("updated %s (%zu chunks built again)\n%s", set.c_str(), summary->chunks, summary->text().c_str());
        return 0;
    }
    std::vector<size_t> updateChunks;  // an update's chunks to build
    surfcast::KeepNode keep;           // and the nodes it keeps
    auto derived = update ? surfcast::updateContext(planned.opt, *plan, work, &updateChunks, &keep)
                          : surfcast::BuildContext::derive(planned.opt, plan->stats, false);
    if (!derived) return fail(derived.status());
    const surfcast::BuildContext& c = **derived;
    // The meshes' store: within what the budget leaves while distribute reads
    // them (as in one process); nothing after it reads a mesh.
    c.options().inputs.meshes->setCapacity(stage == "distribute" ? meshCapacity(c) : 0);
    surfcast::ChunkLayout layout = plan->layout(c);
    surfcast::Progress progress(planned.opt.progress);
    if (stage == "distribute") {
        if (a.partGiven && a.part >= plan->parts.size())
            return usageError("--part " + std::to_string(a.part) + ": the plan has parts 0 to " + std::to_string(plan->parts.size() - 1));
        for (size_t p = a.partGiven ? a.part : 0; p < (a.partGiven ? a.part + 1 : plan->parts.size()); ++p)
            if (auto st = surfcast::distributeStage(c, *plan, layout, p, work, progress, &summary, a.standIns); !st.ok()) return fail(st);
        std::printf("distributed %s into %zu chunks\n", a.partGiven ? ("part " + std::to_string(a.part)).c_str() : "every part",
                    layout.chunks().size());
        return 0;
    }
    if (stage == "chunk") {
        if (a.chunks.empty()) return usageError("chunk needs the numbers of the chunks to build (0 to " + std::to_string(layout.chunks().size() - 1) + ")");
        for (size_t i : a.chunks)
            if (i >= layout.chunks().size())
                return usageError("chunk " + std::to_string(i) + ": the plan has chunks 0 to " + std::to_string(layout.chunks().size() - 1));
            else if (update && std::find(updateChunks.begin(), updateChunks.end(), i) == updateChunks.end())
                return usageError("chunk " + std::to_string(i) + ": the update keeps it as the set holds it (plan.json's \"build\" names the chunks to build)");
        if (auto st = surfcast::readDistribution(work, *plan, layout); !st.ok()) return fail(st);
        uint64_t points = 0;
        for (size_t i : a.chunks) points += layout.chunks()[i].points;
        progress.begin("build", points);
        for (size_t i : a.chunks) {
            if (auto st = surfcast::chunkStage(c, *plan, layout, i, work, c.threads(), false, keep); !st.ok()) return fail(st);
            progress.advance(layout.chunks()[i].points);
        }
        progress.end();
        return 0;
    }
    if (stage == "refine") {
        // A version of the build in progress (refine.h): the chunks whose
        // output is in place (the .nodes file comes last), the others' stand-ins.
        if (a.standIns == 0) return usageError("refine needs --stand-ins N, the stride distribute was given");
        if (surfcast::isS3Url(planned.opt.output))
            return usageError("versions while building publish to a folder; a set in a store is published whole");
        if (auto st = surfcast::readDistribution(work, *plan, layout); !st.ok()) return fail(st);
        if (auto st = surfcast::buildStandIns(c, *plan, layout, work); !st.ok()) return fail(st);
        std::vector<bool> built(layout.chunks().size());
        std::error_code ec;
        for (size_t i = 0; i < built.size(); ++i) built[i] = std::filesystem::exists(work.nodes(i), ec);
        const size_t done = size_t(std::count(built.begin(), built.end(), true));
        surfcast::SetLock lock, version;
        if (auto st = surfcast::lockOutput(planned.opt.output, &lock); !st.ok()) return fail(st);
        if (auto st = surfcast::publishRefinement(c, *plan, layout, work, std::move(built), a.standIns, &version); !st.ok())
            return fail(st);
        std::printf("published a version at %s: %zu of %zu chunks built\n", planned.opt.output.c_str(), done, layout.chunks().size());
        return 0;
    }
    // merge: into the set's folder, or for a set in a store into a local
    // one, then published (set_publisher.h).
    const std::string publishTo = surfcast::isS3Url(planned.opt.output) ? planned.opt.output : "";
    std::unique_ptr<surfcast::PublishStaging> staging;
    if (!publishTo.empty()) {
        auto created = surfcast::PublishStaging::create();
        if (!created) return fail(created.status());
        staging = std::move(*created);
        // A merge run again after its set was published (its worker lost
        // before it said so): the set at the prefix keeps this plan as its
        // build record, and is done.
        if (auto there = surfcast::mirrorSetMetadata(publishTo, staging->dir()); there) {
            std::ifstream record(staging->dir() + "/" + surfcast::buildRecordFile(there->info.hierarchyFile), std::ios::binary),
                mine(work.plan(), std::ios::binary);
            if (record && mine && std::string{std::istreambuf_iterator<char>(record), {}} == std::string{std::istreambuf_iterator<char>(mine), {}}) {
                std::printf("%s holds this build already (its build record is its plan)\n", publishTo.c_str());
                return 0;
            }
        }
        planned.opt.output = staging->dir() + "/set";
    }
    surfcast::SetLock lock;
    if (auto st = surfcast::lockOutput(planned.opt.output, &lock); !st.ok()) return fail(st);
    c.describe(&summary);
    summary.chunks = layout.chunks().size();
    auto writer = surfcast::TilesetWriter::create(planned.opt.output);
    if (!writer) return fail(writer.status());
    // The set keeps the plan as its build record (update.h): plan.bin's bytes, synced.
    if (auto st = surfcast::keepBuildRecord(**writer, (*writer)->partialDir(), *plan, stored); !st.ok()) return fail(st);
    if (auto st = surfcast::mergeStage(c, *plan, layout, work, **writer, progress, &summary); !st.ok()) return fail(st);
    summary.inputPoints = c.stats().points;
    summary.skippedPoints = c.stats().skipped;
    summary.peakRss = surfcast::peakRssBytes();
    // The set is in place: the parts' and chunks' files go (plan.bin and
    // plan.json stay, a record of the build).
    std::error_code ec;
    for (const char* folder : {"scan", "count", "chunks", "nodes", "stand-ins"}) std::filesystem::remove_all(work.dir + "/" + folder, ec);
    if (int status = finishBuild(planned, summary, !publishTo.empty()); status != 0 || publishTo.empty()) return status;
    auto published = surfcast::publishFolder(planned.opt.output, publishTo);
    if (!published) return fail(published.status());
    std::printf("wrote %s (%llu objects, %llu bytes, %llu requests)\n", publishTo.c_str(), (unsigned long long)published->objects,
                (unsigned long long)published->bytes, (unsigned long long)published->requests);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    Args a;
    if (int status = parseBuildCommandLine(std::vector<std::string>(argv + 1, argv + argc), &a); status >= 0) return status;
    if (a.stage == "update-plan") {
        if (a.work.empty()) return usageError("update-plan needs --work DIR, a folder every stage's process sees");
        if (a.update.empty()) return usageError("update-plan needs --add, --remove or --replace, and --to SET");
        return runUpdate(a);
    }
    if (!a.stage.empty()) return runStage(a);
    if (a.merge && (!a.update.empty() || !a.to.empty() || !a.compact.empty()))
        return usageError("--merge writes a new set (-o OUT); it takes no --add, --remove, --replace, --to or --compact");
    if (!a.info.empty() && (!a.update.empty() || !a.to.empty() || a.merge || !a.compact.empty()))
        return usageError("--info SET prints a set's summary: it takes no update, --merge or --compact");
    if (a.preview && (!a.compact.empty() || !a.info.empty()))
        return usageError("--preview is for builds (inputs and -o OUT)");
    if (!a.compact.empty()) {
        if (!a.update.empty() || !a.to.empty() || !a.opt.output.empty() || !a.opt.inputs.paths.empty() || a.opt.inputs.defaultScene)
            return usageError("--compact SET takes no inputs, no -o and no update");
        return runCompact(a.compact);
    }
    if (!a.update.empty() || !a.to.empty()) {
        if (a.update.empty()) return usageError("--to names the set that --add, --remove or --replace updates");
        if (a.preview) return usageError("--preview is for builds: viewers that follow a set see an update when it is done");
        return runUpdate(a);
    }
    if (a.merge) {
        // A build from the sets' points (set_reader.h), with the first set's
        // build options (its record, where it keeps one; not those of reading
        // its inputs), then the command line's.
        if (a.opt.inputs.defaultScene) return usageError("--merge joins tile sets; it takes no --default-scene");
        if (a.opt.output.empty()) return usageError("--merge needs the folder to write the joined set to (-o OUT)");
        if (a.opt.inputs.paths.size() < 2) return usageError("--merge joins two or more tile sets");
        std::vector<std::string> sets;
        for (std::string set : a.opt.inputs.paths) {
            if (surfcast::isS3Url(set)) {  // a set in a store (set_reader.h), checked as it is read
                while (set.back() == '/') set.pop_back();
                sets.push_back(set + "/tileset.json");
                continue;
            }
            const std::filesystem::path json = std::filesystem::path(set) / "tileset.json";
            if (!std::filesystem::is_regular_file(json)) return fail(surfcast::Status::error(set + ": not a tile set (no tileset.json)"));
            sets.push_back(json.string());
        }
        surfcast::BuildPlan record;
        Args first;
        bool found = false;
        std::string firstSet = a.opt.inputs.paths[0];
        std::unique_ptr<surfcast::PublishStaging> mirror;  // the first set's metadata, where it lies in a store
        if (surfcast::isS3Url(firstSet)) {
            auto created = surfcast::PublishStaging::create();
            if (!created) return fail(created.status());
            mirror = std::move(*created);
            auto mirrored = surfcast::mirrorSetMetadata(firstSet, mirror->dir());
            if (!mirrored) return fail(mirrored.status());
            firstSet = mirror->dir();
        }
        if (auto st = readRecord(firstSet, &record, &first, "merge it", &found, a.opt.inputs.paths[0]); !st.ok()) return fail(st);
        // Options of how the first set read its inputs act on the sets'
        // points no more: they hold the result (--opacity would scale their
        // alpha twice, --default-scene add the scene again, --remove-outliers
        // judge the points it kept again).
        std::vector<std::string> args;
        for (size_t i = 0; i < first.kept.size(); ++i) {
            const std::string& o = first.kept[i];
            if (o == "--scene-points" || o == "--seed" || o == "--opacity" || o == "--columns" || o == "--mesh-spacing" ||
                o == "--mesh-max-surfels" || o == "--texture-filter" || o == "--remove-outliers")
                ++i;
            else if (o != "--default-scene" && o != "--read-alpha" && o != "--vertices-only" && o != "--allow-missing-textures" &&
                     o != "--allow-outside-paths")
                args.push_back(o);
        }
        args.insert(args.end(), a.kept.begin(), a.kept.end());
        args.insert(args.end(), {"-o", a.opt.output});
        args.insert(args.end(), sets.begin(), sets.end());
        Args merged;
        if (int status = parseBuildCommandLine(args, &merged); status >= 0) return status;
        merged.opt.inputs.http = a.opt.inputs.http;
        merged.preview = a.preview;
        merged.previewPoints = a.previewPoints;
        merged.previewInterval = a.previewInterval;
        a = std::move(merged);
    }
    const surfcast::BuildOptions& opt = a.opt;
    const surfcast::HttpOptions& http = a.opt.inputs.http;
    const std::string& info = a.info;
    if (!info.empty()) {
        auto reader = surfcast::openTileset(info, http);
        auto summary = reader ? surfcast::verifyTileset(*reader) : surfcast::Result<std::string>(reader.status());
        if (!summary) {
            std::fprintf(stderr, "surfcast-build: %s\n", summary.status().message().c_str());
            return 1;
        }
        std::printf("%s\n", summary->c_str());
        return 0;
    }
    if (opt.output.empty()) return usageError("no output folder (-o OUT)");
    if (opt.inputs.paths.empty() && !opt.inputs.defaultScene) return usageError("no inputs (give files or --default-scene)");
    // A set for an object store is built in a local folder, then published
    // (set_publisher.h): objects are written whole, never renamed.
    const std::string publishTo = surfcast::isS3Url(opt.output) ? opt.output : "";
    std::unique_ptr<surfcast::PublishStaging> staging;
    if (!publishTo.empty()) {
        if (a.preview) return usageError("--preview publishes to a folder (-o DIR); a set in a store is published whole");
        if (auto url = surfcast::parseS3Url(publishTo); !url) return fail(url.status());
        if (a.work.size() > 0) return usageError("-o s3://... builds in one process; --work is for folders");
        auto created = surfcast::PublishStaging::create();
        if (!created) return fail(created.status());
        staging = std::move(*created);
        a.opt.output = staging->dir() + "/set";
    }
    surfcast::SetLock lock;
    if (auto st = surfcast::lockOutput(opt.output, &lock); !st.ok()) return fail(st);
    auto paths = surfcast::expandInputPaths(opt.inputs.paths);
    if (!paths) {
        std::fprintf(stderr, "surfcast-build: %s\n", paths.status().message().c_str());
        return 1;
    }
    a.opt.inputs.paths = std::move(*paths);
    {
        // The build record's command line: inputs and output absolute, so an
        // update finds them from anywhere.
        Args recorded = a;
        auto absolute = absoluteInputs(a.opt.inputs.paths);
        if (!absolute) return fail(absolute.status());
        recorded.opt.inputs.paths = std::move(*absolute);
        recorded.opt.output = publishTo.empty() ? std::filesystem::absolute(a.opt.output).lexically_normal().string() : publishTo;
        a.opt.commandLine = storedCommandLine(recorded);
    }

    surfcast::SetLock previewLock;  // the preview is a set: other writers wait for the build
    if (a.preview) {
        if (auto written = surfcast::publishPreview(a.opt, a.previewPoints); !written) {
            std::fprintf(stderr, "surfcast-build: no preview: %s\n", written.status().message().c_str());
        } else if (*written) {
            if (auto locked = surfcast::lockOutput(opt.output, &previewLock); !locked.ok()) return fail(locked);
            a.opt.refine = surfcast::BuildOptions::Refine{a.previewPoints, a.previewInterval};
        }
    }
    auto summary = surfcast::buildTileset(a.opt);
    if (!summary) return fail(summary.status());
    if (int status = finishBuild(a, *summary, !publishTo.empty()); status != 0 || publishTo.empty()) return status;
    auto published = surfcast::publishFolder(a.opt.output, publishTo);
    if (!published) return fail(published.status());
    std::printf("wrote %s (%llu objects, %llu bytes, %llu requests)\n", publishTo.c_str(), (unsigned long long)published->objects,
                (unsigned long long)published->bytes, (unsigned long long)published->requests);
    return 0;
}
