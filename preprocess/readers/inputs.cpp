#include "inputs.h"

#include <algorithm>
#include <bit>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>

#include "byte_stream.h"
#include "input_file.h"
#include "object_store.h"
#include "set_reader.h"
#include "e57_reader.h"
#include "las_reader.h"
#include "pcd_reader.h"
#include "ply_reader.h"
#include "text_reader.h"

namespace surfcast {

namespace {

constexpr size_t kBatchPoints = 1 << 16;
// Read-ahead: inputs opened and decoded ahead of the one being visited, at
// most this many, and whole only when their points fit kPrefetchBytes.
constexpr size_t kPrefetchFiles = 64;
// Extensions of text point files (text_reader.h).
constexpr const char* kTextExtensions[] = {".xyz", ".txt", ".pts", ".csv", ".asc"};

bool isTextExtension(const std::string& ext) {
    return std::find(std::begin(kTextExtensions), std::end(kTextExtensions), ext) != std::end(kTextExtensions);
}

enum class InputKind { Points, Mesh };

// How openOne reads `path`: by extension and magic bytes, a PLY by whether
// its header declares faces.
Result<InputKind> inputKind(const std::string& path, const InputOptions& options) {
    std::error_code ec;
    if (!isRemoteInput(path) && !std::filesystem::is_regular_file(path, ec)) return Status::error(path + ": no such file");
    char magic[4] = {};
    {
        auto in = ByteStream::open(path, options.http);
        if (!in) return in.status();
        if (in->fileSize() == 0) return Status::error(path + ": empty file");
        in->readBytes(magic, std::min<uint64_t>(4, in->fileSize()));
    }
    if (lowerExtension(path) == ".ply" || std::string(magic, 3) == "ply") {
        if (options.verticesOnly) return InputKind::Points;
        auto in = ByteStream::open(path, options.http);
        if (!in) return in.status();
        auto header = parsePlyHeader(*in);
        if (!header) return header.status();
        return plyHasFaces(*header) ? InputKind::Mesh : InputKind::Points;
    }
    const std::string m(magic, 4);
    if (m == "# .P" || m == "VERS" || m == "LASF" || m == "ASTM") return InputKind::Points;
    return isMeshExtension(path) ? InputKind::Mesh : InputKind::Points;
}

// Input `index` of options.paths, read whole or in the part options give.
Result<std::unique_ptr<PointReader>> openOne(size_t index, const InputOptions& options) {
    const std::string& path = options.paths[index];
    const RecordRange range{index == 0 ? options.firstBegin : 0, index + 1 == options.paths.size() ? options.lastEnd : 0};
    auto kind = inputKind(path, options);
    if (!kind) return kind.status();
    const bool whole = range.begin == 0 && range.end == 0;
    std::string ext = lowerExtension(path);
    char magic[4] = {};
    {
        auto in = ByteStream::open(path, options.http);
        if (!in) return in.status();
        in->readBytes(magic, std::min<uint64_t>(4, in->fileSize()));
    }
    const bool las = ext == ".las" || ext == ".laz" || std::string(magic, 4) == "LASF";
    if (!whole && (*kind == InputKind::Mesh || !las))
        return Status::error(path + ": only LAS and LAZ files are read in parts (records " + std::to_string(range.begin) + " to " +
                             (range.end ? std::to_string(range.end) : "the end") + " asked for)");
    if (*kind == InputKind::Mesh && isRemoteInput(path))
        return Status::error(path + ": meshes are read from local files only (point files may be URLs)");
    if (*kind == InputKind::Mesh) return openMeshReader(path, options.mesh, options.meshes.get());
    if (isSetInput(path)) return openSetReader(path, options.scalars);
    if (ext == ".ply" || std::string(magic, 3) == "ply") return openPlyReader(path, options.scalars, options.http);
    if (ext == ".pcd" || std::string(magic, 4) == "# .P" || std::string(magic, 4) == "VERS")
        return openPcdReader(path, options.scalars, options.readAlpha, options.http);
    if (las && options.chunkStarts && whole) return openLasChunkStarts(path, options.scalars, options.http);
    if (las) return openLasReader(path, options.threads, options.scalars, range, options.http);
    if (ext == ".e57" || std::string(magic, 4) == "ASTM") return openE57Reader(path, options.scalars, options.http);
    if (isTextExtension(ext)) return openTextReader(path, options.columns, options.http);
    return Status::error(path + ": unknown input format '" + ext + "' (PLY, LAS, LAZ, E57, PCD, XYZ/TXT/PTS/CSV, OBJ, OFF, STL, a tile set's tileset.json)");
}

uint16_t scaled(uint16_t raw, double scale) { return uint16_t(std::min(65535.0, raw * scale)); }

// The extensions openOne() recognizes (it also goes by magic bytes).
bool readableExtension(const std::string& path) {
    std::string ext = lowerExtension(path);
    return ext == ".ply" || ext == ".pcd" || ext == ".las" || ext == ".laz" || ext == ".e57" || isMeshExtension(path) ||
           isTextExtension(ext);
}

}  // namespace

std::string crsIdentity(const std::string& crs) {
    if (crs.rfind("GeoTIFF keys:", 0) == 0) {
        for (const char* key : {" 3072=", " 2048="})
            if (const size_t at = crs.find(key); at != std::string::npos)
                return "EPSG:" + crs.substr(at + 6, crs.find(' ', at + 6) - (at + 6));
        return crs;
    }
    // The WKT's own code is its last (WKT1 AUTHORITY and WKT2 ID close the
    // definition they name; the root's closes it).
    static const std::string kAuthority = "AUTHORITY[\"EPSG\",\"", kId = "ID[\"EPSG\",";
    const size_t authority = crs.rfind(kAuthority), id = crs.rfind(kId);
    if (authority != std::string::npos && (id == std::string::npos || authority > id)) {
        const size_t from = authority + kAuthority.size();
        return "EPSG:" + crs.substr(from, crs.find('"', from) - from);
    }
    if (id != std::string::npos) {
        const size_t from = id + kId.size();
        return "EPSG:" + crs.substr(from, crs.find_first_of(",]", from) - from);
    }
    return crs;
}

std::string crsName(const std::string& crs) {
    if (crs.rfind("GeoTIFF keys:", 0) == 0) {
        const std::string code = crsIdentity(crs);
        return code != crs ? code : crs.substr(0, 80);
    }
    const size_t open = crs.find("[\""), close = open == std::string::npos ? open : crs.find('"', open + 2);
    return close == std::string::npos ? crs.substr(0, 80) : crs.substr(open + 2, close - open - 2);
}

int finestBitOf(double v) {
    if (v == 0 || !std::isfinite(v)) return INT_MAX;
    int e = 0;
    // v = f · 2^e with 0.5 <= |f| < 1: f's 53 significant bits as an integer.
    const uint64_t m = uint64_t(std::fabs(std::frexp(v, &e)) * 0x1p53);
    return e - 53 + std::countr_zero(m);
}

bool ScalarSelection::wants(const std::string& name) const {
    return all || std::find(names.begin(), names.end(), name) != names.end();
}

Result<std::vector<std::string>> expandInputPaths(const std::vector<std::string>& args) {
    namespace fs = std::filesystem;
    std::vector<std::string> out;
    for (const std::string& arg : args) {
        std::error_code ec;
        if (arg.size() > 1 && arg[0] == '@') {
            const std::string list = arg.substr(1);
            std::ifstream in(list);
            if (!in) return Status::error(list + ": cannot open the input list");
            const fs::path base = fs::path(list).parent_path();
            std::string line;
            while (std::getline(in, line)) {
                while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t')) line.pop_back();
                size_t start = line.find_first_not_of(" \t");
                if (start == std::string::npos || line[start] == '#') continue;
                fs::path p(line.substr(start));
                const std::string entry = p.string();
                out.push_back(isRemoteInput(entry) ? signedInput(entry) : p.is_absolute() ? entry : (base / p).string());
            }
            if (in.bad()) return Status::error(list + ": read error");
        } else if (isS3Url(arg) && (arg.back() == '/' || arg.find('/', 5) == std::string::npos)) {
            // A prefix: every object under it of a readable format, in key order.
            auto prefix = parseS3Url(arg);
            if (!prefix) return prefix.status();
            auto store = ObjectStore::shared();
            if (!store) return store.status();
            auto objects = (*store)->list(*prefix);
            if (!objects) return objects.status();
            size_t found = 0;
            for (const ListedObject& o : *objects)
                if (o.size > 0 && readableExtension(o.key)) {
                    out.push_back("s3://" + prefix->bucket + "/" + o.key);
                    ++found;
                }
            if (found == 0) return Status::error(arg + ": the prefix holds no object of a readable format");
        } else if (isRemoteInput(arg)) {
            out.push_back(signedInput(arg));
        } else if (fs::is_directory(arg, ec) && fs::exists(fs::path(arg) / "tileset.json", ec)) {
            out.push_back((fs::path(arg) / "tileset.json").string());  // a tile set: its points (set_reader.h)
        } else if (fs::is_directory(arg, ec)) {
            std::vector<std::string> found;
            fs::recursive_directory_iterator it(arg, fs::directory_options::skip_permission_denied, ec), end;
            if (ec) return Status::error(arg + ": cannot list the folder (" + ec.message() + ")");
            for (; it != end; it.increment(ec)) {
                if (ec) return Status::error(arg + ": cannot list the folder (" + ec.message() + ")");
                if (it->is_regular_file(ec) && readableExtension(it->path().string())) found.push_back(it->path().string());
            }
            if (found.empty()) return Status::error(arg + ": the folder holds no file of a readable format");
            std::sort(found.begin(), found.end());
            out.insert(out.end(), found.begin(), found.end());
        } else {
            out.push_back(arg);
        }
    }
    return out;
}

namespace {

// An input read whole into memory by the read-ahead thread.
class BufferedReader final : public PointReader {
public:
    BufferedReader(InputDescription d, std::vector<InputPoint> points, std::vector<double> scalars, uint64_t skipped)
        : desc_(std::move(d)), points_(std::move(points)), scalars_(std::move(scalars)) {
        skipped_ = skipped;
    }
    const InputDescription& description() const override { return desc_; }
    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = std::min(max, points_.size() - next_);
        std::copy_n(points_.begin() + long(next_), n, out);
        const size_t fields = desc_.scalars.size();
        scalarValues_.assign(scalars_.begin() + long(next_ * fields), scalars_.begin() + long((next_ + n) * fields));
        next_ += n;
        return n;
    }

private:
    InputDescription desc_;
    std::vector<InputPoint> points_;
    std::vector<double> scalars_;  // desc_.scalars.size() per point
    size_t next_ = 0;
};

// Opens the input files on threads of their own (one per --threads), ahead of
// the visitor, which gets them in order: a point file whose declared points
// fit a quarter of kPrefetchBytes is decoded whole (small files, whose decoding
// cannot be split over threads, decode side by side and alongside the
// visitor's work); a larger one is handed over open and unread; a mesh is
// opened by the visitor. At most kPrefetchFiles files and kPrefetchBytes of
// points are ahead.
class ReadAhead {
public:
    explicit ReadAhead(const InputOptions& options) : options_(options) {
        for (int t = 0; t < std::max(1, options.threads); ++t) threads_.emplace_back([this] { run(); });
    }
    ~ReadAhead() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        changed_.notify_all();
        for (std::thread& t : threads_) t.join();
    }

    // The next input in order: its reader, or the error that opening or
    // decoding it met.
    Result<std::unique_ptr<PointReader>> next() {
        std::unique_lock lock(mutex_);
        changed_.wait(lock, [&] { return ready_.count(nextToVisit_) != 0; });
        const size_t index = nextToVisit_++;
        auto node = ready_.extract(index);
        Item& item = node.mapped();
        bytes_ -= item.bytes;
        --ahead_;
        changed_.notify_all();
        if (!item.status.ok()) return item.status;
        if (item.deferred) {
            lock.unlock();
            return openOne(index, options_);
        }
        return std::move(item.reader);
    }

private:
    struct Item {
        std::unique_ptr<PointReader> reader;
        Status status;
        size_t bytes = 0;
        bool deferred = false;  // opened by the visitor (a mesh)
    };

    Item load(size_t index) {
        const std::string& path = options_.paths[index];
        Item item;
        // A mesh is read whole (and kept by the MeshStore): left to the
        // visitor, so that the meshes in memory beside the store's are the
        // one being visited alone, as the build's budget counts them.
        if (auto kind = inputKind(path, options_); kind && *kind == InputKind::Mesh) {
            item.deferred = true;
            return item;
        }
        auto r = openOne(index, options_);
        if (!r) {
            item.status = r.status();
            return item;
        }
        const InputDescription& d = (*r)->description();
        const size_t pointBytes = sizeof(InputPoint) + d.scalars.size() * sizeof(double);
        // (Compared as a count: a header's claim times the point size could wrap.)
        if (d.declaredPoints == 0 || d.declaredPoints > kPrefetchBytes / 4 / pointBytes) {
            item.reader = std::move(*r);
            item.bytes = kPrefetchBytes / 4;  // an open decoder and its buffers
            return item;
        }
        std::vector<InputPoint> points(d.declaredPoints);
        std::vector<double> scalars;
        size_t n = 0;
        while (n < points.size()) {
            auto got = (*r)->read(points.data() + n, points.size() - n);
            if (!got) {
                item.status = got.status();
                return item;
            }
            if (*got == 0) break;
            n += *got;
            scalars.insert(scalars.end(), (*r)->scalarValues().begin(), (*r)->scalarValues().end());
        }
        InputPoint extra;
        auto more = (*r)->read(&extra, 1);
        if (!more) {
            item.status = more.status();
            return item;
        }
        if (*more) {  // more points than declared: the visitor reads it again and names the mismatch
            auto again = openOne(index, options_);
            if (!again) item.status = again.status();
            else item.reader = std::move(*again);
            item.bytes = kPrefetchBytes / 4;
            return item;
        }
        points.resize(n);
        item.bytes = n * pointBytes;
        item.reader = std::make_unique<BufferedReader>(d, std::move(points), std::move(scalars), (*r)->skipped());
        return item;
    }

    void run() {
        while (true) {
            size_t i = 0;
            {
                std::unique_lock lock(mutex_);
                // Files are taken in order, so the one the visitor waits for is
                // always loading or loaded: the bounds cannot block it.
                changed_.wait(lock, [&] { return stop_ || (ahead_ < kPrefetchFiles && bytes_ < kPrefetchBytes); });
                if (stop_ || nextToLoad_ == options_.paths.size()) return;
                i = nextToLoad_++;
                ++ahead_;
            }
            Item item = load(i);
            {
                std::lock_guard lock(mutex_);
                bytes_ += item.bytes;
                ready_.emplace(i, std::move(item));
            }
            changed_.notify_all();
        }
    }

    const InputOptions& options_;
    std::mutex mutex_;
    std::condition_variable changed_;
    std::map<size_t, Item> ready_;  // by input index
    size_t nextToLoad_ = 0, nextToVisit_ = 0;
    size_t ahead_ = 0;  // taken by a loader and not yet visited
    size_t bytes_ = 0;  // of the loaded ones
    bool stop_ = false;
    std::vector<std::thread> threads_;
};

}  // namespace

// An input captured in memory, read again.
class CapturedReader : public PointReader {
public:
    explicit CapturedReader(const CapturedInput& input) : input_(input) { skipped_ = input.skipped; }
    const InputDescription& description() const override { return input_.description; }
    Result<size_t> read(InputPoint* out, size_t max) override {
        const size_t n = std::min(max, input_.points.size() - at_), fields = input_.description.scalars.size();
        std::copy_n(input_.points.begin() + long(at_), n, out);
        scalarValues_.assign(input_.scalars.begin() + long(at_ * fields), input_.scalars.begin() + long((at_ + n) * fields));
        at_ += n;
        return n;
    }

private:
    const CapturedInput& input_;
    size_t at_ = 0;
};

Result<CapturedInputs> captureInputs(const InputOptions& options, uint32_t stride, uint64_t most) {
    CapturedInputs out;
    out.stride = std::max<uint32_t>(1, stride);
    auto inputs = std::make_shared<std::vector<CapturedInput>>();
    std::vector<std::vector<uint64_t>> indices;  // per input: each held point's index in it
    uint64_t held = 0;
    // Every held point whose index is not a multiple of the doubled stride goes.
    std::vector<bool> starts;   // per input: read by its chunk starts, each kept (every startsStride-th once thinned)
    uint32_t startsStride = 1;
    uint64_t standFor = 0;      // the points of the inputs read by their chunk starts
    auto thin = [&] {
        out.stride *= 2;
        startsStride *= 2;
        held = 0;
        for (size_t k = 0; k < inputs->size(); ++k) {
            CapturedInput& c = (*inputs)[k];
            const size_t fields = c.description.scalars.size();
            size_t kept = 0;
            for (size_t i = 0; i < c.points.size(); ++i) {
                if (indices[k][i] % (starts[k] ? startsStride : out.stride) != 0) continue;
                c.points[kept] = c.points[i];
                indices[k][kept] = indices[k][i];
                std::copy_n(c.scalars.begin() + long(i * fields), fields, c.scalars.begin() + long(kept * fields));
                ++kept;
            }
            c.points.resize(kept);
            indices[k].resize(kept);
            c.scalars.resize(kept * fields);
            held += kept;
        }
    };
    std::vector<InputPoint> batch(kBatchPoints);
    SC_TRY(forEachInput(options, [&](size_t, PointReader& reader) -> Status {
        CapturedInput& c = inputs->emplace_back();
        indices.emplace_back();
        c.description = reader.description();
        starts.push_back(options.chunkStarts && c.description.format == "laz");
        if (starts.back()) standFor += c.description.declaredPoints;
        c.description.declaredPoints = 0;  // a sample: the build's own read checks the header's count
        const size_t fields = c.description.scalars.size();
        for (uint64_t at = 0;;) {
            auto n = reader.read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) break;
            const std::span<const double> values = reader.scalarValues();
            for (size_t i = 0; i < *n; ++i, ++at) {
                if (at % (starts.back() ? startsStride : out.stride) != 0) continue;
                c.points.push_back(batch[i]);
                indices.back().push_back(at);
                c.scalars.insert(c.scalars.end(), values.begin() + long(i * fields), values.begin() + long((i + 1) * fields));
                if (++held > most) thin();
            }
        }
        c.skipped = reader.skipped();
        return {};
    }));
    uint64_t startsHeld = 0;
    for (size_t k = 0; k < inputs->size(); ++k) startsHeld += starts[k] ? (*inputs)[k].points.size() : 0;
    if (startsHeld > 0) out.stride = uint32_t(std::clamp<uint64_t>(standFor / startsHeld, out.stride, UINT32_MAX));
    out.inputs = std::move(inputs);
    return out;
}

Status forEachInput(const InputOptions& options, const std::function<Status(size_t index, PointReader& reader)>& visit) {
    size_t index = 0;
    if (options.captured) {
        for (const CapturedInput& input : *options.captured) {
            CapturedReader reader(input);
            SC_TRY(visit(index++, reader));
        }
        return {};
    }
    if (options.defaultScene)
        for (auto& r : openDefaultScene(options.scene)) SC_TRY(visit(index++, *r));
    if (!options.paths.empty()) {
        ReadAhead ahead(options);
        for (size_t i = 0; i < options.paths.size(); ++i) {
            auto r = ahead.next();
            if (!r) return r.status();
            SC_TRY(visit(index++, **r));
        }
    }
    if (index == 0) return Status::error("no inputs given");
    return {};
}

Result<InputStats> scanInputs(const InputOptions& options, const std::function<void(uint64_t)>& progress) {
    InputStats stats;
    std::vector<InputPoint> batch(kBatchPoints);
    SC_TRY(forEachInput(options, [&](size_t, PointReader& reader) -> Status {
        SourceStats s;
        s.description = reader.description();
        AttributeStats& a = stats.attributes;
        // This input's scalar fields among the set's (indices), by name.
        std::vector<size_t> fields;
        for (const ScalarField& f : s.description.scalars) {
            auto it = std::find_if(stats.scalars.begin(), stats.scalars.end(), [&](const ScalarStats& t) { return t.field.name == f.name; });
            fields.push_back(size_t(it - stats.scalars.begin()));
            if (it == stats.scalars.end()) stats.scalars.push_back({f});
        }
        while (true) {
            auto n = reader.read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) break;
            for (size_t i = 0; i < *n; ++i) {
                const InputPoint& p = batch[i];
                s.bounds.extend(p.position);
                for (int c = 0; c < 3; ++c) {
                    s.colorMax = std::max(s.colorMax, p.color[c]);
                    // 8-bit values scaled by 257 (v = c·257) or shifted by 8 (v = c·256).
                    uint16_t v = p.color[c];
                    if ((v >> 8) * 257 != v && (v & 0xFF) != 0) s.colors8Bit = false;
                    if (v & 0xFF) s.colorsTimes256 = false;
                }
                if (s.description.hasIntensity) a.intensityHistogram[p.intensity]++;
                if (s.description.hasClassification) a.classCounts[p.classification]++;
                if (s.description.hasReturns) a.returnsHistogram[p.returns]++;
                a.translucentPoints += pointAlpha(p.alpha, options.opacity) < 255;
                for (size_t f = 0; f < fields.size(); ++f) {
                    const double v = reader.scalarValues()[i * fields.size() + f];
                    if (std::isnan(v)) continue;
                    ScalarStats& t = stats.scalars[fields[f]];
                    t.min = std::min(t.min, v);
                    t.max = std::max(t.max, v);
                    t.finestBit = std::min(t.finestBit, finestBitOf(v));
                    t.points++;
                }
            }
            if (s.description.hasIntensity) a.intensityPoints += *n;
            if (s.description.hasClassification) a.classifiedPoints += *n;
            if (s.description.hasReturns) a.returnPoints += *n;
            s.points += *n;
            progress(*n);
        }
        s.skipped = reader.skipped();
        // LAS stores 16-bit colour, but many writers put 8-bit values in it.
        if (s.description.colorBits == 16 && s.colorMax <= 255) {
            s.colorScale = 257;
            s.colors8Bit = true;
        }
        if (s.description.declaredPoints && s.points + s.skipped != s.description.declaredPoints &&
            s.description.format != "mesh")
            return Status::error(s.description.path + ": header declares " + std::to_string(s.description.declaredPoints) +
                                 " points, the file holds " + std::to_string(s.points + s.skipped));
        stats.points += s.points;
        stats.skipped += s.skipped;
        stats.bounds.extend(s.bounds);
        if (s.description.hasColors) {
            stats.anyColors = true;
            stats.colorBits = std::max(stats.colorBits, s.colors8Bit ? 8 : 16);
        }
        stats.sources.push_back(std::move(s));
        return {};
    }));
    return stats;
}

InputStats mergeInputStats(std::vector<InputStats> parts, const std::vector<bool>& continues) {
    InputStats all;
    for (size_t p = 0; p < parts.size(); ++p) {
        InputStats& part = parts[p];
        auto source = part.sources.begin();
        if (p < continues.size() && continues[p] && source != part.sources.end() && !all.sources.empty()) {
            // One file read in two parts: one source, as one scan would find it.
            SourceStats& a = all.sources.back();
            const SourceStats& b = *source++;
            // scanInputs took a 16-bit channel whose values all fit 8 bits
            // for 8-bit values (colorScale 257, colors8Bit set); the values
            // under it were 8-bit codes only if they were all 0.
            auto codes8Bit = [](const SourceStats& s) { return s.colorScale == 257 ? s.colorMax == 0 : s.colors8Bit; };
            a.colors8Bit = codes8Bit(a) && codes8Bit(b);
            a.colorsTimes256 = a.colorsTimes256 && b.colorsTimes256;
            a.colorMax = std::max(a.colorMax, b.colorMax);
            a.colorScale = 1;
            if (a.description.colorBits == 16 && a.colorMax <= 255) {
                a.colorScale = 257;
                a.colors8Bit = true;
            }
            a.description.declaredPoints += b.description.declaredPoints;
            a.points += b.points;
            a.skipped += b.skipped;
            a.bounds.extend(b.bounds);
        }
        for (; source != part.sources.end(); ++source) all.sources.push_back(std::move(*source));
        all.points += part.points;
        all.skipped += part.skipped;
        all.bounds.extend(part.bounds);
        all.anyColors = all.anyColors || part.anyColors;
        all.largestMeshBytes = std::max(all.largestMeshBytes, part.largestMeshBytes);
        AttributeStats& a = all.attributes;
        const AttributeStats& b = part.attributes;
        a.intensityPoints += b.intensityPoints;
        a.classifiedPoints += b.classifiedPoints;
        a.returnPoints += b.returnPoints;
        a.translucentPoints += b.translucentPoints;
        for (size_t v = 0; v < a.intensityHistogram.size(); ++v) a.intensityHistogram[v] += b.intensityHistogram[v];
        for (size_t v = 0; v < a.classCounts.size(); ++v) a.classCounts[v] += b.classCounts[v];
        for (size_t v = 0; v < a.returnsHistogram.size(); ++v) a.returnsHistogram[v] += b.returnsHistogram[v];
        // Fields in the order the inputs first offer them; the first one's kind and resolution hold.
        for (const ScalarStats& f : part.scalars) {
            auto it = std::find_if(all.scalars.begin(), all.scalars.end(), [&](const ScalarStats& t) { return t.field.name == f.field.name; });
            if (it == all.scalars.end()) {
                all.scalars.push_back(f);
                continue;
            }
            it->points += f.points;
            it->min = std::min(it->min, f.min);
            it->max = std::max(it->max, f.max);
            it->finestBit = std::min(it->finestBit, f.finestBit);
        }
    }
    for (const SourceStats& s : all.sources)  // after the joins: a cut file's colours are judged whole
        if (s.description.hasColors) all.colorBits = std::max(all.colorBits, s.colors8Bit ? 8 : 16);
    return all;
}

Status forEachBatch(const InputOptions& options, const InputStats& stats, const Vec3d& origin,
                    std::span<const uint16_t> sourceIds, std::span<const ScalarQuantization> stored,
                    const BatchConsumer& consume, std::span<const uint32_t> inputOf) {
    std::vector<InputPoint> batch(kBatchPoints);
    std::vector<Surfel> surfels(kBatchPoints);
    std::vector<uint32_t> scalars;
    return forEachInput(options, [&](size_t r, PointReader& reader) -> Status {
        if (r >= stats.sources.size() || r >= sourceIds.size())
            return Status::error("the inputs changed while being read: more inputs than the first pass saw");
        const SourceStats& src = stats.sources[r];
        // A file of several scans has a rule per scan from sourceIds[r] on (BuildContext::chooseOrientationRules).
        const size_t scans = std::max<size_t>(1, src.description.scanOrigins.size());
        // Where each stored field is among this input's, or -1.
        const std::vector<ScalarField>& own = reader.description().scalars;
        std::vector<int> from(stored.size(), -1);
        for (size_t f = 0; f < stored.size(); ++f)
            for (size_t j = 0; j < own.size() && !stored[f].provenance; ++j)
                if (own[j].name == stored[f].name || (stored[f].lowPart && own[j].name + kLowPartSuffix == stored[f].name)) from[f] = int(j);
        while (true) {
            auto n = reader.read(batch.data(), batch.size());
            if (!n) return n.status();
            if (*n == 0) break;
            for (size_t i = 0; i < *n; ++i) {
                Surfel& s = surfels[i];
                s = Surfel{};
                s.position = batch[i].position - origin;
                s.normal = batch[i].normal;
                if (batch[i].scan >= scans) return Status::error(src.description.path + ": a point of scan " + std::to_string(batch[i].scan) +
                                                                 ", which the first pass did not see (the input changed while being read)");
                s.source = uint16_t(sourceIds[r] + batch[i].scan);
                for (int c = 0; c < 3; ++c)
                    s.color[c] = src.description.hasColors ? scaled(batch[i].color[c], src.colorScale) : 65535;
                s.intensity = batch[i].intensity;
                s.classification = batch[i].classification;
                s.returns = batch[i].returns;
                s.alpha = pointAlpha(batch[i].alpha, options.opacity);
            }
            scalars.assign(*n * stored.size(), 0);
            for (size_t f = 0; f < stored.size(); ++f) {
                if (stored[f].provenance && r < inputOf.size())
                    for (size_t i = 0; i < *n; ++i) scalars[i * stored.size() + f] = inputOf[r];
                if (from[f] < 0) continue;
                const ScalarQuantization& q = stored[f];
                const double maxQ = std::ldexp(1.0, q.bits) - 1;
                // A wide field's parts: the whole code N of its finest step, split.
                const ScalarQuantization* wide = q.lowBits ? &q : q.lowPart && f > 0 ? &stored[f - 1] : nullptr;
                const double fine = wide ? std::ldexp(wide->step, -wide->lowBits) : 0;
                const double maxN = wide ? std::ldexp(1.0, wide->bits + wide->lowBits) - 1 : 0;
                for (size_t i = 0; i < *n; ++i) {
                    const double v = reader.scalarValues()[i * own.size() + size_t(from[f])];
                    if (std::isnan(v)) continue;
                    uint32_t& out = scalars[i * stored.size() + f];
                    if (wide) {
                        const uint64_t all = uint64_t(std::clamp(std::round((v - wide->offset) / fine), 0.0, maxN));
                        out = uint32_t(q.lowPart ? all & ((uint64_t(1) << wide->lowBits) - 1) : all >> wide->lowBits);
                    } else {
                        out = uint32_t(std::clamp(std::round((v - q.offset) / q.step), 0.0, maxQ));
                    }
                }
            }
            SC_TRY(consume(std::span<Surfel>(surfels.data(), *n), scalars));
        }
        return {};
    });
}

}  // namespace surfcast
