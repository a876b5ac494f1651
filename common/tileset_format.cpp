#include "tileset_format.h"

#include "block_codec.h"
#include "las_format.h"

#include <algorithm>
#include <set>
#include <cmath>
#include <limits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <utility>

#include "byte_io.h"
#include "crc32.h"

namespace surfcast {

void encodeRecord(const NodeRecord& r, uint8_t out[kRecordSize]) {
    std::memset(out, 0, kRecordSize);
    out[0] = r.key.level;
    out[1] = r.childMask;
    le::put<uint16_t>(out + 2, r.flags);
    le::put<uint32_t>(out + 4, r.key.x);
    le::put<uint32_t>(out + 8, r.key.y);
    le::put<uint32_t>(out + 12, r.key.z);
    le::put<uint64_t>(out + 16, r.blockOffset);
    le::put<uint32_t>(out + 24, r.blockSize);
    le::put<uint32_t>(out + 28, r.blockCrc);
    le::put<uint32_t>(out + 32, r.surfelCount);
    le::put<float>(out + 36, r.spacing);
    le::put<float>(out + 40, r.coneAxis.x);
    le::put<float>(out + 44, r.coneAxis.y);
    le::put<float>(out + 48, r.coneAxis.z);
    le::put<float>(out + 52, r.coneCosHalfAngle);
    out[56] = r.positionBits;  // 57..59 reserved, zero
    le::put<uint32_t>(out + 60, r.childPage);
}

NodeRecord decodeRecord(const uint8_t in[kRecordSize]) {
    NodeRecord r;
    r.key.level = in[0];
    r.childMask = in[1];
    r.flags = le::get<uint16_t>(in + 2);
    r.key.x = le::get<uint32_t>(in + 4);
    r.key.y = le::get<uint32_t>(in + 8);
    r.key.z = le::get<uint32_t>(in + 12);
    r.blockOffset = le::get<uint64_t>(in + 16);
    r.blockSize = le::get<uint32_t>(in + 24);
    r.blockCrc = le::get<uint32_t>(in + 28);
    r.surfelCount = le::get<uint32_t>(in + 32);
    r.spacing = le::get<float>(in + 36);
    r.coneAxis = {le::get<float>(in + 40), le::get<float>(in + 44), le::get<float>(in + 48)};
    r.coneCosHalfAngle = le::get<float>(in + 52);
    r.positionBits = in[56];
    r.childPage = le::get<uint32_t>(in + 60);
    return r;
}

namespace {

// The records in their on-disk order: pages breadth first from the root page,
// each page breadth first, with the page links set. Every page but the first
// starts with its root, which its parent page holds too.
std::vector<std::vector<NodeRecord>> paginate(const std::vector<NodeRecord>& nodes, uint32_t pageDepth) {
    assert(pageDepth >= 2);
    std::map<NodeKey, NodeRecord> byKey;
    for (const NodeRecord& n : nodes) byKey[n.key] = n;

    std::vector<std::vector<NodeRecord>> pages;
    std::deque<NodeKey> pageRoots;
    if (!byKey.empty()) pageRoots.push_back(NodeKey{});
    while (!pageRoots.empty()) {
        NodeKey pageRoot = pageRoots.front();
        pageRoots.pop_front();
        std::vector<NodeRecord> page;
        std::deque<NodeKey> queue{pageRoot};
        while (!queue.empty()) {
            NodeRecord rec = byKey.at(queue.front());
            queue.pop_front();
            rec.flags &= uint16_t(~kFlagChildrenInPage);
            rec.childPage = kNoPage;
            bool atPageBottom = uint32_t(rec.key.level - pageRoot.level) == pageDepth - 1;
            if (atPageBottom && rec.childMask) {
                rec.flags |= kFlagChildrenInPage;
                rec.childPage = uint32_t(pages.size() + 1 + pageRoots.size());
                pageRoots.push_back(rec.key);
            } else {
                for (int i = 0; i < 8; ++i)
                    if (rec.childMask & (1u << i)) queue.push_back(rec.key.child(i));
            }
            page.push_back(rec);
        }
        pages.push_back(std::move(page));
    }
    return pages;
}

}  // namespace

std::vector<NodeKey> hierarchyOrder(const std::vector<NodeRecord>& nodes, uint32_t pageDepth) {
    std::vector<NodeKey> order;
    const auto pages = paginate(nodes, pageDepth);
    for (size_t p = 0; p < pages.size(); ++p)
        for (size_t i = p == 0 ? 0 : 1; i < pages[p].size(); ++i) order.push_back(pages[p][i].key);  // a page root is its parent page's too
    return order;
}

std::vector<uint8_t> writeHierarchy(std::vector<NodeRecord> nodes, uint32_t pageDepth) {
    const std::vector<std::vector<NodeRecord>> pages = paginate(nodes, pageDepth);
    size_t tableEnd = kHierarchyHeaderSize + pages.size() * kPageEntrySize;
    size_t total = tableEnd;
    for (const auto& p : pages) total += p.size() * kRecordSize;
    std::vector<uint8_t> out(total, 0);
    uint64_t offset = tableEnd;
    for (size_t i = 0; i < pages.size(); ++i) {
        uint8_t* pageStart = out.data() + offset;
        for (size_t j = 0; j < pages[i].size(); ++j) encodeRecord(pages[i][j], pageStart + j * kRecordSize);
        size_t bytes = pages[i].size() * kRecordSize;
        uint8_t* entry = out.data() + kHierarchyHeaderSize + i * kPageEntrySize;
        le::put<uint64_t>(entry, offset);
        le::put<uint32_t>(entry + 8, uint32_t(pages[i].size()));
        le::put<uint32_t>(entry + 12, crc32(pageStart, bytes));
        offset += bytes;
    }
    std::memcpy(out.data(), kHierarchyMagic, 4);
    le::put<uint32_t>(out.data() + 4, kFormatVersion);
    le::put<uint32_t>(out.data() + 8, kRecordSize);
    le::put<uint32_t>(out.data() + 12, uint32_t(pages.size()));
    le::put<uint32_t>(out.data() + 16, pageDepth);
    const size_t records = (total - tableEnd) / kRecordSize;
    le::put<uint32_t>(out.data() + 20, uint32_t(pages.empty() ? 0 : records - (pages.size() - 1)));  // page roots once
    le::put<uint32_t>(out.data() + 24, crc32(out.data() + kHierarchyHeaderSize, tableEnd - kHierarchyHeaderSize));
    return out;
}

Result<HierarchyIndex> readHierarchyIndex(std::span<const uint8_t> bytes, uint64_t fileBytes, const std::string& what) {
    auto fail = [&](const std::string& why) { return Status::error(what + ": " + why); };
    if (bytes.size() < kHierarchyHeaderSize || fileBytes < kHierarchyHeaderSize)
        return fail("shorter than the 32-byte header");
    const uint8_t* b = bytes.data();
    if (std::memcmp(b, kHierarchyMagic, 4) != 0) return fail("bad magic at byte 0 (expected SCHY)");
    if (le::get<uint32_t>(b + 4) < uint32_t(kOldestFormatVersion) || le::get<uint32_t>(b + 4) > uint32_t(kFormatVersion))
        return fail("unsupported version " + std::to_string(le::get<uint32_t>(b + 4)) + " at byte 4");
    if (le::get<uint32_t>(b + 8) != kRecordSize) return fail("record size at byte 8 is not 64");
    const uint64_t pageCount = le::get<uint32_t>(b + 12);
    const uint64_t tableEnd = kHierarchyHeaderSize + pageCount * kPageEntrySize;
    if (tableEnd > fileBytes || tableEnd > bytes.size()) return fail("page table runs past the end of the file");
    if (crc32(b + kHierarchyHeaderSize, tableEnd - kHierarchyHeaderSize) != le::get<uint32_t>(b + 24))
        return fail("page table CRC mismatch");
    HierarchyIndex index;
    index.pageDepth = le::get<uint32_t>(b + 16);
    index.nodeCount = le::get<uint32_t>(b + 20);
    index.pages.resize(pageCount);  // bounded: the table is inside `bytes`
    for (uint64_t p = 0; p < pageCount; ++p) {
        const uint8_t* entry = b + kHierarchyHeaderSize + p * kPageEntrySize;
        HierarchyPageEntry& e = index.pages[p];
        e.offset = le::get<uint64_t>(entry);
        e.records = le::get<uint32_t>(entry + 8);
        e.crc = le::get<uint32_t>(entry + 12);
        if (e.records == 0 || e.offset < tableEnd || e.offset > fileBytes || uint64_t(e.records) * kRecordSize > fileBytes - e.offset)
            return fail("page " + std::to_string(p) + " at byte " + std::to_string(e.offset) + ": out of the file's bounds");
    }
    return index;
}

Result<std::vector<NodeRecord>> readHierarchyPage(const HierarchyIndex& index, uint32_t page, std::span<const uint8_t> bytes,
                                                  const NodeKey& root, uint64_t blocksBytes, const std::string& what) {
    if (page >= index.pages.size()) return Status::error(what + ": no page " + std::to_string(page));
    const HierarchyPageEntry& entry = index.pages[page];
    const std::string where = what + ": page " + std::to_string(page) + " at byte " + std::to_string(entry.offset);
    auto fail = [&](const std::string& why) { return Status::error(where + ": " + why); };
    if (bytes.size() != uint64_t(entry.records) * kRecordSize)
        return fail(std::to_string(bytes.size()) + " bytes, not the " + std::to_string(entry.records) + " records of the page table");
    if (crc32(bytes.data(), bytes.size()) != entry.crc) return fail("CRC mismatch");
    std::vector<NodeRecord> recs(entry.records);
    for (size_t i = 0; i < recs.size(); ++i) recs[i] = decodeRecord(bytes.data() + i * kRecordSize);
    if (recs[0].key != root) return fail("page root does not match the record that points to it");
    size_t next = 1;
    for (const NodeRecord& r : recs) {
        const std::string node = "node " + r.key.name();
        if (r.key.level > kMaxLevel) return fail(node + ": level beyond " + std::to_string(kMaxLevel));
        if (r.blockOffset > blocksBytes || r.blockSize > blocksBytes - r.blockOffset)
            return fail(node + " points past the end of blocks.bin (block offset + size: " + std::to_string(r.blockOffset) +
                        " + " + std::to_string(r.blockSize) + " of " + std::to_string(blocksBytes) + " bytes)");
        // Positions are min + q * edge / (2^b - 1): b = 0 divides by zero, b >= 64
        // shifts past a u64; h sizes every splat.
        if (r.positionBits < 1 || r.positionBits > kMaxPositionBits)
            return fail(node + ": " + std::to_string(r.positionBits) + " position bits, not 1 to " + std::to_string(kMaxPositionBits));
        if (!(std::isfinite(r.spacing) && r.spacing > 0))
            return fail(node + ": spacing " + std::to_string(r.spacing) + " is not a positive number");
        // Decoders size buffers by this count (decodeBlock checks the block against it).
        if (r.surfelCount > kMaxBlockPoints)
            return fail(node + " declares " + std::to_string(r.surfelCount) + " surfels, more than the " +
                        std::to_string(kMaxBlockPoints) + " a node may hold");
        if (r.flags & kFlagChildrenInPage) {
            if (r.childPage <= page || r.childPage >= index.pages.size() || r.childMask == 0)
                return fail(node + ": bad child page " + std::to_string(r.childPage));
            continue;
        }
        for (int c = 0; c < 8; ++c) {
            if (!(r.childMask & (1u << c))) continue;
            if (next >= recs.size() || recs[next].key != r.key.child(c)) return fail("children of " + node + " out of order");
            ++next;
        }
    }
    if (next != recs.size()) return fail("records not reachable from the page root");
    if (page > 0) recs.erase(recs.begin());
    return recs;
}

namespace {
Result<std::vector<NodeRecord>> readPages(const std::vector<uint8_t>& bytes, uint64_t blocksBytes, const std::string& what) {
    auto index = readHierarchyIndex(bytes, bytes.size(), what);
    if (!index) return index.status();
    const size_t pageCount = index->pages.size();
    std::vector<int> referenced(pageCount, 0);
    std::vector<NodeKey> rootOf(pageCount);  // from each page's proxy
    std::vector<NodeRecord> nodes;
    for (uint32_t p = 0; p < pageCount; ++p) {
        if (p > 0 && referenced[p] != 1)
            return Status::error(what + ": page " + std::to_string(p) + " is referenced by " + std::to_string(referenced[p]) +
                                 " records, not one");
        const HierarchyPageEntry& e = index->pages[p];
        auto recs = readHierarchyPage(*index, p, std::span(bytes).subspan(e.offset, size_t(e.records) * kRecordSize), rootOf[p],
                                      blocksBytes, what);
        if (!recs) return recs.status();
        for (const NodeRecord& r : *recs)
            if (r.flags & kFlagChildrenInPage) {
                referenced[r.childPage]++;
                rootOf[r.childPage] = r.key;
            }
        nodes.insert(nodes.end(), recs->begin(), recs->end());
    }
    if (nodes.size() != index->nodeCount) return Status::error(what + ": node count in header does not match the pages");
    return nodes;
}
}  // namespace

Result<std::vector<NodeRecord>> readHierarchy(const std::vector<uint8_t>& bytes, const std::string& what) {
    return readPages(bytes, ~uint64_t(0), what);
}

namespace {
using ordered_json = nlohmann::ordered_json;
ordered_json vec(const Vec3d& v) { return ordered_json::array({v.x, v.y, v.z}); }
}  // namespace

namespace {
std::string hex(const std::vector<uint8_t>& bytes) {
    static const char digits[] = "0123456789abcdef";
    std::string out;
    for (uint8_t b : bytes) out += digits[b >> 4], out += digits[b & 15];
    return out;
}
nlohmann::ordered_json lasJson(const LasSourceInfo& las) {
    nlohmann::ordered_json j = nlohmann::ordered_json::object();
    if (las.pointFormat >= 0) j["point_format"] = las.pointFormat;
    if (las.gpsTimeType >= 0) j["gps_time_type"] = las.gpsTimeType;
    if (!las.systemIdentifier.empty()) j["system_identifier"] = las.systemIdentifier;
    if (!las.generatingSoftware.empty()) j["generating_software"] = las.generatingSoftware;
    if (las.colorMultiplier != 257) j["color_multiplier"] = las.colorMultiplier;
    if (las.creationYear >= 0) j["creation"] = {{"day", las.creationDay}, {"year", las.creationYear}};
    if (las.scale.x > 0) {
        j["scale"] = {las.scale.x, las.scale.y, las.scale.z};
        j["offset"] = {las.offset.x, las.offset.y, las.offset.z};
    }
    if (!las.crsVlrs.empty()) {
        nlohmann::ordered_json vlrs = nlohmann::ordered_json::array();
        for (const auto& [record, payload] : las.crsVlrs) vlrs.push_back({{"record", record}, {"data", hex(payload)}});
        j["crs_vlrs"] = vlrs;
    }
    if (!las.extraBytes.empty()) {
        nlohmann::ordered_json eb = nlohmann::ordered_json::array();
        for (const std::vector<uint8_t>& d : las.extraBytes) eb.push_back(hex(d));
        j["extra_bytes"] = eb;
    }
    return j;
}
}  // namespace

std::string writeTilesetJson(const TilesetInfo& info) {
    ordered_json j;
    j["format"] = "surfcast-tileset";
    j["version"] = info.blocksParts.empty() ? kFormatVersion : kPartsFormatVersion;
    j["generator"] = info.generator;
    j["input_points"] = info.inputPoints;
    j["surfels"] = info.surfels;
    j["nodes"] = info.nodes;
    j["levels"] = info.levels;
    j["grid"] = info.grid;
    j["root"] = {{"min", vec(info.rootMin)}, {"edge", info.rootEdge}};
    j["bounds"] = {{"min", vec(info.bounds.min)}, {"max", vec(info.bounds.max)}};
    j["color_bits"] = info.colorBits;
    ordered_json attrs = ordered_json::array();
    for (const AttributeInfo& a : info.attributes) {
        ordered_json e = {{"name", a.name}, {"type", a.type}, {"components", a.components},
                          {"quantization_bits", a.quantizationBits}};
        if (!a.kind.empty()) {
            e["kind"] = a.kind;
            e["scale"] = a.scale;
            e["offset"] = a.offset;
        }
        attrs.push_back(e);
    }
    j["attributes"] = attrs;
    if (!info.constants.empty()) {
        ordered_json constants = ordered_json::array();
        for (const ConstantAttribute& c : info.constants) constants.push_back({{"name", c.name}, {"value", c.value}});
        j["constants"] = constants;
    }
    if (!info.leftOut.empty()) j["left_out"] = info.leftOut;
    if (info.las.present) j["las"] = lasJson(info.las);
    if (info.duplicatesKept) j["duplicates"] = "kept";
    if (info.previewStride) {
        j["preview"] = {{"stride", info.previewStride}};
        if (info.previewDone > 0) j["preview"]["done"] = info.previewDone;
    }
    const TilesetStatistics& st = info.statistics;
    ordered_json stats = {{"elevation", {{"min", st.elevationMin}, {"max", st.elevationMax}}}};
    if (st.intensity)
        stats["intensity"] = {{"min", st.intensityMin}, {"max", st.intensityMax}, {"p2", st.intensityP2}, {"p98", st.intensityP98}};
    if (!st.classCounts.empty()) {
        ordered_json counts = ordered_json::object();
        for (auto [c, n] : st.classCounts) counts[std::to_string(c)] = n;
        stats["classification"] = {{"counts", counts}};
    }
    j["statistics"] = stats;
    j["normal_source"] = info.normalSource;
    j["weights"] = info.weights;
    j["kernel_scale"] = info.kernelScale;
    if (!info.textureFilter.empty()) j["texture_filter"] = info.textureFilter;
    if (!info.inputs.empty()) j["inputs"] = info.inputs;
    j["hierarchy"] = {{"file", info.hierarchyFile}, {"bytes", info.hierarchyBytes}, {"pages", info.hierarchyPages},
                      {"page_depth", info.pageDepth}, {"crc32", info.hierarchyCrc}};
    j["blocks"] = {{"file", info.blocksParts.empty() ? std::string("blocks.bin") : info.blocksParts[0].file}, {"bytes", info.blocksBytes},
                   {"codec", blockCodecName(info.blockCodec)}};
    if (!info.blocksParts.empty()) {
        ordered_json parts = ordered_json::array();
        for (const BlocksPart& p : info.blocksParts) parts.push_back({{"file", p.file}, {"bytes", p.bytes}});
        j["blocks"]["parts"] = parts;
    }
    return j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

namespace {
// tileset.json's fields, each read with its path ("hierarchy.bytes",
// "attributes[2].scale") in the error, which tests/conformance/tileset_json.json
// asks of both readers. Integers are read through integer(): nlohmann's
// get<int>() casts a fraction or an out-of-range number unchecked (undefined
// for 1e70: fuzz_tileset).
struct FieldError : std::runtime_error {
    using std::runtime_error::runtime_error;
};
// A value quoted in an error: at most about 60 bytes of it, cut between characters.
std::string shown(const nlohmann::json& v) {
    std::string s = v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    if (s.size() <= 64) return s;
    size_t cut = 60;
    while (cut > 0 && (uint8_t(s[cut]) & 0xC0) == 0x80) --cut;
    return s.substr(0, cut) + "...";
}
std::string joined(const std::string& parent, const std::string& key) { return parent.empty() ? key : parent + "." + key; }
[[noreturn]] void fieldError(const std::string& path, const std::string& why) { throw FieldError(path + ": " + why); }

const nlohmann::json& member(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    if (!o.is_object() || !o.contains(key)) fieldError(joined(parent, key), "missing");
    return o.at(key);
}
const nlohmann::json& object(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = member(o, parent, key);
    if (!v.is_object()) fieldError(joined(parent, key), "not an object");
    return v;
}
const nlohmann::json& array(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = member(o, parent, key);
    if (!v.is_array()) fieldError(joined(parent, key), "not an array");
    return v;
}
std::vector<std::string> strings(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = array(o, parent, key);
    std::vector<std::string> out;
    for (size_t i = 0; i < v.size(); ++i) {
        if (!v[i].is_string()) fieldError(joined(parent, key) + "[" + std::to_string(i) + "]", "not a string");
        out.push_back(v[i].get<std::string>());
    }
    return out;
}
// JSON has one kind of number: 2.0 and 1e2 are the integers 2 and 100 (as in
// JavaScript, whose reader agrees).
template <class T>
T integer(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = member(o, parent, key);
    if (v.is_number_unsigned() && std::in_range<T>(v.get<uint64_t>())) return T(v.get<uint64_t>());
    if (v.is_number_integer() && !v.is_number_unsigned() && std::in_range<T>(v.get<int64_t>())) return T(v.get<int64_t>());
    if (v.is_number_float()) {
        const double d = v.get<double>();
        // Both bounds are exact in a double (2^63 and 2^64 for the 64-bit types).
        const double below = double(std::numeric_limits<T>::min()), beyond = 2.0 * (double(std::numeric_limits<T>::max() / 2) + 1);
        if (std::isfinite(d) && d == std::floor(d) && d >= below && d < beyond) return T(d);
    }
    fieldError(joined(parent, key), shown(v) + " is not an integer in its range");
}
double number(const nlohmann::json& v, const std::string& path) {
    if (!v.is_number() || !std::isfinite(v.get<double>())) fieldError(path, shown(v) + " is not a finite number");
    return v.get<double>();
}
double number(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    return number(member(o, parent, key), joined(parent, key));
}
std::string text(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = member(o, parent, key);
    if (!v.is_string()) fieldError(joined(parent, key), shown(v) + " is not a string");
    return v.get<std::string>();
}
Vec3d vec3(const nlohmann::json& o, const std::string& parent, const std::string& key) {
    const nlohmann::json& v = member(o, parent, key);
    const std::string path = joined(parent, key);
    if (!v.is_array() || v.size() != 3) fieldError(path, "not an array of three numbers");
    return {number(v[0], path), number(v[1], path), number(v[2], path)};
}
// Hex digits into bytes, at most `most` of them.
std::vector<uint8_t> unhex(const nlohmann::json& v, const std::string& path, size_t most) {
    if (!v.is_string()) fieldError(path, shown(v) + " is not a string");
    const std::string& s = v.get_ref<const std::string&>();
    if (s.size() % 2 || s.size() / 2 > most) fieldError(path, "not hex digits of at most " + std::to_string(most) + " bytes");
    std::vector<uint8_t> out(s.size() / 2);
    for (size_t i = 0; i < s.size(); ++i) {
        const char c = s[i];
        const int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
        if (d < 0) fieldError(path, "not hex digits");
        out[i / 2] = uint8_t(out[i / 2] << 4 | d);
    }
    return out;
}
// LAS's VLR payloads are at most 65,535 bytes.
constexpr size_t kMaxVlrPayload = 65535;
LasSourceInfo readLas(const nlohmann::json& j) {
    LasSourceInfo las;
    las.present = true;
    if (j.contains("point_format")) {
        las.pointFormat = integer<int>(j, "las", "point_format");
        if (las.pointFormat < 0 || las.pointFormat > 10) fieldError("las.point_format", "not 0 to 10");
    }
    if (j.contains("gps_time_type")) {
        las.gpsTimeType = integer<int>(j, "las", "gps_time_type");
        if (las.gpsTimeType != 0 && las.gpsTimeType != 1) fieldError("las.gps_time_type", "not 0 or 1");
    }
    if (j.contains("color_multiplier")) {
        las.colorMultiplier = integer<int>(j, "las", "color_multiplier");
        if (las.colorMultiplier != 1 && las.colorMultiplier != 256 && las.colorMultiplier != 257)
            fieldError("las.color_multiplier", "not 1, 256 or 257");
    }
    if (j.contains("system_identifier")) las.systemIdentifier = text(j, "las", "system_identifier");
    if (j.contains("generating_software")) las.generatingSoftware = text(j, "las", "generating_software");
    if (j.contains("creation")) {
        const nlohmann::json& c = object(j, "las", "creation");
        las.creationDay = integer<uint16_t>(c, "las.creation", "day");
        las.creationYear = integer<uint16_t>(c, "las.creation", "year");
    }
    if (j.contains("scale")) {
        las.scale = vec3(j, "las", "scale");
        las.offset = vec3(j, "las", "offset");
        if (!(las.scale.x > 0 && las.scale.y > 0 && las.scale.z > 0)) fieldError("las.scale", "not positive");
    }
    if (j.contains("crs_vlrs")) {
        const nlohmann::json& vlrs = array(j, "las", "crs_vlrs");
        for (size_t i = 0; i < vlrs.size(); ++i) {
            const std::string at = "las.crs_vlrs[" + std::to_string(i) + "]";
            if (!vlrs[i].is_object()) fieldError(at, "not an object");
            las.crsVlrs.push_back({integer<uint16_t>(vlrs[i], at, "record"), unhex(member(vlrs[i], at, "data"), at + ".data", kMaxVlrPayload)});
        }
    }
    if (j.contains("extra_bytes")) {
        const nlohmann::json& eb = array(j, "las", "extra_bytes");
        if (eb.size() > kMaxVlrPayload / las::kDescriptorBytes) fieldError("las.extra_bytes", "more than the 341 descriptors a VLR holds");
        for (size_t i = 0; i < eb.size(); ++i) {
            const std::string at = "las.extra_bytes[" + std::to_string(i) + "]";
            las.extraBytes.push_back(unhex(eb[i], at, las::kDescriptorBytes));
            const std::vector<uint8_t>& d = las.extraBytes.back();
            if (d.size() != las::kDescriptorBytes) fieldError(at, "not a 192-byte descriptor");
            // One scalar of data type 1-10 (LAS 1.4 R15, table 24), a finite non-zero scale where it has one.
            double scale = 1, offset = 0;
            std::memcpy(&scale, &d[112], 8);
            std::memcpy(&offset, &d[136], 8);
            if (d[2] < 1 || d[2] > 10) fieldError(at, "data type " + std::to_string(d[2]) + " is not 1 to 10");
            if (((d[3] & 8) && (scale == 0 || !std::isfinite(scale))) || ((d[3] & 16) && !std::isfinite(offset)))
                fieldError(at, "scale or offset is not a finite non-zero number");
        }
    }
    return las;
}
}  // namespace

Result<TilesetInfo> readTilesetJson(const std::string& json, const std::string& what) {
    const nlohmann::json j = nlohmann::json::parse(json, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) return Status::error(what + ": not valid JSON");
    if (!j.is_object()) return Status::error(what + ": not a JSON object");
    try {
        if (text(j, "", "format") != "surfcast-tileset") fieldError("format", "not \"surfcast-tileset\"");
        TilesetInfo info;
        info.version = integer<int>(j, "", "version");
        if (info.version < kOldestFormatVersion || info.version > kPartsFormatVersion)
            fieldError("version", "unsupported version " + std::to_string(info.version) + " (this reader takes " +
                                      std::to_string(kOldestFormatVersion) + " to " + std::to_string(kPartsFormatVersion) + ")");
        info.generator = text(j, "", "generator");
        info.inputPoints = integer<uint64_t>(j, "", "input_points");
        info.surfels = integer<uint64_t>(j, "", "surfels");
        info.nodes = integer<uint64_t>(j, "", "nodes");
        info.levels = integer<int>(j, "", "levels");
        if (info.levels < 1 || info.levels > kMaxLevel + 1)
            fieldError("levels", std::to_string(info.levels) + " is not 1 to " + std::to_string(kMaxLevel + 1));
        info.grid = integer<int>(j, "", "grid");
        if (info.grid < 1) fieldError("grid", std::to_string(info.grid) + " is not positive");
        const nlohmann::json& root = object(j, "", "root");
        info.rootMin = vec3(root, "root", "min");
        info.rootEdge = number(root, "root", "edge");
        if (!(info.rootEdge > 0)) fieldError("root.edge", "not positive");
        const nlohmann::json& bounds = object(j, "", "bounds");
        info.bounds.min = vec3(bounds, "bounds", "min");
        info.bounds.max = vec3(bounds, "bounds", "max");
        info.colorBits = integer<int>(j, "", "color_bits");
        if (info.colorBits != 0 && info.colorBits != 8 && info.colorBits != 16)
            fieldError("color_bits", std::to_string(info.colorBits) + ", not 0, 8 or 16");
        const nlohmann::json& attributes = array(j, "", "attributes");
        for (size_t i = 0; i < attributes.size(); ++i) {
            const nlohmann::json& a = attributes[i];
            const std::string at = "attributes[" + std::to_string(i) + "]";
            if (!a.is_object()) fieldError(at, "not an object");
            AttributeInfo added{text(a, at, "name"), text(a, at, "type"), integer<int>(a, at, "components"),
                                integer<int>(a, at, "quantization_bits")};
            if (a.contains("kind")) added.kind = text(a, at, "kind");
            if (a.contains("scale")) added.scale = number(a, at, "scale");
            if (a.contains("offset")) added.offset = number(a, at, "offset");
            const std::string of = " (attribute " + added.name + ")";
            if (added.scale == 0) fieldError(at + ".scale", "0" + of);
            if (added.components < 1 || added.components > 4)
                fieldError(at + ".components", std::to_string(added.components) + " is not 1 to 4" + of);
            // Draco quantizes with 1 to 30 bits; 0 means not quantized.
            if (added.quantizationBits < 0 || added.quantizationBits > 30)
                fieldError(at + ".quantization_bits", std::to_string(added.quantizationBits) + " is not 0 to 30" + of);
            info.attributes.push_back(std::move(added));
        }
        if (j.contains("constants")) {
            const nlohmann::json& constants = array(j, "", "constants");
            for (size_t i = 0; i < constants.size(); ++i) {
                const std::string at = "constants[" + std::to_string(i) + "]";
                if (!constants[i].is_object()) fieldError(at, "not an object");
                info.constants.push_back({text(constants[i], at, "name"), number(constants[i], at, "value")});
            }
        }
        if (j.contains("left_out")) info.leftOut = strings(j, "", "left_out");
        if (j.contains("las")) info.las = readLas(object(j, "", "las"));
        if (j.contains("preview")) {
            const nlohmann::json& preview = object(j, "", "preview");
            info.previewStride = integer<uint32_t>(preview, "preview", "stride");
            if (info.previewStride == 0) fieldError("preview.stride", "0 is not a stride");
            if (preview.contains("done")) {
                info.previewDone = number(preview, "preview", "done");
                if (!(info.previewDone >= 0 && info.previewDone < 1)) fieldError("preview.done", "not in [0, 1)");
            }
        }
        if (j.contains("duplicates")) {
            const std::string d = text(j, "", "duplicates");
            if (d != "kept" && d != "merged") fieldError("duplicates", "'" + d + "' is not kept or merged");
            info.duplicatesKept = d == "kept";
        }
        // Absent in version 1: the elevation range is the bounds'.
        TilesetStatistics& st = info.statistics;
        st.elevationMin = info.bounds.min.z;
        st.elevationMax = info.bounds.max.z;
        if (j.contains("statistics")) {
            const nlohmann::json& js = object(j, "", "statistics");
            const nlohmann::json& elevation = object(js, "statistics", "elevation");
            st.elevationMin = number(elevation, "statistics.elevation", "min");
            st.elevationMax = number(elevation, "statistics.elevation", "max");
            if (js.contains("intensity")) {
                const nlohmann::json& ji = object(js, "statistics", "intensity");
                st.intensity = true;
                st.intensityMin = number(ji, "statistics.intensity", "min");
                st.intensityMax = number(ji, "statistics.intensity", "max");
                st.intensityP2 = number(ji, "statistics.intensity", "p2");
                st.intensityP98 = number(ji, "statistics.intensity", "p98");
            }
            if (js.contains("classification")) {
                const nlohmann::json& counts = object(object(js, "statistics", "classification"), "statistics.classification", "counts");
                for (const auto& [key, count] : counts.items()) {
                    // A class as written by std::to_string: digits without leading
                    // zeros (strtol would take " 7", "+7", "07" and "-0").
                    const bool digits = !key.empty() && key.size() <= 3 && (key == "0" || key[0] != '0') &&
                                        std::all_of(key.begin(), key.end(), [](char ch) { return ch >= '0' && ch <= '9'; });
                    if (!digits || std::stoi(key) > 255)
                        fieldError("statistics.classification.counts", "'" + key + "' is not a class (0-255)");
                    st.classCounts.push_back({std::stoi(key), integer<uint64_t>(counts, "statistics.classification.counts", key)});
                }
            }
            std::sort(st.classCounts.begin(), st.classCounts.end());
        }
        info.normalSource = text(j, "", "normal_source");
        info.weights = text(j, "", "weights");
        // Absent in sets written before it existed, whose weights assumed k = 1.
        info.kernelScale = j.contains("kernel_scale") ? number(j, "", "kernel_scale") : 1.0;
        if (!(info.kernelScale > 0)) fieldError("kernel_scale", "not positive");
        if (j.contains("texture_filter")) info.textureFilter = text(j, "", "texture_filter");
        if (j.contains("inputs")) info.inputs = strings(j, "", "inputs");
        const nlohmann::json& h = object(j, "", "hierarchy");
        // Absent or "hierarchy.bin" in sets never updated in place.
        if (h.contains("file")) info.hierarchyFile = text(h, "hierarchy", "file");
        if (!validHierarchyFile(info.hierarchyFile))
            fieldError("hierarchy.file", "'" + info.hierarchyFile + "' is not hierarchy.bin or hierarchy-XXXXXXXX.bin");
        info.hierarchyBytes = integer<uint64_t>(h, "hierarchy", "bytes");
        info.hierarchyPages = integer<uint32_t>(h, "hierarchy", "pages");
        info.pageDepth = integer<uint32_t>(h, "hierarchy", "page_depth");
        info.hierarchyCrc = integer<uint32_t>(h, "hierarchy", "crc32");
        const nlohmann::json& blocks = object(j, "", "blocks");
        info.blocksBytes = integer<uint64_t>(blocks, "blocks", "bytes");
        const std::string codec = text(blocks, "blocks", "codec");
        if (auto known = parseBlockCodec(codec)) info.blockCodec = *known;
        else fieldError("blocks.codec", "'" + codec + "' is not \"draco\" or \"draco-columns\"");
        if (blocks.contains("parts") != (info.version >= kPartsFormatVersion))
            fieldError("blocks.parts", info.version >= kPartsFormatVersion ? "missing (version 3 lists the blocks' files)"
                                                                           : "only in version 3");
        if (blocks.contains("parts")) {
            const nlohmann::json& parts = array(blocks, "blocks", "parts");
            if (parts.empty() || parts.size() > kMaxBlocksParts)
                fieldError("blocks.parts", std::to_string(parts.size()) + " files, not 1 to " + std::to_string(kMaxBlocksParts));
            uint64_t sum = 0;
            std::set<std::string> files;
            for (size_t i = 0; i < parts.size(); ++i) {
                const std::string at = "blocks.parts[" + std::to_string(i) + "]";
                if (!parts[i].is_object()) fieldError(at, "not an object");
                BlocksPart part{text(parts[i], at, "file"), integer<uint64_t>(parts[i], at, "bytes")};
                if (!validBlocksFile(part.file)) fieldError(at + ".file", "'" + part.file + "' is not blocks.bin or blocks-XXXXXXXX.bin");
                if (!files.insert(part.file).second) fieldError(at + ".file", "'" + part.file + "' listed twice");
                if (part.bytes == 0 || part.bytes > ~uint64_t(0) - sum) fieldError(at + ".bytes", "0, or past 2^64 in all");
                sum += part.bytes;
                info.blocksParts.push_back(std::move(part));
            }
            if (sum != info.blocksBytes)
                fieldError("blocks.parts", "the files' bytes add up to " + std::to_string(sum) + ", not blocks.bytes " + std::to_string(info.blocksBytes));
        }
        return info;
    } catch (const FieldError& e) {
        return Status::error(what + ": " + e.what());
    }
}

Result<std::vector<NodeRecord>> readHierarchyOf(const TilesetInfo& info, const std::vector<uint8_t>& bytes,
                                                const std::string& what) {
    if (bytes.size() != info.hierarchyBytes || crc32(bytes.data(), bytes.size()) != info.hierarchyCrc)
        return Status::error(what + ": " + std::to_string(bytes.size()) + " bytes whose size or CRC differs from tileset.json (" +
                             std::to_string(info.hierarchyBytes) + " bytes): a set being rebuilt, or a damaged copy");
    return readPages(bytes, info.blocksBytes, what);
}

std::string versionedHierarchyFile(uint32_t crc) {
    char name[32];
    std::snprintf(name, sizeof name, "hierarchy-%08x.bin", crc);
    return name;
}

std::string buildRecordFile(const std::string& hierarchyFile) {
    return "build" + hierarchyFile.substr(std::string("hierarchy").size());
}

std::vector<std::string> versionFiles(const TilesetInfo& info) {
    std::vector<std::string> files = {info.hierarchyFile, buildRecordFile(info.hierarchyFile)};
    for (const BlocksPart& p : blocksPartsOf(info)) files.push_back(p.file);
    return files;
}

bool versionFileName(const std::string& name) {
    return validHierarchyFile(name) || validBlocksFile(name) || (name.rfind("build", 0) == 0 && validHierarchyFile("hierarchy" + name.substr(5)));
}

std::string versionedBlocksFile(uint32_t crc) {
    char name[32];
    std::snprintf(name, sizeof name, "blocks-%08x.bin", crc);
    return name;
}

bool validBlocksFile(const std::string& name) {
    if (name == "blocks.bin") return true;
    if (name.size() != 19 || name.compare(0, 7, "blocks-") != 0 || name.compare(15, 4, ".bin") != 0) return false;
    return std::all_of(name.begin() + 7, name.begin() + 15, [](char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); });
}

std::vector<BlocksPart> blocksPartsOf(const TilesetInfo& info) {
    if (!info.blocksParts.empty()) return info.blocksParts;
    return {BlocksPart{"blocks.bin", info.blocksBytes}};
}

BlocksLayout::BlocksLayout(std::vector<BlocksPart> parts) : parts_(std::move(parts)) {
    uint64_t end = 0;
    for (const BlocksPart& p : parts_) ends_.push_back(end += p.bytes);
}

Result<BlockPlace> BlocksLayout::place(uint64_t offset, uint64_t size) const {
    // The first part that ends after `offset`.
    const auto it = std::upper_bound(ends_.begin(), ends_.end(), offset);
    if (it == ends_.end())
        return Status::error(std::to_string(size) + " bytes at " + std::to_string(offset) + " lie past the blocks' " +
                             std::to_string(ends_.empty() ? 0 : ends_.back()) + " bytes");
    const size_t i = size_t(it - ends_.begin());
    if (size > *it - offset) return Status::error(std::to_string(size) + " bytes at " + std::to_string(offset) + " cross the end of " + parts_[i].file);
    return BlockPlace{i, parts_[i].file, offset - (*it - parts_[i].bytes)};
}

bool validHierarchyFile(const std::string& name) {
    if (name == "hierarchy.bin") return true;
    if (name.size() != 22 || name.compare(0, 10, "hierarchy-") != 0 || name.compare(18, 4, ".bin") != 0) return false;
    return std::all_of(name.begin() + 10, name.begin() + 18, [](char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); });
}

double nodeEdge(const TilesetInfo& info, int level) { return std::ldexp(info.rootEdge, -level); }

Vec3d nodeMin(const TilesetInfo& info, const NodeKey& key) {
    double e = nodeEdge(info, key.level);
    return info.rootMin + Vec3d{key.x * e, key.y * e, key.z * e};
}

bool normalsOriented(const std::string& normalSource) {
    if (normalSource.empty()) return false;
    size_t begin = 0;
    while (begin <= normalSource.size()) {
        size_t end = normalSource.find('+', begin);
        if (end == std::string::npos) end = normalSource.size();
        const std::string part = normalSource.substr(begin, end - begin);
        if (part != "input" && part != "estimated-scan-origin") return false;
        begin = end + 1;
    }
    return true;
}

}  // namespace surfcast
