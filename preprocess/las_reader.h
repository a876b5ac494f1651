// ASPRS LAS 1.0-1.4, point data record formats 0-10, streamed. LAZ (the
// compressed variant) is read by laz_reader, a later issue.
#pragma once

#include <memory>
#include <string>

#include "input_point.h"

namespace surfcast {

Result<std::unique_ptr<PointReader>> openLasReader(const std::string& path);

}  // namespace surfcast
