#include "texture.h"

#include <stb_image.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <sstream>

namespace surfcast {

namespace fs = std::filesystem;

Vec3f Texture::sample(double u, double v) const {
    if (!std::isfinite(u) || !std::isfinite(v)) u = v = 0;
    // Repeat first, so that huge coordinates never reach an integer conversion.
    const double x = (u - std::floor(u)) * width - 0.5;
    const double y = (1 - (v - std::floor(v))) * height - 0.5;
    const double fx = std::floor(x), fy = std::floor(y);
    const float ax = float(x - fx), ay = float(y - fy);
    auto wrap = [](long i, int n) { return size_t(((i % n) + n) % n); };
    const size_t x0 = wrap(long(fx), width), x1 = wrap(long(fx) + 1, width);
    const size_t y0 = wrap(long(fy), height), y1 = wrap(long(fy) + 1, height);
    auto texel = [&](size_t i, size_t j, int c) { return float(rgb[3 * (j * size_t(width) + i) + size_t(c)]); };
    Vec3f out;
    for (int c = 0; c < 3; ++c) {
        const float top = texel(x0, y0, c) * (1 - ax) + texel(x1, y0, c) * ax;
        const float bottom = texel(x0, y1, c) * (1 - ax) + texel(x1, y1, c) * ax;
        out[c] = (top * (1 - ay) + bottom * ay) / 255.f;
    }
    return out;
}

MipTexture::MipTexture(std::shared_ptr<const Texture> texture)
    : base_(texture ? std::move(texture) : std::make_shared<const Texture>(Texture{"", 1, 1, {128, 128, 128}})) {
    while (level(levels() - 1).width > 1 || level(levels() - 1).height > 1) {
        const Texture& a = level(levels() - 1);
        Texture b;
        b.path = a.path;
        b.width = std::max(1, a.width / 2);
        b.height = std::max(1, a.height / 2);
        b.rgb.resize(size_t(b.width) * size_t(b.height) * 3);
        for (int y = 0; y < b.height; ++y)
            for (int x = 0; x < b.width; ++x)
                for (int c = 0; c < 3; ++c) {
                    int sum = 0;
                    for (int dy = 0; dy < 2; ++dy)
                        for (int dx = 0; dx < 2; ++dx) {
                            const int sx = std::min(a.width - 1, 2 * x + dx), sy = std::min(a.height - 1, 2 * y + dy);
                            sum += a.rgb[3 * (size_t(sy) * size_t(a.width) + size_t(sx)) + size_t(c)];
                        }
                    b.rgb[3 * (size_t(y) * size_t(b.width) + size_t(x)) + size_t(c)] = uint8_t((sum + 2) / 4);
                }
        coarser_.push_back(std::move(b));
    }
}

uint64_t MipTexture::coarserBytes() const {
    uint64_t sum = 0;
    for (const Texture& t : coarser_) sum += t.bytes();
    return sum;
}

Vec3f MipTexture::sample(double u, double v, double texelsPerSample) const {
    const double lod = std::clamp(std::log2(std::max(texelsPerSample, 1e-9)), 0.0, double(levels() - 1));
    const size_t l0 = size_t(lod), l1 = std::min(l0 + 1, levels() - 1);
    const float f = float(lod - double(l0));
    return level(l0).sample(u, v) * (1 - f) + level(l1).sample(u, v) * f;
}

Result<Texture> decodeTexture(std::span<const uint8_t> bytes, const std::string& name) {
    if (bytes.size() > size_t(std::numeric_limits<int>::max())) return Status::error(name + ": image file over 2 GiB");
    int w = 0, h = 0, channels = 0;
    if (!stbi_info_from_memory(bytes.data(), int(bytes.size()), &w, &h, &channels))
        return Status::error(name + ": not an image stb_image can read, or a corrupt or oversized one (stb_image: " +
                             std::string(stbi_failure_reason()) + ")");
    if (w <= 0 || h <= 0) return Status::error(name + ": empty texture (" + std::to_string(w) + " x " + std::to_string(h) + ")");
    if (uint64_t(w) * uint64_t(h) > kMaxTexels)
        return Status::error(name + ": texture of " + std::to_string(w) + " x " + std::to_string(h) + " texels, more than the " +
                             std::to_string(kMaxTexels) + " Surfcast decodes");
    std::unique_ptr<uint8_t, void (*)(void*)> pixels(stbi_load_from_memory(bytes.data(), int(bytes.size()), &w, &h, &channels, 3),
                                                     stbi_image_free);
    if (!pixels) return Status::error(name + ": corrupt texture (" + std::string(stbi_failure_reason()) + ")");
    Texture t;
    t.path = name;
    t.width = w;
    t.height = h;
    t.rgb.assign(pixels.get(), pixels.get() + size_t(w) * size_t(h) * 3);
    return t;
}

Result<Texture> loadTexture(const std::string& path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) return Status::error(path + ": texture not found");
    if (fs::file_size(path, ec) > (uint64_t(1) << 30)) return Status::error(path + ": texture file over 1 GiB");
    std::ifstream in(path, std::ios::binary);
    std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (!in.good() && !in.eof()) return Status::error(path + ": cannot read");
    return decodeTexture(bytes, path);
}

Result<std::string> resolveModelFile(const std::string& model, const std::string& from, const std::string& name,
                                     bool allowOutside) {
    const fs::path file = (fs::path(from).parent_path() / name).lexically_normal();
    if (allowOutside) return file.string();
    const fs::path root = fs::path(model).parent_path().lexically_normal();
    const fs::path inside = root.empty() ? file : file.lexically_relative(root);
    if (inside.empty() || inside.is_absolute() || *inside.begin() == "..")
        return Status::error("'" + name + "' lies outside the model's folder " + (root.empty() ? "." : root.string()) +
                             " (--allow-outside-paths reads it)");
    return file.string();
}

Result<MtlLibrary> readMtl(const std::string& path, const std::string& model, bool allowOutside) {
    std::ifstream in(path);
    if (!in) return Status::error(path + ": cannot open the material library");
    MtlLibrary lib;
    lib.path = path;
    auto resolve = [&](std::string name) {
        std::replace(name.begin(), name.end(), '\\', '/');  // libraries written on Windows
        return resolveModelFile(model, path, name, allowOutside);
    };
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
        if (!line.empty() && line.back() == '\r') line.pop_back();
        std::istringstream words(line);
        std::string key;
        if (!(words >> key) || key[0] == '#') continue;
        std::vector<std::string> rest;
        for (std::string w; words >> w;) rest.push_back(w);
        const std::string where = path + ": line " + std::to_string(number) + ": ";
        if (key == "newmtl") {
            if (rest.empty()) return Status::error(where + "newmtl without a name");
            lib.materials.push_back({rest[0], "", "", 0});
        } else if (key == "map_Kd") {
            if (lib.materials.empty()) return Status::error(where + "map_Kd before any newmtl");
            if (rest.empty()) return Status::error(where + "map_Kd without a file name");
            MtlMaterial& m = lib.materials.back();
            auto file = resolve(rest.back());
            if (!file) return Status::error(where + "map_Kd " + file.status().message());
            m.diffuseMap = rest.back();
            m.diffusePath = *file;
            m.diffuseLine = number;
        } else if ((key.rfind("map_", 0) == 0 || key == "bump" || key == "disp" || key == "decal" || key == "refl") &&
                   !rest.empty()) {
            std::error_code ec;
            auto file = resolve(rest.back());  // unused: outside the folder is not looked at
            if (file && !fs::exists(*file, ec))
                lib.missingUnusedMaps.push_back(where + key + " '" + rest.back() + "' not found (unused)");
        }
    }
    return lib;
}

}  // namespace surfcast
