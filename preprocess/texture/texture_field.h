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
#include <span>
#include <utility>
#include <vector>

#include "mesh_reader.h"
#include "texture.h"
#include "vec3.h"

namespace surfcast {

// --texture-filter optimal (§5, eq. 10-11 and Appendix A): the coefficients
// w that minimize the L2 distance on the surface between the texture and the
// surfels' reconstruction. Our renderer normalizes per pixel (eq. 9), so the
// reconstruction it draws under magnification is Σ_k w_k r̂_k with the
// normalized basis r̂_k = r_k / Σ_j r_j, r_k the renderer's kernel (a Gaussian
// of standard deviation sigma_k in the surfel's tangent plane, cut off at
// y'y <= 2c, within z_t sigma_k along its normal, facing the surface's side).
// Eq. 10 with that basis gives R w = c with R_kj = ⟨r̂_k, r̂_j⟩ and
// c_k = ⟨r̂_k, f̃⟩, both integrated on the mesh by quadrature: a lattice of
// step about sampleStep x sigma in each triangle's plane (a triangle smaller than
// two lattice cells is one sample at its centroid), the texture at each
// sample trilinearly filtered to the lattice step. A ridge term
// ridge x mean(diag R) x (w - w0) keeps R positive definite where samples
// barely touch a kernel (two surfels on one spot), pulling such w towards
// the starting guess w0 (the ewa coefficients), and the coefficients stay in
// [0, 1], the range of a stored colour (an active set of bounds; both
// measured in bench/BENCHMARKS.md, "Textured meshes").
struct FitSurfel {
    Vec3d position;  // relative to the field's origin
    Vec3f normal;    // unit; zero: any side
    double sigma = 0;
    Vec3f color;     // in: the starting guess w0; out: the fit (a group's own surfels only)
};

struct FitParams {
    double cutoff = 1;        // c: the kernel reaches y'y <= 2c
    double zt = 0.5;          // z_t in units of sigma
    double sampleStep = 0.5;  // quadrature lattice step, in units of a group's smallest sigma (or of
                              // a quarter of its largest, where that is more)
    double ridge = 0.1;       // measured best of 0.001, 0.03, 0.1 and 0.3
    int maxIterations = 200;  // conjugate-gradient iterations per channel and round of the bounds
    double tolerance = 1e-4;  // relative residual |R w - c| / |c| at which CG stops
    int threads = 1;
};

struct FitReport {
    size_t groups = 0, unknowns = 0, samples = 0;
    uint64_t iterations = 0;  // summed over groups (the largest of the three channels each)
    int maxIterations = 0;
    double maxResidual = 0;   // largest relative residual CG ended with
    void add(const FitReport& o);
};

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
    // Bytes it holds: triangles, their hierarchy and every texture level
    // (level 0 too, though the mesh shares it while the build holds that).
    uint64_t bytes() const;

    // Solves eq. 10-11 for each group [begin, end) of `surfels` on its own:
    // the unknowns are every surfel whose kernel reaches a quadrature sample
    // within the group's bounding box grown by twice the largest kernel reach
    // (the halo, so that the group's border does not show), and only the
    // group's own surfels take the result. Groups may share no surfels.
    // Surfels outside every group serve as halo only.
    FitReport fitOptimal(std::span<FitSurfel> surfels, std::span<const std::pair<uint32_t, uint32_t>> groups,
                         const FitParams& params) const;

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
    // f(triangle) for every triangle whose box passes test(lo, hi), which
    // must pass every node box containing one that passes.
    template <class Test, class F>
    void forEachWhere(Test&& test, F&& f) const;
    template <class F>
    void forEachNear(const Vec3d& p, double radius, F&& f) const;
    template <class F>
    void forEachInBox(const Vec3d& lo, const Vec3d& hi, F&& f) const;
    // Quadrature samples of the surface inside [lo, hi], lattice step `step`:
    // f(position, unit normal of the facing side, area, texture value).
    template <class F>
    void forEachSample(const Vec3d& lo, const Vec3d& hi, double step, F&& f) const;
    // A textured triangle's texels under the Gaussian; false where its
    // footprint would hold too many of them (stretched texture coordinates).
    template <class Add>
    bool textured(const Tri& t, const Vec3d& p, double sigma, Add&& add) const;

    std::vector<Tri> tris_;
    std::vector<MipTexture> mips_;
    std::vector<Node> nodes_;
};

}  // namespace surfcast
