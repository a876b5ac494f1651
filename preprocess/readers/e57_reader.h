// E57 (ASTM E2807), through the `e57` crate (laz_ffi/src/e57_ffi.rs): every
// scan (Data3D entry) of the file in order, with its pose applied, cartesian
// or spherical coordinates, intensity scaled by the scan's limits, colour,
// and row and column indices as scalar fields ("row", "column"). Points
// without a return (the invalid-state fields) are skipped and counted.
// Each scan's scanner position orients the normals of its points
// (InputDescription::scanOrigins): the pose's translation, where the scan
// has a pose or spherical coordinates (whose origin is the scanner); a
// cartesian scan posed at the file's origin, as georeferenced files often
// are, has a default origin (scanOriginIsDefault: ignored far from the
// data). Images in the file are not read; a warning says so.
#pragma once

#include <memory>
#include <string>

#include "input_point.h"
#include "tile_source.h"

namespace surfcast {

Result<std::unique_ptr<PointReader>> openE57Reader(const std::string& path, const ScalarSelection& scalars = {},
                                                   const HttpOptions& http = {});

}  // namespace surfcast
