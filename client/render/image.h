// An RGBA8 frame and its PNG file (stb_image_write, written atomically).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "status.h"

namespace surfcast {

struct Image {
    int width = 0, height = 0;
    std::vector<uint8_t> rgba;  // row-major from the top-left pixel; alpha 255 = covered
};

// Writes RGB (alpha is coverage, not transparency) to path via a temporary file.
Status writePng(const Image& image, const std::string& path);
Result<Image> readPng(const std::string& path);

}  // namespace surfcast
