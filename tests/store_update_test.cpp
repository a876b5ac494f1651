// Living sets in a real S3 store (SeaweedFS, tests/store_support.h): --add,
// --remove, --compact and --merge on s3:// sets write the objects the same
// commands write as files in a folder; untouched objects keep their ETags;
// of two updates of one version exactly one wins, and no update is lost;
// what no kept version names goes, and nothing else.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <future>
#include <map>
#include <set>
#include <thread>

#include "crc32.h"
#include "object_store.h"
#include "set_publisher.h"
#include "store_support.h"
#include "test_support.h"
#include "tileset_reader.h"
#include "update_support.h"

using namespace surfcast;
using namespace surfcast::test;
using namespace surfcast::update_test;

namespace {

// Every object under `prefix`, by its name below it.
std::map<std::string, ListedObject> objects(ObjectStore& store, const std::string& prefix) {
    auto listed = store.list({SeaweedFs::kBucket, prefix});
    EXPECT_TRUE(listed.ok()) << (listed.ok() ? "" : listed.status().message());
    std::map<std::string, ListedObject> out;
    if (listed.ok())
        for (const ListedObject& o : *listed) out[o.key.substr(prefix.size())] = o;
    return out;
}

std::string get(ObjectStore& store, const std::string& key) {
    auto bytes = store.get({SeaweedFs::kBucket, key}, 1u << 30);
    EXPECT_TRUE(bytes.ok()) << key << ": " << (bytes.ok() ? "" : bytes.status().message());
    return bytes.ok() ? std::string(bytes->begin(), bytes->end()) : std::string();
}

TilesetInfo infoOf(const std::string& json) {
    auto info = readTilesetJson(json, "tileset.json");
    EXPECT_TRUE(info.ok()) << (info.ok() ? "" : info.status().message());
    return info.ok() ? *info : TilesetInfo{};
}

// The objects the store's Last-Modified (whole seconds) tells apart from
// those of the step before: publishVersion deletes by it.
void nextSecond() { std::this_thread::sleep_for(std::chrono::milliseconds(1100)); }

class StoreUpdate : public UpdateTest {
protected:
    void SetUp() override {
        UpdateTest::SetUp();
        if (HasFatalFailure() || IsSkipped()) return;
        s3_ = &SeaweedFs::shared();
        s3_->exportEnvironment();
        store_ = s3_->store();
    }
    void upload(const std::string& folder, const std::string& prefix) { uploadFolder(*store_, folder, prefix); }
    SeaweedFs* s3_ = nullptr;
    std::shared_ptr<ObjectStore> store_;
};

// The same --add, then --remove, of a set in a folder and of its copy in a
// bucket: after each, the bucket holds the folder's files byte for byte
// (the build record aside, which names the set where it lies), the objects
// the update did not write keep their ETags, and the previous version's
// objects stay for readers that opened it while older ones go.
TEST_F(StoreUpdate, AddAndRemoveWriteTheObjectsOfTheSameUpdatesOfAFolder) {
    const std::string prefix = "living/a/", url = "s3://surfcast/living/a";
    ASSERT_NO_FATAL_FAILURE(upload(set(), prefix));
    const auto before = objects(*store_, prefix);
    nextSecond();

    const std::vector<std::vector<std::string>> updates = {{"--add", added[0]}, {"--remove", fs::path(base[3]).filename().string()}};
    std::vector<TilesetInfo> versions = {infoOf(get(*store_, prefix + "tileset.json"))};
    for (const auto& update : updates) {
        std::vector<std::string> args = {binary("surfcast-build"), "-q"};
        args.insert(args.end(), update.begin(), update.end());
        auto local = args, remote = args;
        local.insert(local.end(), {"--to", set()});
        remote.insert(remote.end(), {"--to", url});
        auto r = run(local);
        ASSERT_EQ(r.exitCode, 0) << r.output;
        r = run(remote);
        ASSERT_EQ(r.exitCode, 0) << r.output;
        EXPECT_NE(r.output.find("published " + url + "/"), std::string::npos) << r.output;
        EXPECT_EQ(r.output.find(SeaweedFs::kSecret), std::string::npos) << r.output;

        const auto now = objects(*store_, prefix);
        const TilesetInfo info = infoOf(get(*store_, prefix + "tileset.json"));
        versions.push_back(info);
        for (const std::string& file : versionFiles(info)) {
            if (file == buildRecordFile(info.hierarchyFile)) {
                EXPECT_TRUE(now.count(file)) << file;
                continue;
            }
            ASSERT_TRUE(fs::exists(set() + "/" + file)) << file << " is not the folder update's";
            EXPECT_TRUE(get(*store_, prefix + file) == readFile(set() + "/" + file)) << file;
        }
        EXPECT_TRUE(get(*store_, prefix + "tileset.json") == readFile(set() + "/tileset.json"));
        for (const auto& [name, object] : before) {
            if (now.count(name) && name != "tileset.json") {
                EXPECT_EQ(now.at(name).etag, object.etag) << name << " was written again";
            }
        }
        // What the set holds now: tileset.json and the files of the current
        // version and the previous one; nothing of the versions before.
        std::set<std::string> kept = {"tileset.json"};
        for (size_t v = versions.size() - 2; v < versions.size(); ++v)
            for (const std::string& file : versionFiles(versions[v])) kept.insert(file);
        std::set<std::string> held;
        for (const auto& [name, object] : now) held.insert(name);
        EXPECT_EQ(held, kept);
        nextSecond();
    }
    auto r = run({binary("surfcast-build"), "--info", url});
    EXPECT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("checksums verified"), std::string::npos) << r.output;
}

// Two updates of one version: the second to switch tileset.json finds it
// changed (If-Match) and fails, naming the set, which stays the first's.
// Then two updaters at once, each adding a scan of its own: however they
// interleave, every one that says it succeeded is in the set.
TEST_F(StoreUpdate, OfTwoUpdatesOfOneVersionExactlyOneWins) {
    const std::string prefix = "living/race/", url = "s3://surfcast/living/race";
    ASSERT_NO_FATAL_FAILURE(upload(set(), prefix));
    TempDir mirror;
    auto read = mirrorSetMetadata(url, mirror.path());
    ASSERT_TRUE(read.ok()) << read.status().message();
    auto r = run({binary("surfcast-build"), "-q", "--add", added[0], "--to", url});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::string winner = get(*store_, prefix + "tileset.json");
    auto lost = publishVersion(mirror.path(), *read);
    ASSERT_FALSE(lost.ok()) << "an update of a version that is gone switched the set";
    EXPECT_NE(lost.status().message().find(url + "/: changed since this update read it"), std::string::npos) << lost.status().message();
    EXPECT_TRUE(get(*store_, prefix + "tileset.json") == winner);

    // At once: copies of one cell under two names.
    const std::string a = dir.file("east.laz"), b = dir.file("west.laz");
    fs::copy_file(base[0], a);
    fs::copy_file(base[0], b);
    auto first = std::async(std::launch::async, [&] { return run({binary("surfcast-build"), "-q", "--add", a, "--to", url}); });
    auto second = std::async(std::launch::async, [&] { return run({binary("surfcast-build"), "-q", "--add", b, "--to", url}); });
    const RunResult one = first.get(), two = second.get();
    const TilesetInfo info = infoOf(get(*store_, prefix + "tileset.json"));
    int won = 0;
    for (const auto& [result, name] : {std::pair{one, std::string("east.laz")}, {two, std::string("west.laz")}}) {
        const bool in = std::find(info.inputs.begin(), info.inputs.end(), name) != info.inputs.end();
        if (result.exitCode == 0) {
            ++won;
            EXPECT_TRUE(in) << name << "'s update said it succeeded, but the set has no " << name << ": " << result.output;
        } else {
            EXPECT_EQ(result.exitCode, 1) << result.output;
            EXPECT_FALSE(in) << name;
            EXPECT_NE(result.output.find("run the update again"), std::string::npos) << result.output;
        }
    }
    EXPECT_GE(won, 1);
    r = run({binary("surfcast-build"), "--info", url});
    EXPECT_EQ(r.exitCode, 0) << r.output;
}

// --compact of a set in a bucket writes the nodes' blocks of a folder's
// compaction, byte for byte, in a file named by its CRC beside a new
// hierarchy; once compact, it writes nothing. The next update then deletes
// the objects only the versions before the compaction named.
TEST_F(StoreUpdate, CompactionWritesTheBlocksOfAFolderCompaction) {
    const std::string prefix = "living/compact/", url = "s3://surfcast/living/compact";
    auto r = run({binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_NO_FATAL_FAILURE(upload(set(), prefix));
    nextSecond();
    r = run({binary("surfcast-build"), "-q", "--compact", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = run({binary("surfcast-build"), "-q", "--compact", url});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const TilesetInfo info = infoOf(get(*store_, prefix + "tileset.json"));
    const std::string blocks = readFile(set() + "/blocks.bin"), hierarchy = readFile(set() + "/hierarchy.bin");
    ASSERT_EQ(blocksPartsOf(info).size(), 1u);
    EXPECT_EQ(blocksPartsOf(info)[0].file, versionedBlocksFile(crc32(reinterpret_cast<const uint8_t*>(blocks.data()), blocks.size())));
    EXPECT_TRUE(get(*store_, prefix + blocksPartsOf(info)[0].file) == blocks);
    EXPECT_TRUE(get(*store_, prefix + info.hierarchyFile) == hierarchy);
    EXPECT_TRUE(get(*store_, prefix + buildRecordFile(info.hierarchyFile)) == readFile(set() + "/build.bin"));
    r = run({binary("surfcast-build"), "--compact", url});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("is compact already"), std::string::npos) << r.output;
    nextSecond();

    r = run({binary("surfcast-build"), "-q", "--remove", fs::path(added[0]).filename().string(), "--to", url});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const TilesetInfo last = infoOf(get(*store_, prefix + "tileset.json"));
    std::set<std::string> kept = {"tileset.json"}, held;
    for (const TilesetInfo* v : {&info, &last})
        for (const std::string& file : versionFiles(*v)) kept.insert(file);
    for (const auto& [name, object] : objects(*store_, prefix)) held.insert(name);
    EXPECT_EQ(held, kept) << "blocks.bin and the first hierarchy go once no kept version names them";
    r = run({binary("surfcast-build"), "--info", url});
    EXPECT_EQ(r.exitCode, 0) << r.output;
}

// An update through a proxy that fails 1 % of the requests (503
// SlowDown before the store acts, 500 or a reset after it has) writes the
// objects of the same update made directly, the conditional switch
// included, whose answers may be lost on the way back.
TEST_F(StoreUpdate, TransientFaultsGiveTheSameObjects) {
    ASSERT_NO_FATAL_FAILURE(upload(set(), "living/direct/"));
    ASSERT_NO_FATAL_FAILURE(upload(set(), "living/faults/"));
    auto r = run({binary("surfcast-build"), "-q", "--add", added[0], "--to", "s3://surfcast/living/direct"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    FaultProxy proxy(0.01, 11);
    r = run({"/usr/bin/env", "AWS_ENDPOINT_URL=" + proxy.endpoint(), binary("surfcast-build"), "-q", "--add", added[0], "--to",
             "s3://surfcast/living/faults"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto faults = proxy.counts();
    EXPECT_GE(faults.value("slowdown", 0) + faults.value("error", 0) + faults.value("reset", 0), 1) << faults.dump();
    const auto direct = objects(*store_, "living/direct/"), faulty = objects(*store_, "living/faults/");
    ASSERT_EQ(faulty.size(), direct.size());
    for (const auto& [name, object] : direct) {
        ASSERT_TRUE(faulty.count(name)) << name;
        EXPECT_TRUE(get(*store_, "living/faults/" + name) == get(*store_, "living/direct/" + name)) << name;
    }
}

// --merge takes sets in a bucket as it takes folders: the same set (their
// prefixes named as the folders are, since a set's inputs are named by them).
TEST_F(StoreUpdate, MergeReadsSetsInABucket) {
    ASSERT_NO_FATAL_FAILURE(upload(set(), "living/merge/s/"));
    auto r = run(build({added[0], "-o", dir.file("cell")}));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_NO_FATAL_FAILURE(upload(dir.file("cell"), "living/merge/cell/"));
    r = run({binary("surfcast-build"), "-q", "--merge", set(), dir.file("cell"), "-o", dir.file("merged")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = run({binary("surfcast-build"), "-q", "--merge", "s3://surfcast/living/merge/s", "s3://surfcast/living/merge/cell/", "-o",
             dir.file("merged-from-store")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    for (const char* file : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(readFile(dir.file("merged") + "/" + file) == readFile(dir.file("merged-from-store") + "/" + file)) << file;
}

// Refusals: no set at the prefix, an update in stages, and a user who may
// only read, whose update fails at its first write and leaves the set as it was.
TEST_F(StoreUpdate, RefusalsNameTheSetAndLeaveItAsItWas) {
    const std::string prefix = "living/refused/", url = "s3://surfcast/living/refused";
    auto r = run({binary("surfcast-build"), "-q", "--add", added[0], "--to", "s3://surfcast/living/none"});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("s3://surfcast/living/none/: not a tile set (no tileset.json)"), std::string::npos) << r.output;
    r = run({binary("surfcast-build"), "update-plan", "--work", dir.file("work"), "--add", added[0], "--to", url});
    EXPECT_EQ(r.exitCode, 2) << r.output;

    ASSERT_NO_FATAL_FAILURE(upload(set(), prefix));
    const auto before = objects(*store_, prefix);
    r = run({"/usr/bin/env", std::string("AWS_ACCESS_KEY_ID=") + SeaweedFs::kReaderKey,
             std::string("AWS_SECRET_ACCESS_KEY=") + SeaweedFs::kReaderSecret, binary("surfcast-build"), "-q", "--add", added[0], "--to", url});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("HTTP 403"), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find(SeaweedFs::kReaderSecret), std::string::npos) << r.output;
    const auto after = objects(*store_, prefix);
    ASSERT_EQ(after.size(), before.size());
    for (const auto& [name, object] : before) EXPECT_EQ(after.at(name).etag, object.etag) << name;
}

}  // namespace
