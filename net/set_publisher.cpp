#include "set_publisher.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <vector>

#include "object_store.h"

namespace surfcast {

Result<PublishReport> publishFolder(const std::string& folder, const std::string& url, const std::string& last) {
    namespace fs = std::filesystem;
    auto target = parseS3Url(url);
    if (!target) return target.status();
    std::string prefix = target->key;
    while (!prefix.empty() && prefix.back() == '/') prefix.pop_back();
    if (prefix.empty()) return Status::error(url + ": give the set a prefix of its own (s3://BUCKET/PREFIX), not a whole bucket");
    prefix += '/';
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    const uint64_t requestsBefore = (*store)->counts().requests;

    auto existing = (*store)->list({target->bucket, prefix});
    if (!existing) return existing.status();
    if (!existing->empty())
        return Status::error("s3://" + target->bucket + "/" + prefix + ": the prefix holds " + std::to_string(existing->size()) +
                             " object(s) already (s3://" + target->bucket + "/" + existing->front().key +
                             "): a set's objects are never rewritten while readers may stream them; publish to a new prefix, or "
                             "delete the old set's objects first");

    // The files, in path order, `last` at the end.
    std::vector<std::string> files;
    std::error_code ec;
    for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec))
        if (it->is_regular_file(ec)) files.push_back(fs::relative(it->path(), folder, ec).generic_string());
    if (ec) return Status::error(folder + ": cannot list (" + ec.message() + ")");
    std::sort(files.begin(), files.end());
    if (auto it = std::find(files.begin(), files.end(), last); it != files.end()) std::rotate(it, it + 1, files.end());
    else return Status::error(folder + ": no " + last + " to publish last");

    PublishReport report;
    const S3Url json{target->bucket, prefix + last};
    std::vector<S3Url> written;  // objects holding this publisher's bytes
    // After a failure: a tileset.json whose answer was lost may stand all the
    // same, in which case nothing may go; else what this publisher wrote
    // goes. (Another publisher of the very same bytes, racing for the same
    // prefix and meeting lost answers, could take one of these for its own:
    // the one case where a set could lose a file.)
    bool lastInDoubt = false;  // tileset.json's PUT failed in a way the store may still take it
    auto undo = [&](Status why) -> Status {
        if (lastInDoubt)
            return Status::error(why.message() + "; the store may take " + json.str() + " yet (an answer lost in flight): the objects written stay");
        auto stands = (*store)->head(json);
        if (!stands)
            return Status::error(why.message() + "; whether " + json.str() + " stands could not be asked (" + stands.status().message() +
                                 "): the objects written stay");
        if (stands->has_value()) return why;  // a set stands there (another publisher's): its files bear these names
        std::string left;
        for (auto it = written.rbegin(); it != written.rend(); ++it)
            if (!(*store)->remove(*it).ok()) left += (left.empty() ? "" : ", ") + it->str();
        return left.empty() ? why : Status::error(why.message() + "; these could not be deleted: " + left);
    };
    for (const std::string& file : files) {
        const S3Url object{target->bucket, prefix + file};
        const std::string path = folder + "/" + file;
        auto put = (*store)->putFile(object, path, WriteCondition{true, ""});
        if (!put) {
            // Its answer lost on every try (a 500 or a reset after the store
            // acted): it may stand all the same. The set's last file standing
            // is the set published; any other goes with the rest.
            auto mine = (*store)->holdsFile(object, path);
            if (mine && *mine && file == last)
                put = Result<std::optional<ObjectInfo>>(std::optional(ObjectInfo{std::filesystem::file_size(path), ""}));
            else if (mine && *mine)
                written.push_back(object);
            else if (file == last && put.status().isTransient())
                lastInDoubt = true;  // a refusal (403) is final; a fault may have reached the store
        }
        if (!put) return undo(put.status());
        if (!put->has_value())
            return undo(Status::error(object.str() + ": written meanwhile by another publisher (the store refused If-None-Match: *)"));
        written.push_back(object);
        report.objects += 1;
        report.bytes += (*put)->size;
    }
    report.requests = (*store)->counts().requests - requestsBefore;
    return report;
}

Result<std::unique_ptr<PublishStaging>> PublishStaging::create() {
    namespace fs = std::filesystem;
    constexpr const char* kPrefix = "surfcast-publish-";
    std::error_code ec;
    const fs::path temp = fs::temp_directory_path(ec);
    if (ec) return Status::error("no folder for temporary files ($TMPDIR): " + ec.message());
    for (const auto& e : fs::directory_iterator(temp, ec)) {
        if (e.path().filename().string().rfind(kPrefix, 0) != 0) continue;
        const int fd = ::open(e.path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC | O_NOFOLLOW);
        if (fd < 0) continue;
        std::error_code ignored;
        if (::flock(fd, LOCK_EX | LOCK_NB) == 0) fs::remove_all(e.path(), ignored);  // its process is gone
        ::close(fd);
    }
    std::string pattern = (temp / (std::string(kPrefix) + "XXXXXX")).string();
    if (!::mkdtemp(pattern.data())) return Status::error(pattern + ": cannot create the folder written before the upload (" + std::strerror(errno) + ")");
    auto staging = std::unique_ptr<PublishStaging>(new PublishStaging);
    staging->dir_ = pattern;
    staging->lock_ = ::open(pattern.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (staging->lock_ < 0 || ::flock(staging->lock_, LOCK_EX | LOCK_NB) != 0)
        return Status::error(pattern + ": cannot lock (" + std::strerror(errno) + ")");
    return staging;
}

PublishStaging::~PublishStaging() {
    std::error_code ec;
    if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
    if (lock_ >= 0) ::close(lock_);
}

}  // namespace surfcast
