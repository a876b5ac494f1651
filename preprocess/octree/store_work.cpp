#include "store_work.h"

#include <lz4frame.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
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

// The shuffle's pieces (chunks/P/chunk-I.*) go through the store as LZ4
// frames, named NAME.lz4: surfel records shrink about 2.5 times at LZ4's
// fastest level, which costs the workers less CPU than moving the bytes
// saved costs the store and the network (bench/BENCHMARKS.md, "Dask: two
// workers sharing nothing but the store"). The markers stay as they are,
// for the driver reads them.
constexpr const char* kPacked = ".lz4";
bool packed(const std::string& name) { return name.rfind("chunks/", 0) == 0 && fs::path(name).filename() != "distribution.bin"; }

// `from` into `to` as an LZ4 frame (pack) or back (unpack), in pieces of
// 1 MiB: the buffers are fixed, whatever the bytes say. A frame that ends
// early, does not decode or has bytes after it is an error naming `what`;
// on any error `to` is removed.
Status lz4Frames(std::FILE* in, std::FILE* out, const std::string& from, const std::string& to, bool pack, const std::string& what);

Status lz4File(const std::string& from, const std::string& to, bool pack, const std::string& what) {
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> in(std::fopen(from.c_str(), "rb"), &std::fclose);
    if (!in) return Status::error(from + ": cannot open");
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> out(std::fopen(to.c_str(), "wb"), &std::fclose);
    if (!out) return Status::error(to + ": cannot create");
    Status st = lz4Frames(in.get(), out.get(), from, to, pack, what);
    if (st.ok() && std::fclose(out.release()) != 0) st = Status::error(to + ": write failed (disk full?)");
    if (!st.ok()) {
        out.reset();
        std::error_code gone;
        fs::remove(to, gone);
    }
    return st;
}

Status lz4Frames(std::FILE* inFile, std::FILE* outFile, const std::string& from, const std::string& to, bool pack, const std::string& what) {
    constexpr size_t kPiece = 1u << 20;
    std::vector<char> input(kPiece);
    std::vector<char> output;
    auto put = [&](const char* data, size_t n) {
        return n == 0 || std::fwrite(data, 1, n, outFile) == n ? Status{} : Status::error(to + ": write failed (disk full?)");
    };
    if (pack) {
        LZ4F_cctx* context = nullptr;
        if (LZ4F_isError(LZ4F_createCompressionContext(&context, LZ4F_VERSION))) return Status::error("LZ4: cannot start");
        std::unique_ptr<LZ4F_cctx, decltype(&LZ4F_freeCompressionContext)> owned(context, &LZ4F_freeCompressionContext);
        LZ4F_preferences_t prefs{};
        prefs.frameInfo.contentChecksumFlag = LZ4F_contentChecksumEnabled;
        output.resize(std::max(LZ4F_compressBound(kPiece, &prefs), size_t(LZ4F_HEADER_SIZE_MAX)));
        size_t n = LZ4F_compressBegin(context, output.data(), output.size(), &prefs);
        if (LZ4F_isError(n)) return Status::error("LZ4: " + std::string(LZ4F_getErrorName(n)));
        SC_TRY(put(output.data(), n));
        for (size_t got; (got = std::fread(input.data(), 1, kPiece, inFile)) > 0;) {
            n = LZ4F_compressUpdate(context, output.data(), output.size(), input.data(), got, nullptr);
            if (LZ4F_isError(n)) return Status::error("LZ4: " + std::string(LZ4F_getErrorName(n)));
            SC_TRY(put(output.data(), n));
        }
        if (std::ferror(inFile)) return Status::error(from + ": read failed");
        n = LZ4F_compressEnd(context, output.data(), output.size(), nullptr);
        if (LZ4F_isError(n)) return Status::error("LZ4: " + std::string(LZ4F_getErrorName(n)));
        SC_TRY(put(output.data(), n));
    } else {
        LZ4F_dctx* context = nullptr;
        if (LZ4F_isError(LZ4F_createDecompressionContext(&context, LZ4F_VERSION))) return Status::error("LZ4: cannot start");
        std::unique_ptr<LZ4F_dctx, decltype(&LZ4F_freeDecompressionContext)> owned(context, &LZ4F_freeDecompressionContext);
        output.resize(kPiece);
        size_t hint = 1;  // 0 once the frame is whole
        bool trailing = false;
        for (size_t got; !trailing && (got = std::fread(input.data(), 1, kPiece, inFile)) > 0;) {
            size_t at = 0;
            while (at < got && hint != 0) {
                size_t outSize = output.size(), inSize = got - at;
                hint = LZ4F_decompress(context, output.data(), &outSize, input.data() + at, &inSize, nullptr);
                if (LZ4F_isError(hint)) return Status::error(what + ": not an LZ4 frame of a work file (" + LZ4F_getErrorName(hint) + ")");
                SC_TRY(put(output.data(), outSize));
                at += inSize;
            }
            trailing = hint == 0 && at < got;
        }
        if (std::ferror(inFile)) return Status::error(from + ": read failed");
        if (hint != 0) return Status::error(what + ": its LZ4 frame ends early");
        if (trailing || std::fgetc(inFile) != EOF) return Status::error(what + ": bytes after its LZ4 frame");
    }
    if (std::fflush(outFile) != 0) return Status::error(to + ": write failed (disk full?)");
    return {};
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
    std::vector<std::string> names;  // each one's file, below the work
    for (const ListedObject& o : *listed) {
        std::string name = o.key.substr(w->prefix_.size());
        const bool lz4 = name.size() > 4 && name.compare(name.size() - 4, 4, kPacked) == 0;
        if (lz4) name.resize(name.size() - 4);
        if (!readBy(stage, chunks, name)) continue;
        if (name.find("..") != std::string::npos) return Status::error("s3://" + w->bucket_ + "/" + o.key + ": not a work file's name");
        if (lz4 != packed(name))
            return Status::error("s3://" + w->bucket_ + "/" + o.key + ": not a work file's name (" +
                                 (lz4 ? "only the shuffle's pieces are LZ4 frames" : "the shuffle's pieces are NAME.lz4") + ")");
        wanted.push_back(o);
        names.push_back(name);
        w->copied_.insert(name);
        fs::create_directories((fs::path(local) / name).parent_path(), ec);
    }
    SC_TRY(inParallel(wanted.size(), [&](size_t i) -> Status {
        const std::string path = (fs::path(local) / names[i]).string();
        if (!packed(names[i])) return (*store)->getToFile({w->bucket_, wanted[i].key}, wanted[i].size, path);
        SC_TRY((*store)->getToFile({w->bucket_, wanted[i].key}, wanted[i].size, path + kPacked));
        const Status unpacked = lz4File(path + kPacked, path, false, "s3://" + w->bucket_ + "/" + wanted[i].key);
        std::error_code gone;
        fs::remove(path + kPacked, gone);
        return unpacked;
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
            const std::string path = local_ + "/" + name;
            if (!packed(name)) {
                auto put = (*store)->putFile({bucket_, prefix_ + name}, path);
                return put ? Status() : put.status();
            }
            SC_TRY(lz4File(path, path + kPacked, true, path));
            auto put = (*store)->putFile({bucket_, prefix_ + name + kPacked}, path + kPacked);
            std::error_code gone;
            fs::remove(path + kPacked, gone);
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
