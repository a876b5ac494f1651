#include "folder_publish.h"

#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <vector>

namespace fs = std::filesystem;

namespace surfcast {

namespace {

// Removes the hidden folders that writers into `out` left when they were
// killed (".NAME.partial-PID", ".NAME.partial-PID-work" and ".NAME.old-PID"
// of a process that no longer runs). An old folder that the non-exchanging
// fallback had moved aside goes back into place if nothing took its place.
void removeLeftovers(const fs::path& out, const std::string& marker) {
    const std::string name = out.filename().string();
    std::error_code ec;
    std::vector<std::pair<fs::path, bool>> stale;  // path, is an old folder
    for (const auto& entry : fs::directory_iterator(out.parent_path(), ec))
        for (const char* kind : {".partial-", ".old-"}) {
            const std::string prefix = "." + name + kind, file = entry.path().filename().string();
            if (file.rfind(prefix, 0) != 0) continue;
            char* end = nullptr;
            const long pid = std::strtol(file.c_str() + prefix.size(), &end, 10);
            // ".NAME.partial-PID" and what a writer keeps beside it
            // (".NAME.partial-PID-SUFFIX": the build's "-work", its versions' "-refine").
            if ((*end != '\0' && *end != '-') || pid <= 0 || pid == ::getpid()) continue;
            if (::kill(pid_t(pid), 0) == 0 || errno != ESRCH) continue;  // still running (or not ours to judge)
            stale.push_back({entry.path(), kind[1] == 'o' && *end == '\0'});
        }
    for (const auto& [path, old] : stale) {
        if (old && !fs::exists(out, ec) && fs::exists(path / marker, ec)) {
            fs::rename(path, out, ec);
            if (!ec) continue;
        }
        fs::remove_all(path, ec);
    }
}

}  // namespace

Status writeFileSynced(const std::string& path, const void* data, size_t size) {
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return Status::error(path + ": cannot create (" + std::strerror(errno) + ")");
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        ssize_t w = ::write(fd, p, size);
        if (w < 0) {
            if (errno == EINTR) continue;
            ::close(fd);
            return Status::error(path + ": write failed (" + std::strerror(errno) + ")");
        }
        p += w;
        size -= size_t(w);
    }
    bool ok = ::fsync(fd) == 0;
    ok = ::close(fd) == 0 && ok;
    if (!ok) return Status::error(path + ": could not be flushed to disk");
    return {};
}

Result<std::unique_ptr<PublishedFolder>> PublishedFolder::create(const std::string& output, const std::string& marker,
                                                                 const std::function<bool(const std::string&)>& replaceable,
                                                                 const std::string& what, const std::string& tag) {
    fs::path out = fs::absolute(output).lexically_normal();
    if (out.filename().empty()) out = out.parent_path();
    std::error_code ec;
    if (fs::is_directory(out.parent_path(), ec)) removeLeftovers(out, marker);
    if (fs::exists(out, ec) && !(fs::is_directory(out, ec) && (fs::is_empty(out, ec) || replaceable(out.string()))))
        return Status::error(out.string() + ": exists and is not " + what + "; refusing to replace it");
    fs::create_directories(out.parent_path(), ec);
    std::unique_ptr<PublishedFolder> f(new PublishedFolder);
    f->output_ = out.string();
    f->marker_ = marker;
    f->partial_ = (out.parent_path() / ("." + out.filename().string() + ".partial-" + std::to_string(::getpid()) +
                                        (tag.empty() ? "" : "-" + tag)))
                      .string();
    fs::remove_all(f->partial_, ec);
    if (!fs::create_directory(f->partial_, ec)) return Status::error(f->partial_ + ": cannot create (" + ec.message() + ")");
    return f;
}

PublishedFolder::~PublishedFolder() {
    if (published_) return;
    std::error_code ec;
    fs::remove_all(partial_, ec);
}

Status PublishedFolder::publish() {
    std::error_code ec;
    // Exchange the folders in one step where the file system can; else move
    // the old folder (if any) aside and the new one in.
    if (::renameat2(AT_FDCWD, partial_.c_str(), AT_FDCWD, output_.c_str(), RENAME_EXCHANGE) == 0) {
        published_ = true;
        // Now the old folder: it stops reading as one first, then goes.
        fs::remove(fs::path(partial_) / marker_, ec);
        fs::remove_all(partial_, ec);
        return {};
    }
    std::string oldName = fs::path(output_).filename().string();
    oldName.insert(0, ".");
    oldName += ".old-" + std::to_string(::getpid());
    const fs::path old = fs::path(partial_).parent_path() / oldName;
    bool hadOld = fs::exists(output_, ec);
    if (hadOld) {
        fs::rename(output_, old, ec);
        if (ec) return Status::error(output_ + ": cannot move the previous folder aside (" + ec.message() + ")");
    }
    fs::rename(partial_, output_, ec);
    if (ec) {
        if (hadOld) fs::rename(old, output_, ec);
        return Status::error(output_ + ": cannot move the new folder into place");
    }
    published_ = true;
    if (hadOld) fs::remove_all(old, ec);
    return {};
}

}  // namespace surfcast
