// The server over real HTTP on loopback: every endpoint, ranges, caching,
// traversal attempts, malformed and oversized requests, authentication,
// concurrency, stalled clients, a set replaced during a download, and the
// LAZ export sent as it is produced.
#include <gtest/gtest.h>

#include <cerrno>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <chrono>
#include <random>
#include <thread>

#include "byte_io.h"
#include "crc32.h"
#include "http_server.h"
#include "las_reader.h"
#include "laz_export.h"
#include "octree_builder.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace fs = std::filesystem;
using namespace surfcast;

namespace {

void buildScene(const std::string& out, uint64_t points, uint64_t seed) {
    BuildOptions o;
    o.output = out;
    o.progress = false;
    o.inputs.defaultScene = true;
    o.inputs.scene.targetPoints = points;
    o.inputs.scene.seed = seed;
    auto s = buildTileset(o);
    ASSERT_TRUE(s.ok()) << s.status().message();
}

// One small set shared by the tests (built once).
class ServerTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new test::TempDir;
        fs::create_directories(dir_->file("sets"));
        buildScene(dir_->file("sets/scene"), 40000, 1);
    }
    static void TearDownTestSuite() {
        delete big_;
        big_ = nullptr;
        delete dir_;
    }

    // A root holding "scene" and "big", a set whose whole export (about 5 MB)
    // is more than loopback's socket buffers hold (about 3 MB here: 4 MiB of
    // send buffer at most, tcp_wmem): a client that reads nothing keeps its
    // export, and its place, in progress. Built once, by the tests that need it.
    static std::string bigRoot() {
        if (!big_) {
            big_ = new test::TempDir;
            fs::create_directories(big_->file("sets"));
            fs::copy(dir_->file("sets/scene"), big_->file("sets/scene"), fs::copy_options::recursive);
            buildScene(big_->file("sets/big"), 1200000, 3);
        }
        return big_->file("sets");
    }

    void start(ServerConfig config = {}, const std::string& root = "") {
        auto store = TilesetStore::open(root.empty() ? dir_->file("sets") : root);
        ASSERT_TRUE(store.ok());
        store_ = std::move(*store);
        config.port = 0;
        config.log = LogLevel::Quiet;
        server_ = std::make_unique<HttpServer>(*store_, config);
        ASSERT_TRUE(server_->bind().ok());
        thread_ = std::thread([this] { server_->run(); });
    }
    void TearDown() override {
        if (server_) server_->stop();
        if (thread_.joinable()) thread_.join();
    }
    httplib::Client client() {
        httplib::Client c("127.0.0.1", server_->port());
        c.set_read_timeout(10, 0);
        return c;
    }
    std::string file(const std::string& name) { return test::readFile(dir_->file("sets/scene/" + name)); }

    // Sends raw bytes on a fresh connection; returns what comes back until close or timeout.
    // A raw TCP connection to the server, receives timing out after timeoutMs.
    int connectRaw(int timeoutMs) {
        int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in addr{};
        addr.sin_family = AF_INET;
        addr.sin_port = htons(uint16_t(server_->port()));
        addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
        timeval tv{timeoutMs / 1000, (timeoutMs % 1000) * 1000};
        ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
        return fd;
    }

    std::string raw(const std::string& bytes, int timeoutMs = 3000, bool firstDataOnly = false) {
        int fd = connectRaw(timeoutMs);
        ::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
        std::string out;
        char buf[4096];
        ssize_t n;
        while ((n = ::recv(fd, buf, sizeof buf, 0)) > 0) {
            out.append(buf, size_t(n));
            if (firstDataOnly) break;
        }
        ::close(fd);
        return out;
    }

    // A GET of `path` from a client that then reads nothing (a small receive
    // buffer: the bytes wait on the server's side); the connection, once its
    // status line is read into *status.
    int requestAndStall(const std::string& path, std::string* status) {
        int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        const int small = 4096;
        ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
        sockaddr_in addr{};
        addr.sin_family = AF_INET;
        addr.sin_port = htons(uint16_t(server_->port()));
        addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
        timeval tv{10, 0};
        ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
        const std::string request = "GET " + path + " HTTP/1.1\r\nHost: x\r\n\r\n";
        ::send(fd, request.data(), request.size(), MSG_NOSIGNAL);
        char head[12] = {};
        const ssize_t n = ::recv(fd, head, sizeof head, MSG_WAITALL);
        *status = std::string(head, size_t(std::max<ssize_t>(n, 0)));
        return fd;
    }

    // The exports in progress, from /metrics, once they number `want` (the
    // server frees an export's place when it notices its client gone, a
    // moment after the client leaves), or what they number after 60 s.
    int exportsInProgressOnce(int want) {
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
        int now = -1;
        while (true) {
            auto m = client().Get("/metrics");
            const std::string gauge = "\nsurfcast_exports_in_progress ";
            const size_t at = m ? m->body.find(gauge) : std::string::npos;
            now = at == std::string::npos ? -1 : std::atoi(m->body.c_str() + at + gauge.size());
            if (now == want || std::chrono::steady_clock::now() > deadline) return now;
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
    }

    static test::TempDir* dir_;
    static test::TempDir* big_;
    std::unique_ptr<TilesetStore> store_;
    std::unique_ptr<HttpServer> server_;
    std::thread thread_;
};
test::TempDir* ServerTest::dir_ = nullptr;
test::TempDir* ServerTest::big_ = nullptr;

}  // namespace

TEST_F(ServerTest, HealthSetsAndFiles) {
    start();
    auto c = client();
    auto h = c.Get("/healthz");
    ASSERT_TRUE(h);
    EXPECT_EQ(h->status, 200);
    auto sets = c.Get("/sets");
    ASSERT_TRUE(sets);
    auto j = nlohmann::json::parse(sets->body);
    ASSERT_EQ(j.size(), 1u);
    EXPECT_EQ(j[0]["name"], "scene");
    auto info = TilesetReader::open(dir_->file("sets/scene"));
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(j[0]["points"], info->info().inputPoints);
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"}) {
        auto r = c.Get(std::string("/sets/scene/") + f);
        ASSERT_TRUE(r) << f;
        EXPECT_EQ(r->status, 200);
        EXPECT_EQ(r->body, file(f)) << f;
        EXPECT_EQ(r->get_header_value("Content-Type"), std::string(f) == "tileset.json" ? "application/json" : "application/octet-stream");
        EXPECT_EQ(r->get_header_value("Accept-Ranges"), "bytes");
        auto head = c.Head(std::string("/sets/scene/") + f);
        ASSERT_TRUE(head);
        EXPECT_EQ(head->status, 200);
        EXPECT_TRUE(head->body.empty());
        EXPECT_EQ(head->get_header_value("Content-Length"), std::to_string(r->body.size()));
    }
}

TEST_F(ServerTest, NodesAndBatches) {
    start();
    auto c = client();
    auto set = TilesetReader::open(dir_->file("sets/scene"));
    ASSERT_TRUE(set.ok());
    std::string batchBody;
    std::vector<std::string> expected;
    for (const NodeRecord& n : set->nodes()) {
        auto r = c.Get("/sets/scene/nodes/" + n.key.name());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << n.key.name();
        EXPECT_EQ(crc32(r->body.data(), r->body.size()), n.blockCrc);
        EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");
        if (expected.size() < 5) {
            batchBody += n.key.name() + (expected.size() % 2 ? "\n" : ",");
            expected.push_back(r->body);
        }
    }
    // tileset.json's answer offers the batches, and how many keys one takes.
    EXPECT_EQ(c.Get("/sets/scene/tileset.json")->get_header_value("Surfcast-Batch"), "256");
    EXPECT_FALSE(c.Get("/sets/scene/hierarchy.bin")->has_header("Surfcast-Batch"));
    auto b = c.Post("/sets/scene/batch", batchBody, "text/plain");
    ASSERT_TRUE(b);
    ASSERT_EQ(b->status, 200) << b->body;
    size_t at = 0;
    for (const auto& e : expected) {
        ASSERT_LE(at + 4, b->body.size());
        uint32_t len = le::get<uint32_t>(reinterpret_cast<const uint8_t*>(b->body.data() + at));
        ASSERT_EQ(len, e.size());
        EXPECT_EQ(b->body.substr(at + 4, len), e);
        at += 4 + len;
    }
    EXPECT_EQ(at, b->body.size());
    EXPECT_EQ(c.Post("/sets/scene/batch", "0-0-0-0,9-9-9-9", "text/plain")->status, 404);
    EXPECT_EQ(c.Post("/sets/scene/batch", "nonsense", "text/plain")->status, 400);
    std::string tooMany;
    for (int i = 0; i < 300; ++i) tooMany += "0-0-0-0,";
    EXPECT_EQ(c.Post("/sets/scene/batch", tooMany, "text/plain")->status, 400);
    EXPECT_EQ(c.Get("/sets/scene/nodes/1-5-0-0")->status, 400);  // out of range for level 1
    EXPECT_EQ(c.Get("/sets/scene/nodes/7-0-0-0")->status, 404);
}

TEST_F(ServerTest, RangesSingleMultipleAndUnsatisfiable) {
    start();
    auto c = client();
    std::string blocks = file("blocks.bin");
    auto r = c.Get("/sets/scene/blocks.bin", {{"Range", "bytes=100-199"}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 206);
    EXPECT_EQ(r->body, blocks.substr(100, 100));
    EXPECT_EQ(r->get_header_value("Content-Range"), "bytes 100-199/" + std::to_string(blocks.size()));
    auto suffix = c.Get("/sets/scene/blocks.bin", {{"Range", "bytes=-10"}});
    EXPECT_EQ(suffix->body, blocks.substr(blocks.size() - 10));
    auto multi = c.Get("/sets/scene/blocks.bin", {{"Range", "bytes=0-3,50-59"}});
    ASSERT_TRUE(multi);
    EXPECT_EQ(multi->status, 206);
    std::string type = multi->get_header_value("Content-Type");
    ASSERT_EQ(type.rfind("multipart/byteranges; boundary=", 0), 0u) << type;
    std::string boundary = type.substr(type.find('=') + 1);
    std::string expected = "\r\n--" + boundary + "\r\nContent-Type: application/octet-stream\r\nContent-Range: bytes 0-3/" +
                           std::to_string(blocks.size()) + "\r\n\r\n" + blocks.substr(0, 4) + "\r\n--" + boundary +
                           "\r\nContent-Type: application/octet-stream\r\nContent-Range: bytes 50-59/" +
                           std::to_string(blocks.size()) + "\r\n\r\n" + blocks.substr(50, 10) + "\r\n--" + boundary + "--\r\n";
    EXPECT_EQ(multi->body, expected);
    auto bad = c.Get("/sets/scene/blocks.bin", {{"Range", "bytes=" + std::to_string(blocks.size()) + "-"}});
    EXPECT_EQ(bad->status, 416);
    EXPECT_EQ(bad->get_header_value("Content-Range"), "bytes */" + std::to_string(blocks.size()));
    std::string many = "bytes=";
    for (int i = 0; i < 40; ++i) many += (i ? "," : "") + std::to_string(i) + "-" + std::to_string(i);
    EXPECT_EQ(c.Get("/sets/scene/blocks.bin", {{"Range", many}})->status, 400);
}

TEST_F(ServerTest, EtagsAndVersionPins) {
    start();
    auto c = client();
    auto r = c.Get("/sets/scene/tileset.json");
    std::string etag = r->get_header_value("ETag");
    ASSERT_FALSE(etag.empty());
    auto again = c.Get("/sets/scene/tileset.json", {{"If-None-Match", etag}});
    EXPECT_EQ(again->status, 304);
    EXPECT_TRUE(again->body.empty());
    EXPECT_EQ(c.Get("/sets/scene/tileset.json", {{"If-None-Match", "\"other\""}})->status, 200);
    auto set = TilesetReader::open(dir_->file("sets/scene"));
    std::string v = std::to_string(set->info().hierarchyCrc);
    auto pinned = c.Get("/sets/scene/nodes/0-0-0-0?v=" + v);
    EXPECT_EQ(pinned->status, 200);
    EXPECT_EQ(pinned->get_header_value("Cache-Control"), "public, max-age=31536000, immutable");
    auto node = c.Get("/sets/scene/nodes/0-0-0-0", {{"If-None-Match", pinned->get_header_value("ETag")}});
    EXPECT_EQ(node->status, 304);
    EXPECT_EQ(c.Get("/sets/scene/nodes/0-0-0-0?v=123")->status, 409);
}

TEST_F(ServerTest, TraversalAndSymlinksStayInside) {
    // A tile set outside DIR, reachable only through symlinks placed inside.
    test::TempDir outside;
    buildScene(outside.file("secret"), 2000, 3);
    fs::create_directory_symlink(outside.file("secret"), dir_->file("sets/linked"));
    fs::create_directories(dir_->file("sets/filelink"));
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        fs::create_symlink(outside.file(std::string("secret/") + f), dir_->file(std::string("sets/filelink/") + f));
    start();
    auto c = client();
    for (const char* path : {"/sets/linked/tileset.json", "/sets/filelink/tileset.json", "/sets/../sets/scene/tileset.json",
                             "/sets/%2e%2e/tileset.json", "/sets/..%2fsets%2fscene/tileset.json", "/sets//etc/passwd",
                             "/sets/%2Fetc%2Fpasswd/tileset.json", "/sets/.hidden/tileset.json", "/sets/", "/sets/scene/",
                             "/sets/scene/../../x", "/etc/passwd"}) {
        auto r = c.Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_TRUE(r->status == 400 || r->status == 404) << path << " gave " << r->status;
        EXPECT_EQ(r->body.find("surfcast-tileset"), std::string::npos) << path;
    }
    auto sets = nlohmann::json::parse(c.Get("/sets")->body);
    EXPECT_EQ(sets.size(), 1u) << sets.dump();  // the symlinked sets are not listed
    fs::remove(dir_->file("sets/linked"));
    fs::remove_all(dir_->file("sets/filelink"));
}

TEST_F(ServerTest, MalformedOversizedAndWrongMethods) {
    start();
    std::string garbage = raw("GARBAGE\r\n\r\n", 3000, true);
    EXPECT_TRUE(garbage.empty() || garbage.find(" 400 ") != std::string::npos) << garbage;
    std::string big = raw("GET /healthz HTTP/1.1\r\nHost: x\r\nX-Big: " + std::string(64 * 1024, 'a') + "\r\n\r\n", 3000, true);
    EXPECT_EQ(big.find(" 200 "), std::string::npos) << big.substr(0, 200);
    std::string bin = raw(std::string("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03", 11), 3000, true);
    EXPECT_EQ(bin.find(" 200 "), std::string::npos);
    auto c = client();
    EXPECT_EQ(c.Delete("/sets/scene/blocks.bin")->status, 405);
    EXPECT_EQ(c.Put("/sets/scene/blocks.bin", "x", "text/plain")->status, 405);
    EXPECT_EQ(c.Get("/nope")->status, 404);
    EXPECT_EQ(c.Get("/healthz")->status, 200);  // still serving
}

TEST_F(ServerTest, ErrorsQuotingBytesThatAreNotUtf8AreAnswered) {
    // A batch key with bytes that are not UTF-8 is quoted in the 400's JSON
    // body; the JSON library threw on it, and the uncaught exception ended the
    // server (fuzz_http_request; fuzz/regressions/http_request). The bytes are
    // replaced, and the server goes on answering.
    start({});
    std::string body = "0\x08\x00\x00\xfc\x00-0-0-0";
    auto r = client().Post("/sets/scene/batch", body, "text/plain");
    ASSERT_TRUE(r) << "the server closed the connection";
    EXPECT_EQ(r->status, 400);
    auto parsed = nlohmann::json::parse(r->body, nullptr, false);
    ASSERT_FALSE(parsed.is_discarded()) << r->body;
    EXPECT_TRUE(parsed.contains("error")) << r->body;
    auto health = client().Get("/healthz");
    ASSERT_TRUE(health) << "the server is gone";
    EXPECT_EQ(health->status, 200);
}

TEST_F(ServerTest, TokenRequired) {
    ServerConfig config;
    config.token = "s3cret";
    config.corsOrigin = "*";
    start(config);
    auto c = client();
    auto none = c.Get("/sets/scene/tileset.json");
    EXPECT_EQ(none->status, 401);
    EXPECT_EQ(none->get_header_value("WWW-Authenticate"), "Bearer realm=\"surfcast\"");
    EXPECT_EQ(c.Get("/sets/scene/tileset.json", {{"Authorization", "Bearer wrong!"}})->status, 401);
    EXPECT_EQ(c.Get("/sets/scene/tileset.json", {{"Authorization", "Bearer s3cre"}})->status, 401);
    auto ok = c.Get("/sets/scene/tileset.json", {{"Authorization", "Bearer s3cret"}});
    EXPECT_EQ(ok->status, 200);
    EXPECT_EQ(ok->get_header_value("Access-Control-Allow-Origin"), "*");
    EXPECT_EQ(c.Get("/healthz")->status, 200);
    auto pre = c.Options("/sets/scene/blocks.bin");
    EXPECT_EQ(pre->status, 204);
    EXPECT_NE(pre->get_header_value("Access-Control-Allow-Headers").find("Range"), std::string::npos);
}

TEST_F(ServerTest, ConcurrentClientsAndMetrics) {
    start();
    auto set = TilesetReader::open(dir_->file("sets/scene"));
    ASSERT_TRUE(set.ok());
    const auto& nodes = set->nodes();
    std::atomic<int> good{0}, bad{0};
    std::vector<std::thread> clients;
    for (int t = 0; t < 16; ++t)
        clients.emplace_back([&, t] {
            auto c = client();
            std::mt19937 rng(t);
            for (int i = 0; i < 40; ++i) {
                const NodeRecord& n = nodes[rng() % nodes.size()];
                auto r = c.Get("/sets/scene/nodes/" + n.key.name());
                (r && r->status == 200 && crc32(r->body.data(), r->body.size()) == n.blockCrc ? good : bad)++;
            }
        });
    for (auto& t : clients) t.join();
    EXPECT_EQ(good, 640);
    EXPECT_EQ(bad, 0);
    // A request is counted when libmicrohttpd reports it completed, which
    // may come just after its client has the whole response (under ASan a
    // read can see 639): wait for the count, up to 5 s.
    const std::string counted = "surfcast_requests_total{route=\"nodes\",status=\"200\"} 640\n";
    std::string body;
    for (auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);;) {
        auto m = client().Get("/metrics");
        ASSERT_TRUE(m);
        body = m->body;
        if (body.find(counted) != std::string::npos || std::chrono::steady_clock::now() > deadline) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    EXPECT_NE(body.find(counted), std::string::npos) << body;
    EXPECT_NE(body.find("surfcast_request_duration_seconds_count"), std::string::npos);
}

TEST_F(ServerTest, StalledClientDoesNotBlockOthers) {
    // Half a request, then silence. Another client's request is answered
    // while the stalled connection is still open (not after the server gave
    // up on it), and the server drops the stalled one after its timeout
    // instead of holding it forever. Event-driven: no assumption about how
    // fast this machine answers, beyond the 3 s timeout.
    ServerConfig config;
    config.timeoutSeconds = 3;
    start(config);
    int stalled = connectRaw(10000);
    const std::string half = "GET /healthz HTTP/1.1\r\nHost: x\r\n";
    ASSERT_EQ(::send(stalled, half.data(), half.size(), MSG_NOSIGNAL), ssize_t(half.size()));
    const auto t0 = std::chrono::steady_clock::now();

    auto r = client().Get("/healthz");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200);
    char byte;
    ssize_t n = ::recv(stalled, &byte, 1, MSG_DONTWAIT);
    EXPECT_TRUE(n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
        << "the other client was answered only once the stalled connection was dropped";

    std::string got;
    char buf[4096];
    while ((n = ::recv(stalled, buf, sizeof buf, 0)) > 0) got.append(buf, size_t(n));
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ::close(stalled);
    EXPECT_TRUE(n == 0 || errno == ECONNRESET) << "the stalled connection was not dropped within 10 s";
    EXPECT_EQ(got.find(" 200 "), std::string::npos) << got;
    EXPECT_LT(s, 10.0);
}

TEST_F(ServerTest, ReplacedDuringDownloadNeverMixes) {
    test::TempDir tmp;
    fs::create_directories(tmp.file("sets"));
    buildScene(tmp.file("sets/live"), 300000, 11);
    std::string oldBlocks = test::readFile(tmp.file("sets/live/blocks.bin"));
    auto store = TilesetStore::open(tmp.file("sets"));
    ASSERT_TRUE(store.ok());
    ServerConfig config;
    config.port = 0;
    config.log = LogLevel::Quiet;
    HttpServer server(**store, config);
    ASSERT_TRUE(server.bind().ok());
    std::thread run([&] { server.run(); });
    httplib::Client c("127.0.0.1", server.port());
    std::string got;
    bool replaced = false;
    auto r = c.Get("/sets/live/blocks.bin", [&](const char* data, size_t n) {
        got.append(data, n);
        if (!replaced) {
            // Mid-download: rebuild the set with another seed and rename it over.
            replaced = true;
            buildScene(tmp.file("sets/live"), 300000, 12);
        }
        return true;
    });
    ASSERT_TRUE(r);
    EXPECT_TRUE(replaced);
    EXPECT_EQ(got.size(), oldBlocks.size());
    EXPECT_TRUE(got == oldBlocks) << "the response mixed old and new bytes";
    std::string newBlocks = test::readFile(tmp.file("sets/live/blocks.bin"));
    ASSERT_NE(newBlocks, oldBlocks);
    auto after = c.Get("/sets/live/blocks.bin");
    EXPECT_TRUE(after->body == newBlocks);
    server.stop();
    run.join();
}

// The export route gives the bytes surfcast-export writes (laz_export.h; its
// points are checked against laspy in export_test), from the first pass to
// the last chunk, whole set or a box.
TEST_F(ServerTest, ExportSendsWhatSurfcastExportWrites) {
    start();
    auto c = client();
    auto set = TilesetReader::open(dir_->file("sets/scene"));
    ASSERT_TRUE(set.ok());
    const Box3d& b = set->info().bounds;
    const double midX = (b.min.x + b.max.x) / 2;
    const std::string box = std::to_string(b.min.x - 1) + "," + std::to_string(b.min.y - 1) + "," + std::to_string(b.min.z - 1) + "," +
                            std::to_string(midX) + "," + std::to_string(b.max.y + 1) + "," + std::to_string(b.max.z + 1);
    for (const std::string& query : {std::string(), "?bbox=" + box}) {
        SCOPED_TRACE(query);
        auto r = c.Get("/sets/scene/export.laz" + query);
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << r->body;
        EXPECT_EQ(r->get_header_value("Content-Type"), "application/vnd.laszip");
        EXPECT_EQ(r->get_header_value("Content-Disposition"), "attachment; filename=\"scene.laz\"");
        test::TempDir tmp;
        test::writeFile(tmp.file("served.laz"), r->body);
        std::vector<std::string> args = {test::binary("surfcast-export"), "-q", dir_->file("sets/scene"), "--format", "laz", "-o",
                                         tmp.file("cli.laz")};
        if (!query.empty()) args.insert(args.end(), {"--bbox", box});
        auto e = test::run(args);
        ASSERT_EQ(e.exitCode, 0) << e.output;
        std::string cli = test::readFile(tmp.file("cli.laz")), served = r->body;
        ASSERT_GT(served.size(), 375u);
        cli.replace(90, 4, 4, '\0');  // the header's creation day and year
        served.replace(90, 4, 4, '\0');
        EXPECT_TRUE(served == cli) << "served " << served.size() << " bytes, surfcast-export wrote " << cli.size();
        auto reader = openLasReader(tmp.file("served.laz"));
        ASSERT_TRUE(reader.ok()) << reader.status().message();
        std::vector<InputPoint> batch(4096);
        uint64_t n = 0;
        // A box keeps the points whose decoded positions lie in it; the LAS
        // records round them to the export's scale (1 mm or finer here).
        while (true) {
            auto got = (*reader)->read(batch.data(), batch.size());
            ASSERT_TRUE(got.ok()) << got.status().message();
            if (*got == 0) break;
            if (!query.empty()) {
                for (size_t i = 0; i < *got; ++i) ASSERT_LE(batch[i].position.x, midX + 0.0005 + 1e-9);
            }
            n += *got;
        }
        if (query.empty()) EXPECT_EQ(n, set->info().inputPoints);
        else EXPECT_GT(n, 0u);
    }
}

// Limits and bad queries: 413 over the limit with a count, 400 naming what
// is wrong, 404 with the route off; and clients that leave mid-export stop
// their producers without stopping the server, and give their places back.
TEST_F(ServerTest, ExportLimitsBadQueriesAndClientsThatLeave) {
    ServerConfig config;
    config.exportMaxPoints = 1000;
    start(config);
    auto c = client();
    auto over = c.Get("/sets/scene/export.laz");
    ASSERT_TRUE(over);
    EXPECT_EQ(over->status, 413);
    EXPECT_NE(over->body.find("over this server's limit of 1000"), std::string::npos) << over->body;
    auto badBox = c.Get("/sets/scene/export.laz?bbox=0,0,0,1,1");
    EXPECT_EQ(badBox->status, 400);
    EXPECT_NE(badBox->body.find("six numbers"), std::string::npos) << badBox->body;
    auto noClasses = c.Get("/sets/scene/export.laz?classes=2");
    EXPECT_EQ(noClasses->status, 400);
    EXPECT_NE(noClasses->body.find("stores no classification"), std::string::npos) << noClasses->body;
    EXPECT_EQ(c.Get("/sets/nothing/export.laz")->status, 404);
    server_->stop();
    thread_.join();

    config.exportMaxPoints = 0;
    start(config);
    EXPECT_EQ(client().Get("/sets/scene/export.laz")->status, 404);
    server_->stop();
    thread_.join();

    // A stream lives until libmicrohttpd notices its client gone (when it
    // next writes to it): room for all six at once.
    config.exportMaxPoints = ServerConfig{}.exportMaxPoints;
    config.exportConcurrency = 6;
    config.timeoutSeconds = 60;  // the stalled exports below hold their places until closed
    start(config, bigRoot());
    // Clients that hang up after the status line (with a small receive
    // buffer, of a body larger than the socket buffers: the server is still
    // sending when they go), between ones that read the whole export on a
    // connection the server then closes.
    for (int i = 0; i < 6; ++i) {
        if (i % 2 == 0) {
            std::string status;
            ::close(requestAndStall("/sets/big/export.laz", &status));
            EXPECT_EQ(status, "HTTP/1.1 200");
            continue;
        }
        const std::string got = raw("GET /sets/scene/export.laz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
        EXPECT_EQ(got.rfind("HTTP/1.1 200", 0), 0u) << got.substr(0, 200);
        EXPECT_NE(got.find("\r\n0\r\n\r\n"), std::string::npos) << "the chunked body should end";
    }
    // Every place comes back: six exports at once then run (each held by a
    // client that reads nothing of a body larger than the socket buffers),
    // and a seventh is refused. A place a leaver kept would refuse one of the six.
    EXPECT_EQ(exportsInProgressOnce(0), 0);
    std::vector<int> held;
    for (int i = 0; i < 6; ++i) {
        std::string status;
        held.push_back(requestAndStall("/sets/big/export.laz", &status));
        EXPECT_EQ(status, "HTTP/1.1 200") << "export " << i;
    }
    auto seventh = client().Get("/sets/scene/export.laz");
    ASSERT_TRUE(seventh);
    EXPECT_EQ(seventh->status, 503);
    for (int fd : held) ::close(fd);
    EXPECT_EQ(exportsInProgressOnce(0), 0);
    auto whole = client().Get("/sets/scene/export.laz");
    ASSERT_TRUE(whole);
    EXPECT_EQ(whole->status, 200);
    EXPECT_GT(whole->body.size(), 375u);
}

// A client reading an export more slowly than the server's time limit lets
// through is cut off at the limit, its response left without the chunked
// encoding's last chunk, and its place is free for the next export.
TEST_F(ServerTest, ExportTooSlowForItsTimeLimitIsCutOff) {
    ServerConfig config;
    config.exportConcurrency = 1;
    config.exportSeconds = 1;
    start(config, bigRoot());
    std::string status;
    int fd = requestAndStall("/sets/big/export.laz", &status);
    ASSERT_EQ(status, "HTTP/1.1 200");
    // 4 KiB per 10 ms at most: the 5 MB body would take this reader over 12 s,
    // and each read lets the server send again (no inactivity timeout).
    std::string got;
    char buf[4096];
    ssize_t n;
    while ((n = ::recv(fd, buf, sizeof buf, 0)) > 0) {
        got.append(buf, size_t(n));
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    const int error = n < 0 ? errno : 0;
    ::close(fd);
    const bool whole = got.size() >= 7 && got.compare(got.size() - 7, 7, "\r\n0\r\n\r\n") == 0;
    EXPECT_FALSE(whole) << "the slow reader got the whole export (" << got.size() << " bytes)";
    EXPECT_TRUE(n == 0 || error == ECONNRESET) << std::strerror(error);
    // libmicrohttpd frees the response before it closes (and so resets) the
    // connection: the place is free by now.
    auto next = client().Get("/sets/scene/export.laz");
    ASSERT_TRUE(next);
    EXPECT_EQ(next->status, 200);
    EXPECT_GT(next->body.size(), 375u);
}

// Refusals come before any work that grows with the set: with every place
// taken, 200 exports over the limit are answered 503 (the place is checked
// first, not the limit, which needs the node table), while tile requests on
// other connections keep being answered whole. Once the places are free, the
// same requests get 413, and the limit is the one laz_export counts.
TEST_F(ServerTest, ExportRefusalsComeFirstWhileTilesServe) {
    auto set = TilesetReader::open(bigRoot() + "/big");
    ASSERT_TRUE(set.ok());
    // A box that leaves out the leaves of the highest x: below the whole set's count.
    double lastX = -HUGE_VAL;
    for (const NodeRecord& n : set->nodes())
        if (n.flags & kFlagInputPoints) lastX = std::max(lastX, nodeMin(set->info(), n.key).x);
    const Box3d& b = set->info().bounds;
    PointFilter part;
    part.box = Box3d{{b.min.x - 1, b.min.y - 1, b.min.z - 1}, {lastX - 1e-6, b.max.y + 1, b.max.z + 1}};
    const uint64_t partPoints = exportPointsAtMost(*set, part), allPoints = exportPointsAtMost(*set, PointFilter{});
    ASSERT_LT(partPoints, allPoints);
    const std::string box = std::to_string(part.box->min.x) + "," + std::to_string(part.box->min.y) + "," + std::to_string(part.box->min.z) +
                            "," + std::to_string(part.box->max.x) + "," + std::to_string(part.box->max.y) + "," +
                            std::to_string(part.box->max.z);

    ServerConfig config;
    config.exportConcurrency = 2;
    config.exportMaxPoints = partPoints;  // the box's export is allowed, the whole set's is not
    config.timeoutSeconds = 60;
    start(config, bigRoot());
    std::vector<int> held;
    for (int i = 0; i < config.exportConcurrency; ++i) {
        std::string status;
        held.push_back(requestAndStall("/sets/big/export.laz?bbox=" + box, &status));
        ASSERT_EQ(status, "HTTP/1.1 200") << "export " << i;
    }

    std::vector<std::pair<std::string, std::string>> tiles;  // path, bytes
    for (const NodeRecord& n : set->nodes()) {
        if (tiles.size() == 64) break;
        tiles.emplace_back("/sets/big/nodes/" + n.key.name(), "");
    }
    {
        auto blocks = test::readFile(bigRoot() + "/big/blocks.bin");
        for (size_t i = 0; i < tiles.size(); ++i) {
            const NodeRecord& n = set->nodes()[i];
            tiles[i].second = blocks.substr(size_t(n.blockOffset), n.blockSize);
        }
    }
    std::atomic<bool> refusing{true};
    std::atomic<int> tileAnswers{0}, tileWrong{0};
    std::thread tileClient([&] {
        auto c = client();
        for (size_t i = 0; refusing.load() || i < tiles.size(); ++i) {
            auto r = c.Get(tiles[i % tiles.size()].first);
            if (r && r->status == 200 && r->body == tiles[i % tiles.size()].second) ++tileAnswers;
            else ++tileWrong;
        }
    });
    constexpr int kRefused = 200, kSenders = 4;
    std::vector<std::vector<int>> statuses(kSenders);
    std::vector<std::thread> senders;
    for (int t = 0; t < kSenders; ++t)
        senders.emplace_back([&, t] {
            auto c = client();
            for (int i = t; i < kRefused; i += kSenders) {
                auto r = c.Get("/sets/big/export.laz");
                statuses[size_t(t)].push_back(r ? r->status : 0);
            }
        });
    for (auto& t : senders) t.join();
    refusing = false;
    tileClient.join();
    int busy = 0;
    for (const auto& list : statuses)
        for (int st : list) busy += st == 503;
    EXPECT_EQ(busy, kRefused) << "every export over the limit, with no place free, is refused as busy";
    EXPECT_EQ(tileWrong.load(), 0);
    EXPECT_GE(tileAnswers.load(), int(tiles.size()));

    for (int fd : held) ::close(fd);
    ASSERT_EQ(exportsInProgressOnce(0), 0);
    auto over = client().Get("/sets/big/export.laz");
    ASSERT_TRUE(over);
    EXPECT_EQ(over->status, 413);
    EXPECT_NE(over->body.find("over this server's limit of " + std::to_string(partPoints)), std::string::npos) << over->body;
    auto atLimit = client().Get("/sets/big/export.laz?bbox=" + box);
    ASSERT_TRUE(atLimit);
    EXPECT_EQ(atLimit->status, 200);
    // The bound is exactly laz_export's: one point less refuses the same box.
    server_->stop();
    thread_.join();
    config.exportMaxPoints = partPoints - 1;
    start(config, bigRoot());
    auto justOver = client().Get("/sets/big/export.laz?bbox=" + box);
    ASSERT_TRUE(justOver);
    EXPECT_EQ(justOver->status, 413);
}

// A server stopped while an export is under way (here in its first pass,
// its connection suspended), and a second export beyond the concurrency
// limit. libmicrohttpd aborts the process if it stops with a connection
// suspended: the server ends its exports first.
TEST_F(ServerTest, StoppingDuringAnExportAndTooManyExports) {
    test::TempDir tmp;
    buildScene(tmp.file("sets/big"), 300000, 21);
    auto store = TilesetStore::open(tmp.file("sets"));
    ASSERT_TRUE(store.ok());
    ServerConfig config;
    config.port = 0;
    config.log = LogLevel::Quiet;
    config.exportConcurrency = 1;
    config.drainSeconds = 0;  // stop at once, exports in flight or not
    HttpServer server(**store, config);
    ASSERT_TRUE(server.bind().ok());
    std::thread thread([&] { server.run(); });
    struct Joined {  // a failed assertion below still stops and joins the server
        HttpServer& server;
        std::thread& thread;
        ~Joined() {
            server.stop();
            if (thread.joinable()) thread.join();
        }
    } joined{server, thread};
    auto set = TilesetReader::open(tmp.file("sets/big"));
    ASSERT_TRUE(set.ok());
    const Box3d& b = set->info().bounds;
    // A box (the first pass decodes every leaf it reaches) around all but a sliver.
    const std::string box = std::to_string(b.min.x - 1) + "," + std::to_string(b.min.y - 1) + "," + std::to_string(b.min.z - 1) + "," +
                            std::to_string(b.max.x - 0.01) + "," + std::to_string(b.max.y + 1) + "," + std::to_string(b.max.z + 1);
    const std::string request = "GET /sets/big/export.laz?bbox=" + box + " HTTP/1.1\r\nHost: x\r\n\r\n";
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(uint16_t(server.port()));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    ::send(fd, request.data(), request.size(), MSG_NOSIGNAL);
    char head[12] = {};
    ASSERT_EQ(::recv(fd, head, sizeof head, MSG_WAITALL), ssize_t(sizeof head));  // the status line: the export has started
    EXPECT_EQ(std::string(head, sizeof head), "HTTP/1.1 200");
    httplib::Client c("127.0.0.1", server.port());
    auto busy = c.Get("/sets/big/export.laz");
    ASSERT_TRUE(busy);
    EXPECT_EQ(busy->status, 503);
    EXPECT_EQ(busy->get_header_value("Retry-After"), "5");
    const auto start = std::chrono::steady_clock::now();
    server.stop();
    thread.join();
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(5)) << "stopping waits for one leaf's work at most";
    ::close(fd);
}
