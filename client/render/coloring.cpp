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
    // Stops at t = 0, 0.1, ..., 1 (render_defaults.json), linearly interpolated.
    const auto& k = defaults::kViridis;
    static_assert(std::size(k) == 11);
    t = std::clamp(std::isfinite(t) ? t : 0.f, 0.f, 1.f) * 10.f;
    const int i = std::min(int(t), 9);
    const float f = t - float(i);
    const float* a = k[i];
    const float* b = k[i + 1];
    return {a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f};
}

Vec3f classColor(int c) {
    // ASPRS classes 0-18 from render_defaults.json (which names them).
    const auto& palette = defaults::kClassColors;
    if (c >= 0 && c < int(std::size(palette))) return {palette[c][0], palette[c][1], palette[c][2]};
    // Reserved and user-defined classes: distinct hues from the class number.
    float h = std::fmod(float(c) * 0.618034f, 1.f) * 6.f;
    auto ch = [&](float o) { return std::clamp(std::fabs(std::fmod(h + o, 6.f) - 3.f) - 1.f, 0.f, 1.f) * 0.7f + 0.2f; };
    return {ch(0.f), ch(4.f), ch(2.f)};
}

Vec3f returnColor(int number, int count) {
    auto rgb = [](const float (&c)[3]) { return Vec3f{c[0], c[1], c[2]}; };
    if (count <= 1) return rgb(defaults::kReturnSingle);
    if (number <= 1) return rgb(defaults::kReturnFirst);
    if (number >= count) return rgb(defaults::kReturnLast);
    return rgb(defaults::kReturnIntermediate);
}

Vec3f intensityColor(double value, const TilesetStatistics& s) {
    double range = s.intensityP98 - s.intensityP2;
    double t = range > 0 ? (value - s.intensityP2) / range : 0.5;
    float g = float(std::pow(std::clamp(t, 0.0, 1.0), 1.0 / 2.2));
    return {g, g, g};
}

}  // namespace surfcast
