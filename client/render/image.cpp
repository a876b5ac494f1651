#include "image.h"

#include <stb_image.h>
#include <stb_image_write.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace surfcast {

Status writePng(const Image& image, const std::string& path) {
    std::vector<uint8_t> rgb(size_t(image.width) * image.height * 3);
    for (size_t i = 0; i < rgb.size() / 3; ++i)
        for (int c = 0; c < 3; ++c) rgb[3 * i + c] = image.rgba[4 * i + c];
    std::vector<uint8_t> png;
    auto append = [](void* context, void* data, int size) {
        auto* out = static_cast<std::vector<uint8_t>*>(context);
        out->insert(out->end(), static_cast<uint8_t*>(data), static_cast<uint8_t*>(data) + size);
    };
    if (!stbi_write_png_to_func(append, &png, image.width, image.height, 3, rgb.data(), image.width * 3))
        return Status::error(path + ": PNG encoding failed");
    std::string temp = path + ".partial-" + std::to_string(getpid());
    std::FILE* f = std::fopen(temp.c_str(), "wb");
    if (!f) return Status::error(path + ": cannot write: " + std::strerror(errno));
    bool ok = std::fwrite(png.data(), 1, png.size(), f) == png.size();
    ok = (std::fclose(f) == 0) && ok;
    if (!ok || std::rename(temp.c_str(), path.c_str()) != 0) {
        std::remove(temp.c_str());
        return Status::error(path + ": cannot write: " + std::strerror(errno));
    }
    return {};
}

Result<Image> readPng(const std::string& path) {
    int w = 0, h = 0, channels = 0;
    uint8_t* data = stbi_load(path.c_str(), &w, &h, &channels, 4);
    if (!data) return Status::error(path + ": cannot read PNG: " + stbi_failure_reason());
    Image image{w, h, std::vector<uint8_t>(data, data + size_t(w) * h * 4)};
    stbi_image_free(data);
    return image;
}

}  // namespace surfcast
