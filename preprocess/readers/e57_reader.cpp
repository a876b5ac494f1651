#include "e57_reader.h"

#include <cmath>
#include <cstdio>

#include "input_file.h"
#include "surfcast_e57.h"

namespace surfcast {

namespace {

constexpr size_t kE57BatchPoints = 1 << 14;
// Scans per file, at most: InputPoint::scan is 16-bit, and each scan is an
// orientation rule (Surfel::source).
constexpr uint64_t kMaxScans = 1 << 16;

uint16_t unit16(float v) { return v > 0 ? (v < 1 ? uint16_t(std::lround(double(v) * 65535)) : uint16_t(65535)) : 0; }

class E57PointReader final : public PointReader {
public:
    E57PointReader(ScE57Reader* reader, std::unique_ptr<FfiInput> input) : reader_(reader), input_(std::move(input)) {}
    ~E57PointReader() override { sc_e57_close(reader_); }

    Status describe(const ScalarSelection& scalars) {
        const std::string& path = input_->file->path();
        desc_.path = path;
        desc_.format = "e57";
        desc_.colorBits = 16;  // normalized by the limits; 8-bit limits give values c * 257, stored as 8 bits
        const uint64_t scans = sc_e57_scan_count(reader_);
        if (scans == 0) return Status::error(path + ": no scans (the file holds no points)");
        if (scans > kMaxScans)
            return Status::error(path + ": " + std::to_string(scans) + " scans, more than " + std::to_string(kMaxScans));
        bool rowColumn = false;
        for (uint64_t k = 0; k < scans; ++k) {
            ScE57Scan s{};
            char name[256] = {};
            if (sc_e57_scan(reader_, k, &s, name, sizeof name) != 0) return Status::error(path + ": scan " + std::to_string(k) + " is missing");
            if (desc_.declaredPoints + s.points < desc_.declaredPoints) return Status::error(path + ": more than 2^64 points declared");
            desc_.declaredPoints += s.points;
            desc_.hasColors = desc_.hasColors || s.color;
            desc_.hasIntensity = desc_.hasIntensity || s.intensity;
            rowColumn = rowColumn || s.row_column;
            intensityNormalized_.push_back(s.intensity_normalized != 0);
            // A scan's own frame has its scanner at the origin: the pose says
            // where that is. Cartesian points without a pose are in the
            // file's frame already, where the scanner may be anywhere.
            if (s.has_pose || s.spherical) desc_.scanOrigins.push_back(Vec3d{s.origin[0], s.origin[1], s.origin[2]});
            else desc_.scanOrigins.push_back(std::nullopt);
            // Cartesian points whose pose leaves the scanner at the file's
            // origin: many writers give georeferenced data an identity pose.
            // Such an origin counts only near the data (a default, as PCD's).
            if (!s.spherical && s.has_pose && s.origin[0] == 0 && s.origin[1] == 0 && s.origin[2] == 0) desc_.scanOriginIsDefault = true;
        }
        if (rowColumn)
            for (const char* field : {"row", "column"})
                if (scalars.wants(field)) {
                    desc_.scalars.push_back({field, true, 1.0});
                    rows_.push_back(field[0] == 'r');
                }
        if (const uint64_t images = sc_e57_image_count(reader_))
            warnOnce(path + ": " + std::to_string(images) + " image" + (images == 1 ? "" : "s") + " in the file, not read (points only)");
        return {};
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        scalarValues_.clear();
        while (n < max) {
            batch_.resize(std::min(kE57BatchPoints, max - n));
            char err[512] = {};
            const int64_t got = sc_e57_read(reader_, batch_.data(), batch_.size(), err, sizeof err);
            if (got < 0) return Status::error(input_->file->path() + ": " + input_->explain(err));
            if (got == 0) break;
            for (int64_t i = 0; i < got; ++i) {
                const ScE57Point& e = batch_[size_t(i)];
                InputPoint p;
                p.position = Vec3d{e.position[0], e.position[1], e.position[2]};
                if (!e.valid || !finite(p.position)) {
                    ++skipped_;
                    continue;
                }
                p.scan = uint16_t(e.scan);
                // A scan without colour, or a point whose colour is invalid, is white.
                for (int c = 0; c < 3; ++c) p.color[c] = std::isnan(e.color[c]) ? 65535 : unit16(e.color[c]);
                // Normalized by the scan's limits to the full 16 bits; a scan
                // without limits keeps its raw values (rounded, clamped to 16 bits).
                if (!std::isnan(e.intensity))
                    p.intensity = e.scan < intensityNormalized_.size() && intensityNormalized_[e.scan] ? unit16(e.intensity) : saturate16(e.intensity);
                out[n++] = p;
                for (const bool row : rows_) {
                    const int64_t v = row ? e.row : e.column;
                    scalarValues_.push_back(v < 0 ? NAN : double(v));
                }
            }
        }
        return n;
    }

private:
    ScE57Reader* reader_;
    std::unique_ptr<FfiInput> input_;
    InputDescription desc_;
    std::vector<bool> rows_;  // per scalar field: the row index (else the column)
    std::vector<bool> intensityNormalized_;  // per scan
    std::vector<ScE57Point> batch_;
};

}  // namespace

Result<std::unique_ptr<PointReader>> openE57Reader(const std::string& path, const ScalarSelection& scalars, const HttpOptions& http) {
    auto file = InputFile::open(path, http);
    if (!file) return file.status();
    auto input = std::make_unique<FfiInput>();
    input->file = std::move(*file);
    char err[512] = {};
    ScE57Reader* reader = sc_e57_open(input->file->size(), &FfiInput::readAt, input.get(), err, sizeof err);
    if (!reader) return Status::error(path + ": " + input->explain(err));
    auto r = std::make_unique<E57PointReader>(reader, std::move(input));
    SC_TRY(r->describe(scalars));
    return std::unique_ptr<PointReader>(std::move(r));
}

}  // namespace surfcast
