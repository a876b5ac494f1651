// surfcast-serve s3://BUCKET/PREFIX against a real S3 store (SeaweedFS,
// tests/store_support.h): the sets under the prefix answer every route as the
// same sets in a folder do, byte for byte and with the same ETags; the
// server follows the prefix (new sets, updates, with the version before
// still served); block bytes come through its cache; a store's failure is a
// 502 naming the object, never the credentials.
#include <gtest/gtest.h>

#include <httplib.h>
#include <signal.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <thread>

#include "object_store.h"
#include "store_support.h"
#include "test_support.h"
#include "tileset_reader.h"

using namespace surfcast;
using namespace surfcast::test;
namespace fs = std::filesystem;

namespace {

// A surfcast-serve child on a port of its own, stopped with the object.
struct Server {
    explicit Server(std::vector<std::string> args) {
        args.insert(args.begin(), binary("surfcast-serve"));
        args.insert(args.end(), {"--bind", "127.0.0.1:0", "--no-web", "--log", "errors"});
        child = spawn(args);
        ready = child.waitFor(" tile sets)\n");
        const size_t at = child.log.find("http://127.0.0.1:");
        if (ready && at != std::string::npos) port = std::atoi(child.log.c_str() + at + 17);
    }
    ~Server() {
        ::kill(child.pid, SIGTERM);
        exitCode(child.pid);
    }
    httplib::Client client() const { return httplib::Client("127.0.0.1", port); }
    Child child;
    bool ready = false;
    int port = 0;
};

class StoreServe : public ::testing::Test {
protected:
    void SetUp() override {
        s3_ = &SeaweedFs::shared();
        s3_->exportEnvironment();
        store_ = s3_->store();
    }
    void upload(const std::string& folder, const std::string& prefix) { uploadFolder(*store_, folder, prefix); }
    SeaweedFs* s3_ = nullptr;
    std::shared_ptr<ObjectStore> store_;
};

// Every route of a set in the bucket answers what the same set in a folder
// does: tileset.json, the hierarchy, ranges and the whole of blocks.bin, a
// node, a batch of every node (whose bytes come through the cache: asked
// twice, the second time from it), and a client reading the set through
// the server verifies every block.
TEST_F(StoreServe, SetsInABucketAnswerAsInAFolder) {
    TempDir dir;
    ASSERT_EQ(buildScene(dir.file("sets/scene"), 20000).exitCode, 0);
    ASSERT_NO_FATAL_FAILURE(upload(dir.file("sets/scene"), "served/a/scene/"));
    Server local({dir.file("sets")}), bucket({"s3://surfcast/served/a"});
    ASSERT_TRUE(local.ready) << local.child.log;
    ASSERT_TRUE(bucket.ready) << bucket.child.log;
    EXPECT_NE(bucket.child.log.find("serving s3://surfcast/served/a on http://127.0.0.1:"), std::string::npos) << bucket.child.log;
    auto a = local.client(), b = bucket.client();

    auto reader = TilesetReader::open(dir.file("sets/scene"));
    ASSERT_TRUE(reader) << reader.status().message();
    std::string keys;
    for (const NodeRecord& n : reader->nodes()) keys += n.key.name() + "\n";
    const std::string root = "/sets/scene/nodes/" + reader->nodes()[0].key.name();
    struct Ask {
        std::string path;
        httplib::Headers headers;
    };
    const std::vector<Ask> asks = {{"/sets", {}},
                                   {"/sets/scene/tileset.json", {}},
                                   {"/sets/scene/hierarchy.bin", {{"Range", "bytes=0-99"}}},
                                   {"/sets/scene/blocks.bin", {}},
                                   {"/sets/scene/blocks.bin", {{"Range", "bytes=10-2009, 5000-5099"}}},
                                   {root, {}},
                                   {root, {}}};
    for (const Ask& ask : asks) {
        auto want = a.Get(ask.path, ask.headers), got = b.Get(ask.path, ask.headers);
        ASSERT_TRUE(want && got) << ask.path;
        EXPECT_EQ(got->status, want->status) << ask.path << ": " << got->body;
        EXPECT_EQ(got->get_header_value("ETag"), want->get_header_value("ETag")) << ask.path;
        EXPECT_EQ(got->get_header_value("Content-Range"), want->get_header_value("Content-Range")) << ask.path;
        if (ask.path == "/sets/scene/blocks.bin" && !ask.headers.empty()) {
            // (multipart: the same parts under the same boundary)
            EXPECT_EQ(got->get_header_value("Content-Type"), want->get_header_value("Content-Type"));
        }
        EXPECT_TRUE(got->body == want->body) << ask.path;
        EXPECT_EQ(got->body.find(SeaweedFs::kSecret), std::string::npos);
    }
    for (int round = 0; round < 2; ++round) {
        auto want = a.Post("/sets/scene/batch", keys, "text/plain"), got = b.Post("/sets/scene/batch", keys, "text/plain");
        ASSERT_TRUE(want && got);
        EXPECT_EQ(got->status, 200) << got->body;
        EXPECT_TRUE(got->body == want->body) << "round " << round;
    }
    auto metrics = b.Get("/metrics");
    ASSERT_TRUE(metrics);
    // The root asked twice and every node in the second batch: from the cache.
    const size_t at = metrics->body.find("\nsurfcast_bucket_cache_hits_total ");
    ASSERT_NE(at, std::string::npos) << metrics->body;
    EXPECT_GE(std::stoul(metrics->body.substr(at + 34)), reader->nodes().size() + 1) << metrics->body;

    auto info = run({binary("surfcast-build"), "--info", "http://127.0.0.1:" + std::to_string(bucket.port) + "/sets/scene"});
    EXPECT_EQ(info.exitCode, 0) << info.output;
    EXPECT_NE(info.output.find("checksums verified"), std::string::npos) << info.output;
}

// The server lists the prefix every --store-poll: a set published after it
// started appears, an update is served once listed while the version before
// stays readable by its ?v=, and a deleted set goes.
TEST_F(StoreServe, FollowsThePrefix) {
    REQUIRE_DATA();
    TempDir dir;
    Server server({"s3://surfcast/served/b", "--store-poll", "0.2"});
    ASSERT_TRUE(server.ready) << server.child.log;
    EXPECT_NE(server.child.log.find("(0 tile sets)"), std::string::npos) << server.child.log;
    auto c = server.client();
    auto r = run({binary("surfcast-build"), "-q", dataFile("fragment.pcd"), "-o", "s3://surfcast/served/b/late"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto waitFor = [&](const std::string& path, const std::function<bool(const httplib::Result&)>& done) {
        for (int i = 0; i < 100; ++i) {
            if (auto got = c.Get(path); done(got)) return true;
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        return false;
    };
    ASSERT_TRUE(waitFor("/sets/late/tileset.json", [](const httplib::Result& g) { return g && g->status == 200; }));
    auto before = c.Get("/sets/late/tileset.json");
    ASSERT_TRUE(before);
    const std::string oldVersion = std::to_string(readTilesetJson(before->body, "tileset.json")->hierarchyCrc);
    auto oldRoot = c.Get("/sets/late/nodes/0-0-0-0?v=" + oldVersion);
    ASSERT_TRUE(oldRoot && oldRoot->status == 200);

    const std::string copy = dir.file("again.pcd");
    fs::copy_file(dataFile("fragment.pcd"), copy);
    r = run({binary("surfcast-build"), "-q", "--add", copy, "--to", "s3://surfcast/served/b/late"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_TRUE(waitFor("/sets/late/tileset.json", [&](const httplib::Result& g) { return g && g->status == 200 && g->body != before->body; }));
    auto kept = c.Get("/sets/late/nodes/0-0-0-0?v=" + oldVersion);
    ASSERT_TRUE(kept);
    EXPECT_EQ(kept->status, 200) << kept->body;
    EXPECT_TRUE(kept->body == oldRoot->body) << "the version before, as it was";

    ASSERT_TRUE(store_->remove({SeaweedFs::kBucket, "served/b/late/tileset.json"}).ok());
    EXPECT_TRUE(waitFor("/sets/late/tileset.json", [](const httplib::Result& g) { return g && g->status == 404; }));
}

// A block the store no longer holds as the hierarchy says (replaced with
// other bytes, or gone) is a 502 naming the object; the server goes on
// serving, and never shows the secret.
TEST_F(StoreServe, StoreFailuresAre502sNamingTheObject) {
    TempDir dir;
    ASSERT_EQ(buildScene(dir.file("scene"), 20000).exitCode, 0);
    ASSERT_NO_FATAL_FAILURE(upload(dir.file("scene"), "served/c/scene/"));
    Server server({"s3://surfcast/served/c", "--store-cache", "0"});
    ASSERT_TRUE(server.ready) << server.child.log;
    auto c = server.client();
    ASSERT_EQ(c.Get("/sets/scene/nodes/0-0-0-0")->status, 200);

    std::string blocks = readFile(dir.file("scene/blocks.bin"));
    for (char& ch : blocks) ch = char(ch ^ 0x5a);
    ASSERT_TRUE(store_->put({SeaweedFs::kBucket, "served/c/scene/blocks.bin"}, std::vector<uint8_t>(blocks.begin(), blocks.end())).ok());
    auto damaged = c.Get("/sets/scene/nodes/0-0-0-0");
    ASSERT_TRUE(damaged);
    EXPECT_EQ(damaged->status, 502) << damaged->body;
    EXPECT_NE(damaged->body.find("s3://surfcast/served/c/scene/blocks.bin"), std::string::npos) << damaged->body;
    EXPECT_NE(damaged->body.find("CRC-32"), std::string::npos) << damaged->body;

    ASSERT_TRUE(store_->remove({SeaweedFs::kBucket, "served/c/scene/blocks.bin"}).ok());
    auto gone = c.Get("/sets/scene/nodes/0-0-0-0");
    ASSERT_TRUE(gone);
    EXPECT_EQ(gone->status, 502) << gone->body;
    EXPECT_NE(gone->body.find("HTTP 404"), std::string::npos) << gone->body;
    EXPECT_EQ(gone->body.find(SeaweedFs::kSecret), std::string::npos) << gone->body;
    auto still = c.Get("/sets/scene/tileset.json");
    ASSERT_TRUE(still);
    EXPECT_EQ(still->status, 200);
    EXPECT_EQ(server.child.log.find(SeaweedFs::kSecret), std::string::npos);

    auto bad = run({binary("surfcast-serve"), "s3://surfcast/served/c", "--store-cache", "lots"});
    EXPECT_EQ(bad.exitCode, 2) << bad.output;
    bad = run({"/usr/bin/env", "AWS_SECRET_ACCESS_KEY=wrong-secret-value", binary("surfcast-serve"), "s3://surfcast/served/c"});
    EXPECT_EQ(bad.exitCode, 1) << bad.output;
    EXPECT_NE(bad.output.find("HTTP 403"), std::string::npos) << bad.output;
    EXPECT_EQ(bad.output.find("wrong-secret-value"), std::string::npos) << bad.output;
}

}  // namespace
