// ASPRS LAS 1.0-1.4, point data record formats 0-10, and LAZ (LASzip-
// compressed LAS, COPC files included), streamed. One header parser and one
// record decoder serve both; LAZ records come from the `laz` crate through
// laz_ffi/ (chunks decompressed in parallel with `threads` > 1).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "input_point.h"
#include "tile_source.h"

namespace surfcast {

// Scalar fields (input_point.h) a LAS file offers: scan_angle (degrees),
// user_data, point_source_id, gps_time (formats 1 and 3-10), nir (8 and 10)
// and each documented extra-byte dimension of the Extra Bytes VLR (user
// "LASF_Spec", record 4) under its own name, scaled and offset as the VLR
// says; the reader decodes those `scalars` selects.
// `range`: the records read, [begin, end) (end 0: to the last); a LAZ file's
// must start and end at cuts (lasCuts).
struct RecordRange {
    uint64_t begin = 0, end = 0;
};
Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path, int threads = 1,
                                                   const ScalarSelection& scalars = {}, RecordRange range = {},
                                                   const HttpOptions& http = {});
// A LAZ file's chunk starts: the first record of each chunk, which LASzip
// stores uncompressed, read with nothing decoded (as LidarScout, Erler et al.
// 2025, samples a scan): one point of each chunk's (50,000 by default). The
// description says "laz" and declares the file's points, of which it reads
// one per chunk. A LAS file is read whole, as openLasReader reads it.
Result<std::unique_ptr<PointReader>> openLasChunkStarts(const std::string& path, const ScalarSelection& scalars = {},
                                                        const HttpOptions& http = {});

// Where a LAS or LAZ file may be cut into runs of records that are read on
// their own (a part of a build staged across processes, stages.h): the first
// record after each cut and that record's first byte in the file, in order,
// from record 0. A LAS file is cut every kLasCutRecords records, a LAZ file
// at its chunks.
struct RecordCut {
    uint64_t record = 0, byte = 0;
};
inline constexpr uint64_t kLasCutRecords = 1 << 16;
Result<std::vector<RecordCut>> lasCuts(const std::string& path, const HttpOptions& http = {});

}  // namespace surfcast
