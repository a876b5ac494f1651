// What a surfel's colour shows, and which classes are drawn: applied when a
// block is unpacked for the GPU (appendNode), so a hidden surfel takes part
// in neither the visibility nor the accumulation pass and leaves no hole in
// what stays (docs/CLIENT.md, "Colour by").
#pragma once

#include <array>
#include <optional>
#include <string>

#include "block_codec.h"
#include "tileset_format.h"
#include "vec3.h"

namespace surfcast {

enum class ColorBy { Auto, Rgb, Intensity, Elevation, Classification, Return };

struct Coloring {
    ColorBy by = ColorBy::Auto;  // Auto: rgb where the set has it, else intensity, else elevation
    std::array<bool, 256> hidden{};  // per class: not drawn
    bool anyHidden() const;
};

// "rgb", "intensity", "elevation", "classification", "return" (and "auto").
std::optional<ColorBy> parseColorBy(const std::string& name);
const char* colorByName(ColorBy by);

// The mode Auto stands for on this set, or an error naming what the set lacks.
Result<ColorBy> resolveColorBy(ColorBy by, const TilesetInfo& info);

// The mode after `by` (Auto, or a mode the set lacks, stands for Auto's
// mode) among those the set can show, in the order rgb, intensity, elevation,
// classification, return, wrapping around: what the window's C key steps
// through.
ColorBy nextColorBy(ColorBy by, const TilesetInfo& info);

// Colour ramps and palettes, components in [0, 1].
Vec3f viridis(float t);                   // t in [0, 1], perceptually uniform (Smith & van der Walt 2015)
Vec3f classColor(int asprsClass);         // ASPRS standard classes (LAS 1.4 R15 table 17)
Vec3f returnColor(int number, int count); // single, first, intermediate, last of several
// Intensity through the set's 2-98 % range (statistics), gamma 1/2.2: grey.
Vec3f intensityColor(double value, const TilesetStatistics& stats);

}  // namespace surfcast
