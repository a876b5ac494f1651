// A host that closes a connection while a request is being written raises
// SIGPIPE, whose default action ends the whole process embedding the client
// (fuzz_client_response died so, with status 141, under cpp-httplib). libcurl
// sends with MSG_NOSIGNAL, but OpenSSL's writes on a TLS connection do not,
// and with CURLOPT_NOSIGNAL (needed in threads) libcurl leaves SIGPIPE alone.
// The HTTP tile source's I/O thread, which makes every write, holds a
// SigpipeBlock for its whole life: SIGPIPE is blocked in that thread, so the
// write fails with EPIPE instead, and a SIGPIPE raised meanwhile is taken
// before the mask is restored (unless one was already pending on entry). The
// process's own SIGPIPE disposition is left alone.
#pragma once

#include <signal.h>
#include <time.h>

namespace surfcast {

class SigpipeBlock {
public:
    SigpipeBlock() {
        sigset_t pending;
        sigpending(&pending);
        wasPending_ = sigismember(&pending, SIGPIPE) == 1;
        const sigset_t pipe = only();
        pthread_sigmask(SIG_BLOCK, &pipe, &old_);
    }
    ~SigpipeBlock() {
        if (!wasPending_) {
            const sigset_t pipe = only();
            const timespec zero{0, 0};
            while (sigtimedwait(&pipe, nullptr, &zero) > 0) {
            }
        }
        pthread_sigmask(SIG_SETMASK, &old_, nullptr);
    }
    SigpipeBlock(const SigpipeBlock&) = delete;
    SigpipeBlock& operator=(const SigpipeBlock&) = delete;

private:
    static sigset_t only() {
        sigset_t s;
        sigemptyset(&s);
        sigaddset(&s, SIGPIPE);
        return s;
    }
    sigset_t old_;
    bool wasPending_ = false;
};

}  // namespace surfcast
