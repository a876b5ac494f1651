#include "export_stream.h"

#include <microhttpd.h>
#include <sys/socket.h>

#include <algorithm>
#include <cstdio>
#include <cstring>

namespace surfcast {

ExportStream::ExportStream(std::shared_ptr<const TilesetSnapshot> snapshot, PointFilter filter, MHD_Connection* c, ExportSlot slot,
                           Clock::time_point deadline)
    : snapshot_(std::move(snapshot)), filter_(std::move(filter)), connection_(c), slot_(std::move(slot)), deadline_(deadline) {
    const MHD_ConnectionInfo* info = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
    socket_ = info ? info->connect_fd : -1;
}

void ExportStream::abort() {
    std::lock_guard lock(mutex_);
    aborted_ = true;
    if (suspended_ && !cancelled_) {
        suspended_ = false;
        MHD_resume_connection(connection_);
    }
    space_.notify_all();
}

ssize_t ExportStream::read(void* cls, uint64_t, char* buf, size_t max) {
    return (*static_cast<std::shared_ptr<ExportStream>*>(cls))->take(buf, max);
}

void ExportStream::release(void* cls) {
    auto* held = static_cast<std::shared_ptr<ExportStream>*>(cls);
    (*held)->cancel();
    delete held;
}

ssize_t ExportStream::take(char* buf, size_t max) {
    std::lock_guard lock(mutex_);
    if (aborted_ || expired_) return MHD_CONTENT_READER_END_WITH_ERROR;
    if (!started_) {
        started_ = true;
        try {
            producer_ = std::thread([this] { run(); });
        } catch (const std::exception& e) {
            finished_ = true;
            error_ = std::string("cannot start the export: ") + e.what();
        }
    }
    if (queue_.empty()) {
        if (finished_) {
            if (!error_.empty()) std::fprintf(stderr, "surfcast-serve: export of %s failed: %s\n", snapshot_->name.c_str(), error_.c_str());
            return error_.empty() ? MHD_CONTENT_READER_END_OF_STREAM : MHD_CONTENT_READER_END_WITH_ERROR;
        }
        suspended_ = true;
        MHD_suspend_connection(connection_);
        return 0;
    }
    std::string& front = queue_.front();
    const size_t n = std::min(max, front.size() - taken_);
    std::memcpy(buf, front.data() + taken_, n);
    taken_ += n;
    queued_ -= n;
    if (taken_ == front.size()) {
        queue_.pop_front();
        taken_ = 0;
    }
    sent_ += n;
    space_.notify_all();
    return ssize_t(n);
}

void ExportStream::run() {
    produce();
    std::unique_lock lock(mutex_);
    if (!space_.wait_until(lock, deadline_, [&] { return cancelled_ || aborted_; })) cutOff();
}

void ExportStream::produce() {
    const StopExport stop = [&] {
        std::lock_guard lock(mutex_);
        return cancelled_ || aborted_ || Clock::now() >= deadline_;
    };
    auto push = [&](const uint8_t* data, size_t n) -> Status {
        std::unique_lock lock(mutex_);
        space_.wait_until(lock, deadline_, [&] { return cancelled_ || aborted_ || queued_ < kExportQueueBytes; });
        if (cancelled_ || aborted_ || queued_ >= kExportQueueBytes) return Status::error("export stopped");
        queue_.emplace_back(reinterpret_cast<const char*>(data), n);
        queued_ += n;
        wake();
        return {};
    };
    Status status;
    try {
        // Here, not on the event loop: opening copies and parses the hierarchy.
        auto reader = TilesetReader::open(snapshotSource(snapshot_));
        if (!reader) {
            status = reader.status();
        } else {
            auto plan = planLazExport(*reader, filter_, stop);
            if (!plan) status = plan.status();
            else status = writeLazExport(*reader, filter_, *plan, push, stop);
        }
    } catch (const std::exception& e) {  // std::bad_alloc: the thread must not take the server down
        status = Status::error(e.what());
    } catch (...) {
        status = Status::error("the export failed");
    }
    std::lock_guard lock(mutex_);
    finished_ = true;
    if (!status.ok()) error_ = status.message();
    wake();
}

// The deadline passed with the response still held (with mutex_ held, so
// not cancelled: MHD frees the response before it closes the socket, and
// the descriptor is still this connection's). shutdown() makes MHD's next
// receive or send on it fail, wherever its buffers stand, and MHD then
// closes the connection and frees the response; with SO_LINGER 0 the
// close resets it, dropping what the client has not taken.
void ExportStream::cutOff() {
    expired_ = true;
    std::fprintf(stderr, "surfcast-serve: export of %s cut off at its time limit, %llu bytes sent\n", snapshot_->name.c_str(),
                 static_cast<unsigned long long>(sent_.load()));
    if (socket_ >= 0) {
        const linger reset{1, 0};
        ::setsockopt(socket_, SOL_SOCKET, SO_LINGER, &reset, sizeof reset);
        ::shutdown(socket_, SHUT_RDWR);
    }
    wake();  // a suspended connection resumes and takes the error (take())
}

void ExportStream::wake() {  // with mutex_ held
    if (suspended_ && !cancelled_) {
        suspended_ = false;
        MHD_resume_connection(connection_);
    }
}

void ExportStream::cancel() {
    {
        std::lock_guard lock(mutex_);
        cancelled_ = true;
    }
    space_.notify_all();
    if (producer_.joinable()) producer_.join();
}

}  // namespace surfcast
