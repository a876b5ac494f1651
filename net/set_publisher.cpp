#include "set_publisher.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <vector>

#include "folder_publish.h"
#include "object_store.h"
#include "tile_source.h"

namespace surfcast {

namespace {

// A build record is a plan (stages.h): a few kilobytes per input.
constexpr uint64_t kMaxBuildRecordBytes = 256u << 20;

}  // namespace

Result<PublishReport> publishFolder(const std::string& folder, const std::string& url, const std::string& last) {
    namespace fs = std::filesystem;
    auto target = parseS3Prefix(url, "set");
    if (!target) return target.status();
    const std::string& prefix = target->key;
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

Result<StoredVersion> mirrorSetMetadata(const std::string& url, const std::string& folder) {
    auto set = parseS3Prefix(url, "set");
    if (!set) return set.status();
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    StoredVersion version;
    version.url = set->str();
    const S3Url json{set->bucket, set->key + "tileset.json"};
    ObjectInfo read;
    auto text = (*store)->get(json, kMaxTilesetJsonBytes, &read);
    if (!text) {
        if (text.status().message().find("HTTP 404") != std::string::npos && text.status().message().find("NoSuchBucket") == std::string::npos)
            return Status::error(version.url + ": not a tile set (no tileset.json)");
        return text.status();
    }
    if (read.etag.empty() || read.modified < 0)
        return Status::error(json.str() + ": the store gave no ETag or Last-Modified, which updates in place need (docs/STORAGE.md)");
    version.etag = read.etag;
    version.modified = read.modified;
    auto info = readTilesetJson(std::string(text->begin(), text->end()), json.str());
    if (!info) return info.status();
    version.info = *info;
    SC_TRY(writeFileSynced(folder + "/tileset.json", text->data(), text->size()));
    const std::string recordName = buildRecordFile(info->hierarchyFile);
    const S3Url record{set->bucket, set->key + recordName};
    auto kept = (*store)->head(record);
    if (!kept) return kept.status();
    if (kept->has_value()) {
        auto bytes = (*store)->get(record, kMaxBuildRecordBytes);
        if (!bytes) return bytes.status();
        SC_TRY(writeFileSynced(folder + "/" + recordName, bytes->data(), bytes->size()));
    }
    return version;
}

Result<PublishReport> publishVersion(const std::string& folder, const StoredVersion& base) {
    auto set = parseS3Prefix(base.url, "set");
    if (!set) return set.status();
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    const uint64_t requestsBefore = (*store)->counts().requests;
    std::string text;
    {
        std::ifstream in(folder + "/tileset.json", std::ios::binary);
        if (!in) return Status::error(folder + "/tileset.json: cannot read the version to publish");
        text.assign(std::istreambuf_iterator<char>(in), {});
    }
    auto info = readTilesetJson(text, folder + "/tileset.json");
    if (!info) return info.status();
    const std::vector<std::string> baseFiles = versionFiles(base.info), files = versionFiles(*info);
    std::set<std::string> named(baseFiles.begin(), baseFiles.end());
    named.insert(files.begin(), files.end());
    std::vector<std::string> added;
    for (const std::string& file : files) {
        if (std::find(baseFiles.begin(), baseFiles.end(), file) != baseFiles.end()) continue;
        if (!std::filesystem::exists(folder + "/" + file)) {
            if (file == buildRecordFile(info->hierarchyFile)) continue;  // (a set that keeps none)
            return Status::error(folder + "/" + file + ": missing, though the version's tileset.json names it");
        }
        added.push_back(file);
    }

    PublishReport report;
    // 1. The new files.
    std::vector<std::string> rewritten;  // older versions' objects written again
    for (const std::string& file : added) {
        const S3Url object{set->bucket, set->key + file};
        const std::string path = folder + "/" + file;
        auto there = (*store)->head(object);
        if (!there) return there.status();
        WriteCondition condition{true, ""};
        if (there->has_value() && (*there)->modified >= 0 && (*there)->modified < base.modified) {
            condition = {};  // an older version's, unnamed since: written again, its age now this version's
            rewritten.push_back(file);
        }
        auto put = (*store)->putFile(object, path, condition);
        if (!put) return put.status();
        if (!put->has_value())
            return Status::error(object.str() + ": written meanwhile with other bytes (another update of " + base.url +
                                 " racing this one); the set stays as it is: run the update again");
        report.objects += 1;
        report.bytes += (*put)->size;
    }
    // 2. The switch.
    const S3Url json{set->bucket, set->key + "tileset.json"};
    auto switched = (*store)->put(json, std::vector<uint8_t>(text.begin(), text.end()), WriteCondition{false, base.etag});
    if (!switched) return switched.status();
    if (!switched->has_value())
        return Status::error(base.url + ": changed since this update read it (another update or compaction wrote it first); "
                             "the set stays as that one wrote it: run the update again");
    report.objects += 1;
    report.bytes += text.size();
    // An object written again in step 1 that another update's step 3 had
    // listed as old may have been deleted after it: written once more. One
    // that cannot be is an error: the version names it.
    for (const std::string& file : rewritten) {
        const S3Url object{set->bucket, set->key + file};
        auto there = (*store)->head(object);
        if (there && there->has_value()) continue;
        auto put = there ? (*store)->putFile(object, folder + "/" + file) : Result<std::optional<ObjectInfo>>(there.status());
        if (!put)
            return Status::error("published " + base.url + ", whose new version names " + object.str() +
                                 ", which another update's clean-up may have deleted and which could not be checked or written again (" +
                                 put.status().message() + "): run the update again, or upload " + folder + "/" + file + " there");
    }
    // 3. What neither version names, made before base; each asked again
    // just before it goes, as step 1 of an update racing this one may
    // have written it again meanwhile. The version is published: a failure
    // here leaves objects for the next update, and is a warning.
    auto listed = (*store)->list(*set);
    if (!listed) report.warning = "listing " + base.url + " for objects no kept version names failed (they stay for the next update): " + listed.status().message();
    for (const ListedObject& o : listed ? *listed : std::vector<ListedObject>()) {
        const std::string name = o.key.substr(set->key.size());
        if (name.find('/') != std::string::npos || !versionFileName(name) || named.count(name) || o.modified < 0 || o.modified >= base.modified)
            continue;
        auto now = (*store)->head({set->bucket, o.key});
        if (!now || !now->has_value() || (*now)->modified < 0 || (*now)->modified >= base.modified) continue;
        if (auto st = (*store)->remove({set->bucket, o.key}); !st.ok()) {
            report.warning = "deleting an object no kept version names failed (the rest stay for the next update): " + st.message();
            break;
        }
        report.removed += 1;
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
    // Another process clearing its predecessors' folders may take this one
    // for theirs between its creation and its lock (several stages start on
    // one machine at once): it is made again until, locked, it is still
    // there.
    for (int attempt = 0; attempt < 16; ++attempt) {
        std::string pattern = (temp / (std::string(kPrefix) + "XXXXXX")).string();
        if (!::mkdtemp(pattern.data()))
            return Status::error(pattern + ": cannot create the folder written before the upload (" + std::strerror(errno) + ")");
        auto staging = std::unique_ptr<PublishStaging>(new PublishStaging);
        staging->lock_ = ::open(pattern.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (staging->lock_ < 0) continue;  // removed already
        if (::flock(staging->lock_, LOCK_EX) != 0) return Status::error(pattern + ": cannot lock (" + std::strerror(errno) + ")");
        struct stat held{}, now{};
        if (::fstat(staging->lock_, &held) != 0 || ::stat(pattern.c_str(), &now) != 0 || held.st_ino != now.st_ino || held.st_dev != now.st_dev)
            continue;  // removed before the lock (its fd closes with `staging`)
        staging->dir_ = pattern;
        return staging;
    }
    return Status::error(temp.string() + ": cannot keep a folder of its own there (another process keeps removing them)");
}

PublishStaging::~PublishStaging() {
    std::error_code ec;
    if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
    if (lock_ >= 0) ::close(lock_);
}

}  // namespace surfcast
