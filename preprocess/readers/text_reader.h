// Text columns (XYZ, TXT, PTS, CSV): one point per line, whitespace or comma
// separated. The column layout is a comma-separated list of field names
// (x, y, z, r, g, b, nx, ny, nz, i, and _ to ignore a column), given by the user
// or detected from the first data line (see detectTextLayout).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "input_point.h"
#include "tile_source.h"

namespace surfcast {

// Layout for a line of `columns` numbers. 3: x,y,z. 4: x,y,z,i. 6: x,y,z then
// r,g,b when those three are integers in [0,255], else nx,ny,nz. 7: x,y,z,i,r,g,b
// (the PTS convention). 9: x,y,z,r,g,b,nx,ny,nz. Empty when unknown.
std::string detectTextLayout(const std::vector<double>& firstRow);

// `layout` empty: detect. A PTS file's leading point-count line is skipped.
Result<std::unique_ptr<PointReader>> openTextReader(const std::string& path, const std::string& layout, const HttpOptions& http = {});

}  // namespace surfcast
