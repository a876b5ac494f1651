// Field offsets follow the LAS 1.4 R15 specification, tables 3 (header), 4
// (variable-length record header) and 7-17 (point data record formats).
#include "las_reader.h"

#include <surfcast_laz.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "byte_io.h"
#include "byte_stream.h"

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
constexpr char kLaszipUser[] = "laszip encoded";
constexpr uint16_t kLaszipRecord = 22204;

// Bytes each point format needs before any extra bytes, and where RGB starts
// (0 when the format has no colour).
struct FormatLayout { size_t minLength; size_t rgbOffset; };
constexpr FormatLayout kFormats[11] = {
    {20, 0}, {28, 0}, {26, 20}, {34, 28}, {57, 0}, {63, 28}, {30, 0}, {36, 30}, {38, 30}, {59, 0}, {67, 30}};

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
        uint64_t at = in_.offset();
        if (!in_.readBytes(out, records * length_))
            return Status::error(in_.path() + ": byte " + std::to_string(at) + ": file ends at point " +
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
    LazRecords(ScLazReader* reader, std::string path, int threads, size_t recordLength)
        : reader_(reader), path_(std::move(path)), threads_(threads), recordLength_(recordLength) {}
    ~LazRecords() override { sc_laz_close(reader_); }
    Status read(uint8_t* out, size_t records, uint64_t firstIndex) override {
        char err[512] = {};
        if (sc_laz_read(reader_, out, records, err, sizeof err) != 0)
            return Status::error(path_ + ": LAZ data, points " + std::to_string(firstIndex) + "-" +
                                 std::to_string(firstIndex + records - 1) + ": " + err);
        return {};
    }
    // Enough chunks per call for every thread to decompress several.
    size_t preferredBatch() const override {
        size_t chunk = std::max<size_t>(sc_laz_chunk_size(reader_), kLazBatchFloor);
        size_t want = chunk * size_t(std::max(threads_, 1)) * kLazChunksPerThread;
        return std::max(chunk, std::min(want, kLazBatchBytes / recordLength_));
    }

private:
    ScLazReader* reader_;
    std::string path_;
    int threads_;
    size_t recordLength_;
};

class LasReader final : public PointReader {
public:
    LasReader(std::unique_ptr<RecordSource> source, InputDescription desc, uint64_t count, size_t recordLength,
              int format, const double scale[3], const double offset[3])
        : source_(std::move(source)), desc_(std::move(desc)), count_(count), recordLength_(recordLength),
          rgbOffset_(kFormats[format].rgbOffset), extended_(format >= 6) {
        for (int i = 0; i < 3; ++i) { scale_[i] = scale[i]; offset_[i] = offset[i]; }
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
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
            if (finite(p.position)) ++n; else ++skipped_;
        }
        return n;
    }

private:
    std::unique_ptr<RecordSource> source_;
    InputDescription desc_;
    uint64_t count_;
    size_t recordLength_, rgbOffset_;
    bool extended_;  // point formats 6-10
    double scale_[3], offset_[3];
    uint64_t index_ = 0;           // records fetched from the source
    size_t buffered_ = 0, next_ = 0;
    std::vector<uint8_t> buffer_;
};

// The LASzip VLR's payload, or an error.
Result<std::vector<uint8_t>> findLaszipVlr(ByteStream& in, size_t headerSize, uint32_t vlrCount, uint32_t dataOffset) {
    if (!in.seek(headerSize)) return Status::error(in.path() + ": cannot seek to the VLRs");
    for (uint32_t i = 0; i < vlrCount; ++i) {
        uint64_t at = in.offset();
        uint8_t h[kVlrHeaderSize];
        if (at + kVlrHeaderSize > dataOffset || !in.readBytes(h, kVlrHeaderSize))
            return Status::error(in.path() + ": byte " + std::to_string(at) + ": VLR " + std::to_string(i) + " runs past the point data");
        uint16_t record = le::get<uint16_t>(h + 18), length = le::get<uint16_t>(h + 20);
        bool laszip = std::strncmp(reinterpret_cast<const char*>(h + 2), kLaszipUser, 16) == 0 && record == kLaszipRecord;
        if (laszip) {
            std::vector<uint8_t> payload(length);
            if (!in.readBytes(payload.data(), length))
                return Status::error(in.path() + ": byte " + std::to_string(at) + ": LASzip VLR truncated");
            return payload;
        }
        if (!in.skip(length)) return Status::error(in.path() + ": byte " + std::to_string(at) + ": VLR truncated");
    }
    return Status::error(in.path() + ": compressed point format but no LASzip VLR (user 'laszip encoded', record 22204)");
}

}  // namespace

Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path, int threads) {
    auto in = ByteStream::open(path);
    if (!in) return in.status();
    uint8_t h[kLas14HeaderSize] = {};
    if (!in->readBytes(h, kLegacyHeaderSize)) return Status::error(path + ": shorter than a LAS header (227 bytes)");
    if (std::memcmp(h, "LASF", 4) != 0) return Status::error(path + ": not a LAS file (no 'LASF' at byte 0)");
    int major = h[24], minor = h[25];
    if (major != 1 || minor > 4) return Status::error(path + ": byte 24: unsupported LAS version " + std::to_string(major) + "." + std::to_string(minor));
    size_t headerSize = le::get<uint16_t>(h + 94);
    uint32_t dataOffset = le::get<uint32_t>(h + 96);
    uint32_t vlrCount = le::get<uint32_t>(h + 100);
    uint8_t formatId = h[104];
    size_t recordLength = le::get<uint16_t>(h + 105);
    uint64_t count = le::get<uint32_t>(h + 107);
    bool compressed = (formatId & kCompressedBits) != 0;
    int format = formatId & 0x3F;
    if (format > 10) return Status::error(path + ": byte 104: unknown point data format " + std::to_string(format));
    if (recordLength < kFormats[format].minLength)
        return Status::error(path + ": byte 105: record length " + std::to_string(recordLength) + " is shorter than format " +
                             std::to_string(format) + " needs (" + std::to_string(kFormats[format].minLength) + ")");
    if (minor >= 4 && headerSize >= kLas14HeaderSize) {
        if (!in->readBytes(h + kLegacyHeaderSize, kLas14HeaderSize - kLegacyHeaderSize))
            return Status::error(path + ": LAS 1.4 header truncated");
        uint64_t count64 = le::get<uint64_t>(h + 247);
        if (count64 != 0) count = count64;
    }
    double scale[3], offset[3];
    for (int a = 0; a < 3; ++a) {
        scale[a] = le::get<double>(h + 131 + 8 * a);
        offset[a] = le::get<double>(h + 155 + 8 * a);
        if (!(scale[a] > 0) || !std::isfinite(scale[a]) || !std::isfinite(offset[a]))
            return Status::error(path + ": byte " + std::to_string(131 + 8 * a) + ": invalid scale or offset");
    }
    if (dataOffset < headerSize || dataOffset > in->fileSize())
        return Status::error(path + ": byte 96: point data offset " + std::to_string(dataOffset) + " out of range");

    InputDescription desc;
    desc.path = path;
    desc.format = compressed ? "laz" : "las";
    desc.declaredPoints = count;
    desc.hasColors = kFormats[format].rgbOffset != 0;
    desc.hasIntensity = true;
    desc.hasClassification = true;
    desc.hasReturns = true;
    desc.colorBits = 16;
    desc.precision = std::min({scale[0], scale[1], scale[2]});
    desc.airborne = true;

    std::unique_ptr<RecordSource> source;
    if (compressed) {
        auto vlr = findLaszipVlr(*in, headerSize, vlrCount, dataOffset);
        if (!vlr) return vlr.status();
        char err[512] = {};
        ScLazReader* laz = sc_laz_open(path.c_str(), dataOffset, vlr->data(), vlr->size(), count, threads, err, sizeof err);
        if (!laz) return Status::error(path + ": LAZ: " + err);
        if (sc_laz_point_size(laz) != recordLength) {
            sc_laz_close(laz);
            return Status::error(path + ": LASzip VLR describes " + std::to_string(sc_laz_point_size(laz)) +
                                 "-byte records, the header " + std::to_string(recordLength));
        }
        source = std::make_unique<LazRecords>(laz, path, threads, recordLength);
    } else {
        uint64_t available = (in->fileSize() - dataOffset) / recordLength;
        if (available < count)
            return Status::error(path + ": header declares " + std::to_string(count) + " points, the file holds " +
                                 std::to_string(available) + " (truncated at byte " + std::to_string(in->fileSize()) + ")");
        if (!in->seek(dataOffset)) return Status::error(path + ": cannot seek to the point data");
        source = std::make_unique<RawRecords>(std::move(*in), recordLength, count);
    }
    return std::unique_ptr<PointReader>(
        new LasReader(std::move(source), desc, count, recordLength, format, scale, offset));
}

}  // namespace surfcast
