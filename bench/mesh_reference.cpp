// surfcast-mesh-reference: the reference image of a triangle mesh for
// bench/accuracy_bench.py and the texture tests. A z-buffer rasterizer with
// 4 x 4 samples per pixel (16x supersampling), perspective-correct vertex
// normals and texture coordinates, and the renderer's own shading
// (shadePixel: unlit, headlight Lambert or Phong; white background), with the
// camera model of surfcast-view (common/camera.h). Surfaces are grey 0.8, or
// with --colors the colours the sampler gives surfels: the diffuse texture,
// filtered trilinearly from a box-filtered mip pyramid at each sample's
// footprint (GPU-style, isotropic), else the face's colour.
// Usage: surfcast-mesh-reference MESH --camera ex,..,fov --size WxH [--shading unlit|lambert|phong] [--colors] --out PNG
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "camera.h"
#include "image.h"
#include "mesh_reader.h"
#include "render_settings.h"

using namespace surfcast;

namespace {
constexpr int kSamples = 4;  // per axis

}

int main(int argc, char** argv) {
    std::string mesh, cameraText, out;
    int W = 320, H = 240;
    std::optional<Shading> shading = Shading::Lambert;
    bool colors = false;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        if (a.rfind("--camera=", 0) == 0) cameraText = a.substr(9);
        else if (a == "--camera" && i + 1 < argc) cameraText = argv[++i];
        else if (a == "--size" && i + 1 < argc) std::sscanf(argv[++i], "%dx%d", &W, &H);
        else if (a == "--out" && i + 1 < argc) out = argv[++i];
        else if (a == "--shading" && i + 1 < argc) shading = parseShading(argv[++i]);
        else if (a == "--colors") colors = true;
        else mesh = a;
    }
    auto camera = parseCamera(cameraText);
    if (mesh.empty() || out.empty() || !camera || W < 1 || H < 1 || !shading) {
        std::fprintf(stderr, "usage: surfcast-mesh-reference MESH --camera ex,ey,ez,tx,ty,tz,ux,uy,uz,fov --size WxH "
                             "[--shading unlit|lambert|phong] [--colors] --out PNG\n");
        return 2;
    }
    auto m = readMeshTriangles(mesh, colors);
    if (!m) {
        std::fprintf(stderr, "surfcast-mesh-reference: %s\n", m.status().message().c_str());
        return 1;
    }
    Box3d bounds;
    for (const Vec3d& p : m->vertices.positions) bounds.extend(p);
    const Vec3d origin = (bounds.min + bounds.max) * 0.5;
    const int SW = W * kSamples, SH = H * kSamples;
    auto view = makeViewTransform(*camera, origin, SW, SH);
    if (!view) return 1;
    std::vector<Vec3f> cam(m->vertices.positions.size()), nrm(cam.size());
    for (size_t i = 0; i < cam.size(); ++i) {
        cam[i] = view->apply(cast<float>(m->vertices.positions[i] - origin));
        nrm[i] = view->rotate(m->vertices.normals[i]);
    }
    std::vector<MipTexture> mips;
    for (const auto& t : m->textures) mips.emplace_back(t);
    std::vector<float> depth(size_t(SW) * SH, INFINITY);
    std::vector<Vec3f> normal(size_t(SW) * SH);
    std::vector<Vec3f> color(colors ? size_t(SW) * SH : 0);
    const float near = 1e-6f;
    for (size_t t = 0; t + 2 < m->triangles.size(); t += 3) {
        const uint32_t idx[3] = {m->triangles[t], m->triangles[t + 1], m->triangles[t + 2]};
        float sx[3], sy[3], iz[3];
        bool ok = true;
        for (int k = 0; k < 3; ++k) {
            const Vec3f& o = cam[idx[k]];
            ok = ok && o.z > near;
            const PixelPoint s = view->project(o);
            sx[k] = s.x;
            sy[k] = s.y;
            iz[k] = 1.f / o.z;
        }
        if (!ok) continue;  // the reference views keep meshes in front of the camera
        float area = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sx[2] - sx[0]) * (sy[1] - sy[0]);
        if (!(std::fabs(area) > 0)) continue;
        int x0 = std::max(0, int(std::floor(std::min({sx[0], sx[1], sx[2]}))));
        int x1 = std::min(SW - 1, int(std::ceil(std::max({sx[0], sx[1], sx[2]}))));
        int y0 = std::max(0, int(std::floor(std::min({sy[0], sy[1], sy[2]}))));
        int y1 = std::min(SH - 1, int(std::ceil(std::max({sy[0], sy[1], sy[2]}))));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                float px = x + 0.5f, py = y + 0.5f;
                float w0 = ((sx[1] - px) * (sy[2] - py) - (sx[2] - px) * (sy[1] - py)) / area;
                float w1 = ((sx[2] - px) * (sy[0] - py) - (sx[0] - px) * (sy[2] - py)) / area;
                float w2 = 1 - w0 - w1;
                if (w0 < 0 || w1 < 0 || w2 < 0) continue;
                float invz = w0 * iz[0] + w1 * iz[1] + w2 * iz[2];
                float z = 1 / invz;
                size_t i = size_t(y) * SW + x;
                if (!(z < depth[i])) continue;
                depth[i] = z;
                // Perspective-correct: interpolate n/z, then multiply by z.
                Vec3f n = (nrm[idx[0]] * (w0 * iz[0]) + nrm[idx[1]] * (w1 * iz[1]) + nrm[idx[2]] * (w2 * iz[2])) * z;
                normal[i] = n;
                if (!colors) continue;
                const size_t tri = t / 3;
                const int texture = m->triangleTexture[tri];
                if (texture < 0) {
                    color[i] = m->triangleColor[tri];
                    continue;
                }
                // Texture coordinates at this sample and one sample to the
                // right and below (perspective-correct): their spread in
                // texels is the footprint that picks the mip level.
                const auto& uv = m->cornerUvs[tri];
                auto uvAt = [&](float qx, float qy) {
                    float a = ((sx[1] - qx) * (sy[2] - qy) - (sx[2] - qx) * (sy[1] - qy)) / area;
                    float b = ((sx[2] - qx) * (sy[0] - qy) - (sx[0] - qx) * (sy[2] - qy)) / area;
                    float c = 1 - a - b;
                    float wa = a * iz[0], wb = b * iz[1], wc = c * iz[2], sum = wa + wb + wc;
                    return std::array<double, 2>{(wa * uv[0] + wb * uv[2] + wc * uv[4]) / sum,
                                                 (wa * uv[1] + wb * uv[3] + wc * uv[5]) / sum};
                };
                const auto here = uvAt(px, py), right = uvAt(px + 1, py), below = uvAt(px, py + 1);
                const Texture& level0 = mips[size_t(texture)].level(0);
                auto texels = [&](const std::array<double, 2>& o) {
                    return std::hypot((o[0] - here[0]) * level0.width, (o[1] - here[1]) * level0.height);
                };
                color[i] = mips[size_t(texture)].sample(here[0], here[1], std::max(texels(right), texels(below)));
            }
    }
    const Vec3f grey{0.8f, 0.8f, 0.8f}, background{1, 1, 1};
    Image image{W, H, std::vector<uint8_t>(size_t(W) * H * 4)};
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            Vec3f sum{};
            int hits = 0;
            for (int sy = 0; sy < kSamples; ++sy)
                for (int sx = 0; sx < kSamples; ++sx) {
                    int X = x * kSamples + sx, Y = y * kSamples + sy;
                    size_t i = size_t(Y) * SW + X;
                    if (std::isfinite(depth[i])) {
                        Vec3f ray = view->pixelRay(X + 0.5f, Y + 0.5f);
                        sum += shadePixel(*shading, colors ? color[i] : grey, normal[i], ray);
                        ++hits;
                    } else {
                        sum += background;
                    }
                }
            sum = sum * (1.f / (kSamples * kSamples));
            uint8_t* p = &image.rgba[4 * (size_t(y) * W + x)];
            for (int c = 0; c < 3; ++c) p[c] = uint8_t(std::lround(std::clamp(sum[c], 0.f, 1.f) * 255));
            p[3] = hits ? 255 : 0;
        }
    if (Status s = writePng(image, out); !s) {
        std::fprintf(stderr, "surfcast-mesh-reference: %s\n", s.message().c_str());
        return 1;
    }
    return 0;
}
