// The HTTP front of the server (docs/PROTOCOL.md). libmicrohttpd stays inside
// http_server.cpp; this header is free of it.
#pragma once

#include <memory>
#include <string>

#include "metrics.h"
#include "status.h"
#include "tileset_store.h"
#include "web_files.h"

namespace surfcast {

enum class LogLevel { Quiet, Errors, Requests };

struct ServerConfig {
    std::string host = "127.0.0.1";  // loopback unless asked otherwise
    int port = 8080;                 // 0: any free port
    int threads = 0;                 // event-loop threads; 0: one per core
    std::string token;               // bearer token; empty: no authentication
    std::string corsOrigin;          // Access-Control-Allow-Origin; empty: no CORS headers
    LogLevel log = LogLevel::Requests;
    size_t maxBatch = 256;           // nodes per batch request
    size_t maxRanges = 16;           // ranges per Range header
    int timeoutSeconds = 10;         // inactivity timeout: stalled clients and idle keep-alive connections are dropped
    double drainSeconds = 5;         // how long run(), once stopped, lets requests in flight finish
    // HTTPS (libmicrohttpd's GnuTLS) when both are set: the PEM texts of the
    // certificate chain and of its private key.
    std::string tlsCertificate, tlsKey;
    // GET /sets/NAME/export.laz: the most points of the leaves a request's box
    // reaches (more is 413); 0 turns the route off (404).
    uint64_t exportMaxPoints = 20'000'000;
    int exportConcurrency = 2;       // exports at once; more get 503 (each is a thread and a few MiB)
    // The most seconds an export may take, from its request to its last
    // byte; a client too slow for it is cut off, so it cannot hold one of
    // the exportConcurrency places for long. 600 lets the largest export of
    // the default limit (about 120 MB of LAZ) through at about 200 KB/s.
    double exportSeconds = 600;
    // The browser viewer, served at / and /NAME (public even with a token:
    // the page holds no data; it sends the token from its URL's fragment).
    // Empty: no viewer, / is 404.
    WebFiles web;
};

class HttpServer {
public:
    HttpServer(TilesetStore& store, ServerConfig config);
    ~HttpServer();
    Status bind();       // listens; with port 0, port() tells the one chosen
    int port() const;
    void run();          // serves until stop(); call after bind()
    void stop();         // thread-safe; run() returns after in-flight requests finish (waiting at most drainSeconds)
    const Metrics& metrics() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace surfcast
