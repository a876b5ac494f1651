// The project's object-store client: S3's REST API (AWS S3, and the stores
// that speak it: Ceph, SeaweedFS, MinIO, GCS's interoperability mode) over
// libcurl, every request signed by libcurl's own SigV4 (CURLOPT_AWS_SIGV4).
// Credentials come from the standard AWS chain (s3Environment) and are sent
// to the store's endpoint only: never in a message, a log or a URL.
// docs/STORAGE.md is the user's page.
#pragma once

#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "s3_xml.h"
#include "status.h"

namespace surfcast {

// "s3://bucket/key": an object, or with a trailing '/' (or an empty key) a
// prefix, a "folder" of objects.
struct S3Url {
    std::string bucket, key;
    std::string str() const { return "s3://" + bucket + "/" + key; }
};
bool isS3Url(const std::string& location);
// Fails naming the URL where the bucket name is not one S3 takes.
Result<S3Url> parseS3Url(const std::string& url);
// s3://BUCKET/PREFIX as a prefix: the key ends in exactly one '/', or is empty
// for a whole bucket. `what` names the thing that must not take a whole bucket
// ("set", "work"); empty lets a whole bucket through.
Result<S3Url> parseS3Prefix(const std::string& url, const std::string& what = {});

// Where the store is and who asks it. Never printed.
struct S3Environment {
    std::string endpoint;      // "https://s3.REGION.amazonaws.com" or AWS_ENDPOINT_URL(_S3)
    std::string region;        // signs requests; us-east-1 where nothing says otherwise
    bool pathStyle = false;    // ENDPOINT/BUCKET/KEY (every endpoint but AWS's own) or BUCKET.HOST/KEY
    std::string accessKey, secretKey, sessionToken;  // empty access key: unsigned (a public bucket)
    int timeoutSeconds = 30;   // a response that stalls this long fails (and is retried)
};
// The standard AWS chain, in its order: AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY
// and AWS_SESSION_TOKEN; else the profile AWS_PROFILE names ("default" where
// unset) in the shared credentials file (AWS_SHARED_CREDENTIALS_FILE or
// ~/.aws/credentials), then in the config file (AWS_CONFIG_FILE or
// ~/.aws/config). Region: AWS_REGION, AWS_DEFAULT_REGION, the profile's
// `region`. Endpoint: AWS_ENDPOINT_URL_S3, AWS_ENDPOINT_URL, the profile's
// `endpoint_url`. Fails naming the file where one is malformed, or where
// only half of a key pair is given.
Result<S3Environment> s3Environment();
// The http(s) URL of an object (or prefix) at the environment's endpoint,
// its key percent-encoded as SigV4 signs it.
std::string s3HttpUrl(const S3Environment& environment, const S3Url& object);
std::string s3EncodeKey(const std::string& key);

struct ObjectInfo {
    uint64_t size = 0;
    std::string etag;       // as the store quotes it, "\"…\""
    int64_t modified = -1;  // Last-Modified, seconds since 1970 (UTC); -1 where not known
};

// A write's precondition (If-None-Match: * or If-Match: ETAG): stores that
// honour them (AWS S3 since 2024, SeaweedFS, MinIO) answer 412 where it fails.
struct WriteCondition {
    bool ifAbsent = false;
    std::string ifMatch;  // an ETag, quoted as the store gave it
};

// One store, shared by every thread of a process: requests run on pooled
// libcurl handles, so connections are kept alive between them. Transient
// faults (a reset, a timeout, HTTP 500, 502, 503 SlowDown, 504, 429) are
// asked again a bounded number of times with backoff; every other answer
// (403, NoSuchBucket, ...) fails at once, naming the bucket and key.
class ObjectStore {
public:
    // Objects larger than this go up in parts of kPartBytes (or more, for
    // objects of more than 10,000 such parts): bench/BENCHMARKS.md, "Object storage".
    static constexpr uint64_t kMultipartThreshold = 64ull << 20;
    static constexpr uint64_t kPartBytes = 32ull << 20;

    static Result<std::shared_ptr<ObjectStore>> open(S3Environment environment);
    // The process's store, opened from s3Environment() on first use.
    static Result<std::shared_ptr<ObjectStore>> shared();
    ~ObjectStore();
    ObjectStore(const ObjectStore&) = delete;
    ObjectStore& operator=(const ObjectStore&) = delete;

    // A whole object, failing where it is longer than maxBytes; `info`, where
    // given, gets the ETag and Last-Modified of the bytes returned.
    Result<std::vector<uint8_t>> get(const S3Url& object, uint64_t maxBytes, ObjectInfo* info = nullptr);
    // Exactly bytes [offset, offset + size) of an object, or an error.
    Result<std::vector<uint8_t>> getRange(const S3Url& object, uint64_t offset, uint64_t size);
    // The first `size` bytes of an object (its size, from a listing or a
    // HEAD) into a new file at `path`, by ranges of `piece` bytes: the
    // memory it takes is one piece, however large the object.
    Status getToFile(const S3Url& object, uint64_t size, const std::string& path, uint64_t piece = 16ull << 20);
    // nullopt where there is no such object (an error where the bucket is missing).
    Result<std::optional<ObjectInfo>> head(const S3Url& object);
    // Writes an object whole. nullopt where the condition failed (412, or 409
    // for a concurrent conditional write); the object is then untouched. A
    // write refused by its condition reads the object back first: an earlier
    // try of its own may have taken effect with its answer lost (a reset, a
    // 500, or libcurl's own unseen resend on a reused connection), and an
    // object holding these bytes is taken as this write's.
    Result<std::optional<ObjectInfo>> put(const S3Url& object, const std::vector<uint8_t>& bytes, const WriteCondition& condition = {});
    // The file at `path` as an object: one PUT up to `threshold`, else a
    // multipart upload in parts of `partBytes` (aborted where it fails).
    struct Multipart {
        uint64_t threshold, partBytes;
    };
    Result<std::optional<ObjectInfo>> putFile(const S3Url& object, const std::string& path, const WriteCondition& condition,
                                              Multipart multipart);
    Result<std::optional<ObjectInfo>> putFile(const S3Url& object, const std::string& path, const WriteCondition& condition = {}) {
        return putFile(object, path, condition, {kMultipartThreshold, kPartBytes});
    }
    // Whether the object exists and holds exactly the bytes of the file at `path`.
    Result<bool> holdsFile(const S3Url& object, const std::string& path);
    // Deletes an object; deleting one that is absent succeeds.
    Status remove(const S3Url& object);
    // Every object whose key starts with prefix.key, in key order.
    Result<std::vector<ListedObject>> list(const S3Url& prefix);

    // Requests sent and bytes moved, since open (for the benchmarks' costs).
    struct Counts {
        uint64_t requests = 0, bytesIn = 0, bytesOut = 0, retries = 0;
    };
    Counts counts() const;

private:
    // Whether the object holds exactly the `size` bytes of `file`.
    Result<bool> sameAsFile(const S3Url& object, std::FILE* file, uint64_t size);
    struct Impl;
    explicit ObjectStore(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace surfcast
