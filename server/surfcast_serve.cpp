// surfcast-serve: serves every tile set under a folder over HTTP
// (docs/PROTOCOL.md). main() parses arguments, wires the store and the HTTP
// server, and turns SIGINT/SIGTERM into a graceful stop.
#include <signal.h>

#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>

#include "http_server.h"
#include "tileset_store.h"

namespace {

const char* kUsage = R"(usage: surfcast-serve DIR [options]
       surfcast-serve s3://BUCKET/PREFIX [options]

Serves every tile set under DIR (its sub-folders holding tileset.json) over
HTTP: the three files with Range support, single node blocks, batches of nodes,
/sets, /healthz and /metrics. Read-only; a set rebuilt in place is picked up.
Or the sets under an S3 prefix (PREFIX/NAME/tileset.json), with the standard
AWS credentials (docs/STORAGE.md), which browsers and CDNs never see: block
bytes are fetched as clients ask for them and kept in a bounded cache.

  --store-cache SIZE   bytes of the bucket's blocks kept, e.g. 512M, 2G (default 256M)
  --store-poll S       seconds between listings of the prefix, which find new,
                       updated and deleted sets (default 5)

  --bind HOST:PORT     address to listen on (default 127.0.0.1:8080; port 0 picks one)
  --threads N          event-loop threads, each serving many connections (default: one per core)
  --token-file F       require "Authorization: Bearer <token>" with the token in F
  --cors ORIGIN        send Access-Control-Allow-Origin: ORIGIN (e.g. *)
  --log LEVEL          requests (default), errors or quiet; one line per request on stderr
  --timeout S          read/write timeout for stalled clients, seconds (default 10)
  --tls-cert F         serve HTTPS with the PEM certificate chain in F (and --tls-key)
  --tls-key F          the certificate's PEM private key (unencrypted)
  --web DIR            serve the browser viewer from DIR at / (default: web/ beside
                       the executable's folder, as the build leaves it: build/web);
                       open http://HOST:PORT/?set=/sets/NAME
  --no-web             serve no viewer
  --export-max-points N
                       GET /sets/NAME/export.laz?bbox=...&classes=... answers 413 where
                       the box reaches nodes of more than N points (default 20000000;
                       0: no export route)
  --export-seconds S   the most seconds an export may take; a client slower than
                       that is cut off and its place freed (default 600)
  -h, --help           this text
)";

int usageError(const std::string& m) {
    std::fprintf(stderr, "surfcast-serve: %s\n(see surfcast-serve --help)\n", m.c_str());
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    surfcast::ServerConfig config;
    std::string dir, web;
    bool noWeb = false;
    uint64_t storeCache = 256ull << 20;
    double storePoll = 5;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto value = [&](std::string* out) {
            if (i + 1 >= argc) return false;
            *out = argv[++i];
            return true;
        };
        std::string v;
        if (a == "-h" || a == "--help") {
            std::fputs(kUsage, stdout);
            return 0;
        } else if (a == "--bind") {
            size_t colon;
            if (!value(&v) || (colon = v.rfind(':')) == std::string::npos) return usageError("--bind needs HOST:PORT");
            config.host = v.substr(0, colon);
            char* end = nullptr;
            long port = std::strtol(v.c_str() + colon + 1, &end, 10);
            if (*end || port < 0 || port > 65535 || config.host.empty()) return usageError("--bind needs HOST:PORT");
            config.port = int(port);
        } else if (a == "--threads") {
            if (!value(&v) || (config.threads = std::atoi(v.c_str())) < 1 || config.threads > 4096)
                return usageError("--threads needs a value in [1, 4096]");
        } else if (a == "--token-file") {
            if (!value(&v)) return usageError("--token-file needs a file");
            std::ifstream f(v);
            if (!f) return usageError("cannot read token file " + v);
            std::getline(f, config.token);
            while (!config.token.empty() && std::isspace(static_cast<unsigned char>(config.token.back()))) config.token.pop_back();
            if (config.token.empty()) return usageError("token file " + v + " is empty");
        } else if (a == "--cors") {
            if (!value(&config.corsOrigin)) return usageError("--cors needs an origin");
        } else if (a == "--log") {
            if (!value(&v) || (v != "requests" && v != "errors" && v != "quiet"))
                return usageError("--log is requests, errors or quiet");
            config.log = v == "requests" ? surfcast::LogLevel::Requests
                         : v == "errors" ? surfcast::LogLevel::Errors
                                         : surfcast::LogLevel::Quiet;
        } else if (a == "--tls-cert" || a == "--tls-key") {
            if (!value(&v)) return usageError(a + " needs a PEM file");
            std::ifstream f(v, std::ios::binary);
            std::ostringstream text;
            text << f.rdbuf();
            if (!f || text.str().find("-----BEGIN ") == std::string::npos)
                return usageError("cannot read " + v + " as PEM (" + a + ")");
            (a == "--tls-cert" ? config.tlsCertificate : config.tlsKey) = text.str();
        } else if (a == "--web") {
            if (!value(&web)) return usageError("--web needs a folder");
        } else if (a == "--no-web") {
            noWeb = true;
        } else if (a == "--export-max-points") {
            char* end = nullptr;
            if (!value(&v) || v.empty() || v[0] == '-' || (config.exportMaxPoints = std::strtoull(v.c_str(), &end, 10), *end))
                return usageError("--export-max-points needs a count (0: no exports)");
        } else if (a == "--export-seconds") {
            char* end = nullptr;
            if (!value(&v) || v.empty() || (config.exportSeconds = std::strtod(v.c_str(), &end), *end) || !(config.exportSeconds > 0) ||
                !std::isfinite(config.exportSeconds))
                return usageError("--export-seconds needs seconds > 0");
        } else if (a == "--store-cache") {
            char* end = nullptr;
            double n = value(&v) && !v.empty() && v[0] != '-' ? std::strtod(v.c_str(), &end) : -1;
            const std::string unit = end ? end : "";
            const double scale = unit == "" ? 1 : unit == "K" ? 1024.0 : unit == "M" ? 1048576.0 : unit == "G" ? 1073741824.0 : -1;
            if (!(n >= 0) || scale < 0 || !std::isfinite(n * scale) || n * scale > 1e15)
                return usageError("--store-cache needs a size, e.g. 512M or 2G (0: keep nothing)");
            storeCache = uint64_t(n * scale);
        } else if (a == "--store-poll") {
            char* end = nullptr;
            if (!value(&v) || v.empty() || (storePoll = std::strtod(v.c_str(), &end), *end) || !(storePoll >= 0.1) || !std::isfinite(storePoll))
                return usageError("--store-poll needs seconds >= 0.1");
        } else if (a == "--timeout") {
            if (!value(&v) || (config.timeoutSeconds = std::atoi(v.c_str())) < 1) return usageError("--timeout needs seconds >= 1");
        } else if (!a.empty() && a[0] == '-') {
            return usageError("unknown option " + a);
        } else if (dir.empty()) {
            dir = a;
        } else {
            return usageError("one folder only");
        }
    }
    if (dir.empty()) return usageError("no folder given");
    if (config.tlsCertificate.empty() != config.tlsKey.empty()) return usageError("--tls-cert and --tls-key go together");

    if (!noWeb) {
        // An explicit --web must be a viewer; the default folder is optional
        // (a server installed without the viewer still serves sets).
        auto files = surfcast::loadWebFiles(web.empty() ? surfcast::defaultWebFolder() : web);
        if (files) config.web = std::move(*files);
        else if (!web.empty()) return usageError(files.status().message());
    }

    // Block the stop signals in every thread, those a bucket's store starts
    // included (so before it opens); one thread waits for them, from the
    // start: a stop before the server runs (a store slow to answer) ends
    // the process at once.
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);
    signal(SIGPIPE, SIG_IGN);
    std::atomic<surfcast::HttpServer*> running{nullptr};
    std::atomic<bool> done{false};
    std::thread waiter([&] {
        int sig = 0;
        sigwait(&signals, &sig);
        if (done) return;  // woken by main at the end
        surfcast::HttpServer* server = running.load();
        std::fprintf(stderr, "surfcast-serve: %s, %s\n", sig == SIGINT ? "SIGINT" : "SIGTERM",
                     server ? "finishing requests in flight" : "stopped before serving");
        if (!server) std::_Exit(0);
        server->stop();
    });
    auto stopWaiter = [&] {
        done = true;
        pthread_kill(waiter.native_handle(), SIGTERM);
        waiter.join();
    };
    auto store = dir.rfind("s3://", 0) == 0 ? surfcast::TilesetStore::openBucket(dir, storeCache, storePoll) : surfcast::TilesetStore::open(dir);
    if (!store) {
        std::fprintf(stderr, "surfcast-serve: %s\n", store.status().message().c_str());
        stopWaiter();
        return 1;
    }

    surfcast::HttpServer server(**store, config);
    surfcast::Status st = server.bind();
    if (!st.ok()) {
        std::fprintf(stderr, "surfcast-serve: %s\n", st.message().c_str());
        stopWaiter();
        return 1;
    }
    running = &server;
    std::fprintf(stderr, "surfcast-serve: serving %s on %s://%s:%d (%zu tile sets)\n", dir.c_str(),
                 config.tlsCertificate.empty() ? "http" : "https", config.host.c_str(), server.port(), (*store)->list().size());
    if (!config.web.empty())
        std::fprintf(stderr, "surfcast-serve: viewer at %s://%s:%d/?set=/sets/NAME\n", config.tlsCertificate.empty() ? "http" : "https",
                     config.host.c_str(), server.port());
    server.run();
    // run() also returns when listening fails; wake the waiter either way.
    stopWaiter();
    std::fprintf(stderr, "surfcast-serve: stopped\n");
    return 0;
}
