// Field offsets follow the LAS 1.4 R15 specification, tables 3 (header), 4
// (variable-length record header) and 7-17 (point data record formats).
#include "las_reader.h"

#include <surfcast_laz.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <vector>

#include "byte_io.h"
#include "byte_stream.h"
#include "las_format.h"

namespace surfcast {

namespace {

constexpr size_t kLegacyHeaderSize = 227;     // LAS 1.0-1.2 public header block
constexpr size_t kLas14HeaderSize = 375;      // adds 64-bit counts at byte 247
constexpr size_t kVlrHeaderSize = 54;
constexpr uint8_t kCompressedBits = 0xC0;     // LAZ marks the format id with bit 7 (and 6)
constexpr size_t kBatchRecords = 4096;        // records per read of uncompressed data
constexpr size_t kLazBatchFloor = 50000;      // LAZ: at least a typical chunk per read
constexpr size_t kLazChunksPerThread = 4;     // per read: keeps every thread busy to the end
constexpr size_t kLazBatchBytes = 32 << 20;   // ...within this much decompressed data
// A read never asks for more decompressed bytes than this, whatever chunk size
// the header claims (a 2 KB LAZ claimed 50 M-point chunks: a 9 GB buffer,
// fuzz_read_laz); larger chunks are decoded across several reads.
constexpr size_t kLazMaxBatchBytes = 256 << 20;
// lasCuts lists at most about this many cuts of a LAS file.
constexpr uint64_t kMaxCuts = 1 << 16;
constexpr char kLaszipUser[] = "laszip encoded";
constexpr uint16_t kLaszipRecord = 22204;

// A per-point scalar field's place in the record and its decoding:
// value = raw · scale + offset, NaN where raw equals the no-data value.
// Bit fields (flags packed in a byte) take `bits` bits from bit `shift` of a U8.
struct ScalarLayout {
    enum Type { U8, I8, U16, I16, U32, I32, U64, I64, F32, F64 } type = U8;
    size_t offset = 0;
    double scale = 1, add = 0;
    bool hasNoData = false;
    double noData = 0;
    int shift = 0, bits = 0;  // bits 0: the whole value
};


double rawValue(const uint8_t* p, ScalarLayout::Type t) {
    switch (t) {
    case ScalarLayout::U8: return p[0];
    case ScalarLayout::I8: return int8_t(p[0]);
    case ScalarLayout::U16: return le::get<uint16_t>(p);
    case ScalarLayout::I16: return le::get<int16_t>(p);
    case ScalarLayout::U32: return le::get<uint32_t>(p);
    case ScalarLayout::I32: return le::get<int32_t>(p);
    case ScalarLayout::U64: return double(le::get<uint64_t>(p));
    case ScalarLayout::I64: return double(le::get<int64_t>(p));
    case ScalarLayout::F32: return le::get<float>(p);
    case ScalarLayout::F64: return le::get<double>(p);
    }
    return 0;
}

// Where point records come from: the file itself, or the LAZ decompressor.
class RecordSource {
public:
    virtual ~RecordSource() = default;
    // Exactly `records` records into out, or an error naming the place.
    virtual Status read(uint8_t* out, size_t records, uint64_t firstIndex) = 0;
    virtual size_t preferredBatch() const = 0;
};

class RawRecords final : public RecordSource {
public:
    RawRecords(ByteStream in, size_t recordLength, uint64_t count) : in_(std::move(in)), length_(recordLength), count_(count) {}
    Status read(uint8_t* out, size_t records, uint64_t firstIndex) override {
        if (!in_.readBytes(out, records * length_))
            return Status::error(in_.at() + ": " + (in_.failed() ? "cannot read" : "file ends at") + " point " +
                                 std::to_string(firstIndex) + " of the " + std::to_string(count_) + " the header declares");
        return {};
    }
    size_t preferredBatch() const override { return kBatchRecords; }

private:
    ByteStream in_;
    size_t length_;
    uint64_t count_;
};

class LazRecords final : public RecordSource {
public:
    LazRecords(ScLazReader* reader, std::unique_ptr<FfiInput> input, int threads, size_t recordLength)
        : reader_(reader), input_(std::move(input)), threads_(threads), recordLength_(recordLength) {}
    ~LazRecords() override { sc_laz_close(reader_); }
    Status read(uint8_t* out, size_t records, uint64_t firstIndex) override {
        char err[512] = {};
        if (sc_laz_read(reader_, out, records, err, sizeof err) != 0)
            return Status::error(input_->file->path() + ": LAZ data, points " + std::to_string(firstIndex) + "-" +
                                 std::to_string(firstIndex + records - 1) + ": " + input_->explain(err));
        return {};
    }
    uint64_t chunkCount() const { return sc_laz_chunk_count(reader_); }
    RecordCut chunkStart(uint64_t k) const {
        RecordCut c;
        sc_laz_chunk_start(reader_, k, &c.record, &c.byte);
        return c;
    }
    // Enough chunks per call for every thread to decompress several.
    size_t preferredBatch() const override {
        size_t chunk = std::max<size_t>(sc_laz_chunk_size(reader_), kLazBatchFloor);
        size_t want = chunk * size_t(std::max(threads_, 1)) * kLazChunksPerThread;
        return std::max<size_t>(1, std::min(std::max(chunk, std::min(want, kLazBatchBytes / recordLength_)),
                                            kLazMaxBatchBytes / recordLength_));
    }

private:
    ScLazReader* reader_;
    std::unique_ptr<FfiInput> input_;  // read by reader_: outlives it
    int threads_;
    size_t recordLength_;
};

// The first record of each of a LAZ file's chunks, as it lies in the file
// (LASzip writes a chunk's first point raw, then codes the rest).
class ChunkStarts final : public RecordSource {
public:
    ChunkStarts(ByteStream in, size_t recordLength, std::vector<RecordCut> starts)
        : in_(std::move(in)), length_(recordLength), starts_(std::move(starts)) {}
    Status read(uint8_t* out, size_t records, uint64_t firstIndex) override {
        for (size_t i = 0; i < records; ++i) {
            const RecordCut& c = starts_.at(firstIndex + i);
            if (!in_.seek(c.byte) || !in_.readBytes(out + i * length_, length_))
                return Status::error(in_.at() + ": cannot read the first point of chunk " + std::to_string(firstIndex + i) + " (record " +
                                     std::to_string(c.record) + ")");
        }
        return {};
    }
    size_t preferredBatch() const override { return kBatchRecords; }

private:
    ByteStream in_;
    size_t length_;
    std::vector<RecordCut> starts_;
};

class LasReader final : public PointReader {
public:
    // Reads records [begin, end) of `source`, which starts at `begin`.
    LasReader(std::unique_ptr<RecordSource> source, InputDescription desc, uint64_t begin, uint64_t end, size_t recordLength,
              int format, const double scale[3], const double offset[3], std::vector<ScalarLayout> scalars)
        : source_(std::move(source)), desc_(std::move(desc)), count_(end), recordLength_(recordLength),
          rgbOffset_(las::kFormats[format].rgb), extended_(format >= 6), scalars_(std::move(scalars)), index_(begin) {
        for (int i = 0; i < 3; ++i) { scale_[i] = scale[i]; offset_[i] = offset[i]; }
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        scalarValues_.resize(max * scalars_.size());
        while (n < max) {
            if (next_ == buffered_) {
                if (index_ == count_) break;
                size_t batch = size_t(std::min<uint64_t>(count_ - index_, source_->preferredBatch()));
                buffer_.resize(batch * recordLength_);
                SC_TRY(source_->read(buffer_.data(), batch, index_));
                index_ += batch;
                buffered_ = batch;
                next_ = 0;
            }
            const uint8_t* r = buffer_.data() + next_++ * recordLength_;
            InputPoint& p = out[n];
            p = InputPoint{};
            for (int a = 0; a < 3; ++a) p.position[a] = le::get<int32_t>(r + 4 * a) * scale_[a] + offset_[a];
            p.intensity = le::get<uint16_t>(r + 12);
            // Table 7 (formats 0-5): byte 14 holds the return number in bits 0-2
            // and the number of returns in bits 3-5, byte 15 the class in bits
            // 0-4 (5-7 are flags). Table 13 (formats 6-10): byte 14 holds them
            // in bits 0-3 and 4-7, byte 16 the whole class.
            if (extended_) {
                p.returns = r[14];
                p.classification = r[16];
            } else {
                p.returns = uint8_t((r[14] & 7) | (r[14] >> 3 & 7) << 4);
                p.classification = r[15] & 31;
            }
            if (rgbOffset_)
                for (int c = 0; c < 3; ++c) p.color[c] = le::get<uint16_t>(r + rgbOffset_ + 2 * c);
            if (!finite(p.position)) {
                ++skipped_;
                continue;
            }
            double* values = scalarValues_.data() + n * scalars_.size();
            for (const ScalarLayout& f : scalars_) {
                const double raw = f.bits ? double(r[f.offset] >> f.shift & ((1 << f.bits) - 1)) : rawValue(r + f.offset, f.type);
                *values++ = f.hasNoData && raw == f.noData ? NAN : raw * f.scale + f.add;
            }
            ++n;
        }
        scalarValues_.resize(n * scalars_.size());
        return n;
    }

private:
    std::unique_ptr<RecordSource> source_;
    InputDescription desc_;
    uint64_t count_;  // the end of the records read
    size_t recordLength_, rgbOffset_;
    bool extended_;  // point formats 6-10
    double scale_[3], offset_[3];
    std::vector<ScalarLayout> scalars_;  // per desc_.scalars
    uint64_t index_;               // the next record to fetch from the source
    size_t buffered_ = 0, next_ = 0;
    std::vector<uint8_t> buffer_;
};

// The payloads of the VLRs the reader uses (each absent when the file has none).
struct Vlrs {
    std::optional<std::vector<uint8_t>> laszip, extraBytes;
    int extraBytesIndex = -1;
    // The coordinate system (LAS 1.4 R15, 2.5): OGC WKT, or GeoTIFF's keys
    // with their double and ASCII parameters.
    std::optional<std::vector<uint8_t>> wkt, geoKeys, geoDoubles, geoAscii;
};

Result<Vlrs> readVlrs(ByteStream& in, size_t headerSize, uint32_t vlrCount, uint32_t dataOffset) {
    Vlrs out;
    if (!in.seek(headerSize)) return Status::error(in.path() + ": cannot seek to the VLRs");
    for (uint32_t i = 0; i < vlrCount; ++i) {
        uint64_t at = in.offset();
        uint8_t h[kVlrHeaderSize];
        if (at + kVlrHeaderSize > dataOffset || !in.readBytes(h, kVlrHeaderSize))
            return Status::error(in.path() + ": byte " + std::to_string(at) + ": VLR " + std::to_string(i) + " runs past the point data");
        uint16_t record = le::get<uint16_t>(h + 18), length = le::get<uint16_t>(h + 20);
        auto user = [&](const char* name) { return std::strncmp(reinterpret_cast<const char*>(h + 2), name, 16) == 0; };
        const bool projection = user(las::kProjectionUser);
        std::optional<std::vector<uint8_t>>* keep = user(kLaszipUser) && record == kLaszipRecord       ? &out.laszip
                                                    : user(las::kSpecUser) && record == las::kExtraBytesRecord ? &out.extraBytes
                                                    : projection && record == las::kWktRecord             ? &out.wkt
                                                    : projection && record == las::kGeoKeysRecord         ? &out.geoKeys
                                                    : projection && record == las::kGeoDoublesRecord      ? &out.geoDoubles
                                                    : projection && record == las::kGeoAsciiRecord        ? &out.geoAscii
                                                                                                     : nullptr;
        if (keep) {
            std::vector<uint8_t> payload(length);  // at most 64 KiB: the field is 16-bit
            if (!in.readBytes(payload.data(), length))
                return Status::error(in.path() + ": byte " + std::to_string(at) + ": VLR " + std::to_string(i) + " truncated");
            *keep = std::move(payload);
            if (keep == &out.extraBytes) out.extraBytesIndex = int(i);
        } else if (!in.skip(length)) {
            return Status::error(in.path() + ": byte " + std::to_string(at) + ": VLR truncated");
        }
    }
    return out;
}

// The coordinate system the VLRs declare, as text (InputDescription::crs):
// the WKT, else every GeoTIFF key as "id=value" (a value stored in the double
// or ASCII parameters given from them; one they do not hold, as "?").
std::string crsOf(const Vlrs& v) {
    if (v.wkt) {
        std::string wkt(v.wkt->begin(), std::find(v.wkt->begin(), v.wkt->end(), 0));
        while (!wkt.empty() && std::isspace(static_cast<unsigned char>(wkt.back()))) wkt.pop_back();
        if (!wkt.empty()) return wkt;
    }
    if (!v.geoKeys || v.geoKeys->size() < 8) return {};
    const std::vector<uint8_t>& k = *v.geoKeys;
    const size_t keys = std::min<size_t>(le::get<uint16_t>(&k[6]), k.size() / 8 - 1);
    if (keys == 0) return {};
    std::string out = "GeoTIFF keys:";
    for (size_t i = 1; i <= keys; ++i) {
        const uint16_t id = le::get<uint16_t>(&k[8 * i]), where = le::get<uint16_t>(&k[8 * i + 2]);
        const uint16_t count = le::get<uint16_t>(&k[8 * i + 4]), value = le::get<uint16_t>(&k[8 * i + 6]);
        std::string text = "?";
        if (where == 0) {
            text = std::to_string(value);
        } else if (where == las::kGeoDoublesRecord && v.geoDoubles && (size_t(value) + count) * 8 <= v.geoDoubles->size()) {
            text.clear();
            for (size_t j = 0; j < count; ++j) {
                char number[32];
                std::snprintf(number, sizeof number, "%s%.17g", j ? "," : "", le::get<double>(&(*v.geoDoubles)[8 * (value + j)]));
                text += number;
            }
        } else if (where == las::kGeoAsciiRecord && v.geoAscii && size_t(value) + count <= v.geoAscii->size()) {
            text.assign(v.geoAscii->begin() + value, v.geoAscii->begin() + value + count);
            while (!text.empty() && (text.back() == '|' || text.back() == 0)) text.pop_back();  // GeoTIFF ends each string with '|'
            text = '"' + text + '"';
        }
        out += " " + std::to_string(id) + "=" + text;
    }
    return out;
}

// The scalar fields of a record: the standard ones of its format, then the
// Extra Bytes VLR's dimensions, which follow the format's own fields, each
// with its descriptor in `descriptors`. Errors name the VLR; deprecated array,
// undocumented and unnamed dimensions are skipped (their bytes still counted)
// and named in `skipped`. `noData`: a dimension's no-data value reads as NaN
// (no value), else as itself (a set that keeps every attribute gives it back).
Status scalarFields(const std::string& path, int format, size_t recordLength, const Vlrs& vlrs, bool noData,
                    std::vector<std::pair<ScalarField, ScalarLayout>>* out, std::vector<std::vector<uint8_t>>* descriptors,
                    std::vector<std::string>* skipped) {
    auto add = [&](const char* name, bool categorical, double resolution, ScalarLayout::Type type, size_t offset, double scale) {
        ScalarLayout l;
        l.type = type;
        l.offset = offset;
        l.scale = scale;
        out->push_back({{name, categorical, resolution}, l});
    };
    auto addBits = [&](const char* name, size_t offset, int shift, int bits) {
        ScalarLayout l;
        l.offset = offset;
        l.shift = shift;
        l.bits = bits;
        out->push_back({{name, true, 1}, l});
    };
    // GPS time and the waveform's floats are stored exactly where the set's
    // range allows (resolution 0: BuildContext::chooseAttributes).
    if (format < 6) {
        add("scan_angle", false, 1, ScalarLayout::I8, 16, 1);  // the rank, whole degrees
        add("user_data", true, 1, ScalarLayout::U8, 17, 1);
        add("point_source_id", true, 1, ScalarLayout::U16, 18, 1);
        if (format == 1 || format >= 3) add("gps_time", false, 0, ScalarLayout::F64, 20, 1);
        // Table 7: byte 15's bits 5-7 are LAS 1.4's flag bits 0-2 (synthetic, key point, withheld).
        addBits("classification_flags", 15, 5, 3);
        addBits("scan_direction_flag", 14, 6, 1);
        addBits("edge_of_flight_line", 14, 7, 1);
    } else {
        add("scan_angle", false, 0.006, ScalarLayout::I16, 18, 0.006);  // 0.006 degree units
        add("user_data", true, 1, ScalarLayout::U8, 17, 1);
        add("point_source_id", true, 1, ScalarLayout::U16, 20, 1);
        add("gps_time", false, 0, ScalarLayout::F64, 22, 1);
        if (format == 8 || format == 10) add("nir", false, 1, ScalarLayout::U16, 36, 1);
        // Table 13: byte 15 holds the flags (synthetic, key point, withheld, overlap) in
        // bits 0-3, the scanner channel in 4-5, scan direction 6, edge of flight line 7.
        addBits("classification_flags", 15, 0, 4);
        addBits("scan_channel", 15, 4, 2);
        addBits("scan_direction_flag", 15, 6, 1);
        addBits("edge_of_flight_line", 15, 7, 1);
    }
    if (const size_t w = las::kFormats[format].wave) {  // tables 12, 16: the wave packet's fields
        add("wavepacket_index", true, 1, ScalarLayout::U8, w, 1);
        add("wavepacket_offset", false, 1, ScalarLayout::U64, w + 1, 1);
        add("wavepacket_size", false, 1, ScalarLayout::U32, w + 9, 1);
        add("return_point_wave_location", false, 0, ScalarLayout::F32, w + 13, 1);
        add("x_t", false, 0, ScalarLayout::F32, w + 17, 1);
        add("y_t", false, 0, ScalarLayout::F32, w + 21, 1);
        add("z_t", false, 0, ScalarLayout::F32, w + 25, 1);
    }
    auto undescribed = [&](size_t from) {
        if (recordLength > from) skipped->push_back(std::to_string(recordLength - from) + " undescribed bytes of each record");
    };
    if (!vlrs.extraBytes) {
        undescribed(las::kFormats[format].bytes);
        return {};
    }
    const std::vector<uint8_t>& v = *vlrs.extraBytes;
    const std::string where = path + ": VLR " + std::to_string(vlrs.extraBytesIndex) + " (Extra Bytes, LASF_Spec 4)";
    if (v.empty() || v.size() % las::kDescriptorBytes != 0)
        return Status::error(where + ": " + std::to_string(v.size()) + " bytes, not a whole number of 192-byte descriptors");
    const size_t available = recordLength - las::kFormats[format].bytes;
    size_t offset = las::kFormats[format].bytes;
    for (size_t d = 0; d < v.size() / las::kDescriptorBytes; ++d) {
        const uint8_t* e = v.data() + d * las::kDescriptorBytes;
        const int type = e[2], options = e[3];
        const std::string name = las::descriptorName(e);
        const std::string dim = where + ", dimension " + std::to_string(d) + " '" + name + "'";
        if (type > 30) return Status::error(dim + ": unknown data type " + std::to_string(type));
        // Type 0: `options` undocumented bytes; 1-10: one scalar; 11-30: deprecated 2- and 3-element arrays.
        const size_t elements = type == 0 ? 0 : size_t((type - 1) / 10 + 1);
        const size_t size = type == 0 ? size_t(options) : elements * las::kTypeBytes[(type - 1) % 10 + 1];
        if (size == 0) return Status::error(dim + ": zero bytes");
        if (offset + size > recordLength)
            return Status::error(dim + ": the dimensions need more than the " + std::to_string(available) +
                                 " extra bytes each record holds");
        if (type >= 1 && type <= 10 && !name.empty()) {
            const bool duplicate = std::any_of(out->begin(), out->end(), [&](const auto& f) { return f.first.name == name; });
            if (duplicate) {
                std::fprintf(stderr, "warning: %s: a dimension of that name exists; skipped\n", dim.c_str());
                skipped->push_back("extra bytes " + std::to_string(d) + " ('" + name + "', a second of that name)");
            } else {
                ScalarLayout l;
                l.type = ScalarLayout::Type(type - 1);
                l.offset = offset;
                if (options & 8) l.scale = le::get<double>(e + 112);
                if (options & 16) l.add = le::get<double>(e + 136);
                if (!std::isfinite(l.scale) || l.scale == 0 || !std::isfinite(l.add))
                    return Status::error(dim + ": scale or offset is not a finite non-zero number");
                if (options & 1) l.noData = l.type >= ScalarLayout::F32 ? le::get<double>(e + 40) : rawValue(e + 40, l.type);
                l.hasNoData = noData && (options & 1) != 0;
                const bool integral = l.type < ScalarLayout::F32;
                out->push_back({{name, false, integral ? std::fabs(l.scale) : 0}, l});
                descriptors->emplace_back(e, e + las::kDescriptorBytes);
            }
        } else {
            if (type != 0 && !name.empty()) std::fprintf(stderr, "warning: %s: deprecated array type %d; skipped\n", dim.c_str(), type);
            skipped->push_back("extra bytes " + std::to_string(d) + (name.empty() ? "" : " ('" + name + "')") +
                               (type == 0 ? " (undocumented)" : type > 10 ? " (a deprecated array)" : " (unnamed)"));
        }
        offset += size;
    }
    undescribed(offset);
    return {};
}

}  // namespace

namespace {

// What the reader takes from the public header and the VLRs.
struct LasHeader {
    uint32_t dataOffset = 0;
    int format = 0;
    bool compressed = false;
    size_t recordLength = 0;
    uint64_t count = 0;
    double scale[3] = {}, offset[3] = {};
    Vlrs vlrs;
    LasSourceInfo source;  // the fields an export gives back (all but the lattice, the CRS and the extra bytes)
};

std::string headerText(const uint8_t* at, size_t size) {
    return std::string(reinterpret_cast<const char*>(at), strnlen(reinterpret_cast<const char*>(at), size));
}

// Reads and checks `in`'s header and VLRs.
Result<LasHeader> readLasHeader(ByteStream& in) {
    const std::string& path = in.path();
    uint8_t h[kLas14HeaderSize] = {};
    if (!in.readBytes(h, kLegacyHeaderSize)) return Status::error(in.at() + ": shorter than a LAS header (227 bytes)");
    if (std::memcmp(h, "LASF", 4) != 0) return Status::error(path + ": not a LAS file (no 'LASF' at byte 0)");
    int major = h[24], minor = h[25];
    if (major != 1 || minor > 4) return Status::error(path + ": byte 24: unsupported LAS version " + std::to_string(major) + "." + std::to_string(minor));
    LasHeader l;
    size_t headerSize = le::get<uint16_t>(h + 94);
    l.dataOffset = le::get<uint32_t>(h + 96);
    uint32_t vlrCount = le::get<uint32_t>(h + 100);
    uint8_t formatId = h[104];
    l.recordLength = le::get<uint16_t>(h + 105);
    l.count = le::get<uint32_t>(h + 107);
    l.compressed = (formatId & kCompressedBits) != 0;
    l.format = formatId & 0x3F;
    l.source.present = true;
    l.source.pointFormat = l.format;
    l.source.gpsTimeType = le::get<uint16_t>(h + 6) & 1;
    l.source.systemIdentifier = headerText(h + 26, 32);
    l.source.generatingSoftware = headerText(h + 58, 32);
    l.source.creationDay = le::get<uint16_t>(h + 90);
    l.source.creationYear = le::get<uint16_t>(h + 92);
    if (l.format > 10) return Status::error(path + ": byte 104: unknown point data format " + std::to_string(l.format));
    if (l.recordLength < las::kFormats[l.format].bytes)
        return Status::error(path + ": byte 105: record length " + std::to_string(l.recordLength) + " is shorter than format " +
                             std::to_string(l.format) + " needs (" + std::to_string(las::kFormats[l.format].bytes) + ")");
    if (minor >= 4 && headerSize >= kLas14HeaderSize) {
        if (!in.readBytes(h + kLegacyHeaderSize, kLas14HeaderSize - kLegacyHeaderSize))
            return Status::error(path + ": LAS 1.4 header truncated");
        uint64_t count64 = le::get<uint64_t>(h + 247);
        if (count64 != 0) l.count = count64;
    }
    for (int a = 0; a < 3; ++a) {
        l.scale[a] = le::get<double>(h + 131 + 8 * a);
        l.offset[a] = le::get<double>(h + 155 + 8 * a);
        if (!(l.scale[a] > 0) || !std::isfinite(l.scale[a]) || !std::isfinite(l.offset[a]))
            return Status::error(path + ": byte " + std::to_string(131 + 8 * a) + ": invalid scale or offset");
    }
    if (l.dataOffset < headerSize || l.dataOffset > in.fileSize())
        return Status::error(path + ": byte 96: point data offset " + std::to_string(l.dataOffset) + " out of range");
    auto vlrs = readVlrs(in, headerSize, vlrCount, l.dataOffset);
    if (!vlrs) return vlrs.status();
    l.vlrs = std::move(*vlrs);
    if (l.compressed && !l.vlrs.laszip)
        return Status::error(path + ": compressed point format but no LASzip VLR (user 'laszip encoded', record 22204)");
    if (const uint64_t available = (in.fileSize() - l.dataOffset) / l.recordLength; !l.compressed && available < l.count)
        return Status::error(path + ": header declares " + std::to_string(l.count) + " points, the file holds " +
                             std::to_string(available) + " (truncated at byte " + std::to_string(in.fileSize()) + ")");
    return l;
}

// The LAZ decompressor of `l`'s records [begin, end) (`tableOnly`: of none; its chunk table).
Result<std::unique_ptr<LazRecords>> openLaz(const std::string& path, const HttpOptions& http, const LasHeader& l, uint64_t begin,
                                            uint64_t end, int threads, bool tableOnly = false) {
    auto input = std::make_unique<FfiInput>();
    auto file = InputFile::open(path, http);
    if (!file) return file.status();
    input->file = std::move(*file);
    const std::vector<uint8_t>& vlr = *l.vlrs.laszip;
    char err[512] = {};
    ScLazReader* laz = sc_laz_open(input->file->size(), &FfiInput::readAt, input.get(), l.dataOffset, vlr.data(), vlr.size(), l.count,
                                   begin, end, threads, tableOnly, err, sizeof err);
    if (!laz) return Status::error(path + ": LAZ: " + input->explain(err));
    auto records = std::make_unique<LazRecords>(laz, std::move(input), threads, l.recordLength);
    if (sc_laz_point_size(laz) != l.recordLength)
        return Status::error(path + ": LASzip VLR describes " + std::to_string(sc_laz_point_size(laz)) + "-byte records, the header " +
                             std::to_string(l.recordLength));
    return records;
}

// The first record after each of a LAZ file's chunk boundaries (chunks of no
// points start where the next does: one place each).
Result<std::vector<RecordCut>> chunkStarts(const std::string& path, const HttpOptions& http, const LasHeader& l) {
    auto laz = openLaz(path, http, l, 0, l.count, 1, true);
    if (!laz) return laz.status();
    std::vector<RecordCut> cuts;
    for (uint64_t k = 0, n = (*laz)->chunkCount(); k < n; ++k) {
        const RecordCut c = (*laz)->chunkStart(k);
        if (c.record < l.count && (cuts.empty() || c.record > cuts.back().record)) cuts.push_back(c);
    }
    return cuts;
}

// openLasReader, or with `starts` a LAZ file's chunk starts (openLasChunkStarts).
Result<std::unique_ptr<PointReader>> openLas(const std::string& path, int threads, const ScalarSelection& scalars, RecordRange range,
                                             const HttpOptions& http, bool starts) {
    auto in = ByteStream::open(path, http);
    if (!in) return in.status();
    auto header = readLasHeader(*in);
    if (!header) return header.status();
    const LasHeader& l = *header;
    const uint64_t end = range.end ? range.end : l.count;
    if (end > l.count || range.begin > end)
        return Status::error(path + ": points [" + std::to_string(range.begin) + ", " + std::to_string(end) + ") asked for, the header declares " +
                             std::to_string(l.count));

    InputDescription desc;
    desc.path = path;
    desc.format = l.compressed ? "laz" : "las";
    desc.declaredPoints = end - range.begin;
    desc.hasColors = las::kFormats[l.format].rgb != 0;
    desc.hasIntensity = true;
    desc.hasClassification = true;
    desc.hasReturns = true;
    desc.colorBits = 16;
    desc.precision = std::min({l.scale[0], l.scale[1], l.scale[2]});
    desc.latticeScale = {l.scale[0], l.scale[1], l.scale[2]};
    desc.latticeOffset = {l.offset[0], l.offset[1], l.offset[2]};
    desc.crs = crsOf(l.vlrs);
    desc.airborne = true;
    desc.las = l.source;
    desc.las.scale = desc.latticeScale;
    desc.las.offset = desc.latticeOffset;
    for (const auto& [record, payload] : {std::pair{las::kWktRecord, &l.vlrs.wkt}, {las::kGeoKeysRecord, &l.vlrs.geoKeys},
                                          {las::kGeoDoublesRecord, &l.vlrs.geoDoubles}, {las::kGeoAsciiRecord, &l.vlrs.geoAscii}})
        if (*payload) desc.las.crsVlrs.push_back({record, **payload});

    std::vector<std::pair<ScalarField, ScalarLayout>> fields;
    SC_TRY(scalarFields(path, l.format, l.recordLength, l.vlrs, !scalars.all, &fields, &desc.las.extraBytes, &desc.otherScalars));
    std::vector<ScalarLayout> layouts;
    for (auto& [field, layout] : fields)
        if (scalars.wants(field.name)) {
            desc.scalars.push_back(field);
            layouts.push_back(layout);
        } else {
            desc.otherScalars.push_back(field.name);
        }

    std::unique_ptr<RecordSource> source;
    if (starts && l.compressed) {
        auto cuts = chunkStarts(path, http, l);
        if (!cuts) return cuts.status();
        const uint64_t n = cuts->size();
        source = std::make_unique<ChunkStarts>(std::move(*in), l.recordLength, std::move(*cuts));
        return std::unique_ptr<PointReader>(new LasReader(std::move(source), desc, 0, n, l.recordLength, l.format, l.scale, l.offset,
                                                          std::move(layouts)));
    }
    if (l.compressed) {
        auto laz = openLaz(path, http, l, range.begin, end, threads);
        if (!laz) return laz.status();
        source = std::move(*laz);
    } else {
        if (!in->seek(l.dataOffset + range.begin * l.recordLength)) return Status::error(path + ": cannot seek to the point data");
        source = std::make_unique<RawRecords>(std::move(*in), l.recordLength, l.count);
    }
    return std::unique_ptr<PointReader>(new LasReader(std::move(source), desc, range.begin, end, l.recordLength, l.format, l.scale,
                                                      l.offset, std::move(layouts)));
}

}  // namespace

Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path, int threads, const ScalarSelection& scalars,
                                                   RecordRange range, const HttpOptions& http) {
    return openLas(path, threads, scalars, range, http, false);
}

Result<std::unique_ptr<PointReader>> openLasChunkStarts(const std::string& path, const ScalarSelection& scalars, const HttpOptions& http) {
    return openLas(path, 1, scalars, {}, http, true);
}

Result<std::vector<RecordCut>> lasCuts(const std::string& path, const HttpOptions& http) {
    auto in = ByteStream::open(path, http);
    if (!in) return in.status();
    auto l = readLasHeader(*in);
    if (!l) return l.status();
    std::vector<RecordCut> cuts;
    if (!l->compressed) {
        // Every kLasCutRecords records, or a multiple of it that keeps the cuts under kMaxCuts.
        const uint64_t stride = kLasCutRecords * std::max<uint64_t>(1, l->count / (kLasCutRecords * kMaxCuts) + 1);
        for (uint64_t r = 0; r < l->count; r += stride) cuts.push_back({r, l->dataOffset + r * l->recordLength});
        return cuts;
    }
    return chunkStarts(path, http, *l);
}

}  // namespace surfcast
