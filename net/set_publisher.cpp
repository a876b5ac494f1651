#include "set_publisher.h"

#include <algorithm>
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
    std::vector<S3Url> written;
    auto undo = [&](Status why) -> Status {
        for (auto it = written.rbegin(); it != written.rend(); ++it) (void)(*store)->remove(*it);  // best effort
        return why;
    };
    for (const std::string& file : files) {
        const S3Url object{target->bucket, prefix + file};
        auto put = (*store)->putFile(object, folder + "/" + file, WriteCondition{true, ""});
        if (!put) return undo(put.status());
        if (!put->has_value())
            return undo(Status::error(object.str() + ": written meanwhile by another publisher (the store refused If-None-Match: *); "
                                      "this one wrote nothing that stays"));
        written.push_back(object);
        report.objects += 1;
        report.bytes += (*put)->size;
    }
    report.requests = (*store)->counts().requests - requestsBefore;
    return report;
}

}  // namespace surfcast
