// A textured mesh's colour as a function on its surface, for the surfels of
// every level of the tree (Zwicker et al. 2001, §5, view-independent EWA
// texture filtering): a surfel of kernel r_k (an isotropic Gaussian of
// standard deviation sigma = k h in its tangent plane, h its level's spacing)
// carries
//     w_k = Σ_i c_i ⟨r_k, n_i∘t⁻¹⟩ / Σ_i ⟨r_k, n_i∘t⁻¹⟩
// over the texels i near it, n_i∘t⁻¹ texel i's reconstruction basis mapped
// onto the surface by the texture coordinates. Here ⟨r_k, n_i∘t⁻¹⟩ is the
// kernel at the texel's centre on the surface times the texel's area there,
// each triangle within 3 sigma contributing the texels of its own part of
// the texture (a footprint may span several triangles and UV charts). Where
// texels are smaller than half a sigma, a mip level's averaged texels stand
// in for them, and the Gaussian gives up the variance that averaging adds.
// Faces without a texture contribute their colour, integrated on a lattice.
// Triangles facing away from the surfel's normal (the other side of a thin
// part) do not count.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "mesh_reader.h"
#include "texture.h"
#include "vec3.h"

namespace surfcast {

class TextureField {
public:
    // `mesh` from readMeshTriangles(path, true); positions are taken relative
    // to `origin` (the builder's root minimum).
    TextureField(const MeshTriangles& mesh, const Vec3d& origin);

    // w_k for a surfel at p (relative to origin) with unit normal n (zero:
    // any side) and kernel standard deviation sigma; channels in [0, 1].
    // False where no surface facing n lies within 3 sigma (then `out` is untouched).
    bool filter(const Vec3d& p, const Vec3f& n, double sigma, Vec3f* out) const;

    size_t triangles() const { return tris_.size(); }

private:
    struct Tri {
        Vec3d a, b, c;
        Vec3d normal;  // unit
        double area = 0;
        double size = 0;  // sqrt(2 area): about an edge
        int texture = -1;
        std::array<float, 6> uv{};
        double texelsPerUnit = 0;  // level-0 texels per world unit along the surface
        Vec3f color;               // where there is no texture
        Vec3d lo, hi;              // bounding box
    };
    // A bounding-volume hierarchy over the triangles, sorted along a Morton
    // curve and halved at every node.
    struct Node {
        Vec3d lo, hi;
        uint32_t begin = 0, end = 0;  // its triangles
        int32_t left = -1, right = -1;  // children; -1 for a leaf
    };
    int32_t build(uint32_t begin, uint32_t end);
    template <class F>
    void forEachNear(const Vec3d& p, double radius, F&& f) const;
    // A textured triangle's texels under the Gaussian; false where its
    // footprint would hold too many of them (stretched texture coordinates).
    template <class Add>
    bool textured(const Tri& t, const Vec3d& p, double sigma, Add&& add) const;

    std::vector<Tri> tris_;
    std::vector<MipTexture> mips_;
    std::vector<Node> nodes_;
};

}  // namespace surfcast
