#include "coloring.h"

#include <algorithm>
#include <cmath>

namespace surfcast {

bool Coloring::anyHidden() const { return std::find(hidden.begin(), hidden.end(), true) != hidden.end(); }

std::optional<ColorBy> parseColorBy(const std::string& name) {
    for (ColorBy by : {ColorBy::Auto, ColorBy::Rgb, ColorBy::Intensity, ColorBy::Elevation, ColorBy::Classification, ColorBy::Return})
        if (name == colorByName(by)) return by;
    return std::nullopt;
}

const char* colorByName(ColorBy by) {
    switch (by) {
        case ColorBy::Auto: return "auto";
        case ColorBy::Rgb: return "rgb";
        case ColorBy::Intensity: return "intensity";
        case ColorBy::Elevation: return "elevation";
        case ColorBy::Classification: return "classification";
        case ColorBy::Return: return "return";
    }
    return "auto";
}

Result<ColorBy> resolveColorBy(ColorBy by, const TilesetInfo& info) {
    const bool intensity = info.attribute("intensity") != nullptr;
    if (by == ColorBy::Auto) return info.colorBits ? ColorBy::Rgb : intensity ? ColorBy::Intensity : ColorBy::Elevation;
    const char* lacks = by == ColorBy::Rgb && !info.colorBits                                       ? "colour"
                        : by == ColorBy::Intensity && !intensity                                     ? "intensity"
                        : by == ColorBy::Classification && !info.attribute("classification")         ? "classification"
                        : by == ColorBy::Return && !info.attribute("return_number")                  ? "return numbers"
                                                                                                      : nullptr;
    if (lacks) return Status::error(std::string("--color-by ") + colorByName(by) + ": the set stores no " + lacks);
    return by;
}

ColorBy nextColorBy(ColorBy by, const TilesetInfo& info) {
    static const ColorBy order[] = {ColorBy::Rgb, ColorBy::Intensity, ColorBy::Elevation, ColorBy::Classification,
                                    ColorBy::Return};
    auto resolved = resolveColorBy(by, info);
    const ColorBy from = resolved ? *resolved : *resolveColorBy(ColorBy::Auto, info);
    size_t at = size_t(std::find(std::begin(order), std::end(order), from) - std::begin(order));
    for (size_t step = 1; step <= std::size(order); ++step) {
        ColorBy next = order[(at + step) % std::size(order)];
        if (resolveColorBy(next, info)) return next;
    }
    return from;
}

Vec3f viridis(float t) {
    // matplotlib's viridis at t = 0, 0.1, ..., 1, linearly interpolated.
    static const float k[11][3] = {{0.267f, 0.005f, 0.329f}, {0.283f, 0.141f, 0.458f}, {0.254f, 0.265f, 0.530f},
                                   {0.207f, 0.372f, 0.553f}, {0.164f, 0.471f, 0.558f}, {0.128f, 0.567f, 0.551f},
                                   {0.135f, 0.659f, 0.518f}, {0.267f, 0.749f, 0.441f}, {0.478f, 0.821f, 0.318f},
                                   {0.741f, 0.873f, 0.150f}, {0.993f, 0.906f, 0.144f}};
    t = std::clamp(std::isfinite(t) ? t : 0.f, 0.f, 1.f) * 10.f;
    const int i = std::min(int(t), 9);
    const float f = t - float(i);
    const float* a = k[i];
    const float* b = k[i + 1];
    return {a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f};
}

Vec3f classColor(int c) {
    // ASPRS classes 0-18 in the colours LiDAR viewers commonly give them.
    static const float palette[19][3] = {
        {0.50f, 0.50f, 0.50f},  // 0 created, never classified
        {0.70f, 0.70f, 0.70f},  // 1 unclassified
        {0.63f, 0.43f, 0.22f},  // 2 ground
        {0.56f, 0.85f, 0.44f},  // 3 low vegetation
        {0.27f, 0.70f, 0.24f},  // 4 medium vegetation
        {0.09f, 0.45f, 0.13f},  // 5 high vegetation
        {0.90f, 0.25f, 0.20f},  // 6 building
        {0.95f, 0.35f, 0.85f},  // 7 low point (noise)
        {0.95f, 0.80f, 0.20f},  // 8 reserved (model key-point in LAS 1.0-1.3)
        {0.20f, 0.45f, 0.95f},  // 9 water
        {0.55f, 0.35f, 0.60f},  // 10 rail
        {0.35f, 0.35f, 0.40f},  // 11 road surface
        {0.95f, 0.95f, 0.60f},  // 12 reserved (overlap in LAS 1.0-1.3)
        {0.95f, 0.70f, 0.30f},  // 13 wire - guard
        {0.95f, 0.55f, 0.10f},  // 14 wire - conductor
        {0.75f, 0.20f, 0.45f},  // 15 transmission tower
        {0.85f, 0.60f, 0.75f},  // 16 wire-structure connector
        {0.45f, 0.40f, 0.35f},  // 17 bridge deck
        {1.00f, 0.00f, 0.00f},  // 18 high noise
    };
    if (c >= 0 && c < 19) return {palette[c][0], palette[c][1], palette[c][2]};
    // Reserved and user-defined classes: distinct hues from the class number.
    float h = std::fmod(float(c) * 0.618034f, 1.f) * 6.f;
    auto ch = [&](float o) { return std::clamp(std::fabs(std::fmod(h + o, 6.f) - 3.f) - 1.f, 0.f, 1.f) * 0.7f + 0.2f; };
    return {ch(0.f), ch(4.f), ch(2.f)};
}

Vec3f returnColor(int number, int count) {
    if (count <= 1) return {0.95f, 0.85f, 0.25f};          // single return: yellow
    if (number <= 1) return {0.90f, 0.25f, 0.20f};         // first of several: red
    if (number >= count) return {0.20f, 0.40f, 0.95f};     // last of several: blue
    return {0.25f, 0.80f, 0.30f};                          // intermediate: green
}

Vec3f intensityColor(double value, const TilesetStatistics& s) {
    double range = s.intensityP98 - s.intensityP2;
    double t = range > 0 ? (value - s.intensityP2) / range : 0.5;
    float g = float(std::pow(std::clamp(t, 0.0, 1.0), 1.0 / 2.2));
    return {g, g, g};
}

}  // namespace surfcast
