// Viewers that follow a set (ClientOptions::followSeconds, VersionWatcher):
// an --add on a set a client has open shows without reopening it; only the
// nodes the update changed are fetched (the rest decode from the blocks the
// old version kept); no frame mixes versions; the last frame equals a fresh
// open of the updated set, pixel for pixel. From a folder, from nginx as a
// static host and from surfcast-serve, both polled with If-None-Match. A torn
// tileset.json and a version whose files are gone are retried, never shown.

#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>

#include <chrono>
#include <filesystem>
#include <functional>
#include <set>
#include <thread>
#include <tuple>
#include <utility>

#include "context.h"
#include "http_tile_source.h"
#include "stream_support.h"
#include "surfcast_client.h"
#include "test_support.h"
#include "tileset_reader.h"
#include "update_support.h"

namespace surfcast {
namespace {

namespace fs = std::filesystem;
using update_test::UpdateTest;

constexpr int kWidth = 200, kHeight = 150;

// A file replaced as writers replace it: whole, by rename.
void replaceFile(const std::string& path, const std::string& bytes) {
    test::writeFile(path + ".next", bytes);
    fs::rename(path + ".next", path);
}

// Every frame drew the base version's nodes (`nodes`), none of a later one.
void expectOnlyTheBase(const std::vector<ClientFrame>& frames, uint32_t nodes) {
    for (const ClientFrame& f : frames) {
        EXPECT_EQ(f.version, 0u);
        EXPECT_EQ(f.nodesCrc, nodes);
    }
}

// Pixel for pixel, and not both empty (a failed render).
bool same(const Image& a, const Image& b) {
    return !a.rgba.empty() && a.width == b.width && a.height == b.height && a.rgba == b.rgba;
}

// The base set of autzen's cells but the inner one (UpdateTest), with one
// Vulkan context for the program (validation on: zero errors after each case).
class FollowTest : public UpdateTest {
protected:
    static void SetUpTestSuite() {
        UpdateTest::SetUpTestSuite();
        auto ctx = gpu::createContext({"", true, {}, false});
        if (ctx) context_ = std::move(*ctx);
        else contextError_ = ctx.status().message();
    }
    static void TearDownTestSuite() {
        if (context_) gpu::destroyContext(context_);
        UpdateTest::TearDownTestSuite();
    }
    void SetUp() override {
        UpdateTest::SetUp();
        ASSERT_TRUE(context_) << contextError_;
    }
    void TearDown() override {
        if (context_) {
            EXPECT_EQ(context_->validationErrors.load(), 0) << "Vulkan validation errors (see stderr)";
        }
    }

    std::unique_ptr<SurfcastClient> open(const std::string& location, double followSeconds, ColorBy by = ColorBy::Auto) {
        ClientOptions options;
        options.followSeconds = followSeconds;
        options.coloring.by = by;
        options.lod.targetPixels = 1;
        auto client = SurfcastClient::open(*context_, location, options);
        EXPECT_TRUE(client) << client.status().message();
        return client ? std::move(*client) : nullptr;
    }

    // Updates `client` until `done(frame)` (60 s at most); every frame on the way.
    std::vector<ClientFrame> follow(SurfcastClient& client, const Camera& camera,
                                    const std::function<bool(const ClientFrame&)>& done) {
        std::vector<ClientFrame> frames;
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
        while (std::chrono::steady_clock::now() < deadline) {
            auto frame = client.update(camera, kWidth, kHeight);
            EXPECT_TRUE(frame) << frame.status().message();
            if (!frame) return frames;
            frames.push_back(*frame);
            if (done(*frame)) return frames;
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
        ADD_FAILURE() << "not done after 60 s";
        return frames;
    }

    Image image(SurfcastClient& client) {
        auto rendered = client.renderImage(client.defaultSettings());
        EXPECT_TRUE(rendered) << rendered.status().message();
        return rendered ? *rendered : Image{};
    }

    // A follower of the set polling every 0.1 s, converged on it: its camera
    // (the set framed) and the nodes it draws; a null client on failure.
    struct Follower {
        std::unique_ptr<SurfcastClient> client;
        Camera camera;
        uint32_t nodes = 0;
    };
    Follower convergedFollower() {
        Follower f{this->open(set(), 0.1), {}, 0};
        if (!f.client) return f;
        f.camera = frameBox(f.client->info().bounds, double(kWidth) / kHeight);
        auto frames = follow(*f.client, f.camera, [](const ClientFrame& frame) { return frame.converged; });
        EXPECT_FALSE(frames.empty());
        if (frames.empty()) f.client.reset();
        else f.nodes = frames.back().nodesCrc;
        return f;
    }

    // The image a fresh client converges to on `location`.
    Image freshImage(const std::string& location, const Camera& camera, ColorBy by = ColorBy::Auto) {
        auto client = this->open(location, 0, by);
        if (!client) return {};
        follow(*client, camera, [](const ClientFrame& f) { return f.converged; });
        return image(*client);
    }

    // Opens `location` following, converges on the base set, adds the inner
    // cell to the set's folder and follows until the new version converged.
    // Checks that no frame before the switch drew anything but the base
    // set's converged nodes, that the last image equals a fresh open's, and
    // that the follower fetched only changed nodes (hierarchies compared).
    // `stats`: the follower's stream stats of the new version.
    void expectFollowsTheAdd(const std::string& location, ColorBy by = ColorBy::Auto, StreamStats* stats = nullptr) {
        auto client = this->open(location, 0.2, by);
        ASSERT_TRUE(client);
        const Camera camera = frameBox(client->info().bounds, double(kWidth) / kHeight);
        auto before = follow(*client, camera, [](const ClientFrame& f) { return f.converged; });
        ASSERT_FALSE(before.empty());
        ASSERT_TRUE(before.back().converged);
        const uint32_t baseNodes = before.back().nodesCrc;
        auto old = openTileset(set());
        ASSERT_TRUE(old) << old.status().message();

        auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
        ASSERT_EQ(update.exitCode, 0) << update.output;
        auto after = follow(*client, camera, [](const ClientFrame& f) { return f.version == 1 && f.converged; });
        ASSERT_FALSE(after.empty());
        ASSERT_EQ(after.back().version, 1u);
        bool loaded = false;
        for (const ClientFrame& f : after) {
            loaded |= f.loadingVersion;
            if (f.version == 0) {
                EXPECT_EQ(f.nodesCrc, baseNodes) << "a frame before the switch drew other nodes";
            }
        }
        EXPECT_TRUE(loaded) << "the new version should load beside the one drawn";

        auto updated = openTileset(set());
        ASSERT_TRUE(updated) << updated.status().message();
        std::set<std::tuple<NodeKey, uint32_t, uint32_t>> kept;
        for (const NodeRecord& n : old->nodes()) kept.insert({n.key, n.blockCrc, n.blockSize});
        size_t changed = 0;
        uint64_t changedBytes = 0;
        for (const NodeRecord& n : updated->nodes())
            if (!kept.count({n.key, n.blockCrc, n.blockSize})) {
                ++changed;
                changedBytes += n.blockSize;
            }
        const StreamStats& s = after.back().stream;
        EXPECT_GT(changed, 0u);
        EXPECT_GT(s.nodesFetched, 0u);
        EXPECT_LE(s.nodesFetched, changed) << "fetched nodes the update did not change";
        EXPECT_LE(s.bytesDownloaded, changedBytes);
        EXPECT_GT(s.adopted, 0u) << "unchanged nodes should come from the old version's blocks";
        EXPECT_EQ(s.failures, 0u) << s.lastError;
        EXPECT_TRUE(same(image(*client), freshImage(set(), camera, by))) << "the followed image differs from a fresh open's";
        if (stats) *stats = s;
    }

private:
    static inline std::unique_ptr<gpu::Context> context_;
    static inline std::string contextError_;
};

TEST_F(FollowTest, AnAddedScanShowsFetchingOnlyTheChangedNodes) {
    // Coloured by RGB, which the update leaves alone: the nodes that did
    // not change are drawn from the old version's GPU copies, not decoded.
    StreamStats s;
    expectFollowsTheAdd(set(), ColorBy::Auto, &s);
    EXPECT_GT(s.shared, 0u);
}

TEST_F(FollowTest, EqualDecodingKeysDecodeToEqualSurfels) {
    // What lets a follower draw an old version's copy of a node for the new
    // version (decodingKey): a node of the base set decoded under its
    // tileset.json and under changed ones that an update may bring. Where
    // the surfels differ, the keys must differ (else a follower would draw
    // wrong surfels); where the change leaves the surfels alone, the keys
    // should agree (else nothing is shared).
    auto reader = TilesetReader::open(set());
    ASSERT_TRUE(reader) << reader.status().message();
    const NodeRecord* node = &reader->nodes()[0];
    for (const NodeRecord& n : reader->nodes())
        if (n.surfelCount > node->surfelCount) node = &n;
    auto block = reader->readBlock(*node);
    ASSERT_TRUE(block) << block.status().message();
    auto surfels = [&](const TilesetInfo& info, const Coloring& coloring) {
        SurfelSet s = emptySurfelSet(info, coloring);
        appendNode(s, info, *node, *block);
        std::string bytes(reinterpret_cast<const char*>(s.surfels.data()), s.surfels.size() * sizeof(s.surfels[0]));
        return bytes;
    };
    const TilesetInfo base = reader->info();
    struct Change {
        const char* what;
        std::function<void(TilesetInfo&)> apply;
    };
    const std::vector<Change> changes = {
        {"intensity range", [](TilesetInfo& i) { i.statistics.intensityP98 += 100; }},
        {"elevation range", [](TilesetInfo& i) { i.statistics.elevationMax += 10; }},
        {"bounds (the origin)", [](TilesetInfo& i) { i.bounds.max.x += 10; }},
        {"class counts", [](TilesetInfo& i) { i.statistics.classCounts.push_back({40, 1000}); }},
    };
    size_t agreed = 0, differed = 0;
    for (ColorBy by : {ColorBy::Rgb, ColorBy::Intensity, ColorBy::Elevation, ColorBy::Classification}) {
        Coloring coloring;
        coloring.by = by;
        for (const Change& c : changes) {
            TilesetInfo changed = base;
            c.apply(changed);
            const bool sameSurfels = surfels(base, coloring) == surfels(changed, coloring);
            const bool sameKey = decodingKey(base, coloring) == decodingKey(changed, coloring);
            EXPECT_EQ(sameKey, sameSurfels) << colorByName(by) << ", " << c.what;
            (sameSurfels ? agreed : differed) += 1;
        }
        Coloring hidden = coloring;
        hidden.hidden[2] = true;
        EXPECT_NE(decodingKey(base, coloring), decodingKey(base, hidden)) << "hidden classes";
    }
    EXPECT_GT(agreed, 0u);
    EXPECT_GT(differed, 0u);
}

TEST_F(FollowTest, StaticHostAndServerArePolledWithETags) {
    // nginx serves the sets' folder as static files, surfcast-serve the
    // same folder; a follower of each sees the one --add. Each poll after the
    // first asks with If-None-Match and is answered 304 while nothing changed.
    test::Child server;
    const std::string origin = test::startServer(&server, dir.file("sets"));
    ASSERT_FALSE(origin.empty()) << server.log;
    struct ServerGuard {  // ends the server, whichever way the case ends
        int pid;
        ~ServerGuard() {
            ::kill(pid, SIGTERM);
            test::exitCode(pid);
        }
    } guard{server.pid};
    auto nginx = test::startNginx(dir.file("nginx"), 1, [&](const std::vector<int>& ports) {
        return " server { listen 127.0.0.1:" + std::to_string(ports[0]) + "; root " + dir.path() + ";\n"
               "  access_log " + dir.file("nginx/access.log") + "; }\n";
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string url = "http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/sets/s";

    auto served = this->open(origin + "/sets/s", 0.2);
    ASSERT_TRUE(served);
    const Camera camera = frameBox(served->info().bounds, double(kWidth) / kHeight);
    follow(*served, camera, [](const ClientFrame& f) { return f.converged; });
    // The static host's follower goes through the whole add; the server's
    // watcher sees it meanwhile, and its client is updated after.
    expectFollowsTheAdd(url);
    auto frames = follow(*served, camera, [](const ClientFrame& f) { return f.version == 1 && f.converged; });
    ASSERT_FALSE(frames.empty());
    EXPECT_TRUE(same(image(*served), freshImage(set(), camera))) << "surfcast-serve's follower differs from a fresh open";

    const std::string log = test::readFile(dir.file("nginx/access.log"));
    EXPECT_NE(log.find("\"GET /sets/s/tileset.json HTTP/1.1\" 304"), std::string::npos) << log.substr(0, 2000);
    httplib::Client metrics(origin);
    auto m = metrics.Get("/metrics");
    ASSERT_TRUE(m && m->status == 200);
    EXPECT_NE(m->body.find("surfcast_requests_total{route=\"tileset.json\",status=\"304\"}"), std::string::npos) << m->body;
}

TEST_F(FollowTest, TornAndVanishedVersionsAreRetriedNeverShown) {
    // tileset.json replaced by a torn copy, then by one that names a
    // hierarchy file that is not there: the follower reports each
    // (followError), keeps drawing the version it has, and takes the next
    // good version when it comes.
    Follower follower = convergedFollower();
    ASSERT_TRUE(follower.client);
    SurfcastClient* client = follower.client.get();
    const Camera camera = follower.camera;
    const uint32_t baseNodes = follower.nodes;
    const Image base = image(*client);
    const std::string json = test::readFile(set() + "/tileset.json");
    auto replace = [&](const std::string& bytes) { replaceFile(set() + "/tileset.json", bytes); };
    std::vector<ClientFrame> frames;
    const size_t named = json.find("\"hierarchy.bin\"");
    ASSERT_NE(named, std::string::npos);
    std::string vanished = json;
    vanished.replace(named, 15, "\"hierarchy-0badf00d.bin\"");
    const std::pair<std::string, std::string> cases[] = {{json.substr(0, json.size() / 2), "tileset.json"},
                                                         {vanished, "hierarchy-0badf00d.bin"}};
    for (const auto& c : cases) {
        const std::string& named = c.second;
        replace(c.first);
        frames = follow(*client, camera, [&](const ClientFrame& f) { return f.followError.find(named) != std::string::npos; });
        ASSERT_FALSE(frames.empty());
        expectOnlyTheBase(frames, baseNodes);
        EXPECT_FALSE(frames.back().followError.empty());
    }
    EXPECT_TRUE(same(image(*client), base));
    replace(json);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    frames = follow(*client, camera, [](const ClientFrame& f) { return f.version == 1 && f.converged; });
    ASSERT_FALSE(frames.empty());
    EXPECT_TRUE(frames.back().followError.empty()) << frames.back().followError;
    EXPECT_TRUE(same(image(*client), freshImage(set(), camera)));
}

TEST_F(FollowTest, ANewVersionThatFailsIsOpenedAgainOnceItReads) {
    // The update's new block file damaged before the follower fetches from it:
    // the version loading gives up (its blocks fail their CRCs) and is
    // dropped, the version drawn stays; once the file reads again, the next
    // poll opens that version anew, although its tileset.json never changed.
    Follower follower = convergedFollower();
    ASSERT_TRUE(follower.client);
    SurfcastClient* client = follower.client.get();
    const Camera camera = follower.camera;
    const uint32_t baseNodes = follower.nodes;
    std::set<std::string> before;
    for (const auto& e : fs::directory_iterator(set())) before.insert(e.path().filename().string());
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    std::string blocks;
    for (const auto& e : fs::directory_iterator(set()))
        if (e.path().filename().string().rfind("blocks-", 0) == 0 && !before.count(e.path().filename().string()))
            blocks = e.path().string();
    ASSERT_FALSE(blocks.empty()) << "the update wrote no block file";
    const std::string good = test::readFile(blocks);
    std::string bad = good;
    for (char& c : bad) c = char(~c);
    replaceFile(blocks, bad);
    auto frames = follow(*client, camera, [](const ClientFrame& f) { return !f.followError.empty() && !f.loadingVersion; });
    ASSERT_FALSE(frames.empty());
    expectOnlyTheBase(frames, baseNodes);
    EXPECT_NE(frames.back().followError.find("CRC"), std::string::npos) << frames.back().followError;
    replaceFile(blocks, good);
    frames = follow(*client, camera, [](const ClientFrame& f) { return f.version == 1 && f.converged; });
    ASSERT_FALSE(frames.empty());
    EXPECT_EQ(frames.back().version, 1u);
    EXPECT_TRUE(same(image(*client), freshImage(set(), camera)));
}

// A build process that is killed (and waited for) when the guard goes,
// unless release()d: a case that fails midway leaves no stopped child.
struct BuildGuard {
    int pid = -1;
    ~BuildGuard() {
        if (pid <= 0) return;
        ::kill(pid, SIGKILL);
        test::exitCode(pid);
    }
    int release() { return std::exchange(pid, -1); }
};

// Holds the build `pid` still (SIGSTOP) once the set at `out` says
// `wanted`; false where the build ended first (60 s at most).
bool stopWhen(int pid, const std::string& out, const std::function<bool(const TilesetInfo&)>& wanted) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    auto says = [&] {
        auto info = readTilesetJson(test::readFile(out + "/tileset.json"), "tileset.json");
        return info && wanted(*info);
    };
    while (std::chrono::steady_clock::now() < deadline && ::kill(pid, 0) == 0) {
        if (fs::exists(out + "/tileset.json") && says()) {
            ::kill(pid, SIGSTOP);
            if (says()) return true;  // and not replaced meanwhile
            ::kill(pid, SIGCONT);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    return false;
}

// surfcast-build --preview of `cells` into `out`, started and stopped
// (SIGSTOP) as soon as the preview is there; `previewStride`: the stride of
// the set found there then (0, and a failure, where the build had replaced
// its preview already or none appeared). `interval`: --preview-interval.
BuildGuard startPreviewedBuild(const std::vector<std::string>& cells, const std::string& out, int* previewStride,
                               const std::string& interval = "2") {
    std::vector<std::string> args = {test::binary("surfcast-build"), "-q", "--threads", "1", "--memory", "64M", "--capacity", "1000",
                                     "--preview-points", "5000", "--preview-interval", interval, "-o", out};
    args.insert(args.end(), cells.begin(), cells.end());
    BuildGuard build{test::spawn(args).pid};
    EXPECT_TRUE(stopWhen(build.pid, out, [](const TilesetInfo&) { return true; })) << "no set appeared";
    auto reader = TilesetReader::open(out);
    *previewStride = reader ? int(reader->info().previewStride) : 0;
    EXPECT_GT(*previewStride, 1) << "no preview seen before the build ended: " << (reader ? "" : reader.status().message());
    return build;
}

TEST_F(FollowTest, APreviewComesFirstRefinesAsChunksAreBuiltAndEndsInTheBuildsOwnBytes) {
    // The build with --preview (a version after every chunk: its 14 chunks
    // are built one at a time), held still once its preview is published: a
    // follower shows the preview. Held again at a version with some chunks
    // built: that version is a whole set, its built chunks' nodes are the
    // finished set's (key, CRC and size), the others stand-ins, and the
    // follower switches to it. Let go, the build replaces it with the set a
    // build without --preview writes, byte for byte (the same -o: the build
    // record keeps it), and the follower switches to that set as a fresh open
    // of it draws it.
    std::vector<std::string> cells = base;
    cells.insert(cells.end(), added.begin(), added.end());
    const std::string out = dir.file("sets/previewed");
    std::vector<std::string> plain = {test::binary("surfcast-build"), "-q", "--threads", "1", "--memory", "64M", "--capacity", "1000",
                                      "-o", out};
    plain.insert(plain.end(), cells.begin(), cells.end());
    auto built = test::run(plain);
    ASSERT_EQ(built.exitCode, 0) << built.output;
    fs::rename(out, dir.file("plain"));

    int stride = 0;
    BuildGuard build = startPreviewedBuild(cells, out, &stride, "0");
    ASSERT_GT(stride, 1);
    auto client = this->open(out, 0.1);
    ASSERT_TRUE(client);
    EXPECT_EQ(client->info().previewStride, uint32_t(stride));
    EXPECT_EQ(client->info().previewDone, 0.0);
    const Camera camera = frameBox(client->info().bounds, double(kWidth) / kHeight);
    auto frames = follow(*client, camera, [](const ClientFrame& f) { return f.converged; });
    ASSERT_FALSE(frames.empty());
    EXPECT_GT(frames.back().nodes, 0u) << "the preview draws";
    EXPECT_EQ(frames.back().version, 0u);

    ::kill(build.pid, SIGCONT);
    ASSERT_TRUE(stopWhen(build.pid, out, [](const TilesetInfo& info) { return info.previewDone > 0; }))
        << "no version with chunks built appeared";
    auto refined = TilesetReader::open(out);
    ASSERT_TRUE(refined) << refined.status().message();
    auto verified = verifyTileset(*refined);
    EXPECT_TRUE(verified) << verified.status().message();
    EXPECT_GT(refined->info().previewStride, 1u);  // about 5,000 of the 110,000 points, from the plan's count
    EXPECT_LT(refined->info().previewDone, 1.0);
    frames = follow(*client, camera, [](const ClientFrame& f) { return f.version >= 1 && f.converged; });
    ASSERT_FALSE(frames.empty());
    EXPECT_GT(client->info().previewDone, 0.0) << "the follower shows the version with chunks built";

    ::kill(build.pid, SIGCONT);
    EXPECT_EQ(test::exitCode(build.release()), 0);
    frames = follow(*client, camera, [&](const ClientFrame& f) { return f.converged && client->info().previewStride == 0; });
    ASSERT_FALSE(frames.empty());
    EXPECT_TRUE(same(image(*client), freshImage(out, camera)));
    EXPECT_EQ(update_test::folderFiles(out), update_test::folderFiles(dir.file("plain")))
        << "the build with --preview wrote other bytes than without";

    // The refined version: the built chunks' nodes are the set's; the rest
    // stand in with fewer surfels (every Nth point).
    auto finished = TilesetReader::open(out);
    ASSERT_TRUE(finished) << finished.status().message();
    std::set<std::tuple<NodeKey, uint32_t, uint32_t>> final;
    for (const NodeRecord& n : finished->nodes()) final.insert({n.key, n.blockCrc, n.blockSize});
    size_t shared = 0;
    for (const NodeRecord& n : refined->nodes()) shared += final.count({n.key, n.blockCrc, n.blockSize});
    EXPECT_GT(shared, 0u) << "no node of a built chunk in the version";
    EXPECT_LT(shared, refined->nodes().size());
    EXPECT_LT(refined->info().surfels, finished->info().surfels);
}

TEST_F(FollowTest, AKilledBuildLeavesItsPreviewOrTheSetThatWasThere) {
    // Killed after its preview, a build leaves the preview, whole and
    // readable; killed later, the last version it published, which a build
    // run again replaces with its own preview. Over a set that is there
    // already no preview is written, and a killed build leaves that set.
    std::vector<std::string> cells = base;
    const std::string out = dir.file("sets/killed");
    int stride = 0;
    {
        BuildGuard build = startPreviewedBuild(cells, out, &stride);  // killed here
    }
    ASSERT_GT(stride, 1);
    auto reader = TilesetReader::open(out);
    ASSERT_TRUE(reader) << reader.status().message();
    EXPECT_GT(reader->info().previewStride, 1u);
    auto verified = verifyTileset(*reader);
    EXPECT_TRUE(verified) << verified.status().message();

    // Killed at a version with chunks built, it leaves that version.
    const std::string refined = dir.file("sets/killed-refining");
    {
        BuildGuard build = startPreviewedBuild(cells, refined, &stride, "0");
        ::kill(build.pid, SIGCONT);
        ASSERT_TRUE(stopWhen(build.pid, refined, [](const TilesetInfo& info) { return info.previewDone > 0; }));
    }
    reader = TilesetReader::open(refined);
    ASSERT_TRUE(reader) << reader.status().message();
    EXPECT_GT(reader->info().previewDone, 0.0);
    verified = verifyTileset(*reader);
    EXPECT_TRUE(verified) << verified.status().message();
    // Built again, over what the killed build left: a new preview first (that is no finished set).
    std::vector<std::string> again = {test::binary("surfcast-build"), "--preview", "--threads", "1", "--preview-points", "5000", "-o", refined};
    again.insert(again.end(), cells.begin(), cells.end());
    auto rebuilt = test::run(again);
    EXPECT_EQ(rebuilt.exitCode, 0) << rebuilt.output;
    EXPECT_NE(rebuilt.output.find("preview: " + refined + ", 1 in"), std::string::npos) << rebuilt.output;

    const std::map<std::string, std::string> before = update_test::folderFiles(set());
    std::vector<std::string> args = {test::binary("surfcast-build"), "--preview", "--threads", "1", "-o", set()};
    args.insert(args.end(), cells.begin(), cells.end());
    test::Child child = test::spawn(args);
    BuildGuard build{child.pid};
    EXPECT_TRUE(child.waitFor("none written")) << child.log;
    ::kill(build.pid, SIGSTOP);  // the build has begun (the preview step is behind it)
    EXPECT_EQ(update_test::folderFiles(set()), before) << "the set there should stay as it was";
    EXPECT_EQ(child.log.find("preview: " + set() + ","), std::string::npos) << child.log;
}

TEST_F(FollowTest, APreviewReadsWhatTheBuildReads) {
    // --attributes gps_time: the preview's sample decodes the scalar field
    // the build stores, as the build's own reading does.
    const std::string out = dir.file("sets/timed");
    std::vector<std::string> args = {test::binary("surfcast-build"), "--preview-points", "5000", "--attributes", "gps_time",
                                     "--threads", "1", "-o", out};
    args.insert(args.end(), base.begin(), base.end());
    auto r = test::run(args);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("preview: " + out + ", 1 in"), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find("no preview"), std::string::npos) << r.output;
    auto reader = TilesetReader::open(out);
    ASSERT_TRUE(reader) << reader.status().message();
    EXPECT_TRUE(reader->info().attribute("gps_time")) << "the set stores gps_time";
}

TEST_F(FollowTest, PreviewsAreForBuildsIntoFolders) {
    for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
             {"--preview", base[0], "-o", "s3://bucket/set"}, {"--preview", "--add", added[0], "--to", set()}}) {
        std::vector<std::string> command = {test::binary("surfcast-build")};
        command.insert(command.end(), args.begin(), args.end());
        auto r = test::run(command);
        EXPECT_EQ(r.exitCode, 2) << r.output;
        EXPECT_NE(r.output.find("--preview"), std::string::npos) << r.output;
    }
}

}  // namespace
}  // namespace surfcast
