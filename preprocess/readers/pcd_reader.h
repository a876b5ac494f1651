// PCD (the Point Cloud Library's format, v0.5-0.7): DATA ascii, binary and
// binary_compressed (LZF, decompressed as a stream: lzf_stream.h). Fields x y z,
// packed rgb (float bits) or rgba (uint), normal_x/y/z, intensity; other fields
// are skipped. VIEWPOINT is the scan origin that orients estimated normals.
// Organized clouds mark invalid pixels with NaN; those points are skipped and
// counted.
#pragma once

#include <memory>
#include <string>

#include "input_point.h"
#include "tile_source.h"

namespace surfcast {

// Single-element fields that no fixed attribute takes are scalar fields under
// their own names; `scalars` selects those decoded. The packed colour's top
// byte (rgba's alpha, rgb's padding) is opacity only with `readAlpha`: PCL
// writes 0 or junk there in many files.
Result<std::unique_ptr<PointReader>> openPcdReader(const std::string& path, const ScalarSelection& scalars = {},
                                                   bool readAlpha = false, const HttpOptions& http = {});

}  // namespace surfcast
