// Sets and inputs in a real S3 store (SeaweedFS, tests/store_support.h),
// through the programs: surfcast-build reads scans from a bucket and
// publishes a set to it, surfcast-build --info and surfcast-export read that
// set with signed requests, and the objects are the bytes a build into a
// folder writes. Refusals (a taken prefix, bad credentials, a missing bucket)
// fail at once, leave nothing behind and never show the secret.
#include <gtest/gtest.h>

#include <signal.h>

#include <chrono>
#include <filesystem>
#include <map>
#include <random>
#include <thread>

#include "object_store.h"
#include "store_support.h"
#include "stream_support.h"
#include "test_support.h"

using namespace surfcast;
using namespace surfcast::test;

namespace {

const std::vector<std::string> kScans = {"autzen_trim.las", "lion_takanawa.copc.laz"};

std::string get(ObjectStore& store, const std::string& key) {
    auto bytes = store.get({SeaweedFs::kBucket, key}, 1u << 30);
    EXPECT_TRUE(bytes.ok()) << key << ": " << (bytes.ok() ? "" : bytes.status().message());
    return bytes.ok() ? std::string(bytes->begin(), bytes->end()) : std::string();
}

std::vector<std::string> keys(ObjectStore& store, const std::string& prefix) {
    auto listed = store.list({SeaweedFs::kBucket, prefix});
    EXPECT_TRUE(listed.ok());
    std::vector<std::string> out;
    if (listed.ok())
        for (const auto& o : *listed) out.push_back(o.key.substr(prefix.size()));
    return out;
}

class Store : public ::testing::Test {
protected:
    void SetUp() override {
        REQUIRE_DATA();
        s3_ = &SeaweedFs::shared();
        s3_->exportEnvironment();
        store_ = s3_->store();
    }
    SeaweedFs* s3_ = nullptr;
    std::shared_ptr<ObjectStore> store_;
};

TEST_F(Store, BuildFromAndIntoABucketWritesTheBytesOfAFolderBuild) {
    TempDir dir;
    for (const auto& scan : kScans) {
        auto put = store_->putFile({SeaweedFs::kBucket, "scans/" + scan}, dataFile(scan));
        ASSERT_TRUE(put.ok()) << put.status().message();
    }
    const std::vector<std::string> options = {"-q", "--capacity", "4000"};
    std::vector<std::string> local = {binary("surfcast-build")};
    local.insert(local.end(), options.begin(), options.end());
    for (const auto& scan : kScans) local.push_back(dataFile(scan));
    local.insert(local.end(), {"-o", dir.file("local")});
    auto one = run(local);
    ASSERT_EQ(one.exitCode, 0) << one.output;

    // The prefix stands for both scans, in key order (the order given above).
    std::vector<std::string> remote = {binary("surfcast-build")};
    remote.insert(remote.end(), options.begin(), options.end());
    remote.insert(remote.end(), {"s3://surfcast/scans/", "-o", "s3://surfcast/sets/two"});
    auto built = run(remote);
    ASSERT_EQ(built.exitCode, 0) << built.output;
    EXPECT_NE(built.output.find("wrote s3://surfcast/sets/two (4 objects"), std::string::npos) << built.output;

    // The same objects as the folder's files; the build record differs only
    // in what it records of the inputs' and output's names.
    std::vector<std::string> files;
    for (const auto& e : std::filesystem::directory_iterator(dir.file("local"))) files.push_back(e.path().filename().string());
    std::sort(files.begin(), files.end());
    EXPECT_EQ(keys(*store_, "sets/two/"), files);
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(get(*store_, std::string("sets/two/") + f) == readFile(dir.file("local/") + f)) << f;
    EXPECT_NE(get(*store_, "sets/two/build.bin").find("s3://surfcast/scans/autzen_trim.las"), std::string::npos);

    // Read back with signed requests: --info checks every page and block's CRC.
    auto info = run({binary("surfcast-build"), "--info", "s3://surfcast/sets/two"});
    ASSERT_EQ(info.exitCode, 0) << info.output;
    auto localInfo = run({binary("surfcast-build"), "--info", dir.file("local")});
    EXPECT_EQ(info.output.substr(info.output.find('\n')), localInfo.output.substr(localInfo.output.find('\n')));

    // An export reads every leaf from the store and writes its file there.
    auto exported = run({binary("surfcast-export"), "-q", "s3://surfcast/sets/two", "--format", "laz", "-o", "s3://surfcast/exports/two.laz"});
    ASSERT_EQ(exported.exitCode, 0) << exported.output;
    auto exportedLocal = run({binary("surfcast-export"), "-q", dir.file("local"), "--format", "laz", "-o", dir.file("two.laz")});
    ASSERT_EQ(exportedLocal.exitCode, 0) << exportedLocal.output;
    EXPECT_TRUE(get(*store_, "exports/two.laz") == readFile(dir.file("two.laz")));
    // 3D Tiles: a folder of files, published as a set is (tileset.json last).
    auto tiles = run({binary("surfcast-export"), "-q", "s3://surfcast/sets/two", "--format", "3dtiles", "-o", "s3://surfcast/exports/two-3dtiles"});
    ASSERT_EQ(tiles.exitCode, 0) << tiles.output;
    auto tilesLocal = run({binary("surfcast-export"), "-q", dir.file("local"), "--format", "3dtiles", "-o", dir.file("two-3dtiles")});
    ASSERT_EQ(tilesLocal.exitCode, 0) << tilesLocal.output;
    std::vector<std::string> tileFiles;
    for (const auto& e : std::filesystem::recursive_directory_iterator(dir.file("two-3dtiles")))
        if (e.is_regular_file()) tileFiles.push_back(std::filesystem::relative(e.path(), dir.file("two-3dtiles")).generic_string());
    std::sort(tileFiles.begin(), tileFiles.end());
    EXPECT_EQ(keys(*store_, "exports/two-3dtiles/"), tileFiles);
    for (const auto& f : tileFiles)
        EXPECT_TRUE(get(*store_, "exports/two-3dtiles/" + f) == readFile(dir.file("two-3dtiles/") + f)) << f;

    // A set is never rewritten where it stands: a second build to the prefix
    // is refused before it builds, and the set keeps its objects.
    const std::string blocks = get(*store_, "sets/two/blocks.bin");
    remote.back() = "s3://surfcast/sets/two";
    remote[remote.size() - 3] = "s3://surfcast/scans/lion_takanawa.copc.laz";
    auto again = run(remote);
    EXPECT_EQ(again.exitCode, 1) << again.output;
    EXPECT_NE(again.output.find("s3://surfcast/sets/two/: the prefix holds 4 object(s) already"), std::string::npos) << again.output;
    EXPECT_TRUE(get(*store_, "sets/two/blocks.bin") == blocks);
}

// The viewer streams a set from the bucket, its requests signed, to the
// image it draws from the folder the set was built in.
TEST_F(Store, TheViewerStreamsASetFromABucketLikeFromAFolder) {
    TempDir dir;
    ASSERT_EQ(buildScene(dir.file("scene"), 20000).exitCode, 0);
    auto built = run({binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "20000", "-o", "s3://surfcast/view/scene"});
    ASSERT_EQ(built.exitCode, 0) << built.output;
    expectStreamsLikeLocal("s3://surfcast/view/scene", dir.file("scene"), "--camera=3,-6,2,0,0,0.5,0,0,1,50", dir);
    // Without credentials the private bucket refuses the viewer at once.
    auto refused = run({"/usr/bin/env", "AWS_ACCESS_KEY_ID=", "AWS_SECRET_ACCESS_KEY=", binary("surfcast-view"), "--headless",
                        "s3://surfcast/view/scene", "--lod", "1", "--out", dir.file("x.png")});
    EXPECT_NE(refused.exitCode, 0);
    EXPECT_NE(refused.output.find("s3://surfcast/view/scene/tileset.json: HTTP 403"), std::string::npos) << refused.output;
}

// A publisher killed at any moment leaves readers no set (no tileset.json)
// or the whole set, never a torn one.
TEST_F(Store, KillAnywhereLeavesNoSetOrTheWholeOne) {
    const std::vector<std::string> build = {binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "300000",
                                            "-o", "s3://surfcast/killed/scene"};
    auto clear = [&] {
        auto listed = store_->list({SeaweedFs::kBucket, "killed/"});
        ASSERT_TRUE(listed.ok());
        for (const auto& o : *listed) ASSERT_TRUE(store_->remove({SeaweedFs::kBucket, o.key}).ok());
    };
    const auto t0 = std::chrono::steady_clock::now();
    auto whole = run(build);
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::string json = get(*store_, "killed/scene/tileset.json");
    std::mt19937 random(65);
    std::map<std::string, int> outcomes;
    for (int i = 0; i < (kSanitized ? 4 : 10); ++i) {
        clear();
        // Most of the run builds; the upload is its last moments.
        const double at = std::uniform_real_distribution<double>(0.85 * seconds, 1.02 * seconds)(random);
        Child child = spawn(build);
        std::this_thread::sleep_for(std::chrono::duration<double>(at));
        ::kill(child.pid, SIGKILL);
        exitCode(child.pid);
        ::close(child.err);
        auto head = store_->head({SeaweedFs::kBucket, "killed/scene/tileset.json"});
        ASSERT_TRUE(head.ok()) << head.status().message();
        const size_t objects = keys(*store_, "killed/scene/").size();
        if (!head->has_value()) {
            ++outcomes[objects == 0 ? "nothing" : "objects, no set"];
            auto info = run({binary("surfcast-build"), "--info", "s3://surfcast/killed/scene"});
            EXPECT_EQ(info.exitCode, 1) << "killed after " << at << " s: " << info.output;
            continue;
        }
        ++outcomes["the set"];
        EXPECT_EQ(get(*store_, "killed/scene/tileset.json"), json) << "killed after " << at << " s";
        auto info = run({binary("surfcast-build"), "--info", "s3://surfcast/killed/scene"});
        EXPECT_EQ(info.exitCode, 0) << "killed after " << at << " s: " << info.output;
    }
    for (const auto& [what, n] : outcomes) std::printf("%s: %d\n", what.c_str(), n);
    clear();
}

// A proxy answers a tenth of the requests with 503 SlowDown (before the
// store acts), 500 or a reset connection (after it has): the inputs are read
// and the set published all the same, byte for byte, including the writes
// whose success was lost on the way back.
TEST_F(Store, TransientFaultsGiveTheSameBytes) {
    TempDir dir;
    for (const auto& scan : kScans) ASSERT_TRUE(store_->putFile({SeaweedFs::kBucket, "faults/in/" + scan}, dataFile(scan)).ok());
    const std::vector<std::string> options = {"-q", "--capacity", "4000", "s3://surfcast/faults/in/"};
    std::vector<std::string> direct = {binary("surfcast-build")};
    direct.insert(direct.end(), options.begin(), options.end());
    direct.insert(direct.end(), {"-o", "s3://surfcast/faults/direct"});
    auto clean = run(direct);
    ASSERT_EQ(clean.exitCode, 0) << clean.output;

    FaultProxy proxy(0.1, 7);
    std::vector<std::string> faulty = {"/usr/bin/env", "AWS_ENDPOINT_URL=" + proxy.endpoint(), binary("surfcast-build")};
    faulty.insert(faulty.end(), options.begin(), options.end());
    faulty.insert(faulty.end(), {"-o", "s3://surfcast/faults/through-proxy"});
    auto r = run(faulty);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto faults = proxy.counts();
    for (const char* kind : {"slowdown", "error", "reset"}) EXPECT_GE(faults[kind].get<int>(), 1) << kind << ": " << faults.dump();
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(get(*store_, std::string("faults/direct/") + f) == get(*store_, std::string("faults/through-proxy/") + f)) << f;
}

// A publish that fails half way (an upload's faults past its retries, from a
// proxy that fails most uploads) deletes the objects it had written: the
// prefix is left empty, not holding a set's files without its tileset.json.
TEST_F(Store, APublishThatFailsHalfWayLeavesNothing) {
    TempDir dir;
    ASSERT_EQ(buildScene(dir.file("scene"), 20000).exitCode, 0);
    FaultProxy proxy(0.8, 6, "PUT,POST");
    auto r = run({"/usr/bin/env", "AWS_ENDPOINT_URL=" + proxy.endpoint(), binary("surfcast-build"), "-q", "--default-scene",
                  "--scene-points", "20000", "-o", "s3://surfcast/halfway/scene"});
    const auto faults = proxy.counts();
    // The seed's draw: at least one upload got through before one failed
    // past its retries (else this case tests nothing).
    ASSERT_EQ(r.exitCode, 1) << r.output;
    ASSERT_GE(faults.value("forwarded PUT", 0), 1) << faults.dump();
    EXPECT_TRUE(keys(*store_, "halfway/").empty()) << r.output;
}

// The stages on work in the store, one process each as Dask workers run
// them: the shuffle's pieces are stored as LZ4 frames (chunks/P/NAME.lz4,
// the markers as they are), the set is the bytes of a one-process build,
// and a damaged piece fails its chunk task naming the object.
TEST_F(Store, StagesOnWorkInTheStorePackTheShuffle) {
    TempDir dir;
    const std::vector<std::string> scene = {"--default-scene", "--scene-points", "100000", "--memory", "64M", "--capacity", "1000"};
    auto stage = [&](std::vector<std::string> args, const std::string& work) {
        args.insert(args.begin(), {binary("surfcast-build")});
        args.insert(args.begin() + 2, {"-q", "--work", work});
        return run(args);
    };
    auto stages = [&](const std::string& work, const std::string& out) {
        for (const char* s : {"scan", "count"}) {
            std::vector<std::string> args = {s, "--part", "0/1"};
            args.insert(args.end(), scene.begin(), scene.end());
            args.insert(args.end(), {"-o", out});
            auto r = stage(args, work);
            ASSERT_EQ(r.exitCode, 0) << s << ": " << r.output;
        }
        std::vector<std::string> plan = {"plan"};
        plan.insert(plan.end(), scene.begin(), scene.end());
        plan.insert(plan.end(), {"-o", out});
        auto r = stage(plan, work);
        ASSERT_EQ(r.exitCode, 0) << r.output;
        r = stage({"distribute", "--part", "0"}, work);
        ASSERT_EQ(r.exitCode, 0) << r.output;
    };
    const std::string work = "s3://surfcast/stages/work";
    ASSERT_NO_FATAL_FAILURE(stages(work, dir.file("set")));
    size_t pieces = 0;
    for (const std::string& k : keys(*store_, "stages/work/chunks/")) {
        if (k.ends_with("/distribution.bin")) continue;
        EXPECT_TRUE(k.ends_with(".lz4")) << k << ": a piece stored as it is";
        ++pieces;
    }
    EXPECT_GT(pieces, 2u) << "the case needs a shuffle of several chunks";
    // Every chunk (plan.json names how many), then the merge.
    const nlohmann::json plan = nlohmann::json::parse(get(*store_, "stages/work/plan.json"));
    std::vector<std::string> chunk = {"chunk"};
    for (size_t i = 0; i < plan["chunks"].get<size_t>(); ++i) chunk.push_back(std::to_string(i));
    auto r = stage(chunk, work);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = stage({"merge"}, work);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<std::string> one = {binary("surfcast-build"), "-q"};
    one.insert(one.end(), scene.begin(), scene.end());
    one.insert(one.end(), {"-o", dir.file("one")});
    r = run(one);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(readFile(dir.file(std::string("set/") + f)) == readFile(dir.file(std::string("one/") + f))) << f;

    // A damaged piece: its chunk task fails, naming the object.
    const std::string damaged = "s3://surfcast/stages/damaged";
    ASSERT_NO_FATAL_FAILURE(stages(damaged, dir.file("set2")));
    std::string victim;
    for (const std::string& k : keys(*store_, "stages/damaged/chunks/"))
        if (k.ends_with(".bin.lz4")) victim = "stages/damaged/chunks/" + k;
    ASSERT_FALSE(victim.empty());
    std::string bytes = get(*store_, victim);
    ASSERT_GT(bytes.size(), 64u);
    bytes.resize(bytes.size() / 2);
    auto put = store_->put({SeaweedFs::kBucket, victim}, std::vector<uint8_t>(bytes.begin(), bytes.end()));
    ASSERT_TRUE(put.ok()) << put.status().message();
    const std::string file = victim.substr(victim.rfind('/') + 1);
    const std::string index = file.substr(6, file.find('.') - 6);  // chunk-I.bin.lz4
    r = stage({"chunk", index}, damaged);
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("s3://surfcast/" + victim + ": its LZ4 frame ends early"), std::string::npos) << r.output;
    // A whole frame with a byte after it, and a piece stored as it is.
    ASSERT_NO_FATAL_FAILURE(stages(damaged, dir.file("set3")));  // the plan removes the pieces; distribute puts them again
    std::string whole = get(*store_, victim) + "x";
    put = store_->put({SeaweedFs::kBucket, victim}, std::vector<uint8_t>(whole.begin(), whole.end()));
    ASSERT_TRUE(put.ok()) << put.status().message();
    r = stage({"chunk", index}, damaged);
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("s3://surfcast/" + victim + ": bytes after its LZ4 frame"), std::string::npos) << r.output;
    const std::string plain = victim.substr(0, victim.size() - 4);
    put = store_->put({SeaweedFs::kBucket, plain}, std::vector<uint8_t>{1, 2, 3});
    ASSERT_TRUE(put.ok()) << put.status().message();
    r = stage({"chunk", index}, damaged);
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("s3://surfcast/" + plain + ": not a work file's name"), std::string::npos) << r.output;
}

TEST_F(Store, RefusalsFailAtOnceAndLeaveNothing) {
    auto put = store_->putFile({SeaweedFs::kBucket, "refusals/autzen_trim.las"}, dataFile("autzen_trim.las"));
    ASSERT_TRUE(put.ok()) << put.status().message();
    TempDir dir;
    struct Case {
        std::vector<std::string> environment;  // NAME=VALUE set for the run
        std::string input, message;
    };
    const std::vector<Case> cases = {
        {{"AWS_SECRET_ACCESS_KEY=wrong-secret-value"}, "s3://surfcast/refusals/autzen_trim.las", "s3://surfcast/refusals/autzen_trim.las: HTTP 403"},
        {{}, "s3://no-such-bucket/a.las", "s3://no-such-bucket/a.las: HTTP 404"},
        {{}, "s3://surfcast/refusals/absent.las", "s3://surfcast/refusals/absent.las: HTTP 404"},
        {{}, "s3://surfcast/refusals/empty/", "s3://surfcast/refusals/empty/: the prefix holds no object of a readable format"},
        {{"AWS_ACCESS_KEY_ID=", "AWS_SECRET_ACCESS_KEY=only-half"}, "s3://surfcast/refusals/autzen_trim.las", "one is set without the other"},
    };
    // Through a proxy that fails nothing and counts the requests.
    FaultProxy counter(0, 1);
    for (const auto& c : cases) {
        std::vector<std::string> args = {"/usr/bin/env", "AWS_ENDPOINT_URL=" + counter.endpoint()};
        args.insert(args.end(), c.environment.begin(), c.environment.end());
        args.insert(args.end(), {binary("surfcast-build"), "-q", c.input, "-o", "s3://surfcast/sets/refused"});
        const int before = counter.counts()["forwarded"].get<int>();
        auto r = run(args);
        EXPECT_EQ(r.exitCode, 1) << c.input << ": " << r.output;
        EXPECT_NE(r.output.find(c.message), std::string::npos) << c.input << ": " << r.output;
        EXPECT_EQ(r.output.find("secret-value"), std::string::npos) << r.output;
        EXPECT_EQ(r.output.find(SeaweedFs::kSecret), std::string::npos) << r.output;
        EXPECT_EQ(r.output.find("only-half"), std::string::npos) << r.output;
        // Not retried: a refusal is final. The input's size is asked once (a
        // bucket's refusal a second time, to tell NoSuchBucket apart).
        EXPECT_LE(counter.counts()["forwarded"].get<int>() - before, 2) << c.input;
    }
    EXPECT_TRUE(keys(*store_, "sets/refused/").empty()) << "a failed build leaves no object";
}

}  // namespace
