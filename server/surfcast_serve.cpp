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

#include "command_line.h"
#include "http_server.h"
#include "tileset_store.h"

namespace {

constexpr const char* kUsage = R"(surfcast-serve DIR [options]
       surfcast-serve s3://BUCKET/PREFIX [options])";

constexpr const char* kDescription = R"(Serves every tile set under DIR (its sub-folders holding tileset.json) over
HTTP: the three files with Range support, single node blocks, batches of nodes,
/sets, /healthz and /metrics. Read-only; a set rebuilt in place is picked up.
Or the sets under an S3 prefix (PREFIX/NAME/tileset.json), with the standard
AWS credentials (docs/STORAGE.md), which browsers and CDNs never see: block
bytes are fetched as clients ask for them and kept in a bounded cache.)";

int usageError(const std::string& m) { return surfcast::cli::usageError("surfcast-serve", m); }

// A PEM file's text; a usage error naming `option` where it is not one.
std::string readPem(const std::string& path, const std::string& option) {
    std::ifstream f(path, std::ios::binary);
    std::ostringstream text;
    text << f.rdbuf();
    if (!f || text.str().find("-----BEGIN ") == std::string::npos)
        throw surfcast::cli::UsageError("cannot read " + path + " as PEM (" + option + ")");
    return text.str();
}

}  // namespace

int main(int argc, char** argv) {
    using surfcast::cli::UsageError;
    surfcast::ServerConfig config;
    std::string dir, web;
    bool noWeb = false;
    uint64_t storeCache = 256ull << 20;
    double storePoll = 5;
    CLI::App app{kDescription, "surfcast-serve"};
    surfcast::cli::configure(app)->usage(&app, kUsage);
    app.add_option("DIR", dir, "the folder (or s3://BUCKET/PREFIX) whose sets are served");
    auto option = [&](const std::string& spec, const std::string& type, const std::string& help, std::function<void(const std::string&)> set,
                      const std::string& group) { surfcast::cli::option(app, spec, type, help, std::move(set))->group(group); };
    const std::string bucket = "A bucket's sets";
    option("--store-cache", "SIZE", "bytes of the bucket's blocks kept, e.g. 512M, 2G (default 256M)", [&](const std::string& v) {
        char* end = nullptr;
        double n = !v.empty() && v[0] != '-' ? std::strtod(v.c_str(), &end) : -1;
        const std::string unit = end ? end : "";
        const double scale = unit == "" ? 1 : unit == "K" ? 1024.0 : unit == "M" ? 1048576.0 : unit == "G" ? 1073741824.0 : -1;
        if (!(n >= 0) || scale < 0 || !std::isfinite(n * scale) || n * scale > 1e15)
            throw UsageError("--store-cache needs a size, e.g. 512M or 2G (0: keep nothing)");
        storeCache = uint64_t(n * scale);
    }, bucket);
    option("--store-poll", "S", "seconds between listings of the prefix, which find new, updated and deleted sets (default 5)",
           [&](const std::string& v) {
               char* end = nullptr;
               if (v.empty() || (storePoll = std::strtod(v.c_str(), &end), *end) || !(storePoll >= 0.1) || !std::isfinite(storePoll))
                   throw UsageError("--store-poll needs seconds >= 0.1");
           }, bucket);
    const std::string serving = "Serving";
    option("--bind", "HOST:PORT", "address to listen on (default 127.0.0.1:8080; port 0 picks one)", [&](const std::string& v) {
        const size_t colon = v.rfind(':');
        if (colon == std::string::npos) throw UsageError("--bind needs HOST:PORT");
        config.host = v.substr(0, colon);
        char* end = nullptr;
        long port = std::strtol(v.c_str() + colon + 1, &end, 10);
        if (*end || port < 0 || port > 65535 || config.host.empty()) throw UsageError("--bind needs HOST:PORT");
        config.port = int(port);
    }, serving);
    option("--threads", "N", "event-loop threads, each serving many connections (default: one per core)", [&](const std::string& v) {
        if ((config.threads = std::atoi(v.c_str())) < 1 || config.threads > 4096) throw UsageError("--threads needs a value in [1, 4096]");
    }, serving);
    option("--token-file", "F", "require \"Authorization: Bearer <token>\" with the token in F", [&](const std::string& v) {
        std::ifstream f(v);
        if (!f) throw UsageError("cannot read token file " + v);
        std::getline(f, config.token);
        while (!config.token.empty() && std::isspace(static_cast<unsigned char>(config.token.back()))) config.token.pop_back();
        if (config.token.empty()) throw UsageError("token file " + v + " is empty");
    }, serving);
    option("--cors", "ORIGIN", "send Access-Control-Allow-Origin: ORIGIN (e.g. *)", [&](const std::string& v) { config.corsOrigin = v; },
           serving);
    option("--log", "LEVEL", "requests (default), errors or quiet; one line per request on stderr", [&](const std::string& v) {
        if (v != "requests" && v != "errors" && v != "quiet") throw UsageError("--log is requests, errors or quiet");
        config.log = v == "requests" ? surfcast::LogLevel::Requests : v == "errors" ? surfcast::LogLevel::Errors : surfcast::LogLevel::Quiet;
    }, serving);
    option("--timeout", "S", "read/write timeout for stalled clients, seconds (default 10)", [&](const std::string& v) {
        if ((config.timeoutSeconds = std::atoi(v.c_str())) < 1) throw UsageError("--timeout needs seconds >= 1");
    }, serving);
    option("--tls-cert", "F", "serve HTTPS with the PEM certificate chain in F (and --tls-key)",
           [&](const std::string& v) { config.tlsCertificate = readPem(v, "--tls-cert"); }, serving);
    option("--tls-key", "F", "the certificate's PEM private key (unencrypted)",
           [&](const std::string& v) { config.tlsKey = readPem(v, "--tls-key"); }, serving);
    const std::string viewer = "The browser viewer and exports";
    option("--web", "DIR",
           "serve the browser viewer from DIR at / (default: web/ beside the executable's folder, as the build leaves it: build/web); "
           "open http://HOST:PORT/?set=/sets/NAME",
           [&](const std::string& v) { web = v; }, viewer);
    surfcast::cli::flag(app, "--no-web", "serve no viewer", [&] { noWeb = true; })->group(viewer);
    option("--export-max-points", "N",
           "GET /sets/NAME/export.laz?bbox=...&classes=... answers 413 where the box reaches nodes of more than N points (default "
           "20000000; 0: no export route)",
           [&](const std::string& v) {
               char* end = nullptr;
               if (v.empty() || v[0] == '-' || (config.exportMaxPoints = std::strtoull(v.c_str(), &end, 10), *end))
                   throw UsageError("--export-max-points needs a count (0: no exports)");
           }, viewer);
    option("--export-seconds", "S", "the most seconds an export may take; a client slower than that is cut off and its place freed (default 600)",
           [&](const std::string& v) {
               char* end = nullptr;
               if (v.empty() || (config.exportSeconds = std::strtod(v.c_str(), &end), *end) || !(config.exportSeconds > 0) ||
                   !std::isfinite(config.exportSeconds))
                   throw UsageError("--export-seconds needs seconds > 0");
           }, viewer);
    if (int status = surfcast::cli::parse(app, std::vector<std::string>(argv + 1, argv + argc), nullptr,
                                          [](const CLI::App&, const std::string& arg) {
                                              return !arg.empty() && arg[0] == '-' ? "unknown option " + arg : std::string("one folder only");
                                          });
        status >= 0)
        return status;
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
