// Streaming under faults (client/stream/streamer): a server restart, 500s and
// a stalled response end converged; refusals, corrupt blocks and pages, a node
// over the GPU budget and a rebuilt set stop the stream at once, naming what
// failed; over-long responses are cut off; closing does not wait for a stalled
// host; an unreachable server is a clear error, not a hang; a write to a
// closed socket does not kill the client (SIGPIPE); blocks fetched again to
// recolour fail like any fetch.

#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <set>
#include <thread>

#include "crc32.h"
#include "sigpipe.h"
#include "stream_support.h"
#include "streamer.h"
#include "test_support.h"

namespace surfcast {
namespace {

using test::binary;
using test::run;
using test::TempDir;
using test::startServer;

TEST(Stream, UnreachableServerIsAClearError) {
    TempDir dir;
    auto start = std::chrono::steady_clock::now();
    // Port 1 on loopback: nothing listens there.
    auto r = run({binary("surfcast-view"), "--headless", "http://127.0.0.1:1/sets/scene", "--lod", "1", "--out",
                  dir.file("x.png")});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("http://127.0.0.1:1/sets/scene"), std::string::npos) << r.output;
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(30));
}

// Serves `host` on a free loopback port from a thread of its own, waiting up
// to 10 s for it to listen; stopped and joined however the test leaves.
struct Serving {
    explicit Serving(httplib::Server& server) : host(server), port(server.bind_to_any_port("127.0.0.1")) {
        thread = std::thread([this] { host.listen_after_bind(); });
        for (int i = 0; i < 1000 && !host.is_running(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ~Serving() {
        host.stop();
        if (thread.joinable()) thread.join();
    }
    httplib::Server& host;
    const int port;
    std::thread thread;
};

StreamOptions connections(int n) {
    StreamOptions o;
    o.connections = n;
    return o;
}

// Update until converged (or the deadline); returns whether it converged.
// The nodes drawn are named by key: indices follow the order in which
// hierarchy pages arrived, which differs between streams with other pasts.
bool streamUntilConverged(StreamingSet& stream, const Camera& camera, std::vector<NodeKey>* drawn, double seconds) {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < deadline) {
        StreamUpdate u = stream.update(camera, 200, 150, {});
        if (u.converged) {
            drawn->clear();
            for (const auto& s : u.draw) drawn->push_back(stream.nodes()[s.index].key);
            std::sort(drawn->begin(), drawn->end());
            return true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
}

// A stream that must stop: updates from `camera` (the usual test camera by
// default) until it gives up or notices that its set changed (at most
// `seconds`), expecting no convergence, and returns its stats.
StreamStats streamUntilStopped(StreamingSet& stream, double seconds, const char* camera = "3,-6,2,0,0,0.5,0,0,1,50") {
    auto view = parseCamera(camera);
    EXPECT_TRUE(view);
    auto stopped = [&] { return stream.stats().gaveUp || stream.stats().setChanged; };
    auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < deadline && !stopped()) {
        const bool converged = stream.update(*view, 200, 150, {}).converged;
        if (!stopped()) {  // (a stream that has stopped may report what it holds as converged)
            EXPECT_FALSE(converged);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return stream.stats();
}

// A stream that must fail: as above, and expects that it gave up.
StreamStats streamUntilGaveUp(StreamingSet& stream, double seconds) {
    StreamStats st = streamUntilStopped(stream, seconds);
    EXPECT_TRUE(st.gaveUp) << st.lastError;
    return st;
}

TEST(Stream, SurvivesTheServerRestartingAndFlakyResponses) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/scene"), 100000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto first = parseCamera("3,-6,2,0,0,0.5,0,0,1,50"), second = parseCamera("-4,5,1.5,0,0,0.5,0,0,1,50");
    ASSERT_TRUE(first && second);
    // What a healthy stream converges to, from the folder.
    auto local = StreamingSet::open(dir.file("sets/scene"));
    ASSERT_TRUE(local) << local.status().message();
    std::vector<NodeKey> expectFirst, expectSecond;
    ASSERT_TRUE(streamUntilConverged(**local, *first, &expectFirst, 30));
    ASSERT_TRUE(streamUntilConverged(**local, *second, &expectSecond, 30));

    // 1. The server stops after the first view and comes back on the same port.
    test::Child server;
    const std::string origin = startServer(&server, dir.file("sets"));
    ASSERT_FALSE(origin.empty()) << server.log;
    auto remote = StreamingSet::open(origin + "/sets/scene", connections(4));
    ASSERT_TRUE(remote) << remote.status().message();
    std::vector<NodeKey> drawn;
    ASSERT_TRUE(streamUntilConverged(**remote, *first, &drawn, 30));
    EXPECT_EQ(drawn, expectFirst);
    ::kill(server.pid, SIGTERM);
    ASSERT_EQ(test::exitCode(server.pid), 0);
    // Server gone: the second view cannot converge, but drawing goes on with
    // what is resident, and the failures are counted.
    EXPECT_FALSE(streamUntilConverged(**remote, *second, &drawn, 1.0));
    EXPECT_GT((*remote)->stats().failures, 0u);
    // The same port again: tried until the old listening socket is gone
    // (or 10 s), not assumed free the moment the old server exited.
    test::Child again;
    for (int i = 0; i < 100; ++i) {
        if (startServer(&again, dir.file("sets"), origin.substr(7)) == origin) break;
        test::exitCode(again.pid);
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    ASSERT_NE(again.log.find(origin), std::string::npos) << again.log;
    ASSERT_TRUE(streamUntilConverged(**remote, *second, &drawn, 30)) << (*remote)->stats().lastError;
    EXPECT_EQ(drawn, expectSecond);
    ::kill(again.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(again.pid), 0);

    // 2. A static host (cpp-httplib on loopback) whose first three block
    // responses fail in turn, each a transient fault: a 500, a response that
    // stalls past the client's timeout, and a 429. Retries succeed.
    httplib::Server host;
    std::atomic<int> served{0};
    const std::string blocksPath = dir.file("sets/scene/blocks.bin");
    host.set_mount_point("/static", dir.file("sets/scene"));
    host.Get("/flaky/blocks.bin", [&](const httplib::Request& req, httplib::Response& res) {
        std::string all = test::readFile(blocksPath);
        unsigned long long from = 0, to = 0;
        if (std::sscanf(req.get_header_value("Range").c_str(), "bytes=%llu-%llu", &from, &to) != 2 || to < from ||
            to >= all.size()) {
            res.status = 416;
            return;
        }
        switch (served.fetch_add(1)) {
        case 0:
            res.status = 500;
            return;
        case 1:
            std::this_thread::sleep_for(std::chrono::milliseconds(2500));  // the client gave up after 1 s
            break;
        case 2:
            res.status = 429;
            return;
        }
        res.set_content(all, "application/octet-stream");
    });
    host.Get(R"(/flaky/(tileset\.json|hierarchy\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        res.set_content(test::readFile(dir.file("sets/scene/" + std::string(req.matches[1]))), "application/octet-stream");
    });
    const Serving serving(host);
    ASSERT_TRUE(host.is_running());
    const int port = serving.port;
    StreamOptions one = connections(1);  // one at a time: the faults hit in order
    one.http.timeoutSeconds = 1;
    auto flaky = StreamingSet::open("http://127.0.0.1:" + std::to_string(port) + "/flaky", one);
    ASSERT_TRUE(flaky) << flaky.status().message();
    ASSERT_TRUE(streamUntilConverged(**flaky, *first, &drawn, 60)) << (*flaky)->stats().lastError;
    EXPECT_EQ(drawn, expectFirst);
    EXPECT_GE((*flaky)->stats().failures, 3u);
    EXPECT_GE(served.load(), 4);
    // The 429 was the last fault (one connection: in order).
    EXPECT_NE((*flaky)->stats().lastError.find("HTTP 429"), std::string::npos) << (*flaky)->stats().lastError;
    // The same set from the static mount (Range by cpp-httplib itself) converges too.
    auto mounted = StreamingSet::open("http://127.0.0.1:" + std::to_string(port) + "/static", connections(2));
    ASSERT_TRUE(mounted) << mounted.status().message();
    ASSERT_TRUE(streamUntilConverged(**mounted, *second, &drawn, 30)) << (*mounted)->stats().lastError;
    EXPECT_EQ(drawn, expectSecond);
}

TEST(Stream, ABlockPastTheEndOfBlocksBinIsRejectedAtOpen) {
    // A hierarchy record whose block reaches past blocks.bin, with every CRC
    // valid, is rejected when the set opens, with the node named (the same
    // check the local reader and the server make), rather than asked for and
    // retried forever.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto info = readTilesetJson(test::readFile(dir.file("scene/tileset.json")), "tileset.json");
    ASSERT_TRUE(info) << info.status().message();
    const std::string h = test::readFile(dir.file("scene/hierarchy.bin"));
    auto nodes = readHierarchy(std::vector<uint8_t>(h.begin(), h.end()), "hierarchy.bin");
    ASSERT_TRUE(nodes) << nodes.status().message();
    for (NodeRecord& n : *nodes)
        if (n.key == NodeKey{}) n.blockSize = uint32_t(4u << 30) - 1;  // about 4 GB
    const std::vector<uint8_t> crafted = writeHierarchy(*nodes, info->pageDepth);
    info->hierarchyBytes = crafted.size();
    info->hierarchyCrc = crc32(crafted.data(), crafted.size());
    test::writeFile(dir.file("scene/hierarchy.bin"), std::string(crafted.begin(), crafted.end()));
    test::writeFile(dir.file("scene/tileset.json"), writeTilesetJson(*info));

    auto opened = StreamingSet::open(dir.file("scene"));
    ASSERT_FALSE(opened) << "a set with a block past the end of blocks.bin opened";
    EXPECT_NE(opened.status().message().find("node 0-0-0-0 points past the end of blocks.bin"), std::string::npos)
        << opened.status().message();
    auto view = run({binary("surfcast-view"), "--headless", dir.file("scene"), "--lod", "1", "--size", "64x48", "--out",
                     dir.file("x.png")});
    EXPECT_EQ(view.exitCode, 1) << view.output;
    EXPECT_NE(view.output.find("points past the end of blocks.bin"), std::string::npos) << view.output;

    // tileset.json may lie about blocks.bin's size too; from a folder, the
    // range is checked against the file before any buffer is sized by it.
    info->blocksBytes = uint64_t(1) << 40;
    test::writeFile(dir.file("scene/tileset.json"), writeTilesetJson(*info));
    StreamOptions options;
    options.maxTries = 2;
    auto lying = StreamingSet::open(dir.file("scene"), options);
    ASSERT_TRUE(lying) << lying.status().message();
    const StreamStats st = streamUntilGaveUp(**lying, 3);
    EXPECT_NE(st.lastError.find("reach past the end of the file"), std::string::npos) << st.lastError;
}

TEST(Stream, ACorruptBlockStopsTheStreamAtOnce) {
    // One block fails its CRC (a damaged copy: the set's bytes are fixed, so
    // reading it again gives the same bytes). The stream stops fetching at
    // the first failure and says which node, and surfcast-view exits
    // non-zero at once, not after 8 retries over about 11 s.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto info = readTilesetJson(test::readFile(dir.file("scene/tileset.json")), "tileset.json");
    ASSERT_TRUE(info) << info.status().message();
    const std::string h = test::readFile(dir.file("scene/hierarchy.bin"));
    auto nodes = readHierarchy(std::vector<uint8_t>(h.begin(), h.end()), "hierarchy.bin");
    ASSERT_TRUE(nodes) << nodes.status().message();
    const NodeRecord root = nodes->front();  // breadth-first: the root, which every view needs
    ASSERT_EQ(root.key, NodeKey{});
    std::string blocks = test::readFile(dir.file("scene/blocks.bin"));
    blocks[size_t(root.blockOffset + root.blockSize / 2)] ^= 0x5A;
    test::writeFile(dir.file("scene/blocks.bin"), blocks);

    StreamOptions options;
    options.maxTries = 3;
    auto set = StreamingSet::open(dir.file("scene"), options);
    ASSERT_TRUE(set) << set.status().message();
    StreamStats st = streamUntilGaveUp(**set, 5);
    EXPECT_EQ(st.failures, 1u) << st.lastError;
    EXPECT_NE(st.lastError.find("node 0-0-0-0: failed, not retried"), std::string::npos) << st.lastError;
    EXPECT_NE(st.lastError.find("CRC"), std::string::npos) << st.lastError;
    EXPECT_FALSE(st.setChanged);
    // Fetching stopped.
    auto camera = parseCamera("3,-6,2,0,0,0.5,0,0,1,50");
    std::vector<NodeKey> drawn;
    EXPECT_FALSE(streamUntilConverged(**set, *camera, &drawn, 0.5));
    EXPECT_EQ((*set)->stats().failures, 1u);

    // The program, at its defaults.
    auto view = run({binary("surfcast-view"), "--headless", dir.file("scene"), "--camera", "3,-6,2,0,0,0.5,0,0,1,50", "--lod", "1",
                     "--size", "64x48", "--max-wait", "120", "--out", dir.file("x.png")});
    EXPECT_EQ(view.exitCode, 1) << view.output;
    EXPECT_NE(view.output.find("node 0-0-0-0: failed, not retried"), std::string::npos) << view.output;
}

TEST(Stream, RefusalsFailAtOnceAndServerFaultsAreRetried) {
    // One rule in both clients (web/src/source.ts): 4xx other than 408 and
    // 429 will be answered the same way again, so the stream stops at the
    // first; 5xx, 408 and 429 are retried with backoff up to maxTries.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    httplib::Server host;
    std::atomic<int> blockRequests{0};
    host.Get(R"(/(\d+)/(tileset\.json|hierarchy\.bin|blocks\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        const std::string name = req.matches[2];
        if (name == "blocks.bin") {
            ++blockRequests;
            res.status = std::stoi(req.matches[1]);
            return;
        }
        res.set_content(test::readFile(dir.file("scene/" + name)), "application/octet-stream");
    });
    const Serving serving(host);
    ASSERT_TRUE(host.is_running());
    const int port = serving.port;
    for (int status : {403, 404, 410, 503, 429, 408}) {
        SCOPED_TRACE(status);
        StreamOptions options = connections(1);
        options.maxTries = 3;
        blockRequests = 0;
        auto set = StreamingSet::open("http://127.0.0.1:" + std::to_string(port) + "/" + std::to_string(status), options);
        ASSERT_TRUE(set) << set.status().message();
        const StreamStats st = streamUntilGaveUp(**set, 5);
        EXPECT_NE(st.lastError.find("blocks.bin: HTTP " + std::to_string(status)), std::string::npos) << st.lastError;
        const bool transient = status >= 500 || status == 429 || status == 408;
        EXPECT_EQ(st.failures, transient ? 3u : 1u) << st.lastError;
        EXPECT_EQ(blockRequests.load(), transient ? 3 : 1);
        EXPECT_NE(st.lastError.find(transient ? ": gave up after 3 tries" : ": failed, not retried"), std::string::npos)
            << st.lastError;
    }
}

// Blocks fetched again to recolour (their kept copies gone: a block cache
// of one byte) fail like any fetch: a block that fails its CRC stops the
// stream naming the node (dropped quietly, it would leave the old colours
// and a converged view). A recolouring after the stream stopped re-decodes
// what is kept and converges (fetches queued for the stopped stream would
// never be made: the fetch threads would spin and no update converge).
TEST(Stream, BlocksFetchedAgainToRecolourFailLikeAnyFetch) {
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    httplib::Server host;
    std::atomic<bool> corrupt{false};
    host.Get(R"(/(tileset\.json|hierarchy\.bin|blocks\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        const std::string name = req.matches[1];
        std::string bytes = test::readFile(dir.file("scene/" + name));
        if (name == "blocks.bin" && corrupt)
            for (char& c : bytes) c = char(~c);
        // httplib answers Range requests from the whole content.
        res.set_content(bytes, "application/octet-stream");
    });
    const Serving serving(host);
    ASSERT_TRUE(host.is_running());
    const int port = serving.port;
    StreamOptions options = connections(2);
    options.keptBudget = 1;
    auto set = StreamingSet::open("http://127.0.0.1:" + std::to_string(port), options);
    ASSERT_TRUE(set) << set.status().message();
    auto camera = parseCamera("3,-6,2,0,0,0.5,0,0,1,50");
    ASSERT_TRUE(camera);
    std::vector<NodeKey> drawn;
    ASSERT_TRUE(streamUntilConverged(**set, *camera, &drawn, 20));
    EXPECT_EQ((*set)->stats().keptBytes, 0u);

    corrupt = true;
    Coloring elevation;
    elevation.by = ColorBy::Elevation;
    (*set)->setColoring(elevation);
    const StreamStats st = streamUntilGaveUp(**set, 10);
    EXPECT_NE(st.lastError.find("CRC mismatch"), std::string::npos) << st.lastError;
    EXPECT_GT(st.refetched, 0u);

    Coloring rgb;
    rgb.by = ColorBy::Rgb;
    (*set)->setColoring(rgb);
    EXPECT_TRUE(streamUntilConverged(**set, *camera, &drawn, 3)) << "a recolouring after the stream stopped never converged";
    EXPECT_TRUE((*set)->stats().gaveUp);
}

// Hierarchy pages are fetched as traversal reaches them and checked as they
// arrive: a damaged page stops the stream at once, like a damaged block,
// naming the page, while page 0 (checked at open) keeps drawing.
TEST(Stream, APersistentlyCorruptHierarchyPageGivesUpNamingIt) {
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "500", "--page-depth", "2"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const std::string h = test::readFile(dir.file("scene/hierarchy.bin"));
    auto index = readHierarchyIndex(std::span(reinterpret_cast<const uint8_t*>(h.data()), h.size()), h.size(), "h");
    ASSERT_TRUE(index) << index.status().message();
    ASSERT_GT(index->pages.size(), 2u);
    std::string damaged = h;
    for (size_t p = 1; p < index->pages.size(); ++p) damaged[size_t(index->pages[p].offset) + 40] ^= 0x5A;  // a spacing byte
    test::writeFile(dir.file("scene/hierarchy.bin"), damaged);
    StreamOptions options = connections(1);  // one page at a time: the first failure is the last
    options.maxTries = 2;
    auto set = StreamingSet::open(dir.file("scene"), options);
    ASSERT_TRUE(set) << set.status().message();
    const StreamStats st = streamUntilGaveUp(**set, 5);
    EXPECT_NE(st.lastError.find("/hierarchy.bin: page "), std::string::npos) << st.lastError;
    EXPECT_NE(st.lastError.find(": failed, not retried"), std::string::npos) << st.lastError;
    EXPECT_NE(st.lastError.find("CRC mismatch"), std::string::npos) << st.lastError;
    EXPECT_EQ(st.failures, 1u) << st.lastError;  // not retried
    EXPECT_EQ(st.pages, 1u) << "only page 0 passed its check";
    EXPECT_GT(st.resident, 0u) << "page 0's nodes kept streaming";
}

// A node larger than the memory budget could never be resident. One in
// page 0 fails open(); one in a later page stops the stream when that page
// arrives, naming the node, before the page joins the tree (checked after
// the hand-over and evictions, every later update would fail on it). The
// stream keeps what it has.
TEST(Stream, ANodeLargerThanTheBudgetStopsTheStreamNamingIt) {
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "500", "--page-depth", "2"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    // An octree's largest nodes are near its root, in page 0 (levels 0 and
    // 1 here). So every node below claims more surfels than a budget that
    // holds page 0 twice over: the check reads the records, before any block.
    const std::string h = test::readFile(dir.file("scene/hierarchy.bin"));
    auto all = readHierarchy(std::vector<uint8_t>(h.begin(), h.end()), "hierarchy.bin");
    ASSERT_TRUE(all) << all.status().message();
    uint32_t pageZeroMost = 0, pageZeroAll = 0;
    for (const NodeRecord& r : *all)
        if (r.key.level < 2) pageZeroMost = std::max(pageZeroMost, r.surfelCount), pageZeroAll += r.surfelCount;
    for (NodeRecord& r : *all)
        if (r.key.level >= 2) r.surfelCount = 2 * pageZeroAll + 1;
    const std::vector<uint8_t> inflated = writeHierarchy(*all, 2);
    ASSERT_EQ(inflated.size(), h.size());
    test::writeFile(dir.file("scene/hierarchy.bin"), std::string(inflated.begin(), inflated.end()));

    StreamOptions options = connections(1);  // granule 1: a node needs 32 bytes per surfel
    options.memoryBudget = 32 * size_t(pageZeroMost) - 1;
    auto refused = StreamingSet::open(dir.file("scene"), options);
    ASSERT_FALSE(refused);
    EXPECT_NE(refused.status().message().find("KiB resident, more than the memory budget of"), std::string::npos)
        << refused.status().message();

    options.memoryBudget = 32 * 2 * size_t(pageZeroAll);  // page 0 fits, and room to refine
    auto set = StreamingSet::open(dir.file("scene"), options);
    ASSERT_TRUE(set) << set.status().message();
    const StreamStats st = streamUntilGaveUp(**set, 10);
    EXPECT_NE(st.lastError.find(": node "), std::string::npos) << st.lastError;
    EXPECT_NE(st.lastError.find("KiB resident, more than the memory budget of"), std::string::npos) << st.lastError;
    EXPECT_EQ(st.pages, 2u) << "page 0 and the page that stopped it";
    EXPECT_GT(st.resident, 0u) << "what page 0 brought stays drawable";
    for (const NodeRecord& r : (*set)->nodes()) EXPECT_LT(r.key.level, 2) << r.key.name() << " joined the tree";
}

TEST(Stream, ResponsesLongerThanAskedForAreCutOff) {
    // A broken or hostile host answers with more than was asked for: a huge
    // tileset.json, a range response longer than the range. The client keeps
    // no more than it expects and says so, instead of holding all of it.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const std::string huge(40u << 20, ' ');  // 40 MiB: whitespace, valid JSON padding
    httplib::Server host;
    host.Get(R"(/(\w+)/(tileset\.json|hierarchy\.bin|blocks\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        const std::string name = req.matches[2], mode = req.matches[1];
        std::string content = test::readFile(dir.file("scene/" + name));
        if (mode == "bigjson" && name == "tileset.json") content += huge;
        if (name == "blocks.bin") {
            if (mode != "longrange") {
                res.status = 404;
                return;
            }
            // "Partial", but the whole file and more, chunked so that the
            // library does not cut it to the range.
            res.status = 206;
            content += huge;
            res.set_chunked_content_provider("application/octet-stream", [content](size_t offset, httplib::DataSink& sink) {
                if (offset >= content.size()) {
                    sink.done();
                    return true;
                }
                const size_t n = std::min<size_t>(1 << 20, content.size() - offset);
                return sink.write(content.data() + offset, n);
            });
            return;
        }
        res.set_content(content, "application/octet-stream");
    });
    const Serving serving(host);
    ASSERT_TRUE(host.is_running());
    const int port = serving.port;
    const std::string origin = "http://127.0.0.1:" + std::to_string(port);

    auto big = StreamingSet::open(origin + "/bigjson");
    ASSERT_FALSE(big);
    EXPECT_NE(big.status().message().find("tileset.json: response longer than the 16777216 bytes expected"), std::string::npos)
        << big.status().message();

    StreamOptions options = connections(1);
    options.maxTries = 1;
    auto longRange = StreamingSet::open(origin + "/longrange", options);
    ASSERT_TRUE(longRange) << longRange.status().message();
    const StreamStats st = streamUntilGaveUp(**longRange, 3);
    EXPECT_NE(st.lastError.find("blocks.bin: response longer than the"), std::string::npos) << st.lastError;
}

TEST(Stream, ClosingDoesNotWaitForAStalledHost) {
    // A host that answers tileset.json and hierarchy.bin but never a block:
    // closing a stream, or surfcast-view once its --max-wait is up, once
    // waited for the requests in flight to time out (20 s by default). The
    // transfers are cancelled instead.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    httplib::Server host;
    std::atomic<bool> release{false};
    std::atomic<int> stalled{0};
    host.Get(R"(/scene/(tileset\.json|hierarchy\.bin|blocks\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        const std::string name = req.matches[1];
        if (name == "blocks.bin") {
            ++stalled;
            for (int i = 0; i < 600 && !release; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
            res.status = 503;
            return;
        }
        res.set_content(test::readFile(dir.file("scene/" + name)), "application/octet-stream");
    });
    const int port = host.bind_to_any_port("127.0.0.1");
    std::thread serving([&] { host.listen_after_bind(); });
    struct Stop {
        httplib::Server& host;
        std::thread& thread;
        std::atomic<bool>& release;
        ~Stop() {
            release = true;
            host.stop();
            if (thread.joinable()) thread.join();
        }
    } stop{host, serving, release};
    for (int i = 0; i < 500 && !host.is_running(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_TRUE(host.is_running());
    const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/scene";

    auto set = StreamingSet::open(url, connections(2));
    ASSERT_TRUE(set) << set.status().message();
    auto camera = parseCamera("3,-6,2,0,0,0.5,0,0,1,50");
    ASSERT_TRUE(camera);
    for (int i = 0; i < 500 && (*set)->stats().requestsInFlight == 0; ++i) {
        (void)(*set)->update(*camera, 200, 150, {});
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ASSERT_GT((*set)->stats().requestsInFlight, 0u);
    auto start = std::chrono::steady_clock::now();
    set->reset();
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(1));

    start = std::chrono::steady_clock::now();
    auto view = run({binary("surfcast-view"), "--headless", url, "--camera", "3,-6,2,0,0,0.5,0,0,1,50", "--lod", "1",
                     "--size", "64x48", "--max-wait", "1", "--out", dir.file("x.png")});
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_LT(seconds, 8.0) << view.output;  // 1 s of waiting, the process's start and the Vulkan device's
    EXPECT_GE(stalled.load(), 2);
}

TEST(Stream, ARebuiltSetIsReportedNotRetriedForever) {
    // The set is rebuilt on the server (renamed over the old folder) while a
    // client streams it: its hierarchy no longer matches blocks.bin. The
    // client notices from tileset.json after the first fault, stops fetching
    // and says so, instead of retrying blocks that can never match.
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto build = [&](int points) {
        auto b = test::buildScene(dir.file("sets/scene"), points, {"--capacity", "2000"});
        ASSERT_EQ(b.exitCode, 0) << b.output;
    };
    build(60000);
    test::Child server;
    const std::string origin = startServer(&server, dir.file("sets"));
    ASSERT_FALSE(origin.empty()) << server.log;
    auto remote = StreamingSet::open(origin + "/sets/scene", connections(2));
    ASSERT_TRUE(remote) << remote.status().message();
    auto first = parseCamera("3,-6,2,0,0,0.5,0,0,1,50"), second = parseCamera("0,0,1,5,5,0.5,0,0,1,70");
    std::vector<NodeKey> drawn;
    ASSERT_TRUE(streamUntilConverged(**remote, *first, &drawn, 30));
    EXPECT_FALSE((*remote)->stats().setChanged);
    build(90000);
    StreamStats st = streamUntilStopped(**remote, 30, "0,0,1,5,5,0.5,0,0,1,70");
    EXPECT_TRUE(st.setChanged) << st.lastError;
    EXPECT_NE(st.lastError.find("changed since it was opened"), std::string::npos) << st.lastError;
    // Fetching stopped: no more requests go out.
    size_t requests = st.requests;
    EXPECT_FALSE(streamUntilConverged(**remote, *second, &drawn, 1));
    EXPECT_EQ((*remote)->stats().requests, requests);
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);
}

// Inputs at URLs (preprocess/readers/input_file.h) from a host that fails
// partway through a text file. A host that answers 404 past the first 64 KiB
// fails the build, naming the URL and the answer: the rows it did send are
// not taken for the whole file (a failed read is not an end). A host that
// answers each range 503 once, then serves it, is asked again: the build
// writes the same bytes as from the local file.
TEST(Inputs, AHostFailingMidFileFailsTheBuildOrIsAskedAgain) {
    TempDir dir;
    std::string rows;
    for (int i = 0; i < 20000; ++i)  // about 400 KB
        rows += std::to_string(i % 137) + " " + std::to_string(i / 137) + " " + std::to_string((i * 7) % 11) + " 10 20 30\n";
    test::writeFile(dir.file("rows.xyz"), rows);
    httplib::Server host;
    std::atomic<int> refused{0};
    std::mutex seenMutex;
    std::set<std::string> seen;  // ranges answered 503 once
    host.Get(R"(/(broken|flaky)/rows\.xyz)", [&](const httplib::Request& req, httplib::Response& res) {
        unsigned long long from = 0, to = 0;
        const std::string range = req.get_header_value("Range");
        if (std::sscanf(range.c_str(), "bytes=%llu-%llu", &from, &to) != 2 || to < from || from >= rows.size()) {
            res.status = 416;
            return;
        }
        to = std::min<unsigned long long>(to, rows.size() - 1);
        if (req.matches[1] == "broken" && to >= (64u << 10)) {
            res.status = 404;
            return;
        }
        if (req.matches[1] == "flaky") {
            std::lock_guard lock(seenMutex);
            if (seen.insert(range).second) {
                ++refused;
                res.status = 503;
                return;
            }
        }
        res.status = 206;
        res.set_header("Content-Range", "bytes " + std::to_string(from) + "-" + std::to_string(to) + "/" + std::to_string(rows.size()));
        res.set_content(rows.substr(from, to - from + 1), "application/octet-stream");
    });
    Serving serving(host);
    ASSERT_GT(serving.port, 0);
    const std::string url = "http://127.0.0.1:" + std::to_string(serving.port);
    auto broken = run({binary("surfcast-build"), "-q", url + "/broken/rows.xyz", "-o", dir.file("broken")});
    EXPECT_EQ(broken.exitCode, 1) << broken.output;
    EXPECT_NE(broken.output.find(url + "/broken/rows.xyz"), std::string::npos) << broken.output;
    EXPECT_NE(broken.output.find("HTTP 404"), std::string::npos) << broken.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("broken")));

    auto local = run({binary("surfcast-build"), "-q", dir.file("rows.xyz"), "-o", dir.file("local")});
    ASSERT_EQ(local.exitCode, 0) << local.output;
    auto flaky = run({binary("surfcast-build"), "-q", url + "/flaky/rows.xyz", "-o", dir.file("flaky")});
    ASSERT_EQ(flaky.exitCode, 0) << flaky.output;
    EXPECT_GE(refused.load(), 2) << "the size and the first range were each refused once";
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(test::readFile(dir.file("local/") + f) == test::readFile(dir.file("flaky/") + f)) << f;
}

}  // namespace
}  // namespace surfcast

// Writing to a socket whose peer has closed raises SIGPIPE, which ends the
// process by default; cpp-httplib 0.11.4 writes requests that way
// (common/sigpipe.h), and fuzz_client_response died of it (status 141).
// Inside SigpipeBlock, the one the tile source's I/O thread holds for its
// life, the write fails with EPIPE, the signal is taken, and the thread's mask
// is restored.
TEST(Stream, AWriteToAClosedSocketDoesNotKillTheClient) {
    int fds[2];
    ASSERT_EQ(::socketpair(AF_UNIX, SOCK_STREAM, 0, fds), 0);
    ::close(fds[1]);
    sigset_t before, after;
    pthread_sigmask(SIG_SETMASK, nullptr, &before);
    {
        surfcast::SigpipeBlock guard;
        errno = 0;
        EXPECT_EQ(::write(fds[0], "x", 1), -1);  // without the guard the process ends here
        EXPECT_EQ(errno, EPIPE);
    }
    pthread_sigmask(SIG_SETMASK, nullptr, &after);
    EXPECT_EQ(sigismember(&after, SIGPIPE), sigismember(&before, SIGPIPE));
    sigset_t pending;
    sigpending(&pending);
    EXPECT_EQ(sigismember(&pending, SIGPIPE), 0) << "the SIGPIPE raised was taken";
    ::close(fds[0]);
}