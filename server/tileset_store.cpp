#include "tileset_store.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <map>
#include <vector>

#include "crc32.h"
#include "object_store.h"

namespace surfcast {

namespace {
constexpr size_t kMaxNameLength = 128;

bool sameFile(const struct stat& st, const TilesetSnapshot& s) {
    return st.st_dev == s.device && st.st_ino == s.inode && st.st_mtim.tv_sec == s.modified.tv_sec &&
           st.st_mtim.tv_nsec == s.modified.tv_nsec;
}

struct Fd {
    int fd = -1;
    ~Fd() { if (fd >= 0) ::close(fd); }
};
}  // namespace

Result<std::shared_ptr<MappedFile>> MappedFile::openAt(int dirFd, const std::string& name, const std::string& what) {
    // O_NOFOLLOW: a symlink inside a set cannot point the server outside it.
    Fd f{::openat(dirFd, name.c_str(), O_RDONLY | O_NOFOLLOW | O_CLOEXEC)};
    if (f.fd < 0) return Status::error(what + ": cannot open (" + std::strerror(errno) + ")");
    struct stat st{};
    if (::fstat(f.fd, &st) != 0 || !S_ISREG(st.st_mode)) return Status::error(what + ": not a regular file");
    std::shared_ptr<MappedFile> m(new MappedFile);
    m->size_ = uint64_t(st.st_size);
    if (m->size_ > 0) {
        void* p = ::mmap(nullptr, m->size_, PROT_READ, MAP_SHARED, f.fd, 0);
        if (p == MAP_FAILED) return Status::error(what + ": mmap failed (" + std::strerror(errno) + ")");
        m->data_ = static_cast<const uint8_t*>(p);
    }
    return m;
}

std::shared_ptr<MappedFile> MappedFile::fromBytes(std::vector<uint8_t> bytes) {
    std::shared_ptr<MappedFile> m(new MappedFile);
    m->held_ = std::move(bytes);
    m->data_ = m->held_.data();
    m->size_ = m->held_.size();
    return m;
}

MappedFile::~MappedFile() {
    if (data_ && held_.empty()) ::munmap(const_cast<uint8_t*>(data_), size_);
}

Result<std::unique_ptr<TilesetStore>> TilesetStore::open(const std::string& root) {
    std::unique_ptr<TilesetStore> s(new TilesetStore);
    s->root_ = root;
    s->rootFd_ = ::open(root.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (s->rootFd_ < 0) return Status::error(root + ": cannot open folder (" + std::strerror(errno) + ")");
    return s;
}

Result<std::unique_ptr<TilesetStore>> TilesetStore::openBucket(const std::string& url, uint64_t cacheBytes, double pollSeconds) {
    auto where = parseS3Prefix(url);
    if (!where) return where.status();
    auto objects = ObjectStore::shared();
    if (!objects) return objects.status();
    std::unique_ptr<TilesetStore> s(new TilesetStore);
    s->prefix_ = where->key;
    s->root_ = "s3://" + where->bucket + "/" + s->prefix_;
    // Fetches at once: enough to keep a store's latency hidden behind a few
    // viewers' requests (each of which waits for all of its own).
    // Bytes being fetched at once: at most 256 MiB (what 4 requests for
    // 64 MiB of a block file take), so that clients cannot make the server
    // hold more than its cache and this.
    s->bucket_ = std::make_shared<BucketBlocks>(*objects, where->bucket, cacheBytes, 16, 256ull << 20);
    s->pollSeconds_ = pollSeconds;
    SC_TRY(s->refresh());
    TilesetStore* self = s.get();
    s->poller_ = std::thread([self] {
        std::unique_lock lock(self->mutex_);
        for (;;) {
            self->pollWake_.wait_for(lock, std::chrono::duration<double>(self->pollSeconds_), [&] { return self->stopping_; });
            if (self->stopping_) return;
            lock.unlock();
            Status st = self->refresh();
            if (!st.ok()) std::fprintf(stderr, "surfcast-serve: %s (the sets stay as they were)\n", st.message().c_str());
            lock.lock();
        }
    });
    return s;
}

TilesetStore::~TilesetStore() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    pollWake_.notify_all();
    if (poller_.joinable()) poller_.join();
    if (rootFd_ >= 0) ::close(rootFd_);
}

Status TilesetStore::refresh() {
    auto listed = bucket_->store().list({bucket_->bucket(), prefix_});
    if (!listed) return listed.status();
    std::map<std::string, std::string> etags;  // set name: its tileset.json's ETag
    for (const ListedObject& o : *listed) {
        const std::string rest = o.key.substr(prefix_.size());
        const size_t slash = rest.find('/');
        if (slash != std::string::npos && rest.compare(slash, std::string::npos, "/tileset.json") == 0 && validName(rest.substr(0, slash)))
            etags[rest.substr(0, slash)] = o.etag;
    }
    for (const auto& [name, etag] : etags) {
        {
            std::lock_guard lock(mutex_);
            auto it = sets_.find(name);
            if (it != sets_.end() && it->second->jsonEtag == etag) continue;
        }
        auto loaded = loadFromBucket(name);
        if (!loaded) {
            // A set that fails to load keeps its last snapshot; said once.
            std::lock_guard lock(mutex_);
            if (loadErrors_[name] != loaded.status().message())
                std::fprintf(stderr, "surfcast-serve: %s\n", loaded.status().message().c_str());
            loadErrors_[name] = loaded.status().message();
            continue;
        }
        (*loaded)->jsonEtag = etag;
        install(std::move(*loaded));
        std::lock_guard lock(mutex_);
        loadErrors_.erase(name);
    }
    std::lock_guard lock(mutex_);
    for (auto it = sets_.begin(); it != sets_.end();) {
        if (etags.count(it->first)) {
            ++it;
            continue;
        }
        previous_.erase(it->first);
        it = sets_.erase(it);
    }
    return {};
}

Result<std::shared_ptr<TilesetSnapshot>> TilesetStore::loadFromBucket(const std::string& name) {
    ObjectStore& objects = bucket_->store();
    const std::string where = prefix_ + name + "/";
    const S3Url jsonUrl{bucket_->bucket(), where + "tileset.json"};
    auto json = objects.get(jsonUrl, kMaxTilesetJsonBytes);
    if (!json) return json.status();
    auto info = readTilesetJson(std::string(json->begin(), json->end()), jsonUrl.str());
    if (!info) return info.status();
    const S3Url hierarchyUrl{bucket_->bucket(), where + info->hierarchyFile};
    auto hierarchy = objects.get(hierarchyUrl, info->hierarchyBytes);
    if (!hierarchy) return hierarchy.status();
    auto snap = std::make_shared<TilesetSnapshot>();
    snap->name = name;
    snap->info = *info;
    snap->layout = BlocksLayout(blocksPartsOf(*info));
    auto nodes = readHierarchyOf(*info, *hierarchy, hierarchyUrl.str());
    if (!nodes) return nodes.status();
    for (const NodeRecord& n : *nodes) {
        if (auto place = snap->layout.place(n.blockOffset, n.blockSize); !place)
            return Status::error(hierarchyUrl.str() + ": node " + n.key.name() + ": " + place.status().message());
        snap->nodes[n.key] = n;
    }
    snap->version = crc32(json->data(), json->size());
    snap->json = MappedFile::fromBytes(std::move(*json));
    snap->hierarchy = MappedFile::fromBytes(std::move(*hierarchy));
    snap->bucket = bucket_;
    snap->keyPrefix = where;
    return snap;
}

void TilesetStore::install(std::shared_ptr<const TilesetSnapshot> snap) {
    std::lock_guard lock(mutex_);
    auto& current = sets_[snap->name];
    if (current && current->info.hierarchyCrc != snap->info.hierarchyCrc) previous_[snap->name] = current;
    current = std::move(snap);
}

bool TilesetStore::validName(const std::string& name) {
    if (name.empty() || name.size() > kMaxNameLength || name[0] == '.') return false;
    return std::all_of(name.begin(), name.end(), [](unsigned char c) {
        return std::isalnum(c) || c == '.' || c == '_' || c == '-';
    });
}

Result<std::shared_ptr<TilesetSnapshot>> TilesetStore::load(const std::string& name) {
    // The folder is opened once and its three files relative to it, so all
    // three come from the same folder even if another is renamed in meanwhile.
    Fd dir{::openat(rootFd_, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC)};
    if (dir.fd < 0) return Status::error("no tile set named '" + name + "'");
    std::string where = root_ + "/" + name + "/";
    auto json = MappedFile::openAt(dir.fd, "tileset.json", where + "tileset.json");
    if (!json) return json.status();
    const auto& j = **json;
    auto info = readTilesetJson(std::string(reinterpret_cast<const char*>(j.data()), j.size()), where + "tileset.json");
    if (!info) return info.status();
    auto hierarchy = MappedFile::openAt(dir.fd, info->hierarchyFile, where + info->hierarchyFile);
    if (!hierarchy) return hierarchy.status();
    auto snap = std::make_shared<TilesetSnapshot>();
    snap->name = name;
    snap->info = *info;
    snap->layout = BlocksLayout(blocksPartsOf(*info));
    for (const BlocksPart& part : snap->layout.parts()) {
        auto file = MappedFile::openAt(dir.fd, part.file, where + part.file);
        if (!file) return file.status();
        // blocks.bin of a set updated before version 3 may be longer: bytes a
        // killed update appended, which no version names.
        if ((*file)->size() < part.bytes)
            return Status::error(where + part.file + ": " + std::to_string((*file)->size()) + " bytes, tileset.json says " +
                                 std::to_string(part.bytes) + " (a build in progress?)");
        snap->partFiles.push_back(std::move(*file));
    }
    const auto& h = **hierarchy;
    auto nodes = readHierarchyOf(*info, std::vector<uint8_t>(h.data(), h.data() + h.size()), where + info->hierarchyFile);
    if (!nodes) return nodes.status();
    for (const NodeRecord& n : *nodes) {
        if (auto place = snap->layout.place(n.blockOffset, n.blockSize); !place)
            return Status::error(where + info->hierarchyFile + ": node " + n.key.name() + ": " + place.status().message());
        snap->nodes[n.key] = n;
    }
    snap->version = crc32(j.data(), j.size());
    snap->json = std::move(*json);
    snap->hierarchy = std::move(*hierarchy);
    struct stat st{};
    if (::fstatat(dir.fd, "tileset.json", &st, AT_SYMLINK_NOFOLLOW) == 0) {
        snap->device = st.st_dev;
        snap->inode = st.st_ino;
        snap->modified = st.st_mtim;
    }
    return snap;
}

Result<std::shared_ptr<MappedFile>> TilesetStore::hierarchyFile(const std::string& name, const std::string& file) {
    if (!validName(name) || !validHierarchyFile(file)) return Status::error("no such file");
    if (bucket_) {  // the version before the current one, in memory
        std::lock_guard lock(mutex_);
        auto it = previous_.find(name);
        if (it == previous_.end() || it->second->info.hierarchyFile != file) return Status::error("no such file");
        return it->second->hierarchy;
    }
    Fd dir{::openat(rootFd_, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC)};
    if (dir.fd < 0) return Status::error("no tile set named '" + name + "'");
    return MappedFile::openAt(dir.fd, file, root_ + "/" + name + "/" + file);
}

std::shared_ptr<const TilesetSnapshot> TilesetStore::get(const std::string& name, std::string* error) {
    if (!validName(name)) {
        *error = "invalid tile set name";
        return nullptr;
    }
    if (bucket_) {  // as the last listing left it (refresh)
        std::lock_guard lock(mutex_);
        auto it = sets_.find(name);
        if (it != sets_.end()) return it->second;
        *error = "no tile set named '" + name + "'";
        return nullptr;
    }
    struct stat st{};
    std::string path = name + "/tileset.json";
    bool exists = ::fstatat(rootFd_, path.c_str(), &st, 0) == 0;
    {
        std::lock_guard lock(mutex_);
        auto it = sets_.find(name);
        if (it != sets_.end() && exists && sameFile(st, *it->second)) return it->second;
    }
    // New, replaced or gone: load (outside the lock; concurrent loads of one set are harmless).
    auto loaded = load(name);
    std::lock_guard lock(mutex_);
    if (!loaded) {
        // A set that fails to load mid-replacement keeps serving its last snapshot.
        auto it = sets_.find(name);
        if (it != sets_.end() && exists) return it->second;
        sets_.erase(name);
        previous_.erase(name);
        *error = loaded.status().message();
        return nullptr;
    }
    std::shared_ptr<const TilesetSnapshot> snap = std::move(*loaded);
    // Its mappings stay valid: an update in place writes new files only, and
    // a rebuild replaces the files, whose old inodes the mappings hold.
    auto& current = sets_[name];
    if (current && current->info.hierarchyCrc != snap->info.hierarchyCrc) previous_[name] = current;
    current = snap;
    return snap;
}

std::shared_ptr<const TilesetSnapshot> TilesetStore::pinned(const std::string& name, uint32_t version) {
    std::lock_guard lock(mutex_);
    for (auto* sets : {&sets_, &previous_}) {
        auto it = sets->find(name);
        if (it != sets->end() && it->second->info.hierarchyCrc == version) return it->second;
    }
    return nullptr;
}

uint64_t leafPointsAtMost(const TilesetSnapshot& snapshot, const std::optional<Box3d>& box, uint64_t stopAbove) {
    const TilesetInfo& info = snapshot.info;
    uint64_t points = 0;
    std::vector<NodeKey> todo = {NodeKey{}};
    while (!todo.empty() && points <= stopAbove) {
        const NodeKey key = todo.back();
        todo.pop_back();
        auto it = snapshot.nodes.find(key);
        if (it == snapshot.nodes.end()) continue;
        if (box) {
            // A child's cube lies inside its parent's: a cube the box misses
            // has no descendant it reaches.
            Box3d cube;
            cube.min = nodeMin(info, key);
            cube.max = cube.min + Vec3d{1, 1, 1} * nodeEdge(info, key.level);
            if (!box->intersects(cube)) continue;
        }
        const NodeRecord& n = it->second;
        if (n.flags & kFlagInputPoints) points += n.surfelCount;
        for (int i = 0; i < 8; ++i)
            if (n.childMask & (1u << i)) todo.push_back(key.child(i));
    }
    return points;
}

std::vector<std::shared_ptr<const TilesetSnapshot>> TilesetStore::list() {
    if (bucket_) {
        std::lock_guard lock(mutex_);
        std::vector<std::shared_ptr<const TilesetSnapshot>> out;
        for (const auto& [name, snap] : sets_) out.push_back(snap);
        std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a->name < b->name; });
        return out;
    }
    std::vector<std::string> names;
    // A fresh open file description: concurrent listings must not share a
    // directory offset (dup() would).
    int fd = ::openat(rootFd_, ".", O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (DIR* d = fd >= 0 ? ::fdopendir(fd) : nullptr) {
        while (dirent* e = ::readdir(d))
            if (validName(e->d_name)) names.push_back(e->d_name);
        ::closedir(d);
    }
    std::sort(names.begin(), names.end());
    std::vector<std::shared_ptr<const TilesetSnapshot>> out;
    std::string error;
    for (const auto& n : names)
        if (auto s = get(n, &error)) out.push_back(s);
    return out;
}

namespace {

class SnapshotSource final : public TileSource {
public:
    explicit SnapshotSource(std::shared_ptr<const TilesetSnapshot> s) : s_(std::move(s)) {}
    Result<std::vector<uint8_t>> file(const std::string& name, uint64_t maxBytes) override {
        auto m = mapped(name);
        if (!m) return m.status();
        if ((*m)->size() > maxBytes) return Status::error(describe() + "/" + name + ": longer than the " + std::to_string(maxBytes) + " bytes expected");
        return std::vector<uint8_t>((*m)->data(), (*m)->data() + (*m)->size());
    }
    Result<std::vector<uint8_t>> range(const std::string& name, uint64_t offset, uint64_t size) override {
        if (s_->bucket && name != "tileset.json" && name != s_->info.hierarchyFile) {
            const std::optional<uint64_t> declared = s_->partBytes(name);
            if (!declared) return Status::error(describe() + ": no file " + name);
            if (offset > *declared || size > *declared - offset)
                return Status::error(describe() + "/" + name + ": bytes " + std::to_string(offset) + "+" + std::to_string(size) +
                                     " outside its " + std::to_string(*declared));
            return s_->bucket->read(s_->range(name, offset, size));
        }
        auto m = mapped(name);
        if (!m) return m.status();
        if (offset > (*m)->size() || size > (*m)->size() - offset)
            return Status::error(describe() + "/" + name + ": bytes " + std::to_string(offset) + "+" + std::to_string(size) +
                                 " outside its " + std::to_string((*m)->size()));
        return std::vector<uint8_t>((*m)->data() + offset, (*m)->data() + offset + size);
    }
    Result<uint64_t> size(const std::string& name) override {
        auto m = mapped(name);
        if (!m) return m.status();
        return (*m)->size();
    }
    std::string describe() const override { return "set '" + s_->name + "'"; }

private:
    Result<const MappedFile*> mapped(const std::string& name) const {
        if (name == "tileset.json") return s_->json.get();
        if (name == s_->info.hierarchyFile) return s_->hierarchy.get();
        uint64_t declared = 0;
        if (const MappedFile* part = s_->partFile(name, &declared)) return part;
        return Status::error(describe() + ": no file " + name);
    }
    std::shared_ptr<const TilesetSnapshot> s_;
};

}  // namespace

const uint8_t* TilesetSnapshot::block(const NodeRecord& node) const {
    auto place = layout.place(node.blockOffset, node.blockSize);
    assert(place.ok() && "a node's block outside the parts (load checks every one)");
    return partFiles[place->part]->data() + place->offset;
}

std::optional<uint64_t> TilesetSnapshot::partBytes(const std::string& file) const {
    for (const BlocksPart& part : layout.parts())
        if (part.file == file) return part.bytes;
    return std::nullopt;
}

const MappedFile* TilesetSnapshot::partFile(const std::string& file, uint64_t* declaredBytes) const {
    const auto& parts = layout.parts();
    for (size_t i = 0; i < parts.size() && !bucket; ++i)
        if (parts[i].file == file) {
            *declaredBytes = parts[i].bytes;
            return partFiles[i].get();
        }
    return nullptr;
}

std::unique_ptr<TileSource> snapshotSource(std::shared_ptr<const TilesetSnapshot> snapshot) {
    return std::make_unique<SnapshotSource>(std::move(snapshot));
}

}  // namespace surfcast
