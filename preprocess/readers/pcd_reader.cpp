#include "pcd_reader.h"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <sstream>
#include <vector>

#include "byte_io.h"
#include "byte_stream.h"
#include "lzf_stream.h"

namespace surfcast {

namespace {

constexpr uint64_t kMaxPcdHeaderBytes = 64 * 1024;
constexpr size_t kPcdBatchPoints = 4096;

enum class Role { Ignore, X, Y, Z, Rgb, Rgba, NX, NY, NZ, Intensity, Classification, Scalar };

struct Field {
    std::string name;
    char type = 'F';   // F float, U unsigned, I signed
    size_t size = 4;   // bytes per element
    size_t count = 1;  // elements
    Role role = Role::Ignore;
    size_t offset = 0; // byte offset within a point record (binary)
    size_t scalar = 0; // Role::Scalar: index in InputDescription::scalars
};

enum class DataKind { Ascii, Binary, Compressed };

struct PcdHeader {
    std::vector<Field> fields;
    uint64_t width = 0, height = 1, points = 0;
    double viewpoint[7] = {0, 0, 0, 1, 0, 0, 0};
    bool viewpointGiven = false;
    DataKind data = DataKind::Ascii;
    size_t recordSize = 0;
    uint64_t dataOffset = 0;
};

Role roleOf(const std::string& n) {
    if (n == "x") return Role::X;
    if (n == "y") return Role::Y;
    if (n == "z") return Role::Z;
    if (n == "rgb") return Role::Rgb;
    if (n == "rgba") return Role::Rgba;
    if (n == "normal_x") return Role::NX;
    if (n == "normal_y") return Role::NY;
    if (n == "normal_z") return Role::NZ;
    if (n == "intensity") return Role::Intensity;
    if (n == "label" || n == "classification") return Role::Classification;
    return Role::Ignore;
}

// One element of a field from raw little-endian bytes, as a double (or the
// raw 32 bits for packed colours).
double elementValue(const Field& f, const uint8_t* p) {
    switch (f.type) {
        case 'F': return f.size == 8 ? le::get<double>(p) : double(le::get<float>(p));
        case 'U':
            return f.size == 1 ? p[0] : f.size == 2 ? le::get<uint16_t>(p) : f.size == 4 ? le::get<uint32_t>(p) : double(le::get<uint64_t>(p));
        default:
            return f.size == 1 ? int8_t(p[0]) : f.size == 2 ? le::get<int16_t>(p) : f.size == 4 ? le::get<int32_t>(p) : double(le::get<int64_t>(p));
    }
}

uint32_t packedColor(const Field& f, const uint8_t* p) { return f.size == 4 ? le::get<uint32_t>(p) : 0; }

Result<PcdHeader> parseHeader(ByteStream& in) {
    PcdHeader h;
    std::string line;
    std::vector<std::string> sizes, types, counts;
    bool haveData = false;
    while (!haveData) {
        if (!in.readLine(&line)) return Status::error(in.path() + ": header has no DATA line");
        if (in.offset() > kMaxPcdHeaderBytes) return Status::error(in.path() + ": header longer than 64 KiB");
        uint64_t lineNo = in.line() - 1;
        auto fail = [&](const std::string& why) { return Status::error(in.path() + ": line " + std::to_string(lineNo) + ": " + why); };
        if (line.empty() || line[0] == '#') continue;
        std::istringstream words(line);
        std::string key, w;
        words >> key;
        std::vector<std::string> values;
        while (words >> w) values.push_back(w);
        if (key == "VERSION") continue;
        if (key == "FIELDS" || key == "COLUMNS") {
            for (const auto& v : values) h.fields.push_back({v, 'F', 4, 1, roleOf(v), 0});
        } else if (key == "SIZE") sizes = values;
        else if (key == "TYPE") types = values;
        else if (key == "COUNT") counts = values;
        else if (key == "WIDTH" || key == "HEIGHT" || key == "POINTS") {
            char* end = nullptr;
            long long v = values.size() == 1 ? std::strtoll(values[0].c_str(), &end, 10) : -1;
            if (v < 0 || (end && *end)) return fail(key + " is not a count");
            (key == "WIDTH" ? h.width : key == "HEIGHT" ? h.height : h.points) = uint64_t(v);
        } else if (key == "VIEWPOINT") {
            if (values.size() != 7) return fail("VIEWPOINT needs 7 numbers");
            for (int i = 0; i < 7; ++i) h.viewpoint[i] = std::strtod(values[size_t(i)].c_str(), nullptr);
            h.viewpointGiven = true;
        } else if (key == "DATA") {
            if (values.size() != 1) return fail("DATA needs one word");
            if (values[0] == "ascii") h.data = DataKind::Ascii;
            else if (values[0] == "binary") h.data = DataKind::Binary;
            else if (values[0] == "binary_compressed") h.data = DataKind::Compressed;
            else return fail("unknown DATA kind '" + values[0] + "'");
            haveData = true;
        } else {
            return fail("unknown header keyword '" + key + "'");
        }
    }
    const std::string where = in.path() + ": header: ";
    if (h.fields.empty()) return Status::error(where + "no FIELDS");
    if (sizes.size() != h.fields.size() || types.size() != h.fields.size())
        return Status::error(where + "SIZE and TYPE need one entry per field");
    if (!counts.empty() && counts.size() != h.fields.size()) return Status::error(where + "COUNT needs one entry per field");
    for (size_t i = 0; i < h.fields.size(); ++i) {
        Field& f = h.fields[i];
        f.size = size_t(std::atoi(sizes[i].c_str()));
        f.type = types[i].size() == 1 ? types[i][0] : '?';
        f.count = counts.empty() ? 1 : size_t(std::atoi(counts[i].c_str()));
        bool sizeOk = f.type == 'F' ? (f.size == 4 || f.size == 8)
                      : (f.type == 'U' || f.type == 'I') ? (f.size == 1 || f.size == 2 || f.size == 4 || f.size == 8)
                                                          : false;
        if (!sizeOk) return Status::error(where + "field '" + f.name + "' has unknown type " + types[i] + " of size " + sizes[i]);
        if (f.count < 1 || f.count > 1 << 16) return Status::error(where + "field '" + f.name + "' has a bad COUNT");
        if (f.role != Role::Ignore && f.count != 1) f.role = Role::Ignore;
        f.offset = h.recordSize;
        h.recordSize += f.size * f.count;
    }
    auto has = [&](Role r) { return std::any_of(h.fields.begin(), h.fields.end(), [&](const Field& f) { return f.role == r; }); };
    if (!has(Role::X) || !has(Role::Y) || !has(Role::Z)) return Status::error(where + "no x, y and z fields");
    if (h.points == 0) h.points = h.width * h.height;
    if (h.width * h.height != h.points)
        return Status::error(where + "POINTS " + std::to_string(h.points) + " is not WIDTH x HEIGHT (" + std::to_string(h.width) +
                             " x " + std::to_string(h.height) + ")");
    h.dataOffset = in.offset();
    return h;
}

class PcdReader final : public PointReader {
public:
    PcdReader(std::string path, PcdHeader h, const ScalarSelection& scalars, bool readAlpha, const HttpOptions& http)
        : path_(std::move(path)), http_(http), h_(std::move(h)), readAlpha_(readAlpha) {
        // Single-element fields no fixed attribute takes are scalar fields
        // ("_" marks padding in PCL's files).
        for (Field& f : h_.fields)
            if (f.role == Role::Ignore && f.count == 1 && f.name != "_" && scalars.wants(f.name)) {
                f.role = Role::Scalar;
                f.scalar = desc_.scalars.size();
                desc_.scalars.push_back({f.name, false, f.type == 'F' ? 0.0 : 1.0});
            }
        pending_.resize(desc_.scalars.size());
        desc_.path = path_;
        desc_.format = "pcd";
        desc_.declaredPoints = h_.points;
        for (const Field& f : h_.fields) {
            if (f.role == Role::Rgb || f.role == Role::Rgba) desc_.hasColors = true;
            if (f.role == Role::NX) desc_.hasNormals = true;
            if (f.role == Role::Intensity) desc_.hasIntensity = true;
            if (f.role == Role::Classification) desc_.hasClassification = true;
        }
        desc_.colorBits = 8;
        desc_.float32Coordinates = std::any_of(h_.fields.begin(), h_.fields.end(),
                                               [](const Field& f) { return f.role == Role::X && f.type == 'F' && f.size == 4; });
        // PCL writes VIEWPOINT 0 0 0 1 0 0 0 by default: the sensor at the origin
        // of the cloud's frame, right for depth cameras, meaningless for
        // georeferenced data (see the builder's orientation rules).
        desc_.scanOrigins = {Vec3d{h_.viewpoint[0], h_.viewpoint[1], h_.viewpoint[2]}};
        desc_.scanOriginIsDefault = h_.viewpoint[0] == 0 && h_.viewpoint[1] == 0 && h_.viewpoint[2] == 0;
    }

    Status start() {
        auto in = ByteStream::open(path_, http_);
        if (!in) return in.status();
        uint64_t dataBytes = in->fileSize() - std::min(in->fileSize(), h_.dataOffset);
        if (h_.data == DataKind::Binary) {
            uint64_t need = h_.points * h_.recordSize;
            if (dataBytes < need)
                return Status::error(path_ + ": DATA section is short: " + std::to_string(dataBytes) + " bytes from byte " +
                                     std::to_string(h_.dataOffset) + ", " + std::to_string(h_.points) + " points of " +
                                     std::to_string(h_.recordSize) + " bytes need " + std::to_string(need));
        }
        if (!in->seek(h_.dataOffset)) return Status::error(path_ + ": cannot seek to the data");
        if (h_.data != DataKind::Compressed) {
            in_ = std::make_unique<ByteStream>(std::move(*in));
            return {};
        }
        uint8_t sizes[8];
        if (!in->readBytes(sizes, 8)) return Status::error(path_ + ": byte " + std::to_string(h_.dataOffset) + ": compressed DATA has no size words");
        uint64_t compressed = le::get<uint32_t>(sizes), uncompressed = le::get<uint32_t>(sizes + 4);
        if (uncompressed != h_.points * h_.recordSize)
            return Status::error(path_ + ": byte " + std::to_string(h_.dataOffset + 4) + ": uncompressed size " +
                                 std::to_string(uncompressed) + ", the header needs " + std::to_string(h_.points * h_.recordSize));
        if (compressed > dataBytes - 8)
            return Status::error(path_ + ": DATA section is short: " + std::to_string(compressed) + " compressed bytes declared, " +
                                 std::to_string(dataBytes - 8) + " present");
        // binary_compressed stores fields one after another (all x, then all y,
        // ...): one LZF stream per used field, each skipping to its column.
        uint64_t column = 0;
        for (const Field& f : h_.fields) {
            uint64_t columnBytes = f.size * f.count * h_.points;
            if (f.role != Role::Ignore) {
                auto s = ByteStream::open(path_, http_);
                if (!s) return s.status();
                s->seek(h_.dataOffset + 8);
                auto lzf = std::make_unique<LzfStream>(std::move(*s), compressed, uncompressed);
                SC_TRY(lzf->skip(column));
                columns_.push_back({&f, std::move(lzf)});
            }
            column += columnBytes;
        }
        return {};
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        scalarValues_.clear();
        while (n < max && index_ < h_.points) {
            // Each record gives at most one point: a batch never overfills `out`.
            size_t batch = size_t(std::min<uint64_t>({uint64_t(kPcdBatchPoints), h_.points - index_, uint64_t(max - n)}));
            if (h_.data == DataKind::Compressed) {
                // Gather each used field's column for the batch.
                for (auto& c : columns_) {
                    c.values.resize(batch * c.field->size);
                    SC_TRY(c.stream->read(c.values.data(), c.values.size()));
                }
                for (size_t i = 0; i < batch; ++i) {
                    InputPoint p;
                    for (auto& c : columns_) apply(*c.field, c.values.data() + i * c.field->size, p);
                    emit(p, out, n);
                }
            } else if (h_.data == DataKind::Binary) {
                buffer_.resize(batch * h_.recordSize);
                if (!in_->readBytes(buffer_.data(), buffer_.size()))
                    return Status::error(in_->at() + ": DATA section ends at point " + std::to_string(index_));
                for (size_t i = 0; i < batch; ++i) {
                    InputPoint p;
                    for (const Field& f : h_.fields)
                        if (f.role != Role::Ignore) apply(f, buffer_.data() + i * h_.recordSize + f.offset, p);
                    emit(p, out, n);
                }
            } else {
                batch = 1;
                InputPoint p;
                SC_TRY(readAscii(p));
                emit(p, out, n);
            }
            index_ += batch;
        }
        return n;
    }

private:
    struct Column {
        const Field* field;
        std::unique_ptr<LzfStream> stream;
        std::vector<uint8_t> values{};  // ({}: brace lists may end before it, no -Wmissing-field-initializers)
    };

    // Points go to `out` unless a coordinate is NaN (invalid pixels of
    // organized clouds) or infinite.
    void emit(InputPoint& p, InputPoint* out, size_t& n) {
        p.normal = normalizeOrZero(normal_);
        normal_ = {};
        if (finite(p.position)) {
            out[n++] = p;
            scalarValues_.insert(scalarValues_.end(), pending_.begin(), pending_.end());
        } else {
            ++skipped_;
        }
    }

    void apply(const Field& f, const uint8_t* p, InputPoint& q) {
        switch (f.role) {
            case Role::X: q.position.x = elementValue(f, p); break;
            case Role::Y: q.position.y = elementValue(f, p); break;
            case Role::Z: q.position.z = elementValue(f, p); break;
            case Role::NX: normal_.x = float(elementValue(f, p)); break;
            case Role::NY: normal_.y = float(elementValue(f, p)); break;
            case Role::NZ: normal_.z = float(elementValue(f, p)); break;
            case Role::Intensity: {
                double v = elementValue(f, p);
                q.intensity = saturate16(f.type == 'F' && v <= 1.0 ? v * 65535 : v);
                break;
            }
            case Role::Classification: q.classification = classOf(elementValue(f, p)); break;
            case Role::Scalar: pending_[f.scalar] = elementValue(f, p); break;
            case Role::Rgb: case Role::Rgba: {
                uint32_t c = packedColor(f, p);  // 0x00RRGGBB in the float's or uint's bits
                q.color[0] = uint16_t(((c >> 16) & 0xFF) * 257);
                q.color[1] = uint16_t(((c >> 8) & 0xFF) * 257);
                q.color[2] = uint16_t((c & 0xFF) * 257);
                if (readAlpha_) q.alpha = uint8_t(c >> 24);
                break;
            }
            case Role::Ignore: break;
        }
    }

    Status readAscii(InputPoint& p) {
        for (const Field& f : h_.fields) {
            for (size_t k = 0; k < f.count; ++k) {
                std::string_view tok;
                if (!in_->readToken(&tok))
                    return Status::error(in_->atLine() + ": DATA section ends at point " + std::to_string(index_) + " of " +
                                         std::to_string(h_.points));
                if (f.role == Role::Ignore) continue;
                std::string s(tok);
                char* end = nullptr;
                double v = std::strtod(s.c_str(), &end);
                if (end != s.c_str() + s.size())
                    return Status::error(path_ + ": line " + std::to_string(in_->line()) + ": '" + s + "' is not a number");
                uint8_t bytes[8];
                if (f.role == Role::Rgb && f.type == 'F') {
                    // ascii PCD prints the packed float; its bits are the colour.
                    float fv = float(v);
                    std::memcpy(bytes, &fv, 4);
                } else if (f.role == Role::Rgb || f.role == Role::Rgba) {
                    uint32_t u = uint32_t(v);
                    std::memcpy(bytes, &u, 4);
                } else {
                    double d = v;
                    Field asDouble = f;
                    asDouble.type = 'F';
                    asDouble.size = 8;
                    std::memcpy(bytes, &d, 8);
                    apply(asDouble, bytes, p);
                    continue;
                }
                apply(f, bytes, p);
            }
        }
        return {};
    }

    std::string path_;
    HttpOptions http_;
    PcdHeader h_;
    bool readAlpha_ = false;
    InputDescription desc_;
    std::unique_ptr<ByteStream> in_;
    std::vector<Column> columns_;
    std::vector<uint8_t> buffer_;
    uint64_t index_ = 0;
    Vec3f normal_;
    std::vector<double> pending_;  // the scalar fields' values of the point being read
};

}  // namespace

Result<std::unique_ptr<PointReader>> openPcdReader(const std::string& path, const ScalarSelection& scalars, bool readAlpha,
                                                   const HttpOptions& http) {
    auto in = ByteStream::open(path, http);
    if (!in) return in.status();
    auto h = parseHeader(*in);
    if (!h) return h.status();
    auto reader = std::make_unique<PcdReader>(path, std::move(*h), scalars, readAlpha, http);
    SC_TRY(reader->start());
    return std::unique_ptr<PointReader>(std::move(reader));
}

}  // namespace surfcast
