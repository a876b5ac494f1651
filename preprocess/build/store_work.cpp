#include "store_work.h"

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <functional>
#include <mutex>
#include <thread>

#include "object_store.h"

namespace surfcast {

namespace fs = std::filesystem;

namespace {

// Transfers at once: a task's work files are many small objects (a chunk's
// pieces from every part), whose requests' latency parallel ones hide.
constexpr size_t kTransfers = 8;

// Runs job(i) for i in [0, n) on up to kTransfers threads; the first error.
Status inParallel(size_t n, const std::function<Status(size_t)>& job) {
    std::atomic<size_t> next{0};
    std::mutex mutex;
    Status first;
    auto work = [&] {
        for (size_t i; (i = next++) < n;) {
            Status st = job(i);
            std::lock_guard lock(mutex);
            if (!st.ok() && first.ok()) first = st;
            if (!first.ok()) return;
        }
    };
    std::vector<std::thread> threads;
    for (size_t t = 1; t < std::min(n, kTransfers); ++t) threads.emplace_back(work);
    work();
    for (std::thread& t : threads) t.join();
    return first;
}

// Whether `name` (a path below the work) is a file the stage reads.
bool readBy(const std::string& stage, const std::vector<size_t>& chunks, const std::string& name) {
    auto under = [&](const char* prefix) { return name.rfind(prefix, 0) == 0; };
    if (stage == "count") return under("scan/");
    if (stage == "plan") return under("scan/") || under("count/");
    if (stage == "distribute") return name == "plan.bin";
    if (stage == "merge") return name == "plan.bin" || under("nodes/");
    if (stage == "chunk") {
        if (name == "plan.bin") return true;
        if (!under("chunks/")) return false;
        const std::string file = fs::path(name).filename().string();
        if (file == "distribution.bin") return true;
        // chunk-I.bin, chunk-I.halo, chunk-I.scalars (chunker.h, ChunkWriter::files)
        for (size_t i : chunks)
            if (file.rfind("chunk-" + std::to_string(i) + ".", 0) == 0) return true;
    }
    return false;
}

// Files that mark an output whole go after the rest of it.
int uploadOrder(const std::string& name) {
    const std::string file = fs::path(name).filename().string();
    if (file == "plan.json") return 2;
    if (file == "distribution.bin" || file == "plan.bin" || fs::path(name).extension() == ".nodes") return 1;
    return 0;
}

}  // namespace

Result<std::unique_ptr<StoreWork>> StoreWork::open(const std::string& url, const std::string& stage, const std::vector<size_t>& chunks,
                                                   const std::string& local) {
    auto where = parseS3Prefix(url, "work");
    if (!where) return where.status();
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    std::unique_ptr<StoreWork> w(new StoreWork);
    w->bucket_ = where->bucket;
    w->prefix_ = where->key;
    w->local_ = local;
    std::error_code ec;
    fs::create_directories(local, ec);
    if (ec) return Status::error(local + ": cannot create (" + ec.message() + ")");
    auto listed = (*store)->list({w->bucket_, w->prefix_});
    if (!listed) return listed.status();
    std::vector<ListedObject> wanted;
    for (const ListedObject& o : *listed) {
        const std::string name = o.key.substr(w->prefix_.size());
        if (!readBy(stage, chunks, name)) continue;
        if (name.find("..") != std::string::npos) return Status::error("s3://" + w->bucket_ + "/" + o.key + ": not a work file's name");
        wanted.push_back(o);
        w->copied_.insert(name);
        fs::create_directories((fs::path(local) / name).parent_path(), ec);
    }
    SC_TRY(inParallel(wanted.size(), [&](size_t i) {
        return (*store)->getToFile({w->bucket_, wanted[i].key}, wanted[i].size, (fs::path(local) / wanted[i].key.substr(w->prefix_.size())).string());
    }));
    return w;
}

Status StoreWork::upload() const {
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    std::vector<std::string> files;
    std::error_code ec;
    for (fs::recursive_directory_iterator it(local_, ec), end; !ec && it != end; it.increment(ec))
        if (it->is_regular_file(ec)) {
            const std::string name = fs::relative(it->path(), local_, ec).generic_string();
            if (!copied_.count(name)) files.push_back(name);
        }
    if (ec) return Status::error(local_ + ": cannot list (" + ec.message() + ")");
    // Each rank after the one before it, whole: the files that mark an
    // output whole go up after the rest of it.
    std::stable_sort(files.begin(), files.end(), [](const std::string& a, const std::string& b) { return uploadOrder(a) < uploadOrder(b); });
    for (auto from = files.begin(); from != files.end();) {
        auto to = std::find_if(from, files.end(), [&](const std::string& f) { return uploadOrder(f) != uploadOrder(*from); });
        SC_TRY(inParallel(size_t(to - from), [&](size_t i) -> Status {
            const std::string& name = *(from + long(i));
            auto put = (*store)->putFile({bucket_, prefix_ + name}, local_ + "/" + name);
            return put ? Status() : put.status();
        }));
        from = to;
    }
    return {};
}

Status StoreWork::remove(const std::vector<std::string>& prefixes) const {
    auto store = ObjectStore::shared();
    if (!store) return store.status();
    for (const std::string& p : prefixes) {
        auto listed = (*store)->list({bucket_, prefix_ + p});
        if (!listed) return listed.status();
        SC_TRY(inParallel(listed->size(), [&](size_t i) { return (*store)->remove({bucket_, (*listed)[i].key}); }));
    }
    return {};
}

}  // namespace surfcast
