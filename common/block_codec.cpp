#include "block_codec.h"

#include <algorithm>
#include <array>
#include <cstring>
#include <numeric>
#include <draco/compression/decode.h>
#include <draco/compression/expert_encode.h>
#include <draco/point_cloud/point_cloud_builder.h>

#include "byte_io.h"

namespace surfcast {

namespace {
// Draco speed 0..10, both coders: 5 is its default balance; the kd-tree
// coder's ratio barely changes below it while encoding gets markedly slower
// (bench/BENCHMARKS.md, "Bytes").
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

// A 32-bit scalar attribute stored as two uint16 attributes, its top and its low 16 bits.
bool readHalves(const draco::PointCloud& pc, int index, const std::string& name, std::vector<ScalarAttribute>* out) {
    std::vector<uint16_t> top, low;
    if (!readAttribute(pc, index, draco::DT_UINT16, 1, &top) || !readAttribute(pc, index + 1, draco::DT_UINT16, 1, &low)) return false;
    ScalarAttribute& s = out->emplace_back();
    s.name = name;
    s.bits = 32;
    s.values.resize(top.size());
    for (size_t i = 0; i < top.size(); ++i) s.values[i] = uint32_t(top[i]) << 16 | low[i];
    return true;
}

}  // namespace

const char* blockCodecName(BlockCodec codec) { return codec == BlockCodec::Draco ? "draco" : "draco-columns"; }

std::optional<BlockCodec> parseBlockCodec(const std::string& name) {
    if (name == "draco") return BlockCodec::Draco;
    if (name == "draco-columns") return BlockCodec::DracoColumns;
    return std::nullopt;
}

namespace {

// A Draco point cloud of at least one point; `what` names it in errors.
Result<std::unique_ptr<draco::PointCloud>> decodeCloud(const uint8_t* data, size_t size, const char* what) {
    draco::DecoderBuffer buffer;
    buffer.Init(reinterpret_cast<const char*>(data), size);
    draco::Decoder decoder;
    auto decoded = decoder.DecodePointCloudFromBuffer(&buffer);
    if (!decoded.ok()) return Status::error(std::string("Draco decoding failed (") + what + "): " + decoded.status().error_msg());
    if (decoded.value()->num_points() == 0) return Status::error("block has no points");
    return std::move(decoded).value();
}

// `values` (`components` per point) in `order` (empty: as they are).
template <typename T>
const T* permuted(const std::vector<T>& values, int components, const std::vector<uint32_t>& order, std::vector<T>* scratch) {
    if (order.empty()) return values.data();
    scratch->resize(order.size() * size_t(components));
    for (size_t i = 0; i < order.size(); ++i)
        std::copy_n(values.data() + size_t(order[i]) * components, components, scratch->data() + i * components);
    return scratch->data();
}

// Every attribute of `block` but the positions, in block order, to `builder`,
// point i taking the values of point order[i] (empty: i's own). With `split`,
// a scalar attribute wider than 16 bits is two uint16 attributes, its top and
// its low 16 bits (BlockExpectation::extraBits).
void addOtherAttributes(draco::PointCloudBuilder& builder, const BlockData& block, const BlockCodecOptions& options,
                        const std::vector<uint32_t>& order, bool split, std::vector<std::pair<int, int>>* quantized) {
    const size_t n = block.size();
    auto add = [&](draco::GeometryAttribute::Type type, int components, draco::DataType dataType, const auto& values) {
        assert(values.size() == n * size_t(components));
        std::remove_cvref_t<decltype(values)> scratch;
        const int id = builder.AddAttribute(type, components, dataType);
        builder.SetAttributeValuesForAllPoints(id, permuted(values, components, order, &scratch),
                                               components * sizeof(values[0]));
        return id;
    };
    if (!block.normals.empty())
        quantized->push_back({add(draco::GeometryAttribute::NORMAL, 3, draco::DT_FLOAT32, block.normals), options.normalBits});
    if (!block.colors.empty()) {
        if (options.colorBits == 8) add(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT8, std::vector<uint8_t>(block.colors.begin(), block.colors.end()));
        else add(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT16, block.colors);
    }
    for (auto [values, bits] : {std::pair{&block.weights, options.weightBits}, std::pair{&block.radii, options.radiusBits}})
        if (!values->empty()) quantized->push_back({add(draco::GeometryAttribute::GENERIC, 1, draco::DT_FLOAT32, *values), bits});
    if (!block.edgeWeights.empty())
        quantized->push_back({add(draco::GeometryAttribute::GENERIC, 4, draco::DT_FLOAT32, block.edgeWeights), options.edgeWeightBits});
    // LiDAR attributes, opacity and scalars: integers stored as they are (Draco's integer coders).
    auto addInteger = [&](const auto& values, draco::DataType type) {
        if (!values.empty()) add(draco::GeometryAttribute::GENERIC, 1, type, values);
    };
    addInteger(block.intensity, draco::DT_UINT16);
    addInteger(block.classification, draco::DT_UINT8);
    addInteger(block.returnNumber, draco::DT_UINT8);
    addInteger(block.numberOfReturns, draco::DT_UINT8);
    addInteger(block.opacity, draco::DT_UINT8);
    for (const ScalarAttribute& a : block.scalars) {
        assert(a.bits >= 1 && a.bits <= 32);
        if (a.bits <= 8) {
            addInteger(std::vector<uint8_t>(a.values.begin(), a.values.end()), draco::DT_UINT8);
        } else if (a.bits <= 16) {
            addInteger(std::vector<uint16_t>(a.values.begin(), a.values.end()), draco::DT_UINT16);
        } else if (!split) {
            addInteger(a.values, draco::DT_UINT32);
        } else {
            // Draco's sequential integer coder takes values below 2^31 only.
            std::vector<uint16_t> top(n), low(n);
            for (size_t i = 0; i < n; ++i) {
                top[i] = uint16_t(a.values[i] >> 16);
                low[i] = uint16_t(a.values[i]);
            }
            addInteger(top, draco::DT_UINT16);
            addInteger(low, draco::DT_UINT16);
        }
    }
}

// Readers refuse a block of more than kMaxBlockPoints points, a point cloud
// of more than kMaxBlockAttributes attributes, or a block whose decoding
// would take more than kMaxBlockDecodeBytes (a leaf at the deepest level may
// pass --capacity): never write one.
Status checkReadable(size_t n, std::initializer_list<const draco::PointCloud*> clouds) {
    uint32_t components = 0, valueBytes = 0;
    for (const draco::PointCloud* pc : clouds) {
        if (uint32_t(pc->num_attributes()) > kMaxBlockAttributes)
            return Status::error("a block of " + std::to_string(pc->num_attributes()) + " attributes in one point cloud; readers allow " +
                                 std::to_string(kMaxBlockAttributes) + ": store fewer (--attributes)");
        for (int i = 0; i < pc->num_attributes(); ++i) {
            const draco::PointAttribute* a = pc->attribute(i);
            components += uint32_t(a->num_components());
            valueBytes += uint32_t(a->num_components() * draco::DataTypeLength(a->data_type()));
        }
    }
    const uint64_t footprint = blockDecodeBytes(uint32_t(n), components, valueBytes);
    if (n > kMaxBlockPoints || footprint > kMaxBlockDecodeBytes)
        return Status::error("a node of " + std::to_string(n) + " surfels with " + std::to_string(components) +
                             " attribute components would take " + std::to_string(footprint >> 20) +
                             " MiB to decode; readers allow " + std::to_string(kMaxBlockPoints) + " surfels and " +
                             std::to_string(kMaxBlockDecodeBytes >> 20) + " MiB: lower --capacity");
    return {};
}

Result<draco::EncoderBuffer> encode(const draco::PointCloud& pc, draco::PointCloudEncodingMethod method,
                                    const std::vector<std::pair<int, int>>& quantized) {
    draco::ExpertEncoder encoder(pc);
    encoder.SetEncodingMethod(method);
    encoder.SetSpeedOptions(kDracoSpeed, kDracoSpeed);
    for (auto [id, bits] : quantized) encoder.SetAttributeQuantization(id, bits);
    draco::EncoderBuffer buffer;
    draco::Status st = encoder.EncodeToBuffer(&buffer);
    if (!st.ok()) return Status::error(std::string("Draco encoding failed: ") + st.error_msg());
    return buffer;
}

// For each point of `decoded` (a kd-tree coding of `positions`, 3 per
// point), the index in `positions` of a point at its position, each index
// once: points at one position differ in no value the kd-tree holds, so any
// pairing of them is as good.
Result<std::vector<uint32_t>> decodedOrder(const std::vector<uint32_t>& positions, const draco::PointCloud& decoded) {
    const size_t n = positions.size() / 3;
    auto at = [&](uint32_t i) { return std::array{positions[3 * size_t(i)], positions[3 * size_t(i) + 1], positions[3 * size_t(i) + 2]}; };
    std::vector<uint32_t> sorted(n);
    std::iota(sorted.begin(), sorted.end(), 0u);
    std::sort(sorted.begin(), sorted.end(), [&](uint32_t a, uint32_t b) { return std::pair{at(a), a} < std::pair{at(b), b}; });
    if (size_t(decoded.num_points()) != n || decoded.num_attributes() != 1 || decoded.attribute(0)->num_components() != 3 ||
        decoded.attribute(0)->data_type() != draco::DT_UINT32)
        return Status::error("Draco decoded other positions than it encoded");
    std::vector<uint32_t> taken(n, 0), order(n);
    const draco::PointAttribute* a = decoded.attribute(0);
    for (draco::PointIndex i(0); i < decoded.num_points(); ++i) {
        std::array<uint32_t, 3> p;
        a->GetMappedValue(i, p.data());
        const auto first = std::lower_bound(sorted.begin(), sorted.end(), p, [&](uint32_t s, const auto& q) { return at(s) < q; });
        const size_t run = size_t(first - sorted.begin()), k = run + taken[run < n ? run : 0]++;
        if (run >= n || k >= n || at(sorted[k]) != p) return Status::error("Draco decoded other positions than it encoded");
        order[i.value()] = sorted[k];
    }
    return order;
}

std::vector<uint8_t> bytesOf(const draco::EncoderBuffer& b) { return std::vector<uint8_t>(b.data(), b.data() + b.size()); }

}  // namespace

Result<std::vector<uint8_t>> encodeBlock(const BlockData& block, const BlockCodecOptions& options) {
    const size_t n = block.size();
    assert(n > 0 && block.positions.size() == 3 * n);
    const bool columns = options.codec == BlockCodec::DracoColumns;
    draco::PointCloudBuilder kd;
    kd.Start(uint32_t(n));
    int pos = kd.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_UINT32);
    kd.SetAttributeValuesForAllPoints(pos, block.positions.data(), 3 * sizeof(uint32_t));
    std::vector<std::pair<int, int>> quantized;
    if (!columns) addOtherAttributes(kd, block, options, {}, false, &quantized);
    std::unique_ptr<draco::PointCloud> positions = kd.Finalize(false);
    if (!positions) return Status::error("Draco rejected the block's attributes");
    if (!columns) {
        SC_TRY(checkReadable(n, {positions.get()}));
        auto buffer = encode(*positions, draco::POINT_CLOUD_KD_TREE_ENCODING, quantized);
        if (!buffer) return buffer.status();
        return bytesOf(*buffer);
    }

    auto kdBuffer = encode(*positions, draco::POINT_CLOUD_KD_TREE_ENCODING, {});
    if (!kdBuffer) return kdBuffer.status();
    // The order the kd-tree's decoder gives the points in, which the columns follow.
    auto decoded = decodeCloud(reinterpret_cast<const uint8_t*>(kdBuffer->data()), kdBuffer->size(), "positions");
    if (!decoded) return decoded.status();
    auto order = decodedOrder(block.positions, **decoded);
    if (!order) return order.status();
    draco::PointCloudBuilder seq;
    seq.Start(uint32_t(n));
    addOtherAttributes(seq, block, options, *order, true, &quantized);
    std::unique_ptr<draco::PointCloud> others = seq.Finalize(false);
    if (!others) return Status::error("Draco rejected the block's attributes");
    SC_TRY(checkReadable(n, {positions.get(), others.get()}));
    std::vector<uint8_t> out(4);
    const uint32_t kdBytes = uint32_t(kdBuffer->size());  // a block is at most kMaxBlockDecodeBytes
    le::put(out.data(), kdBytes);
    out.insert(out.end(), kdBuffer->data(), kdBuffer->data() + kdBuffer->size());
    if (others->num_attributes() > 0) {
        auto buffer = encode(*others, draco::POINT_CLOUD_SEQUENTIAL_ENCODING, quantized);
        if (!buffer) return buffer.status();
        out.insert(out.end(), buffer->data(), buffer->data() + buffer->size());
    }
    return out;
}

namespace {
// What Draco sizes its buffers by, read from a block's header before Draco
// sees it, so that a block cannot make it allocate more than the node's
// record and the set's attributes allow (fuzz_block: 2.4 GB from a point
// count, 3.3 GB from the sequential decoder, 2 GB from attribute
// descriptors, 3 GB from a count within the record bound times many wide
// attributes). Header: "DRACO", major, minor, encoder type (0: point
// cloud), method (1: kd-tree, 0: sequential), u16 flags (no
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
// `kdTree`: the blob must be kd-tree coded, else sequentially; `what` names it in errors.
Result<DracoHeader> readDracoHeader(const uint8_t* data, size_t size, bool kdTree, const std::string& what) {
    if (size < 17 || std::memcmp(data, "DRACO", 5) != 0) return Status::error(what + " is not Draco");
    // The fields below sit where bitstream 2.x (Draco 1.5's) puts them.
    if (data[5] != 2)
        return Status::error(what + " is bitstream version " + std::to_string(data[5]) + "." + std::to_string(data[6]) +
                             "; readers take 2.x");
    if (data[7] != 0) return Status::error(what + " is not a point cloud");
    if (data[8] != (kdTree ? 1 : 0)) return Status::error(what + (kdTree ? " is not kd-tree coded" : " is not sequentially coded"));
    if ((data[9] | data[10] << 8) & 0x8000) return Status::error(what + " carries metadata");
    const int32_t count = le::get<int32_t>(data + 11);
    if (count < 0) return Status::error(what + " declares a negative point count");
    if (data[15] != 1) return Status::error(what + " has " + std::to_string(data[15]) + " attribute decoders, not 1");
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
    if (!varint(&h.attributes) || h.attributes > kMaxBlockAttributes) return Status::error(what + "'s attribute count is unreadable");
    for (uint32_t i = 0; i < h.attributes; ++i) {
        if (size - at < 4) return Status::error(what + " ends in its attribute descriptors");
        const uint8_t dataType = data[at + 1], components = data[at + 2];
        at += 4;
        uint32_t id;
        if (dataType < 1 || dataType > 11 || components < 1 || components > 4 || !varint(&id))
            return Status::error(what + "'s attribute " + std::to_string(i) + " has " +
                                 std::to_string(components) + " components of type " + std::to_string(dataType));
        h.components += components;
        h.valueBytes += components * dracoTypeBytes(dataType);
    }
    return h;
}
}  // namespace

namespace {

// The blobs of a block and the attributes they must hold: the expectation's
// checks, before Draco allocates anything.
struct Blobs {
    const uint8_t* first = nullptr;  // every attribute (draco), or the positions (draco-columns)
    size_t firstSize = 0;
    const uint8_t* columns = nullptr;  // draco-columns: the other attributes; null where there are none
    size_t columnsSize = 0;
};

Result<Blobs> checkBlock(const uint8_t* data, size_t size, const BlockExpectation& expect) {
    const bool split = expect.codec == BlockCodec::DracoColumns;
    int others = expect.normals + (expect.colorBits != 0) + expect.weights + expect.radii + expect.edgeWeights;
    for (size_t e = 0; e < expect.extra.size(); ++e) others += expect.splitsColumn(e) ? 2 : 1;
    Blobs b;
    if (!split) {
        b = {data, size, nullptr, 0};
    } else {
        if (size < 4) return Status::error("the block ends before its positions blob's length");
        const uint32_t kdBytes = le::get<uint32_t>(data);
        if (kdBytes > size - 4)
            return Status::error("the block's positions blob of " + std::to_string(kdBytes) + " bytes runs past its end (" +
                                 std::to_string(size) + " bytes)");
        b = {data + 4, kdBytes, data + 4 + kdBytes, size - 4 - kdBytes};
        if (others == 0 && b.columnsSize > 0)
            return Status::error("the block has " + std::to_string(b.columnsSize) + " bytes past its positions; the tile set declares no other attribute");
        if (others == 0) b.columns = nullptr;
    }
    const std::string what = split ? "the positions blob" : "the block";
    std::vector<DracoHeader> headers;
    for (auto [blob, blobSize, kdTree, name, attributes] :
         {std::tuple{b.first, b.firstSize, true, what, split ? 1 : 1 + others},
          std::tuple{b.columns, b.columnsSize, false, std::string("the columns blob"), others}}) {
        if (!blob) continue;
        auto header = readDracoHeader(blob, blobSize, kdTree, name);
        if (!header) return header.status();
        if (expect.points ? header->points != expect.points : header->points > kMaxBlockPoints)
            return Status::error(name + " declares " + std::to_string(header->points) + " points; the tile set " +
                                 (expect.points ? "declares " + std::to_string(expect.points)
                                                : "allows at most " + std::to_string(kMaxBlockPoints)));
        if (header->attributes != uint32_t(attributes))
            return Status::error(name + " has " + std::to_string(header->attributes) + " attributes; the tile set declares " +
                                 std::to_string(attributes));
        if (!headers.empty() && header->points != headers[0].points)
            return Status::error("the columns blob declares " + std::to_string(header->points) + " points, the positions blob " +
                                 std::to_string(headers[0].points));
        headers.push_back(*header);
    }
    uint32_t components = 0, valueBytes = 0;
    for (const DracoHeader& h : headers) components += h.components, valueBytes += h.valueBytes;
    const uint64_t footprint = blockDecodeBytes(headers[0].points, components, valueBytes);
    if (footprint > kMaxBlockDecodeBytes)
        return Status::error("the block's " + std::to_string(headers[0].points) + " points of " + std::to_string(components) +
                             " components would take " + std::to_string(footprint >> 20) + " MiB to decode; at most " +
                             std::to_string(kMaxBlockDecodeBytes >> 20) + " MiB is allowed");
    return b;
}

}  // namespace

Result<BlockData> decodeBlock(const uint8_t* data, size_t size, const BlockExpectation& expect) {
    auto blobs = checkBlock(data, size, expect);
    if (!blobs) return blobs.status();
    const bool split = expect.codec == BlockCodec::DracoColumns;
    // Draco made one attribute per descriptor readDracoHeader counted.
    auto first = decodeCloud(blobs->first, blobs->firstSize, split ? "positions" : "block");
    if (!first) return first.status();
    std::unique_ptr<draco::PointCloud> columns;
    if (blobs->columns) {
        auto decoded = decodeCloud(blobs->columns, blobs->columnsSize, "columns");
        if (!decoded) return decoded.status();
        columns = std::move(*decoded);
        if (columns->num_points() != (*first)->num_points())
            return Status::error("the columns blob decodes to " + std::to_string(columns->num_points()) + " points, the positions to " +
                                 std::to_string((*first)->num_points()));
    }
    BlockData block;
    bool ok = readAttribute(**first, 0, draco::DT_UINT32, 3, &block.positions);
    // The other attributes, in block order, from the columns blob or after the positions.
    const draco::PointCloud& pc = columns ? *columns : **first;
    int index = columns ? 0 : 1;
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
    for (size_t e = 0; e < expect.extra.size() && ok; ++e) {
        const std::string& name = expect.extra[e];
        const bool halves = expect.splitsColumn(e);
        // The LiDAR attributes and the opacity have their own types, never two columns.
        if (halves && (lidarIndex(name) >= 0 || name == kOpacityAttribute)) ok = false;
        else if (name == "intensity") ok = readAttribute(pc, index, draco::DT_UINT16, 1, &block.intensity);
        else if (name == "classification") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.classification);
        else if (name == "return_number") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.returnNumber);
        else if (name == "number_of_returns") ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.numberOfReturns);
        else if (name == kOpacityAttribute) ok = readAttribute(pc, index, draco::DT_UINT8, 1, &block.opacity);
        else if (expect.scalars && !halves) ok = readScalar(pc, index, name, &block.scalars);
        else if (expect.scalars) ok = readHalves(pc, index, name, &block.scalars);
        index += halves ? 2 : 1;  // any other: a newer writer's attribute, skipped
    }
    if (!ok) return Status::error("block attribute " + std::to_string(index - 1) + " has an unexpected type or size");
    return block;
}

}  // namespace surfcast
