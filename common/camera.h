// Cameras in the input's own world coordinates (double precision), and the
// float view transform the renderers use, relative to a render origin so that
// georeferenced coordinates of 10^6 keep their precision (DESIGN.md decision 4).
//
// Camera space: x right, y up, z forward (points in front have z > 0). Screen
// space: pixels, origin at the top-left corner, y down; pixel (i, j) covers
// [i, i+1) x [j, j+1). A camera-space point o projects to
//   x = W/2 + eta * o.x / o.z,   y = H/2 - eta * o.y / o.z,
// with the viewport scale eta = H / (2 tan(fov/2)) (fov vertical).
#pragma once

#include <array>

#include <string>
#include <utility>
#include <vector>

#include "status.h"
#include "vec3.h"

namespace surfcast {

struct Camera {
    Vec3d eye;
    Vec3d target{0, 0, -1};
    Vec3d up{0, 0, 1};
    double fovYDegrees = 45;  // vertical field of view
};

// "ex,ey,ez,tx,ty,tz,ux,uy,uz,fov": eye, target, up, vertical fov in degrees.
Result<Camera> parseCamera(const std::string& text);
// A box, "xmin,ymin,zmin,xmax,ymax,zmax" (surfcast-view's --clip, the exports'
// --bbox and bbox=): errors name the text.
Result<Box3d> parseBox(const std::string& text);
// An image size "WxH", each 1 to 16384 pixels (surfcast-view's and
// surfcast-export's --size): errors name the text.
Result<std::pair<int, int>> parseImageSize(const std::string& text);
// A camera path: {"frames": [{"eye": [x,y,z], "target": [..], "up": [..], "fov": deg}, ...]}
// ("up" defaults to +z, "fov" to 45). `what` names the source in errors.
Result<std::vector<Camera>> parseCameraPath(const std::string& json, const std::string& what);
// The directions (from the target towards the eye) frameBox may look from:
// (±0.35, ±1, ±0.55) normalized, the first, (0.35, -1, 0.55), its usual one:
// from the -y side and above.
std::array<Vec3d, 8> frameDirections();
// A camera that frames the whole box at the given aspect (width / height),
// looking along -frameDirections()[direction], up +z, from as near as its
// corners allow: each projects within defaults::kFrameMargin of the image's
// half extents (a margin for the splats' own size), two reach it on opposite
// sides, and the box is centred in the view (the target is its centre moved
// across the view).
Camera frameBox(const Box3d& box, double aspect, double fovYDegrees = 45, int direction = 0);

// The camera's orthonormal axes in world space (double): x right, y up, z
// forward, as camera space defines them above.
struct CameraAxes {
    Vec3d right, up, forward;
};
CameraAxes cameraAxes(const Camera& camera);
// eta: pixels per unit at camera depth 1 for an image `height` pixels tall.
double viewportScale(const Camera& camera, int height);

struct PixelPoint {
    float x, y;
};

// World -> camera rigid transform, as three rows (r, -r.(eye - origin)) in
// float, computed in double relative to `origin`.
struct ViewTransform {
    float rows[3][4];
    float eta;        // viewport scale (pixels per unit at z = 1)
    int width, height;
    Vec3d origin;     // world position of the render origin, which the rows are relative to

    Vec3f apply(const Vec3f& p) const {
        return {rows[0][0] * p.x + rows[0][1] * p.y + rows[0][2] * p.z + rows[0][3],
                rows[1][0] * p.x + rows[1][1] * p.y + rows[1][2] * p.z + rows[1][3],
                rows[2][0] * p.x + rows[2][1] * p.y + rows[2][2] * p.z + rows[2][3]};
    }
    // The screen position (pixels, continuous) of camera-space point o, o.z > 0.
    PixelPoint project(const Vec3f& o) const {
        return {0.5f * width + eta * o.x / o.z, 0.5f * height - eta * o.y / o.z};
    }
    // The camera-space ray (z = 1) through screen position (x, y).
    Vec3f pixelRay(float x, float y) const { return {(x - 0.5f * width) / eta, -(y - 0.5f * height) / eta, 1.f}; }
    Vec3f rotate(const Vec3f& v) const {
        return {rows[0][0] * v.x + rows[0][1] * v.y + rows[0][2] * v.z,
                rows[1][0] * v.x + rows[1][1] * v.y + rows[1][2] * v.z,
                rows[2][0] * v.x + rows[2][1] * v.y + rows[2][2] * v.z};
    }
};

// Fails on a degenerate camera (eye == target, up parallel to the view
// direction, fov outside (0, 180), non-finite values).
Result<ViewTransform> makeViewTransform(const Camera& camera, const Vec3d& origin, int width, int height);

}  // namespace surfcast
