#include "block_codec.h"

#include <cstring>
#include <draco/compression/decode.h>
#include <draco/compression/expert_encode.h>
#include <draco/point_cloud/point_cloud_builder.h>

namespace surfcast {

namespace {
// Draco speed 0..10: 5 is its default balance; the kd-tree coder's ratio barely
// changes below it while encoding gets markedly slower.
constexpr int kDracoSpeed = 4;

template <typename T>
bool readAttribute(const draco::PointCloud& pc, int index, draco::DataType type, int components, std::vector<T>* out) {
    if (index >= pc.num_attributes()) return false;
    const draco::PointAttribute* a = pc.attribute(index);
    if (a->data_type() != type || a->num_components() != components) return false;
    out->resize(size_t(pc.num_points()) * components);
    for (draco::PointIndex i(0); i < pc.num_points(); ++i) a->GetMappedValue(i, out->data() + size_t(i.value()) * components);
    return true;
}
// A scalar attribute: 1 unsigned integer of 8, 16 or 32 bits per point, widened.
bool readScalar(const draco::PointCloud& pc, int index, const std::string& name, std::vector<ScalarAttribute>* out) {
    if (index >= pc.num_attributes()) return false;
    const draco::PointAttribute* a = pc.attribute(index);
    const draco::DataType type = a->data_type();
    if ((type != draco::DT_UINT8 && type != draco::DT_UINT16 && type != draco::DT_UINT32) || a->num_components() != 1)
        return false;
    ScalarAttribute& s = out->emplace_back();
    s.name = name;
    s.bits = type == draco::DT_UINT8 ? 8 : type == draco::DT_UINT16 ? 16 : 32;
    s.values.resize(size_t(pc.num_points()));
    for (draco::PointIndex i(0); i < pc.num_points(); ++i)
        if (!a->ConvertValue<uint32_t>(a->mapped_index(i), &s.values[i.value()])) return false;
    return true;
}

}  // namespace

Result<std::vector<uint8_t>> encodeBlock(const BlockData& block, const BlockCodecOptions& options) {
    const size_t n = block.size();
    assert(n > 0 && block.positions.size() == 3 * n);
    draco::PointCloudBuilder builder;
    builder.Start(uint32_t(n));
    struct Quantized { int id; int bits; };
    std::vector<Quantized> quantized;
    int pos = builder.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_UINT32);
    builder.SetAttributeValuesForAllPoints(pos, block.positions.data(), 3 * sizeof(uint32_t));
    if (!block.normals.empty()) {
        assert(block.normals.size() == 3 * n);
        int id = builder.AddAttribute(draco::GeometryAttribute::NORMAL, 3, draco::DT_FLOAT32);
        builder.SetAttributeValuesForAllPoints(id, block.normals.data(), 3 * sizeof(float));
        quantized.push_back({id, options.normalBits});
    }
    std::vector<uint8_t> colors8;
    if (!block.colors.empty()) {
        assert(block.colors.size() == 3 * n);
        if (options.colorBits == 8) {
            colors8.assign(block.colors.begin(), block.colors.end());
            int id = builder.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT8);
            builder.SetAttributeValuesForAllPoints(id, colors8.data(), 3);
        } else {
            int id = builder.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT16);
            builder.SetAttributeValuesForAllPoints(id, block.colors.data(), 3 * sizeof(uint16_t));
        }
    }
    for (auto [values, bits] : {std::pair{&block.weights, options.weightBits}, std::pair{&block.radii, options.radiusBits}}) {
        if (values->empty()) continue;
        assert(values->size() == n);
        int id = builder.AddAttribute(draco::GeometryAttribute::GENERIC, 1, draco::DT_FLOAT32);
        builder.SetAttributeValuesForAllPoints(id, values->data(), sizeof(float));
        quantized.push_back({id, bits});
    }
    if (!block.edgeWeights.empty()) {
        assert(block.edgeWeights.size() == 4 * n);
        int id = builder.AddAttribute(draco::GeometryAttribute::GENERIC, 4, draco::DT_FLOAT32);
        builder.SetAttributeValuesForAllPoints(id, block.edgeWeights.data(), 4 * sizeof(float));
        quantized.push_back({id, options.edgeWeightBits});
    }
    // LiDAR attributes, integers stored as they are (Draco's integer coder).
    auto addInteger = [&](const auto& values, draco::DataType type) {
        if (values.empty()) return;
        assert(values.size() == n);
        int id = builder.AddAttribute(draco::GeometryAttribute::GENERIC, 1, type);
        builder.SetAttributeValuesForAllPoints(id, values.data(), sizeof(values[0]));
    };
    addInteger(block.intensity, draco::DT_UINT16);
    addInteger(block.classification, draco::DT_UINT8);
    addInteger(block.returnNumber, draco::DT_UINT8);
    addInteger(block.numberOfReturns, draco::DT_UINT8);
    addInteger(block.opacity, draco::DT_UINT8);
    std::vector<uint8_t> narrow8;
    std::vector<uint16_t> narrow16;
    for (const ScalarAttribute& a : block.scalars) {
        assert(a.bits >= 1 && a.bits <= 32);
        if (a.bits <= 8) {
            narrow8.assign(a.values.begin(), a.values.end());
            addInteger(narrow8, draco::DT_UINT8);
        } else if (a.bits <= 16) {
            narrow16.assign(a.values.begin(), a.values.end());
            addInteger(narrow16, draco::DT_UINT16);
        } else {
            addInteger(a.values, draco::DT_UINT32);
        }
    }
    std::unique_ptr<draco::PointCloud> pc = builder.Finalize(false);
    if (!pc) return Status::error("Draco rejected the block's attributes");
    // Readers refuse a block of more than kMaxBlockPoints points or whose
    // decoding would take more than kMaxBlockDecodeBytes (a leaf at the
    // deepest level may pass --capacity): never write one.
    uint32_t components = 0, valueBytes = 0;
    for (int i = 0; i < pc->num_attributes(); ++i) {
        const draco::PointAttribute* a = pc->attribute(i);
        components += uint32_t(a->num_components());
        valueBytes += uint32_t(a->num_components() * draco::DataTypeLength(a->data_type()));
    }
    const uint64_t footprint = blockDecodeBytes(uint32_t(n), components, valueBytes);
    if (n > kMaxBlockPoints || footprint > kMaxBlockDecodeBytes)
        return Status::error("a node of " + std::to_string(n) + " surfels with " + std::to_string(components) +
                             " attribute components would take " + std::to_string(footprint >> 20) +
                             " MiB to decode; readers allow " + std::to_string(kMaxBlockPoints) + " surfels and " +
                             std::to_string(kMaxBlockDecodeBytes >> 20) + " MiB: lower --capacity");

    draco::ExpertEncoder encoder(*pc);
    encoder.SetEncodingMethod(draco::POINT_CLOUD_KD_TREE_ENCODING);
    encoder.SetSpeedOptions(kDracoSpeed, kDracoSpeed);
    for (const Quantized& q : quantized) encoder.SetAttributeQuantization(q.id, q.bits);
    draco::EncoderBuffer buffer;
    draco::Status st = encoder.EncodeToBuffer(&buffer);
    if (!st.ok()) return Status::error(std::string("Draco encoding failed: ") + st.error_msg());
    return std::vector<uint8_t>(buffer.data(), buffer.data() + buffer.size());
}

namespace {
// What Draco sizes its buffers by, read from a block's header before Draco
// sees it, so that a block cannot make it allocate more than the node's
// record and the set's attributes allow (fuzz_block: 2.4 GB from a point
// count, 3.3 GB from the sequential decoder, 2 GB from attribute
// descriptors, 3 GB from a count within the record bound times many wide
// attributes). Header: "DRACO", major, minor, encoder type (0: point
// cloud), method (1: kd-tree, what surfcast-build writes), u16 flags (no
// metadata: surfcast-build writes none), the point count as int32; then one
// attribute decoder, its attribute count (varint), and per attribute its
// type, data type, component count and normalized flag (a byte each) and a
// unique id (varint).
struct DracoHeader {
    uint32_t points = 0;
    uint32_t attributes = 0;
    uint32_t components = 0;  // summed over the attributes
    uint32_t valueBytes = 0;  // one point's decoded values, summed over the attributes
};
// Bytes of one value of Draco's data types 1..11 (INT8 .. BOOL).
uint32_t dracoTypeBytes(uint8_t type) {
    static constexpr uint8_t bytes[12] = {0, 1, 1, 2, 2, 4, 4, 8, 8, 4, 8, 1};
    return bytes[type];
}
Result<DracoHeader> readDracoHeader(const uint8_t* data, size_t size) {
    if (size < 17 || std::memcmp(data, "DRACO", 5) != 0) return Status::error("not a Draco block");
    // The fields below sit where bitstream 2.x (Draco 1.5's) puts them.
    if (data[5] != 2)
        return Status::error("the Draco block is bitstream version " + std::to_string(data[5]) + "." + std::to_string(data[6]) +
                             "; readers take 2.x");
    if (data[7] != 0) return Status::error("the Draco block is not a point cloud");
    if (data[8] != 1) return Status::error("the Draco block is not kd-tree coded");
    if ((data[9] | data[10] << 8) & 0x8000) return Status::error("the Draco block carries metadata");
    int32_t count;
    std::memcpy(&count, data + 11, 4);
    if (count < 0) return Status::error("the Draco block declares a negative point count");
    if (data[15] != 1) return Status::error("the Draco block has " + std::to_string(data[15]) + " attribute decoders, not 1");
    size_t at = 16;
    auto varint = [&](uint32_t* out) {
        uint64_t v = 0;
        for (int shift = 0; shift < 35 && at < size; shift += 7) {
            const uint8_t b = data[at++];
            v |= uint64_t(b & 0x7f) << shift;
            if (!(b & 0x80)) return v <= UINT32_MAX && (*out = uint32_t(v), true);
        }
        return false;
    };
    DracoHeader h;
    h.points = uint32_t(count);
    if (!varint(&h.attributes) || h.attributes > 64) return Status::error("the Draco block's attribute count is unreadable");
    for (uint32_t i = 0; i < h.attributes; ++i) {
        if (size - at < 4) return Status::error("the Draco block ends in its attribute descriptors");
        const uint8_t dataType = data[at + 1], components = data[at + 2];
        at += 4;
        uint32_t id;
        if (dataType < 1 || dataType > 11 || components < 1 || components > 4 || !varint(&id))
            return Status::error("the Draco block's attribute " + std::to_string(i) + " has " +
                                 std::to_string(components) + " components of type " + std::to_string(dataType));
        h.components += components;
        h.valueBytes += components * dracoTypeBytes(dataType);
    }
    return h;
}
}  // namespace

Result<BlockData> decodeBlock(const uint8_t* data, size_t size, const BlockExpectation& expect) {
    auto header = readDracoHeader(data, size);
    if (!header) return header.status();
    if (expect.points ? header->points != expect.points : header->points > kMaxBlockPoints)
        return Status::error("the Draco block declares " + std::to_string(header->points) + " points; the tile set " +
                             (expect.points ? "declares " + std::to_string(expect.points)
                                            : "allows at most " + std::to_string(kMaxBlockPoints)));
    const int expected = 1 + expect.normals + (expect.colorBits != 0) + expect.weights + expect.radii + expect.edgeWeights +
                         int(expect.extra.size());
    if (header->attributes != uint32_t(expected))
        return Status::error("block has " + std::to_string(header->attributes) + " attributes; the tile set declares " +
                             std::to_string(expected));
    const uint64_t footprint = blockDecodeBytes(header->points, header->components, header->valueBytes);
    if (footprint > kMaxBlockDecodeBytes)
        return Status::error("the Draco block's " + std::to_string(header->points) + " points of " +
                             std::to_string(header->components) + " components would take " +
                             std::to_string(footprint >> 20) + " MiB to decode; at most " +
                             std::to_string(kMaxBlockDecodeBytes >> 20) + " MiB is allowed");
    draco::DecoderBuffer buffer;
    buffer.Init(reinterpret_cast<const char*>(data), size);
    draco::Decoder decoder;
    auto decoded = decoder.DecodePointCloudFromBuffer(&buffer);
    if (!decoded.ok()) return Status::error(std::string("Draco decoding failed: ") + decoded.status().error_msg());
    const draco::PointCloud& pc = *decoded.value();
    // Draco made one attribute per descriptor readDracoHeader counted.
    if (pc.num_points() == 0) return Status::error("block has no points");
    BlockData block;
    int index = 0;
    bool ok = readAttribute(pc, index++, draco::DT_UINT32, 3, &block.positions);
    if (ok && expect.normals) ok = readAttribute(pc, index++, draco::DT_FLOAT32, 3, &block.normals);
    if (ok && expect.colorBits == 8) {
        std::vector<uint8_t> c8;
        ok = readAttribute(pc, index++, draco::DT_UINT8, 3, &c8);
        block.colors.assign(c8.begin(), c8.end());
    } else if (ok && expect.colorBits == 16) {
        ok = readAttribute(pc, index++, draco::DT_UINT16, 3, &block.colors);
    }
    if (ok && expect.weights) ok = readAttribute(pc, index++, draco::DT_FLOAT32, 1, &block.weights);
    if (ok && expect.radii) ok = readAttribute(pc, index++, draco::DT_FLOAT32, 1, &block.radii);
    if (ok && expect.edgeWeights) ok = readAttribute(pc, index++, draco::DT_FLOAT32, 4, &block.edgeWeights);
    for (const std::string& name : expect.extra) {
        if (!ok) break;
        if (name == "intensity") ok = readAttribute(pc, index, draco::DT_UINT16, 1, &block.intensity);
        else if (name == "classification") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.classification);
        else if (name == "return_number") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.returnNumber);
        else if (name == "number_of_returns") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.numberOfReturns);
        else if (name == kOpacityAttribute) ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.opacity);
        else if (expect.scalars) ok = readScalar(pc, index, name, &block.scalars);
        ++index;  // any other: a newer writer's attribute, skipped
    }
    if (!ok) return Status::error("block attribute " + std::to_string(index - 1) + " has an unexpected type or size");
    return block;
}

}  // namespace surfcast
