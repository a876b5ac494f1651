// libFuzzer target: one node's Draco block, decoded as a client decodes what a
// server sends. The first byte picks what the tile set declares (colour bits,
// which optional attributes, LiDAR attributes and scalars), the next two the
// node record's surfel count (readers always pass the record's count; 15
// bits) and the codec (the top bit: draco-columns), the rest is the block.
#include <cstdint>

#include "block_codec.h"

using namespace surfcast;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 3) return 0;
    const uint8_t flags = data[0];
    BlockExpectation expect;
    expect.colorBits = (flags & 3) == 0 ? 0 : (flags & 3) == 1 ? 8 : 16;
    expect.normals = flags & 4;
    expect.weights = flags & 8;
    expect.radii = flags & 16;
    expect.edgeWeights = flags & 32;
    if (flags & 64) {
        expect.extra = {"intensity", "classification", "return_number", "gps_time"};
        expect.extraBits = {16, 8, 8, 32};
    }
    expect.scalars = flags & 128;
    expect.points = uint32_t(data[1] | (data[2] & 0x7f) << 8);
    expect.codec = data[2] & 0x80 ? BlockCodec::DracoColumns : BlockCodec::Draco;
    (void)decodeBlock(data + 3, size - 3, expect);
    return 0;
}
