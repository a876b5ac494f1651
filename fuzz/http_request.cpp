// libFuzzer target: raw bytes from a client to surfcast-serve's HTTP server
// (libmicrohttpd and our routing, Range parsing, batch bodies, ETags, tokens),
// in process on loopback. The server serves the tile sets under
// $SURFCAST_FUZZ_SETS (fuzz/run.sh builds one named "s"). Each input is sent
// on a fresh connection followed by an empty line (libmicrohttpd waits out
// its timeout for a request line that never ends, even after the client's
// half-close; stalls are the server tests' business), the write side is
// closed, and the reply is read to the server's close. A crash or sanitizer
// report in the server thread is the finding.
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>

#include "http_server.h"
#include "tileset_store.h"

using namespace surfcast;

namespace {
int serverPort() {
    static int port = [] {
        const char* sets = std::getenv("SURFCAST_FUZZ_SETS");
        if (!sets) {
            std::fprintf(stderr, "http_request: set SURFCAST_FUZZ_SETS to a folder of tile sets (fuzz/run.sh does)\n");
            std::abort();
        }
        auto store = TilesetStore::open(sets);
        if (!store) {
            std::fprintf(stderr, "http_request: %s\n", store.status().message().c_str());
            std::abort();
        }
        ServerConfig config;
        config.port = 0;
        config.threads = 1;
        config.log = LogLevel::Quiet;
        config.timeoutSeconds = 1;  // a body shorter than its Content-Length waits this long
        config.token = "";
        static auto* keptStore = store->release();
        static auto* server = new HttpServer(*keptStore, config);
        if (Status s = server->bind(); !s) {
            std::fprintf(stderr, "http_request: %s\n", s.message().c_str());
            std::abort();
        }
        std::thread([] { server->run(); }).detach();
        return server->port();
    }();
    return port;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const int port = serverPort();
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_port = htons(uint16_t(port));
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    timeval tv{3, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to) != 0) {
        ::close(fd);
        return 0;
    }
    std::string request(reinterpret_cast<const char*>(data), size);
    request += "\r\n\r\n";
    size_t sent = 0;
    while (sent < request.size()) {
        ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
        if (n <= 0) break;
        sent += size_t(n);
    }
    ::shutdown(fd, SHUT_WR);
    char buf[65536];
    while (::recv(fd, buf, sizeof buf, 0) > 0) {
    }
    ::close(fd);
    return 0;
}
