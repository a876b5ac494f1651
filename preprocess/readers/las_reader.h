// ASPRS LAS 1.0-1.4, point data record formats 0-10, and LAZ (LASzip-
// compressed LAS, COPC files included), streamed. One header parser and one
// record decoder serve both; LAZ records come from the `laz` crate through
// laz_ffi/ (chunks decompressed in parallel with `threads` > 1).
#pragma once

#include <memory>
#include <string>

#include "input_point.h"

namespace surfcast {

// Scalar fields (input_point.h) a LAS file offers: scan_angle (degrees),
// user_data, point_source_id, gps_time (formats 1 and 3-10), nir (8 and 10)
// and each documented extra-byte dimension of the Extra Bytes VLR (user
// "LASF_Spec", record 4) under its own name, scaled and offset as the VLR
// says; the reader decodes those `scalars` selects.
Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path, int threads = 1,
                                                   const ScalarSelection& scalars = {});

}  // namespace surfcast
