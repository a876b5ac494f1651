// The object-store client (net/object_store.h) against a real S3 server
// (SeaweedFS, tests/store_support.h): every request it makes, its conditions,
// multipart uploads, key encoding, and its errors; and the credential chain.
#include <gtest/gtest.h>

#include <cstdlib>
#include <ctime>
#include <fstream>
#include <random>
#include <thread>
#include <atomic>

#include "object_store.h"
#include "set_publisher.h"
#include "store_support.h"
#include "test_support.h"

using namespace surfcast;
using namespace surfcast::test;

namespace {

std::vector<uint8_t> randomBytes(size_t n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::vector<uint8_t> out(n);
    for (auto& b : out) b = uint8_t(rng());
    return out;
}

S3Url object(const std::string& key) { return {SeaweedFs::kBucket, key}; }

// Clears the AWS variables for the chain's tests, and restores them after.
class CleanEnvironment {
public:
    CleanEnvironment() {
        for (const char* name : kNames)
            if (const char* v = std::getenv(name)) saved_.emplace_back(name, v);
        for (const char* name : kNames) unsetenv(name);
    }
    ~CleanEnvironment() {
        for (const char* name : kNames) unsetenv(name);
        for (auto& [name, value] : saved_) setenv(name.c_str(), value.c_str(), 1);
    }

private:
    static constexpr const char* kNames[] = {"AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN", "AWS_PROFILE",
                                             "AWS_SHARED_CREDENTIALS_FILE", "AWS_CONFIG_FILE", "AWS_REGION", "AWS_DEFAULT_REGION",
                                             "AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3", "HOME"};
    std::vector<std::pair<std::string, std::string>> saved_;
};

}  // namespace

TEST(ObjectStore, WritesReadsListsAndDeletes) {
    SeaweedFs& s3 = SeaweedFs::shared();
    auto store = s3.store();
    const auto bytes = randomBytes(300'000, 1);
    auto put = store->put(object("set/a.bin"), bytes);
    ASSERT_TRUE(put.ok()) << put.status().message();
    ASSERT_TRUE(put->has_value());

    auto head = store->head(object("set/a.bin"));
    ASSERT_TRUE(head.ok()) << head.status().message();
    ASSERT_TRUE(head->has_value());
    EXPECT_EQ((*head)->size, bytes.size());
    EXPECT_EQ((*head)->etag, (**put).etag);
    // Last-Modified within a minute of this machine's clock (the store runs on it).
    EXPECT_LT(std::abs((*head)->modified - int64_t(std::time(nullptr))), 60) << (*head)->modified;

    auto whole = store->get(object("set/a.bin"), bytes.size());
    ASSERT_TRUE(whole.ok()) << whole.status().message();
    EXPECT_EQ(*whole, bytes);
    auto tooSmall = store->get(object("set/a.bin"), bytes.size() - 1);
    ASSERT_FALSE(tooSmall.ok());
    EXPECT_NE(tooSmall.status().message().find("longer than"), std::string::npos) << tooSmall.status().message();

    auto range = store->getRange(object("set/a.bin"), 123'456, 1000);
    ASSERT_TRUE(range.ok()) << range.status().message();
    EXPECT_EQ(*range, std::vector<uint8_t>(bytes.begin() + 123'456, bytes.begin() + 124'456));
    auto past = store->getRange(object("set/a.bin"), bytes.size() - 10, 20);
    EXPECT_FALSE(past.ok());

    // Keys with characters that SigV4 encodes, under two prefixes.
    const std::vector<std::string> keys = {"set/b c.bin", "set/ü+x=1&y.bin", "set2/a.bin"};
    for (const auto& k : keys) {
        auto r = store->put(object(k), {1, 2, 3});
        ASSERT_TRUE(r.ok()) << k << ": " << r.status().message();
    }
    auto listed = store->list(object("set/"));
    ASSERT_TRUE(listed.ok()) << listed.status().message();
    for (const auto& o : *listed) EXPECT_LT(std::abs(o.modified - int64_t(std::time(nullptr))), 60) << o.key;
    std::vector<std::string> names;
    for (const auto& o : *listed) names.push_back(o.key);
    EXPECT_EQ(names, (std::vector<std::string>{"set/a.bin", "set/b c.bin", "set/ü+x=1&y.bin"}));
    EXPECT_EQ((*listed)[0].size, bytes.size());
    auto odd = store->get(object("set/ü+x=1&y.bin"), 3);
    ASSERT_TRUE(odd.ok()) << odd.status().message();
    EXPECT_EQ(*odd, (std::vector<uint8_t>{1, 2, 3}));

    ASSERT_TRUE(store->remove(object("set/a.bin")).ok());
    ASSERT_TRUE(store->remove(object("set/a.bin")).ok()) << "deleting an absent object succeeds";
    auto gone = store->head(object("set/a.bin"));
    ASSERT_TRUE(gone.ok()) << gone.status().message();
    EXPECT_FALSE(gone->has_value());
    auto missing = store->get(object("set/a.bin"), 10);
    ASSERT_FALSE(missing.ok());
    EXPECT_NE(missing.status().message().find("s3://surfcast/set/a.bin"), std::string::npos) << missing.status().message();
    EXPECT_NE(missing.status().message().find("404"), std::string::npos) << missing.status().message();
}

TEST(ObjectStore, ListsPastOnePage) {
    // S3 answers a listing 1,000 keys a page: the client follows the pages.
    SeaweedFs& s3 = SeaweedFs::shared();
    auto store = s3.store();
    constexpr int kObjects = 1003;
    for (int i = 0; i < kObjects; ++i) {
        char key[32];
        std::snprintf(key, sizeof key, "many/%05d", i);
        ASSERT_TRUE(store->put(object(key), {uint8_t(i)}).ok());
    }
    auto listed = store->list(object("many/"));
    ASSERT_TRUE(listed.ok()) << listed.status().message();
    ASSERT_EQ(listed->size(), size_t(kObjects));
    EXPECT_EQ(listed->back().key, "many/01002");
}

TEST(ObjectStore, ConditionalWritesLetOneWriterWin) {
    SeaweedFs& s3 = SeaweedFs::shared();
    auto store = s3.store();
    const WriteCondition absent{true, ""};
    auto first = store->put(object("c/tileset.json"), {'1'}, absent);
    ASSERT_TRUE(first.ok()) << first.status().message();
    ASSERT_TRUE(first->has_value());
    auto second = store->put(object("c/tileset.json"), {'2'}, absent);
    ASSERT_TRUE(second.ok()) << second.status().message();
    EXPECT_FALSE(second->has_value()) << "If-None-Match: * over an existing object must fail";

    // If-Match: the writer holding the current ETag wins, a stale one loses.
    const std::string etag1 = (**first).etag;
    auto third = store->put(object("c/tileset.json"), {'3'}, {false, etag1});
    ASSERT_TRUE(third.ok()) << third.status().message();
    ASSERT_TRUE(third->has_value()) << "If-Match with the current ETag must succeed";
    auto stale = store->put(object("c/tileset.json"), {'4'}, {false, etag1});
    ASSERT_TRUE(stale.ok()) << stale.status().message();
    EXPECT_FALSE(stale->has_value()) << "If-Match with a replaced ETag must fail";
    auto now = store->get(object("c/tileset.json"), 10);
    ASSERT_TRUE(now.ok());
    EXPECT_EQ(*now, std::vector<uint8_t>{'3'});
}

// Through a proxy that fails a third of the requests: every write succeeds
// once, including conditional ones whose first try took effect at the store
// while its answer was lost (a 500 or a reset after the store acted), which
// the retry then finds refused by its own condition.
TEST(ObjectStore, ConditionalWritesSurviveLostAnswers) {
    SeaweedFs& s3 = SeaweedFs::shared();
    FaultProxy proxy(0.34, 3);
    S3Environment e = s3.environment();
    e.endpoint = proxy.endpoint();
    auto opened = ObjectStore::open(e);
    ASSERT_TRUE(opened.ok());
    auto store = *opened;
    TempDir dir;
    writeFile(dir.file("f.bin"), "file bytes");
    for (int i = 0; i < 20; ++i) {
        const std::vector<uint8_t> bytes = randomBytes(1000, uint32_t(i));
        auto put = store->put(object("lost/" + std::to_string(i)), bytes, {true, ""});
        ASSERT_TRUE(put.ok()) << i << ": " << put.status().message();
        EXPECT_TRUE(put->has_value()) << i << ": a write refused by its own earlier try";
        auto file = store->putFile(object("lost/f" + std::to_string(i)), dir.file("f.bin"), {true, ""});
        ASSERT_TRUE(file.ok()) << i << ": " << file.status().message();
        EXPECT_TRUE(file->has_value()) << i << ": a file refused by its own earlier try";
    }
    const auto faults = proxy.counts();
    EXPECT_GE(faults["error"].get<int>() + faults["reset"].get<int>(), 5) << faults.dump();
    // And another writer's object still wins over the condition.
    auto taken = store->put(object("lost/0"), {1}, {true, ""});
    ASSERT_TRUE(taken.ok()) << taken.status().message();
    EXPECT_FALSE(taken->has_value());
}

TEST(ObjectStore, UploadsLargeFilesInParts) {
    SeaweedFs& s3 = SeaweedFs::shared();
    auto store = s3.store();
    TempDir dir;
    // Just past the threshold: a multipart upload whose last part is short.
    const auto bytes = randomBytes(size_t(ObjectStore::kMultipartThreshold + 1'000'003), 7);
    writeFile(dir.file("big.bin"), std::string(bytes.begin(), bytes.end()));
    auto put = store->putFile(object("big/blocks.bin"), dir.file("big.bin"), {true, ""});
    ASSERT_TRUE(put.ok()) << put.status().message();
    ASSERT_TRUE(put->has_value());
    const auto before = store->counts().requests;
    auto head = store->head(object("big/blocks.bin"));
    ASSERT_TRUE(head.ok() && head->has_value());
    EXPECT_EQ((*head)->size, bytes.size());
    // A multipart object's ETag is "MD5-PARTS": the parts the file went up in.
    const uint64_t parts = (bytes.size() + ObjectStore::kPartBytes - 1) / ObjectStore::kPartBytes;
    EXPECT_NE((*head)->etag.find("-" + std::to_string(parts) + "\""), std::string::npos) << (*head)->etag;
    auto tail = store->getRange(object("big/blocks.bin"), bytes.size() - 5000, 5000);
    ASSERT_TRUE(tail.ok()) << tail.status().message();
    EXPECT_TRUE(std::equal(tail->begin(), tail->end(), bytes.end() - 5000));
    EXPECT_EQ(store->counts().requests, before + 2);
    // The condition holds for a multipart upload too: it is checked on
    // completion. Other bytes lose; the same bytes are taken as this
    // writer's own (a write whose answer was lost, tried again).
    auto other = bytes;
    other[12345] ^= 1;
    writeFile(dir.file("other.bin"), std::string(other.begin(), other.end()));
    auto lost = store->putFile(object("big/blocks.bin"), dir.file("other.bin"), {true, ""});
    ASSERT_TRUE(lost.ok()) << lost.status().message();
    EXPECT_FALSE(lost->has_value());
    auto same = store->putFile(object("big/blocks.bin"), dir.file("big.bin"), {true, ""});
    ASSERT_TRUE(same.ok()) << same.status().message();
    EXPECT_TRUE(same->has_value());
}

TEST(ObjectStore, RefusalsFailAtOnceNamingBucketAndKeyNeverTheSecret) {
    SeaweedFs& s3 = SeaweedFs::shared();
    // A wrong secret: 403, not retried.
    auto wrong = s3.store(SeaweedFs::kKey, "not-the-secret");
    auto r = wrong->get(object("x/tileset.json"), 100);
    ASSERT_FALSE(r.ok());
    EXPECT_FALSE(r.status().isTransient());
    EXPECT_EQ(wrong->counts().retries, 0u);
    EXPECT_NE(r.status().message().find("s3://surfcast/x/tileset.json"), std::string::npos) << r.status().message();
    EXPECT_NE(r.status().message().find("403"), std::string::npos) << r.status().message();
    EXPECT_EQ(r.status().message().find("not-the-secret"), std::string::npos) << r.status().message();

    // The reader may read and list but not write.
    auto reader = s3.store(SeaweedFs::kReaderKey, SeaweedFs::kReaderSecret);
    auto denied = reader->put(object("x/a.bin"), {1});
    ASSERT_FALSE(denied.ok());
    EXPECT_NE(denied.status().message().find("403"), std::string::npos) << denied.status().message();
    EXPECT_EQ(denied.status().message().find(SeaweedFs::kReaderSecret), std::string::npos);
    EXPECT_TRUE(reader->list(object("x/")).ok());

    // A bucket that does not exist, by GET and by HEAD.
    auto store = s3.store();
    auto nobucket = store->get({"no-such-bucket", "a/tileset.json"}, 100);
    ASSERT_FALSE(nobucket.ok());
    EXPECT_NE(nobucket.status().message().find("NoSuchBucket"), std::string::npos) << nobucket.status().message();
    EXPECT_NE(nobucket.status().message().find("s3://no-such-bucket/a/tileset.json"), std::string::npos);
    auto nohead = store->head({"no-such-bucket", "a/tileset.json"});
    ASSERT_FALSE(nohead.ok());
    EXPECT_NE(nohead.status().message().find("no-such-bucket"), std::string::npos) << nohead.status().message();
    EXPECT_EQ(store->counts().retries, 0u);
}

// A listing page as S3 writes it: entities decoded, sizes checked, the next
// page's token; and pages a broken store might send, refused.
TEST(ObjectStore, ListPagesAreReadStrictly) {
    auto page = parseListPage("<ListBucketResult><IsTruncated>true</IsTruncated><NextContinuationToken>t1</NextContinuationToken>"
                              "<Contents><Key>a&amp;b&#x3C;.bin</Key><ETag>&quot;x&quot;</ETag><Size>18446744073709551615</Size></Contents>"
                              "<Contents><Key>c</Key><Size>0</Size></Contents></ListBucketResult>");
    ASSERT_TRUE(page.ok()) << page.status().message();
    ASSERT_EQ(page->objects.size(), 2u);
    EXPECT_EQ(page->objects[0].key, "a&b<.bin");
    EXPECT_EQ(page->objects[0].etag, "\"x\"");
    EXPECT_EQ(page->objects[0].size, 18446744073709551615ull);
    EXPECT_TRUE(page->truncated);
    EXPECT_EQ(page->next, "t1");
    for (const char* bad : {"<Contents><Size>1</Size></Contents>", "<Contents><Key>k</Key><Size>-1</Size></Contents>",
                            "<Contents><Key>k</Key><Size>18446744073709551616</Size></Contents>",
                            "<Contents><Key>k&bogus;</Key><Size>1</Size></Contents>", "<Contents><Key>k&#300;</Key><Size>1</Size></Contents>"})
        EXPECT_FALSE(parseListPage(bad).ok()) << bad;
    // LastModified: whole seconds since 1970 (Python's calendar.timegm((2026, 12, 7, 1, 2, 3)));
    // anything else leaves it unknown, which no deletion takes for old.
    auto dated = parseListPage("<Contents><Key>k</Key><Size>1</Size><LastModified>2026-12-07T01:02:03.000Z</LastModified></Contents>");
    ASSERT_TRUE(dated.ok()) << dated.status().message();
    EXPECT_EQ(dated->objects[0].modified, 1796605323);
    EXPECT_EQ(parseIsoTime("2026-12-07T01:02:03Z"), std::optional<int64_t>(1796605323));
    for (const char* bad : {"2026-12-07 01:02:03Z", "2026-12-07T01:02:03", "2026-13-07T01:02:03Z", "2026-12-07T01:02:03.Zx", "x026-12-07T01:02:03Z", ""})
        EXPECT_FALSE(parseIsoTime(bad).has_value()) << bad;
    EXPECT_EQ(page->objects[0].modified, -1);
}

// Stages starting at once on one machine each make a staging folder while
// clearing those of processes gone (whose lock nobody holds): none may take
// another's new folder, made but not yet locked, for such a one. Threads
// stand for the processes (flock locks belong to each open of the folder).
TEST(ObjectStore, StagingFoldersMadeAtOnceAreEachTheirOwn) {
    TempDir tmp;
    const char* before = std::getenv("TMPDIR");
    const std::string saved = before ? before : "";
    setenv("TMPDIR", tmp.path().c_str(), 1);
    std::atomic<int> failures{0};
    std::vector<std::thread> threads;
    for (int t = 0; t < 8; ++t)
        threads.emplace_back([&] {
            for (int i = 0; i < 40; ++i) {
                auto staging = PublishStaging::create();
                if (!staging || !std::filesystem::is_directory((*staging)->dir())) ++failures;
                else writeFile((*staging)->dir() + "/file", "x");
            }
        });
    for (auto& t : threads) t.join();
    if (before) setenv("TMPDIR", saved.c_str(), 1);
    else unsetenv("TMPDIR");
    EXPECT_EQ(failures.load(), 0);
    EXPECT_TRUE(std::filesystem::is_empty(tmp.path())) << "staging folders left behind";
}

TEST(ObjectStore, UrlsAreParsedStrictly) {
    auto ok = parseS3Url("s3://my.bucket-1/sets/a b/");
    ASSERT_TRUE(ok.ok());
    EXPECT_EQ(ok->bucket, "my.bucket-1");
    EXPECT_EQ(ok->key, "sets/a b/");
    EXPECT_FALSE(parseS3Url("s3://Upper/key").ok());
    EXPECT_FALSE(parseS3Url("s3://ab/key").ok());
    EXPECT_FALSE(parseS3Url("s3://bucket/a//b").ok());
    EXPECT_FALSE(parseS3Url("s3://bucket/../b").ok());
    EXPECT_FALSE(parseS3Url("http://bucket/b").ok());
    // Prefixes end in exactly one '/'; a whole bucket is "" unless refused.
    for (const auto& [url, key] : std::vector<std::pair<std::string, std::string>>{
             {"s3://bkt/sets/a", "sets/a/"}, {"s3://bkt/sets/a/", "sets/a/"}, {"s3://bkt/", ""}}) {
        auto prefix = parseS3Prefix(url);
        ASSERT_TRUE(prefix.ok()) << url << ": " << prefix.status().message();
        EXPECT_EQ(prefix->key, key) << url;
    }
    auto whole = parseS3Prefix("s3://bkt/", "set");
    ASSERT_FALSE(whole.ok());
    EXPECT_NE(whole.status().message().find("give the set a prefix of its own"), std::string::npos);
    S3Environment e;
    e.endpoint = "http://127.0.0.1:9000";
    e.pathStyle = true;
    EXPECT_EQ(s3HttpUrl(e, {"b-1", "a b/ü"}), "http://127.0.0.1:9000/b-1/a%20b/%C3%BC");
    e.endpoint = "https://s3.eu-west-1.amazonaws.com";
    e.pathStyle = false;
    EXPECT_EQ(s3HttpUrl(e, {"b-1", "k"}), "https://b-1.s3.eu-west-1.amazonaws.com/k");
}

TEST(ObjectStore, CredentialsComeFromTheStandardChainInItsOrder) {
    CleanEnvironment clean;
    TempDir dir;
    setenv("HOME", dir.path().c_str(), 1);
    // Nothing anywhere: unsigned requests to AWS in us-east-1.
    auto none = s3Environment();
    ASSERT_TRUE(none.ok()) << none.status().message();
    EXPECT_TRUE(none->accessKey.empty());
    EXPECT_EQ(none->region, "us-east-1");
    EXPECT_EQ(none->endpoint, "https://s3.us-east-1.amazonaws.com");
    EXPECT_FALSE(none->pathStyle);

    std::filesystem::create_directories(dir.file(".aws"));
    writeFile(dir.file(".aws/credentials"), "[default]\naws_access_key_id = FILEKEY\naws_secret_access_key = filesecret\n"
                                            "[other]\naws_access_key_id=OTHERKEY\naws_secret_access_key=othersecret\naws_session_token=tok\n");
    writeFile(dir.file(".aws/config"), "[default]\nregion = eu-west-1\n[profile other]\nregion = ap-south-1\nendpoint_url = http://store:9000\n");
    auto files = s3Environment();
    ASSERT_TRUE(files.ok()) << files.status().message();
    EXPECT_EQ(files->accessKey, "FILEKEY");
    EXPECT_EQ(files->secretKey, "filesecret");
    EXPECT_EQ(files->region, "eu-west-1");

    setenv("AWS_PROFILE", "other", 1);
    auto other = s3Environment();
    ASSERT_TRUE(other.ok()) << other.status().message();
    EXPECT_EQ(other->accessKey, "OTHERKEY");
    EXPECT_EQ(other->sessionToken, "tok");
    EXPECT_EQ(other->region, "ap-south-1");
    EXPECT_EQ(other->endpoint, "http://store:9000");
    EXPECT_TRUE(other->pathStyle);

    // The environment's keys and region come before the files'.
    setenv("AWS_ACCESS_KEY_ID", "ENVKEY", 1);
    setenv("AWS_SECRET_ACCESS_KEY", "envsecret", 1);
    setenv("AWS_REGION", "us-west-2", 1);
    auto fromEnv = s3Environment();
    ASSERT_TRUE(fromEnv.ok()) << fromEnv.status().message();
    EXPECT_EQ(fromEnv->accessKey, "ENVKEY");
    EXPECT_TRUE(fromEnv->sessionToken.empty()) << "a session token goes with its own key pair";
    EXPECT_EQ(fromEnv->region, "us-west-2");

    // Half a key pair is an error that names no secret.
    unsetenv("AWS_SECRET_ACCESS_KEY");
    auto half = s3Environment();
    ASSERT_FALSE(half.ok());
    EXPECT_NE(half.status().message().find("AWS_SECRET_ACCESS_KEY"), std::string::npos);
    EXPECT_EQ(half.status().message().find("ENVKEY"), std::string::npos);

    unsetenv("AWS_ACCESS_KEY_ID");
    setenv("AWS_PROFILE", "absent", 1);
    setenv("AWS_SHARED_CREDENTIALS_FILE", dir.file("nope").c_str(), 1);
    setenv("AWS_CONFIG_FILE", dir.file("nope2").c_str(), 1);
    auto noFiles = s3Environment();
    ASSERT_FALSE(noFiles.ok());
    EXPECT_NE(noFiles.status().message().find("AWS_PROFILE=absent"), std::string::npos) << noFiles.status().message();
}
