// ASPRS LAS 1.0-1.4, point data record formats 0-10, and LAZ (LASzip-
// compressed LAS, COPC files included), streamed. One header parser and one
// record decoder serve both; LAZ records come from the `laz` crate through
// laz_ffi/ (chunks decompressed in parallel with `threads` > 1).
#pragma once

#include <memory>
#include <string>

#include "input_point.h"

namespace surfcast {

Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path, int threads = 1);

}  // namespace surfcast
