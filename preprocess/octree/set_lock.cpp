#include "set_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

namespace surfcast {

namespace {
// A build or compaction swaps a new folder in for the set's: a lock granted
// on the folder it replaced guards nothing, so it is taken again on the one
// the path names, a few times at most.
constexpr int kLockAttempts = 8;
}  // namespace

SetLock::~SetLock() {
    if (fd >= 0) ::close(fd);
}

Status lockSet(const std::string& set, SetLock* lock) {
    for (int attempt = 0; attempt < kLockAttempts; ++attempt) {
        if (lock->fd >= 0) ::close(lock->fd);
        lock->fd = ::open(set.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (lock->fd < 0) return Status::error(set + ": cannot open (" + std::strerror(errno) + ")");
        if (::flock(lock->fd, LOCK_EX | LOCK_NB) != 0)
            return Status::error(set + (errno == EWOULDBLOCK ? std::string(": another build, update or compaction of this set is running")
                                                             : ": cannot lock (" + std::string(std::strerror(errno)) + ")"));
        struct stat held, named;
        if (::fstat(lock->fd, &held) == 0 && ::stat(set.c_str(), &named) == 0 && held.st_dev == named.st_dev && held.st_ino == named.st_ino)
            return {};
    }
    return Status::error(set + ": replaced by other writers again and again while this one waited for its lock");
}

Status lockOutput(const std::string& output, SetLock* lock) {
    const std::string set = std::filesystem::absolute(output).lexically_normal().string();
    std::error_code ec;
    return std::filesystem::is_directory(set, ec) ? lockSet(set, lock) : Status{};
}

}  // namespace surfcast
