// Field offsets follow the LAS 1.4 R15 specification, tables 3 (header) and
// 7-17 (point data record formats).
#include "las_reader.h"

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
constexpr uint8_t kCompressedBit = 0x80;      // LAZ marks the format id with bit 7
constexpr size_t kBatchRecords = 4096;        // records per read from the file

// Bytes each point format needs before any extra bytes, and where RGB starts
// (0 when the format has no colour).
struct FormatLayout { size_t minLength; size_t rgbOffset; };
constexpr FormatLayout kFormats[11] = {
    {20, 0}, {28, 0}, {26, 20}, {34, 28}, {57, 0}, {63, 28}, {30, 0}, {36, 30}, {38, 30}, {59, 0}, {67, 30}};

class LasReader final : public PointReader {
public:
    LasReader(ByteStream in, InputDescription desc, uint64_t count, size_t recordLength, size_t rgbOffset,
              const double scale[3], const double offset[3])
        : in_(std::move(in)), desc_(std::move(desc)), count_(count), recordLength_(recordLength), rgbOffset_(rgbOffset) {
        for (int i = 0; i < 3; ++i) { scale_[i] = scale[i]; offset_[i] = offset[i]; }
    }

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        while (n < max && index_ < count_) {
            size_t batch = size_t(std::min<uint64_t>({count_ - index_, uint64_t(max - n), uint64_t(kBatchRecords)}));
            buffer_.resize(batch * recordLength_);
            uint64_t at = in_.offset();
            if (!in_.readBytes(buffer_.data(), buffer_.size()))
                return Status::error(desc_.path + ": byte " + std::to_string(at) + ": file ends at point " +
                                     std::to_string(index_) + " of the " + std::to_string(count_) + " the header declares");
            for (size_t i = 0; i < batch; ++i) {
                const uint8_t* r = buffer_.data() + i * recordLength_;
                InputPoint& p = out[n];
                p = InputPoint{};
                for (int a = 0; a < 3; ++a) p.position[a] = le::get<int32_t>(r + 4 * a) * scale_[a] + offset_[a];
                p.intensity = le::get<uint16_t>(r + 12);
                if (rgbOffset_)
                    for (int c = 0; c < 3; ++c) p.color[c] = le::get<uint16_t>(r + rgbOffset_ + 2 * c);
                if (finite(p.position)) ++n; else ++skipped_;
            }
            index_ += batch;
        }
        return n;
    }

private:
    ByteStream in_;
    InputDescription desc_;
    uint64_t count_;
    size_t recordLength_, rgbOffset_;
    double scale_[3], offset_[3];
    uint64_t index_ = 0;
    std::vector<uint8_t> buffer_;
};

}  // namespace

Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path) {
    auto in = ByteStream::open(path);
    if (!in) return in.status();
    uint8_t h[kLas14HeaderSize] = {};
    if (!in->readBytes(h, kLegacyHeaderSize)) return Status::error(path + ": shorter than a LAS header (227 bytes)");
    if (std::memcmp(h, "LASF", 4) != 0) return Status::error(path + ": not a LAS file (no 'LASF' at byte 0)");
    int major = h[24], minor = h[25];
    if (major != 1 || minor > 4) return Status::error(path + ": byte 24: unsupported LAS version " + std::to_string(major) + "." + std::to_string(minor));
    size_t headerSize = le::get<uint16_t>(h + 94);
    uint32_t dataOffset = le::get<uint32_t>(h + 96);
    uint8_t formatId = h[104];
    size_t recordLength = le::get<uint16_t>(h + 105);
    uint64_t count = le::get<uint32_t>(h + 107);
    if (formatId & kCompressedBit)
        return Status::error(path + ": byte 104: compressed LAZ data (format id " + std::to_string(formatId) +
                             "); LAZ input is not supported yet");
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
    uint64_t available = (in->fileSize() - dataOffset) / recordLength;
    if (available < count)
        return Status::error(path + ": header declares " + std::to_string(count) + " points, the file holds " +
                             std::to_string(available) + " (truncated at byte " + std::to_string(in->fileSize()) + ")");
    if (!in->seek(dataOffset)) return Status::error(path + ": cannot seek to the point data");

    InputDescription desc;
    desc.path = path;
    desc.format = "las";
    desc.declaredPoints = count;
    desc.hasColors = kFormats[format].rgbOffset != 0;
    desc.hasIntensity = true;
    desc.colorBits = 16;
    desc.precision = std::min({scale[0], scale[1], scale[2]});
    desc.airborne = true;
    return std::unique_ptr<PointReader>(
        new LasReader(std::move(*in), desc, count, recordLength, kFormats[format].rgbOffset, scale, offset));
}

}  // namespace surfcast
