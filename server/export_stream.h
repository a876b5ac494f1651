// GET /sets/NAME/export.laz's body (docs/PROTOCOL.md, "Export"): a LAZ export
// produced on a thread of its own and sent as it is produced, with the slot
// it holds among the server's exportConcurrency. http_server.cpp routes the
// request; this header is free of libmicrohttpd.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <sys/types.h>
#include <thread>
#include <utility>

#include "laz_export.h"
#include "tileset_store.h"

struct MHD_Connection;

namespace surfcast {

// One of the server's exportConcurrency places, taken before any other work
// of an export request (the server's takeExportSlot, http_server.cpp) and given back when its
// owner (the request's reply, then its ExportStream) goes.
class ExportSlot {
public:
    explicit ExportSlot(std::atomic<int>& live) : live_(&live) {}
    ExportSlot(ExportSlot&& o) noexcept : live_(std::exchange(o.live_, nullptr)) {}
    ExportSlot& operator=(ExportSlot&&) = delete;
    ~ExportSlot() {
        if (live_) --*live_;
    }

private:
    std::atomic<int>* live_;
};

// The export runs into a queue of at most kExportQueueBytes, from the first
// time MHD asks for bytes (so a HEAD never starts it); MHD's content reader
// takes from the queue and suspends the connection while it is empty, and
// the producer resumes it. Resuming happens under the mutex, and cancel()
// takes it first: once MHD frees the response no resume touches its
// connection. The producer checks for cancellation before each leaf it
// decodes, so joining it (on MHD's thread) is prompt. Once it has produced
// everything, the same thread waits for MHD to free the response, and cuts
// the connection off if that has not happened by the export's deadline (a
// client too slow to take it, which would otherwise hold its slot). A
// stopping server aborts every stream first (abort()): libmicrohttpd must
// not stop with a connection suspended.
class ExportStream {
public:
    using Clock = std::chrono::steady_clock;
    // An export's bytes produced ahead of what its client has taken, at most.
    static constexpr size_t kExportQueueBytes = 4u << 20;

    ExportStream(std::shared_ptr<const TilesetSnapshot> snapshot, PointFilter filter, MHD_Connection* c, ExportSlot slot,
                 Clock::time_point deadline);
    ~ExportStream() { cancel(); }
    ExportStream(const ExportStream&) = delete;
    ExportStream& operator=(const ExportStream&) = delete;

    // Ends the export at once (the server is stopping): its connection, if
    // suspended, resumes to take the end of its response.
    void abort();

    // MHD's content reader and its release callback, whose `cls` is a
    // new std::shared_ptr<ExportStream> the response owns (and release deletes).
    static ssize_t read(void* cls, uint64_t, char* buf, size_t max);
    static void release(void* cls);  // MHD is done with the response: the producer stops
    uint64_t sent() const { return sent_.load(); }

private:
    ssize_t take(char* buf, size_t max);
    void run();  // the producer thread: the export, then the watch over its deadline
    void produce();
    void cutOff();
    void wake();  // with mutex_ held
    void cancel();

    std::shared_ptr<const TilesetSnapshot> snapshot_;  // keeps the mapped files the reader reads
    PointFilter filter_;
    MHD_Connection* connection_;
    int socket_ = -1;  // the connection's, while the response is not freed
    ExportSlot slot_;
    Clock::time_point deadline_;  // see ServerConfig::exportSeconds
    std::mutex mutex_;
    std::condition_variable space_;
    std::deque<std::string> queue_;
    size_t queued_ = 0, taken_ = 0;  // bytes in the queue; of its front, those already sent
    bool started_ = false, finished_ = false, suspended_ = false, cancelled_ = false, aborted_ = false, expired_ = false;
    std::string error_;
    std::atomic<uint64_t> sent_{0};
    std::thread producer_;
};

}  // namespace surfcast
