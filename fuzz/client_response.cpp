// libFuzzer target: whatever an HTTP host answers, as the streaming client's
// tile source reads it (net/http_tile_source.cpp): tileset.json,
// hierarchy.bin, a block range and a batch of two nodes. A loopback listener
// answers every request with the input's bytes, as raw HTTP, and closes.
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <thread>

#include "http_tile_source.h"

using namespace surfcast;

namespace {
std::mutex mutex;
std::string reply;  // what the listener answers

int listenerPort() {
    static int port = [] {
        int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        socklen_t len = sizeof a;
        if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(fd, 64) != 0 ||
            ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0)
            std::abort();
        std::thread([fd] {
            for (;;) {
                int c = ::accept(fd, nullptr, nullptr);
                if (c < 0) continue;
                timeval tv{2, 0};
                ::setsockopt(c, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
                // Read the request head (its end, or 64 KiB), then answer.
                std::string head;
                char buf[4096];
                while (head.find("\r\n\r\n") == std::string::npos && head.size() < 65536) {
                    ssize_t n = ::recv(c, buf, sizeof buf, 0);
                    if (n <= 0) break;
                    head.append(buf, size_t(n));
                }
                std::string out;
                {
                    std::lock_guard lock(mutex);
                    out = reply;
                }
                size_t sent = 0;
                while (sent < out.size()) {
                    ssize_t n = ::send(c, out.data() + sent, out.size() - sent, MSG_NOSIGNAL);
                    if (n <= 0) break;
                    sent += size_t(n);
                }
                ::close(c);
            }
        }).detach();
        return int(ntohs(a.sin_port));
    }();
    return port;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const int port = listenerPort();
    {
        std::lock_guard lock(mutex);
        reply.assign(reinterpret_cast<const char*>(data), size);
    }
    HttpOptions http;
    http.timeoutSeconds = 2;
    auto source = openTileSource("http://127.0.0.1:" + std::to_string(port) + "/sets/s", http);
    if (!source) return 0;
    (void)(*source)->file("tileset.json", 16u << 20);
    (void)(*source)->file("hierarchy.bin", 4096);
    (void)(*source)->blocks(100, 300);
    NodeRecord a, b;
    a.key = NodeKey{1, 0, 0, 0};
    a.blockSize = 40;
    b.key = NodeKey{1, 1, 0, 0};
    b.blockSize = 60;
    (void)(*source)->blobs({a, b});
    return 0;
}
