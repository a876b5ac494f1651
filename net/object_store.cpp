#include "object_store.h"

#include <curl/curl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <thread>

#include "s3_xml.h"
#include "sigpipe.h"
#include "transfer_errors.h"

namespace surfcast {
namespace {

// Tries of one request: the first and up to this many more where a fault is
// transient (transfer_errors.h), after a random wait between a quarter of
// and the whole of 0.1, 0.2, 0.4, ... s, so a store that sheds load (503
// SlowDown) gets a spread of retries.
constexpr int kStoreRetries = 6;
constexpr int kFirstBackoffMs = 100;
// An error response's body is kept up to this much (S3's XML is ~300 bytes).
constexpr size_t kMaxErrorBody = 64 << 10;
// A LIST page or an upload's answer is XML of at most this much (1,000 keys).
constexpr uint64_t kMaxListPage = 16 << 20;
// S3 allows at most this many parts per upload.
constexpr uint64_t kMaxParts = 10000;
// ... and parts of at least this much, but the last.
constexpr uint64_t kMinPartBytes = 5 << 20;
constexpr int kStoreConnectTimeoutSeconds = 10;

std::string env(const char* name) {
    const char* v = std::getenv(name);
    return v ? std::string(v) : std::string();
}

std::string trim(const std::string& s) {
    const size_t a = s.find_first_not_of(" \t\r"), b = s.find_last_not_of(" \t\r");
    return a == std::string::npos ? std::string() : s.substr(a, b - a + 1);
}

// The `key = value` lines of section [name] of an AWS ini file; nullopt where
// the file does not exist.
Result<std::optional<std::map<std::string, std::string>>> iniSection(const std::string& path, const std::string& name) {
    std::ifstream in(path);
    if (!in) return std::optional<std::map<std::string, std::string>>();
    std::map<std::string, std::string> values;
    bool inside = false;
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
        line = trim(line);
        if (line.empty() || line[0] == '#' || line[0] == ';') continue;
        if (line[0] == '[') {
            if (line.back() != ']') return Status::error(path + ": line " + std::to_string(number) + ": a section header without ']'");
            inside = trim(line.substr(1, line.size() - 2)) == name;
            continue;
        }
        if (!inside) continue;
        const size_t eq = line.find('=');
        // A nested block (s3 =\n  key = value) is indented: its lines land
        // here too and are harmless; a line without '=' is malformed.
        if (eq == std::string::npos) return Status::error(path + ": line " + std::to_string(number) + ": not 'key = value'");
        values[trim(line.substr(0, eq))] = trim(line.substr(eq + 1));
    }
    return std::optional(values);
}

// RFC 3986 unreserved characters stay; every other byte is %XX (upper case),
// as SigV4's canonical request wants; '/' stays in keys.
std::string uriEncode(const std::string& s, bool keepSlash) {
    static const char* hex = "0123456789ABCDEF";
    std::string out;
    for (unsigned char c : s) {
        if (std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~' || (keepSlash && c == '/')) {
            out += char(c);
        } else {
            out += '%';
            out += hex[c >> 4];
            out += hex[c & 15];
        }
    }
    return out;
}

struct Response {
    long status = 0;
    CURLcode code = CURLE_OK;
    std::string curlError;
    std::vector<uint8_t> body;
    std::string etag;
    int64_t contentLength = -1;  // the last response's header, where it has one
    int64_t modified = -1;       // Last-Modified, seconds since 1970
    bool tooLong = false;
};

// What one request sends: its method, sub-resource query (already in
// canonical order and encoding), headers, and body (memory or a file span).
struct Request {
    const char* method = "GET";
    std::string query;
    std::vector<std::string> headers;
    const uint8_t* body = nullptr;
    std::FILE* file = nullptr;
    uint64_t fileOffset = 0;
    uint64_t bodySize = 0;
    bool hasBody = false;
    uint64_t maxBytes = 0;  // of the response body
};

struct Upload {
    const Request* request;
    uint64_t sent = 0;
};

size_t readBody(char* out, size_t size, size_t n, void* user) {
    auto* up = static_cast<Upload*>(user);
    const Request& r = *up->request;
    const size_t take = size_t(std::min<uint64_t>(uint64_t(size) * n, r.bodySize - up->sent));
    if (take == 0) return 0;
    if (r.file) {
        if (std::fseek(r.file, long(r.fileOffset + up->sent), SEEK_SET) != 0) return CURL_READFUNC_ABORT;
        if (std::fread(out, 1, take, r.file) != take) return CURL_READFUNC_ABORT;
    } else {
        std::memcpy(out, r.body + up->sent, take);
    }
    up->sent += take;
    return take;
}

// A retried request starts its body again.
int seekBody(void* user, curl_off_t offset, int origin) {
    auto* up = static_cast<Upload*>(user);
    if (origin != SEEK_SET || offset < 0 || uint64_t(offset) > up->request->bodySize) return CURL_SEEKFUNC_FAIL;
    up->sent = uint64_t(offset);
    return CURL_SEEKFUNC_OK;
}

struct Sink {
    Response* response;
    uint64_t maxBytes;
};

size_t writeBody(char* data, size_t size, size_t n, void* user) {
    auto* sink = static_cast<Sink*>(user);
    const size_t bytes = size * n;
    auto& body = sink->response->body;
    const uint64_t limit = sink->response->status >= 300 || sink->response->status == 0 ? kMaxErrorBody : sink->maxBytes;
    if (body.size() + bytes > limit) {
        sink->response->tooLong = true;
        return 0;  // aborts the transfer
    }
    body.insert(body.end(), data, data + bytes);
    return bytes;
}

size_t readHeader(char* data, size_t size, size_t n, void* user) {
    auto* sink = static_cast<Sink*>(user);
    const std::string line(data, size * n);
    if (line.rfind("HTTP/", 0) == 0) {  // a new response (after a 100 Continue): forget the last one's
        sink->response->etag.clear();
        sink->response->contentLength = -1;
        sink->response->modified = -1;
        const size_t sp = line.find(' ');
        if (sp != std::string::npos) sink->response->status = std::strtol(line.c_str() + sp + 1, nullptr, 10);
    }
    const size_t colon = line.find(':');
    if (colon != std::string::npos) {
        std::string name = line.substr(0, colon);
        for (char& c : name) c = char(std::tolower(static_cast<unsigned char>(c)));
        const std::string value = trim(line.substr(colon + 1, line.find_last_not_of("\r\n") - colon));
        if (name == "etag") sink->response->etag = value;
        if (name == "content-length") sink->response->contentLength = std::strtoll(value.c_str(), nullptr, 10);
        if (name == "last-modified") sink->response->modified = int64_t(curl_getdate(value.c_str(), nullptr));  // -1 where it does not parse
    }
    return size * n;
}

}  // namespace

bool isS3Url(const std::string& location) { return location.rfind("s3://", 0) == 0; }

Result<S3Url> parseS3Url(const std::string& url) {
    if (!isS3Url(url)) return Status::error(url + ": not an s3:// URL");
    const std::string rest = url.substr(5);
    const size_t slash = rest.find('/');
    S3Url u{rest.substr(0, slash), slash == std::string::npos ? std::string() : rest.substr(slash + 1)};
    // S3's bucket naming rules: 3 to 63 lower-case letters, digits, '.' and '-'.
    bool ok = u.bucket.size() >= 3 && u.bucket.size() <= 63;
    for (char c : u.bucket) ok = ok && (std::islower(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '.' || c == '-');
    if (!ok) return Status::error(url + ": '" + u.bucket + "' is not a bucket name (3 to 63 of a-z, 0-9, '.', '-')");
    if (u.key.find("//") != std::string::npos || u.key.find("/../") != std::string::npos || u.key.rfind("../", 0) == 0)
        return Status::error(url + ": a key with an empty or '..' part");
    return u;
}

Result<S3Url> parseS3Prefix(const std::string& url, const std::string& what) {
    auto where = parseS3Url(url);
    if (!where) return where.status();
    while (!where->key.empty() && where->key.back() == '/') where->key.pop_back();
    if (where->key.empty() && !what.empty())
        return Status::error(url + ": give the " + what + " a prefix of its own (s3://BUCKET/PREFIX), not a whole bucket");
    if (!where->key.empty()) where->key += '/';
    return where;
}

Result<S3Environment> s3Environment() {
    S3Environment e;
    const std::string home = env("HOME");
    const std::string profile = env("AWS_PROFILE").empty() ? "default" : env("AWS_PROFILE");
    const std::string credentialsFile = !env("AWS_SHARED_CREDENTIALS_FILE").empty() ? env("AWS_SHARED_CREDENTIALS_FILE") : home + "/.aws/credentials";
    const std::string configFile = !env("AWS_CONFIG_FILE").empty() ? env("AWS_CONFIG_FILE") : home + "/.aws/config";
    auto credentials = iniSection(credentialsFile, profile);
    if (!credentials) return credentials.status();
    // The config file names a profile's section "profile NAME", except the default.
    auto config = iniSection(configFile, profile == "default" ? profile : "profile " + profile);
    if (!config) return config.status();
    auto fromFiles = [&](const char* key) {
        for (auto* section : {&*credentials, &*config})
            if (section->has_value())
                if (auto it = (*section)->find(key); it != (*section)->end() && !it->second.empty()) return it->second;
        return std::string();
    };

    if (!env("AWS_ACCESS_KEY_ID").empty() || !env("AWS_SECRET_ACCESS_KEY").empty()) {
        e.accessKey = env("AWS_ACCESS_KEY_ID");
        e.secretKey = env("AWS_SECRET_ACCESS_KEY");
        e.sessionToken = env("AWS_SESSION_TOKEN");
        if (e.accessKey.empty() || e.secretKey.empty())
            return Status::error("AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY: one is set without the other");
    } else {
        e.accessKey = fromFiles("aws_access_key_id");
        e.secretKey = fromFiles("aws_secret_access_key");
        e.sessionToken = fromFiles("aws_session_token");
        if (e.accessKey.empty() != e.secretKey.empty())
            return Status::error("profile '" + profile + "' (" + credentialsFile + ", " + configFile +
                                 "): aws_access_key_id and aws_secret_access_key: one is set without the other");
        if (!env("AWS_PROFILE").empty() && e.accessKey.empty() && !credentials->has_value() && !config->has_value())
            return Status::error("AWS_PROFILE=" + profile + ": neither " + credentialsFile + " nor " + configFile + " exists");
    }
    e.region = !env("AWS_REGION").empty() ? env("AWS_REGION") : !env("AWS_DEFAULT_REGION").empty() ? env("AWS_DEFAULT_REGION") : fromFiles("region");
    if (e.region.empty()) e.region = "us-east-1";
    e.endpoint = !env("AWS_ENDPOINT_URL_S3").empty() ? env("AWS_ENDPOINT_URL_S3") : !env("AWS_ENDPOINT_URL").empty() ? env("AWS_ENDPOINT_URL") : fromFiles("endpoint_url");
    // Stores other than AWS's own (Ceph, SeaweedFS, MinIO on premises) want
    // their buckets in the path; AWS wants them in the host name.
    e.pathStyle = !e.endpoint.empty();
    if (e.endpoint.empty()) e.endpoint = "https://s3." + e.region + ".amazonaws.com";
    while (!e.endpoint.empty() && e.endpoint.back() == '/') e.endpoint.pop_back();
    if (e.endpoint.rfind("http://", 0) != 0 && e.endpoint.rfind("https://", 0) != 0)
        return Status::error("the S3 endpoint '" + e.endpoint + "' is not an http(s) URL");
    return e;
}

std::string s3EncodeKey(const std::string& key) { return uriEncode(key, true); }

std::string s3HttpUrl(const S3Environment& e, const S3Url& o) {
    const size_t scheme = e.endpoint.find("://") + 3;
    return e.pathStyle ? e.endpoint + "/" + o.bucket + "/" + uriEncode(o.key, true)
                       : e.endpoint.substr(0, scheme) + o.bucket + "." + e.endpoint.substr(scheme) + "/" + uriEncode(o.key, true);
}

struct ObjectStore::Impl {
    S3Environment env;
    std::mutex mutex;
    std::vector<CURL*> idle;  // handles between requests, keeping their connections
    std::atomic<uint64_t> requests{0}, bytesIn{0}, bytesOut{0}, retries{0};

    ~Impl() {
        for (CURL* h : idle) curl_easy_cleanup(h);
    }

    CURL* take() {
        {
            std::lock_guard lock(mutex);
            if (!idle.empty()) {
                CURL* h = idle.back();
                idle.pop_back();
                return h;
            }
        }
        return curl_easy_init();
    }
    void give(CURL* h) {
        curl_easy_reset(h);
        std::lock_guard lock(mutex);
        idle.push_back(h);
    }

    std::string urlOf(const S3Url& o, const std::string& query) const {
        const std::string url = s3HttpUrl(env, o);
        return query.empty() ? url : url + "?" + query;
    }

    // One try of a request.
    Response once(const S3Url& object, const Request& r) {
        Response response;
        CURL* h = take();
        if (!h) {
            response.code = CURLE_OUT_OF_MEMORY;
            return response;
        }
        const std::string url = urlOf(object, r.query);
        curl_slist* headers = nullptr;
        // Bodies go unsigned (the signature covers the request, TLS the bytes):
        // a streamed file is not read twice to hash it.
        headers = curl_slist_append(headers, "x-amz-content-sha256: UNSIGNED-PAYLOAD");
        if (!env.sessionToken.empty()) headers = curl_slist_append(headers, ("x-amz-security-token: " + env.sessionToken).c_str());
        for (const auto& line : r.headers) headers = curl_slist_append(headers, line.c_str());
        char error[CURL_ERROR_SIZE] = "";
        Sink sink{&response, r.maxBytes};
        Upload upload{&r};
        const std::string sigv4 = "aws:amz:" + env.region + ":s3", userpwd = env.accessKey + ":" + env.secretKey;
        curl_easy_setopt(h, CURLOPT_URL, url.c_str());
        curl_easy_setopt(h, CURLOPT_NOSIGNAL, 1L);
        curl_easy_setopt(h, CURLOPT_PROTOCOLS_STR, "http,https");
        curl_easy_setopt(h, CURLOPT_FOLLOWLOCATION, 0L);  // a redirect would carry the signature elsewhere
        curl_easy_setopt(h, CURLOPT_CONNECTTIMEOUT, long(kStoreConnectTimeoutSeconds));
        curl_easy_setopt(h, CURLOPT_LOW_SPEED_LIMIT, 1L);
        curl_easy_setopt(h, CURLOPT_LOW_SPEED_TIME, long(env.timeoutSeconds));
        curl_easy_setopt(h, CURLOPT_HTTPHEADER, headers);
        curl_easy_setopt(h, CURLOPT_ERRORBUFFER, error);
        curl_easy_setopt(h, CURLOPT_WRITEFUNCTION, &writeBody);
        curl_easy_setopt(h, CURLOPT_WRITEDATA, &sink);
        curl_easy_setopt(h, CURLOPT_HEADERFUNCTION, &readHeader);
        curl_easy_setopt(h, CURLOPT_HEADERDATA, &sink);
        if (!env.accessKey.empty()) {
            curl_easy_setopt(h, CURLOPT_AWS_SIGV4, sigv4.c_str());
            curl_easy_setopt(h, CURLOPT_USERPWD, userpwd.c_str());
        }
        const std::string method = r.method;
        if (method == "HEAD") {
            curl_easy_setopt(h, CURLOPT_NOBODY, 1L);
        } else if (r.hasBody) {
            curl_easy_setopt(h, CURLOPT_UPLOAD, 1L);
            curl_easy_setopt(h, CURLOPT_READFUNCTION, &readBody);
            curl_easy_setopt(h, CURLOPT_READDATA, &upload);
            curl_easy_setopt(h, CURLOPT_SEEKFUNCTION, &seekBody);
            curl_easy_setopt(h, CURLOPT_SEEKDATA, &upload);
            curl_easy_setopt(h, CURLOPT_INFILESIZE_LARGE, curl_off_t(r.bodySize));
            if (method != "PUT") curl_easy_setopt(h, CURLOPT_CUSTOMREQUEST, r.method);
        } else if (method != "GET") {
            curl_easy_setopt(h, CURLOPT_CUSTOMREQUEST, r.method);
        }
        {
            SigpipeBlock block;
            response.code = curl_easy_perform(h);
        }
        curl_easy_getinfo(h, CURLINFO_RESPONSE_CODE, &response.status);
        curl_off_t up = 0, down = 0;
        curl_easy_getinfo(h, CURLINFO_SIZE_UPLOAD_T, &up);
        curl_easy_getinfo(h, CURLINFO_SIZE_DOWNLOAD_T, &down);
        requests += 1;
        bytesOut += uint64_t(up);
        bytesIn += uint64_t(down);
        response.curlError = error[0] ? error : curl_easy_strerror(response.code);
        curl_slist_free_all(headers);
        give(h);
        return response;
    }

    // A request with its retries; a response of any status but a transient one.
    Result<Response> send(const S3Url& object, const Request& r) {
        thread_local std::minstd_rand random(std::random_device{}());
        for (int attempt = 0;; ++attempt) {
            Response response = once(object, r);
            std::string fault;
            if (response.tooLong && response.status < 300)
                return Status::error(object.str() + ": longer than the " + std::to_string(r.maxBytes) + " bytes expected");
            if (response.code != CURLE_OK && !(response.tooLong && response.status >= 300)) {
                if (permanentTransferError(response.code)) return Status::error(object.str() + ": " + response.curlError);
                fault = response.curlError;
            } else if (transientHttpStatus(response.status)) {
                fault = "HTTP " + std::to_string(response.status) + describe(response);
            }
            if (fault.empty()) return response;
            if (attempt == kStoreRetries)
                return Status::transient(object.str() + ": " + fault + " (" + std::to_string(kStoreRetries + 1) + " tries)");
            retries += 1;
            const int ceiling = kFirstBackoffMs << attempt;
            std::this_thread::sleep_for(std::chrono::milliseconds(std::uniform_int_distribution<int>(ceiling / 4, ceiling)(random)));
        }
    }

    // " NoSuchBucket (The specified bucket does not exist)" from an error body.
    static std::string describe(const Response& response) {
        const std::string xml(response.body.begin(), response.body.end());
        const auto code = xmlElement(xml, "Code"), message = xmlElement(xml, "Message");
        std::string out;
        if (code) out += " " + *code;
        if (message && !message->empty()) out += " (" + *message + ")";
        return out;
    }

    // The error of a final answer that is not a success.
    static Status failure(const S3Url& object, const Response& response, const char* what) {
        std::string hint;
        if (response.status == 403) hint = ": the credentials are refused or lack the permission";
        return Status::error(object.str() + ": " + what + ": HTTP " + std::to_string(response.status) + describe(response) + hint);
    }
};

ObjectStore::ObjectStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ObjectStore::~ObjectStore() = default;

Result<std::shared_ptr<ObjectStore>> ObjectStore::open(S3Environment environment) {
    static const CURLcode init = curl_global_init(CURL_GLOBAL_DEFAULT);
    if (init != CURLE_OK) return Status::error(std::string("libcurl: ") + curl_easy_strerror(init));
    auto impl = std::make_unique<Impl>();
    impl->env = std::move(environment);
    return std::shared_ptr<ObjectStore>(new ObjectStore(std::move(impl)));
}

Result<std::shared_ptr<ObjectStore>> ObjectStore::shared() {
    static std::mutex mutex;
    static std::shared_ptr<ObjectStore> store;
    std::lock_guard lock(mutex);
    if (store) return store;
    auto e = s3Environment();
    if (!e) return e.status();
    auto opened = open(std::move(*e));
    if (!opened) return opened.status();
    store = *opened;
    return store;
}

ObjectStore::Counts ObjectStore::counts() const {
    return {impl_->requests.load(), impl_->bytesIn.load(), impl_->bytesOut.load(), impl_->retries.load()};
}

Result<std::vector<uint8_t>> ObjectStore::get(const S3Url& object, uint64_t maxBytes, ObjectInfo* info) {
    Request r;
    r.maxBytes = maxBytes;
    auto response = impl_->send(object, r);
    if (!response) return response.status();
    if (response->status != 200) return Impl::failure(object, *response, "GET");
    if (info) *info = ObjectInfo{response->body.size(), response->etag, response->modified};
    return std::move(response->body);
}

Result<std::vector<uint8_t>> ObjectStore::getRange(const S3Url& object, uint64_t offset, uint64_t size) {
    if (size == 0) return std::vector<uint8_t>();
    Request r;
    r.maxBytes = size;
    r.headers.push_back("Range: bytes=" + std::to_string(offset) + "-" + std::to_string(offset + size - 1));
    auto response = impl_->send(object, r);
    if (!response) return response.status();
    if (response->status != 206 && !(response->status == 200 && offset == 0))
        return Impl::failure(object, *response, ("GET bytes " + std::to_string(offset) + "+" + std::to_string(size)).c_str());
    if (response->body.size() != size)
        return Status::error(object.str() + ": bytes " + std::to_string(offset) + "+" + std::to_string(size) + ": the store sent " +
                             std::to_string(response->body.size()) + " (the object is shorter)");
    return std::move(response->body);
}

Status ObjectStore::getToFile(const S3Url& object, uint64_t size, const std::string& path, uint64_t piece) {
    piece = std::max<uint64_t>(piece, 1);
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "wb"), &std::fclose);
    if (!file) return Status::error(path + ": cannot create (" + std::strerror(errno) + ")");
    Status failed;
    for (uint64_t at = 0; at < size && failed.ok(); at += piece) {
        auto bytes = getRange(object, at, std::min(piece, size - at));
        if (!bytes) failed = bytes.status();
        else if (std::fwrite(bytes->data(), 1, bytes->size(), file.get()) != bytes->size())
            failed = Status::error(path + ": cannot write a copy of " + object.str() + " (disk full?)");
    }
    if (failed.ok() && (std::fflush(file.get()) != 0 || ::fsync(::fileno(file.get())) != 0))
        failed = Status::error(path + ": cannot flush a copy of " + object.str() + " to disk (disk full?)");
    if (!failed.ok()) {  // no half copy left behind
        file.reset();
        std::remove(path.c_str());
    }
    return failed;
}

Result<std::optional<ObjectInfo>> ObjectStore::head(const S3Url& object) {
    Request r;
    r.method = "HEAD";
    auto response = impl_->send(object, r);
    if (!response) return response.status();
    if (response->status == 404) {
        // A HEAD has no body to say NoSuchBucket: ask the bucket.
        Request b;
        b.method = "HEAD";
        auto answer = impl_->send(S3Url{object.bucket, ""}, b);
        if (!answer) return answer.status();
        if (answer->status == 404) return Status::error(object.str() + ": no bucket '" + object.bucket + "' (NoSuchBucket)");
        return std::optional<ObjectInfo>();
    }
    if (response->status != 200) return Impl::failure(object, *response, "HEAD");
    if (response->contentLength < 0) return Status::error(object.str() + ": HEAD: the store gave no Content-Length");
    return std::optional(ObjectInfo{uint64_t(response->contentLength), response->etag, response->modified});
}

namespace {

std::vector<std::string> conditionHeaders(const WriteCondition& c) {
    std::vector<std::string> h;
    if (c.ifAbsent) h.push_back("If-None-Match: *");
    if (!c.ifMatch.empty()) h.push_back("If-Match: " + c.ifMatch);
    return h;
}

// 412, or 409 ConditionalRequestConflict (AWS: another conditional write
// to the key is in flight): the write lost.
bool conditionFailed(long status) { return status == 412 || status == 409; }

}  // namespace

Result<std::optional<ObjectInfo>> ObjectStore::put(const S3Url& object, const std::vector<uint8_t>& bytes, const WriteCondition& condition) {
    Request r;
    r.method = "PUT";
    r.headers = conditionHeaders(condition);
    r.body = bytes.data();
    r.bodySize = bytes.size();
    r.hasBody = true;
    auto response = impl_->send(object, r);
    if (!response) return response.status();
    if (conditionFailed(response->status) && (condition.ifAbsent || !condition.ifMatch.empty())) {
        // Lost to another writer, or to this one's own earlier try: one this
        // client saw fail, or one libcurl sent again unseen (a reused
        // connection that died before the answer). Longer than these bytes,
        // or gone: not this write's.
        auto now = get(object, bytes.size());
        if (now && *now == bytes) return head(object);
        const std::string why = now ? std::string() : now.status().message();
        if (!now && (now.status().isTransient() || (why.find("longer than") == std::string::npos && why.find("HTTP 404") == std::string::npos)))
            return now.status();
        return std::optional<ObjectInfo>();
    }
    if (response->status != 200) return Impl::failure(object, *response, "PUT");
    return std::optional(ObjectInfo{bytes.size(), response->etag});
}

Result<std::optional<ObjectInfo>> ObjectStore::putFile(const S3Url& object, const std::string& path, const WriteCondition& condition,
                                                      Multipart multipart) {
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
    if (!file) return Status::error(path + ": cannot open (" + std::strerror(errno) + ")");
    if (std::fseek(file.get(), 0, SEEK_END) != 0) return Status::error(path + ": cannot seek");
    const long end = std::ftell(file.get());
    if (end < 0) return Status::error(path + ": cannot tell its size");
    const uint64_t size = uint64_t(end);
    Request r;
    r.file = file.get();
    r.hasBody = true;
    if (size <= multipart.threshold) {
        r.method = "PUT";
        r.headers = conditionHeaders(condition);
        r.bodySize = size;
        auto response = impl_->send(object, r);
        if (!response) return response.status();
        if (conditionFailed(response->status) && (condition.ifAbsent || !condition.ifMatch.empty())) {
            // As in put(): this write's own earlier try, seen or not?
            auto same = sameAsFile(object, file.get(), size);
            if (!same) return same.status();
            if (*same) return head(object);
            return std::optional<ObjectInfo>();
        }
        if (response->status != 200) return Impl::failure(object, *response, "PUT");
        return std::optional(ObjectInfo{size, response->etag});
    }

    // Multipart: start, send the parts, complete (the condition applies to
    // the completion, which is when the object appears).
    Request start;
    start.method = "POST";
    start.query = "uploads=";
    start.maxBytes = kMaxListPage;
    start.hasBody = true;  // an empty body
    auto started = impl_->send(object, start);
    if (!started) return started.status();
    if (started->status != 200) return Impl::failure(object, *started, "start a multipart upload");
    const auto uploadId = xmlElement(std::string(started->body.begin(), started->body.end()), "UploadId");
    if (!uploadId || uploadId->empty()) return Status::error(object.str() + ": the store's answer to a multipart upload has no UploadId");
    const std::string id = uriEncode(*uploadId, false);
    auto abort = [&](Status why) -> Status {
        Request a;
        a.method = "DELETE";
        a.query = "uploadId=" + id;
        (void)impl_->send(object, a);  // best effort: a store also ends abandoned uploads by its lifecycle rules
        return why;
    };

    const uint64_t partBytes = std::max(std::max(multipart.partBytes, kMinPartBytes), (size + kMaxParts - 1) / kMaxParts);
    std::string complete = "<CompleteMultipartUpload>";
    for (uint64_t part = 1, offset = 0; offset < size; ++part, offset += partBytes) {
        Request p = r;
        p.method = "PUT";
        p.query = "partNumber=" + std::to_string(part) + "&uploadId=" + id;
        p.fileOffset = offset;
        p.bodySize = std::min(partBytes, size - offset);
        auto sent = impl_->send(object, p);
        if (!sent) return abort(sent.status());
        if (sent->status != 200) return abort(Impl::failure(object, *sent, ("PUT part " + std::to_string(part)).c_str()));
        complete += "<Part><PartNumber>" + std::to_string(part) + "</PartNumber><ETag>" + sent->etag + "</ETag></Part>";
    }
    complete += "</CompleteMultipartUpload>";
    Request c;
    c.method = "POST";
    c.query = "uploadId=" + id;
    c.headers = conditionHeaders(condition);
    c.body = reinterpret_cast<const uint8_t*>(complete.data());
    c.bodySize = complete.size();
    c.hasBody = true;
    c.maxBytes = kMaxListPage;
    auto done = impl_->send(object, c);
    if (!done) return abort(done.status());
    // A completion tried again after it took effect (by this client, or by
    // libcurl unseen) finds the upload gone (NoSuchUpload) or, conditional,
    // the object there: its own, where the object holds the file's bytes.
    if (done->status == 404 || conditionFailed(done->status)) {
        auto same = sameAsFile(object, file.get(), size);
        if (!same) return abort(same.status());
        if (*same) return head(object);
    }
    if (conditionFailed(done->status) && (condition.ifAbsent || !condition.ifMatch.empty())) {
        (void)abort(Status());
        return std::optional<ObjectInfo>();
    }
    // S3 may answer 200 with an <Error> body when the completion fails late.
    const std::string answer(done->body.begin(), done->body.end());
    if (done->status != 200 || answer.find("<Error>") != std::string::npos)
        return abort(Impl::failure(object, *done, "complete a multipart upload"));
    const auto etag = xmlElement(answer, "ETag");
    return std::optional(ObjectInfo{size, etag ? *etag : std::string()});
}

Result<bool> ObjectStore::holdsFile(const S3Url& object, const std::string& path) {
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
    if (!file) return Status::error(path + ": cannot open (" + std::strerror(errno) + ")");
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(path, ec);
    if (ec) return Status::error(path + ": " + ec.message());
    return sameAsFile(object, file.get(), size);
}

Result<bool> ObjectStore::sameAsFile(const S3Url& object, std::FILE* file, uint64_t size) {
    auto info = head(object);
    if (!info) return info.status();
    if (!info->has_value() || (*info)->size != size) return false;
    constexpr uint64_t kSpan = 8 << 20;
    std::vector<uint8_t> local;
    for (uint64_t at = 0; at < size; at += kSpan) {
        const uint64_t n = std::min(kSpan, size - at);
        auto remote = getRange(object, at, n);
        if (!remote) return remote.status();
        local.resize(n);
        if (std::fseek(file, long(at), SEEK_SET) != 0 || std::fread(local.data(), 1, n, file) != n)
            return Status::error(object.str() + ": cannot read back the file it was written from");
        if (local != *remote) return false;
    }
    return true;
}

Status ObjectStore::remove(const S3Url& object) {
    Request r;
    r.method = "DELETE";
    auto response = impl_->send(object, r);
    if (!response) return response.status();
    if (response->status != 204 && response->status != 200 && response->status != 404) return Impl::failure(object, *response, "DELETE");
    return {};
}

Result<std::vector<ListedObject>> ObjectStore::list(const S3Url& prefix) {
    std::vector<ListedObject> out;
    std::string token;
    const S3Url bucket{prefix.bucket, ""};
    do {
        Request r;
        r.maxBytes = kMaxListPage;
        // Parameters in SigV4's canonical order: sorted by name.
        r.query = (token.empty() ? "" : "continuation-token=" + uriEncode(token, false) + "&") + "list-type=2&prefix=" + uriEncode(prefix.key, false);
        auto response = impl_->send(bucket, r);
        if (!response) return response.status();
        if (response->status != 200) return Impl::failure(prefix, *response, "LIST");
        auto page = parseListPage(std::string(response->body.begin(), response->body.end()));
        if (!page) return Status::error(prefix.str() + ": LIST: " + page.status().message());
        out.insert(out.end(), page->objects.begin(), page->objects.end());
        if (page->truncated && (page->next.empty() || page->next == token))
            return Status::error(prefix.str() + ": LIST: truncated, without a new continuation token (a broken store would list forever)");
        token = page->truncated ? page->next : "";
    } while (!token.empty());
    std::sort(out.begin(), out.end(), [](const ListedObject& a, const ListedObject& b) { return a.key < b.key; });
    return out;
}

}  // namespace surfcast
