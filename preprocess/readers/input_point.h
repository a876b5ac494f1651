// The point record every reader produces, and what a reader knows about its file.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "status.h"
#include "tileset_format.h"
#include "vec3.h"

namespace surfcast {

struct InputPoint {
    Vec3d position;          // world coordinates of the input, double precision
    Vec3f normal;            // unit; the zero vector where the input has none
    uint16_t color[3] = {};  // raw channel values as the file stores them (see colorMax)
    uint16_t intensity = 0;
    uint8_t classification = 0;  // ASPRS class (LAS 1.4: 0-255)
    uint8_t returns = 0;         // return number in bits 0-3, number of returns in bits 4-7
    uint8_t alpha = 255;         // opacity, 255 = opaque (PLY alpha/opacity, PCD rgba with --read-alpha)
    uint16_t scan = 0;           // the scan of the file the point belongs to (InputDescription::scanOrigins)
};

// A named per-point scalar beyond the fixed attributes of InputPoint: LAS's
// gps_time, scan_angle, user_data, point_source_id, nir and extra-byte
// dimensions, PLY and PCD properties no fixed attribute takes. Read only when
// asked for (ScalarSelection); the build stores them with --attributes.
struct ScalarField {
    std::string name;
    bool categorical = false;  // values are labels: resampled by majority, never averaged
    double resolution = 0;     // step of the file's own encoding (1 for integers, the scale of scaled integers); 0: floating point
};

// Which scalar fields readers decode: every one, or those named.
struct ScalarSelection {
    bool all = false;
    std::vector<std::string> names;
    bool wants(const std::string& name) const;
};

struct InputDescription {
    std::string path;
    std::string format;              // "ply", "las", "laz", "pcd", "text", "mesh", "scene"
    uint64_t declaredPoints = 0;     // from the header; 0 when the format has no count
    bool hasNormals = false;
    bool hasColors = false;
    bool textured = false;           // a mesh whose colours come from image textures
    bool hasIntensity = false;
    bool hasClassification = false;
    bool hasReturns = false;         // return number and number of returns
    int colorBits = 8;               // bits of the file's colour channels (8 or 16)
    double precision = 0;            // coordinate step the file can express (LAS scale); 0: unknown
    bool float32Coordinates = false; // 24 significant bits: the step follows the magnitude
    // Where the file stores integers, position = integer * scale + offset per
    // axis (LAS/LAZ): a position known within half a step gives back the very
    // coordinates (an update's decoded leaves: update.cpp). Scale 0: none.
    Vec3d latticeScale, latticeOffset;
    // Where the scanner stood for each scan of the file, where the format says
    // (InputPoint::scan indexes it; empty: one scan, origin unknown).
    std::vector<std::optional<Vec3d>> scanOrigins;
    bool scanOriginIsDefault = false; // the format's default (0,0,0), possibly meaningless
    bool airborne = false;           // aerial LiDAR: normals point up
    // The coordinate system the file declares, as its own text (a LAS or LAZ
    // file's WKT VLR, else its GeoTIFF keys: las_reader.cpp); empty where it
    // declares none or the format has no such field. An update compares it.
    std::string crs;
    std::vector<ScalarField> scalars; // the scalar fields this reader decodes (its ScalarSelection's), in value order
    std::vector<std::string> otherScalars;  // the file's scalar fields it does not decode, by name
    LasSourceInfo las;               // a LAS or LAZ file's header fields (las.present); the lattice in latticeScale/Offset
};

// A streaming reader: never holds the whole file. Points with NaN or infinite
// coordinates are skipped and counted, never returned.
class PointReader {
public:
    virtual ~PointReader() = default;
    virtual const InputDescription& description() const = 0;
    // Fills up to `max` points; 0 means the end. Errors name the file and place.
    virtual Result<size_t> read(InputPoint* out, size_t max) = 0;
    uint64_t skipped() const { return skipped_; }
    // The scalar fields' values of the points the last read() returned:
    // description().scalars.size() per point, in that order; NaN where a
    // point has no valid value.
    std::span<const double> scalarValues() const { return scalarValues_; }

protected:
    uint64_t skipped_ = 0;
    std::vector<double> scalarValues_;
};

// Prints "warning: MESSAGE" to stderr once per message in the process: a
// build opens each input in several passes, and may read a mesh again.
void warnOnce(const std::string& message);

// A file name's extension in lower case, with its dot ("" when none).
std::string lowerExtension(const std::string& path);

// A scalar class label (PLY, PCD) as a class: 0 where it is not an integer in
// 0..255 (ASPRS class 0, "never classified").
inline uint8_t classOf(double v) { return v >= 0 && v <= 255 && v == std::floor(v) ? uint8_t(v) : 0; }

// A value rounded into 0..65535; NaN gives 0 (a float-to-integer cast of NaN
// or of a value out of range is undefined: found by fuzz_read_ply).
inline uint16_t saturate16(double v) { return v > 0 ? (v < 65535 ? uint16_t(std::lround(v)) : uint16_t(65535)) : 0; }

inline bool finite(const Vec3d& p) { return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z); }

}  // namespace surfcast
