// Image textures of textured meshes (Zwicker et al. 2001, §5): decoded with
// stb_image, reconstructed bilinearly, texture coordinates repeating outside
// [0, 1]; and the Wavefront material libraries (MTL) that name them.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "status.h"
#include "vec3.h"

namespace surfcast {

// Largest texture decoded: 16384 x 16384 texels (768 MiB as RGB bytes), checked
// from the image header before anything is allocated.
inline constexpr uint64_t kMaxTexels = uint64_t(1) << 28;

struct Texture {
    std::string path;
    int width = 0, height = 0;
    std::vector<uint8_t> rgb;  // 3 bytes per texel, rows from the image's top

    // The bilinear reconstruction at texture coordinates (u, v): u to the
    // right, v up from the image's bottom row (the OBJ and PLY convention),
    // both repeating with period 1. Texel (i, j) (column i, row j from the
    // top) is centred at u = (i + 0.5) / width, v = 1 - (j + 0.5) / height.
    // Channels in [0, 1]. Non-finite coordinates sample (0, 0).
    Vec3f sample(double u, double v) const;

    uint64_t bytes() const { return rgb.capacity() + path.capacity() + sizeof *this; }
};

// A texture's mip pyramid: level 0 the texture (shared with the mesh that
// holds it, not copied; null: one mid-grey texel, for a texture that could
// not be loaded), each next level its 2 x 2 texels averaged (a box
// filter; the last row or column repeated at odd sizes), down to 1 x 1.
class MipTexture {
public:
    explicit MipTexture(std::shared_ptr<const Texture> texture);
    size_t levels() const { return coarser_.size() + 1; }
    const Texture& level(size_t i) const { return i == 0 ? *base_ : coarser_[i - 1]; }
    // Trilinear: the bilinear reconstructions of the two levels around
    // log2(texelsPerSample) (level-0 texels per sample spacing), blended.
    Vec3f sample(double u, double v, double texelsPerSample) const;
    // Of the levels above 0 (level 0 belongs to its owners: Texture::bytes).
    uint64_t coarserBytes() const;

private:
    std::shared_ptr<const Texture> base_;
    std::vector<Texture> coarser_;
};

// Decodes a JPEG, PNG, BMP, TGA, ... into RGB. Errors name the file and say
// why: missing, not an image, corrupt, empty or larger than kMaxTexels (the
// header's size is checked before anything is allocated).
Result<Texture> loadTexture(const std::string& path);
// The same from an image file's bytes (an image inside a .glb); `name` names it in errors.
Result<Texture> decodeTexture(std::span<const uint8_t> bytes, const std::string& name);

// A material library: each material's diffuse map (map_Kd), the only map
// Surfcast uses, as written and resolved against the library's folder.
struct MtlMaterial {
    std::string name;
    std::string diffuseMap;      // as written after map_Kd (its last word: options come first)
    std::string diffusePath;     // resolved; empty without map_Kd
    int diffuseLine = 0;         // line of map_Kd in the library
};
struct MtlLibrary {
    std::string path;
    std::vector<MtlMaterial> materials;
    // Maps other than map_Kd that name missing files: worth a warning, never
    // an error (the shared dragon's library names a map_Ks that is not there).
    std::vector<std::string> missingUnusedMaps;
};
// `model`: the OBJ that names the library (scanObj has checked that the
// library lies in its folder); its maps must lie there too, unless
// `allowOutside` (--allow-outside-paths).
Result<MtlLibrary> readMtl(const std::string& path, const std::string& model, bool allowOutside);

// A file a model names (a glTF buffer or image, an OBJ material library or
// map_Kd, a PLY TextureFile), `name` resolved against the folder of `from`,
// the file that names it. It must lie inside `model`'s folder: an absolute
// path elsewhere, or one that climbs out with "..", is an error naming it,
// unless allowOutside (--allow-outside-paths). A model from elsewhere must not
// make the build read whatever file the user can. The check is lexical: a
// symbolic link inside the folder is the user's own, and is followed.
Result<std::string> resolveModelFile(const std::string& model, const std::string& from, const std::string& name,
                                     bool allowOutside);

}  // namespace surfcast
