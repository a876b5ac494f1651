#include "camera.h"

#include "render_defaults.h"  // kFrameMargin

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <nlohmann/json.hpp>

namespace surfcast {

namespace {

bool finite(const Vec3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

Status checkCamera(const Camera& c) {
    if (!finite(c.eye) || !finite(c.target) || !finite(c.up) || !std::isfinite(c.fovYDegrees))
        return Status::error("camera has a non-finite value");
    if (!(c.fovYDegrees > 0 && c.fovYDegrees < 180))
        return Status::error("camera field of view " + std::to_string(c.fovYDegrees) + " is outside (0, 180) degrees");
    Vec3d forward = c.target - c.eye;
    if (!(length(forward) > 0)) return Status::error("camera eye and target coincide");
    Vec3d side = cross(normalizeOrZero(forward), normalizeOrZero(c.up));
    if (!(length(side) > 1e-9)) return Status::error("camera up vector is parallel to the view direction (or zero)");
    return Status{};
}

}  // namespace

Result<Camera> parseCamera(const std::string& text) {
    double v[10];
    const char* p = text.c_str();
    for (int i = 0; i < 10; ++i) {
        char* end = nullptr;
        v[i] = std::strtod(p, &end);
        if (end == p) return Status::error("--camera '" + text + "': value " + std::to_string(i + 1) + " of 10 is not a number (want ex,ey,ez,tx,ty,tz,ux,uy,uz,fov)");
        p = end;
        if (i < 9) {
            if (*p != ',') return Status::error("--camera '" + text + "': want 10 comma-separated numbers ex,ey,ez,tx,ty,tz,ux,uy,uz,fov");
            ++p;
        }
    }
    if (*p != '\0') return Status::error("--camera '" + text + "': trailing text after 10 numbers");
    Camera c{{v[0], v[1], v[2]}, {v[3], v[4], v[5]}, {v[6], v[7], v[8]}, v[9]};
    SC_TRY(checkCamera(c));
    return c;
}

Result<Box3d> parseBox(const std::string& text) {
    std::vector<double> v;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        char* end = nullptr;
        const double x = std::strtod(item.c_str(), &end);
        if (item.empty() || *end != '\0' || !std::isfinite(x)) return Status::error("box '" + text + "': '" + item + "' is not a number");
        v.push_back(x);
    }
    if (v.size() != 6) return Status::error("box '" + text + "': six numbers wanted (xmin,ymin,zmin,xmax,ymax,zmax), " + std::to_string(v.size()) + " given");
    Box3d b;
    b.min = {v[0], v[1], v[2]};
    b.max = {v[3], v[4], v[5]};
    for (int a = 0; a < 3; ++a)
        if (b.min[a] > b.max[a]) return Status::error("box '" + text + "': its minimum exceeds its maximum on axis " + "xyz"[a]);
    return b;
}

Result<std::pair<int, int>> parseImageSize(const std::string& text) {
    const auto fail = [&] { return Status::error("size '" + text + "': WxH wanted, each 1 to 16384 pixels"); };
    const size_t x = text.find('x');
    if (x == std::string::npos) return fail();
    int side[2] = {};
    for (int i = 0; i < 2; ++i) {
        const std::string part = i == 0 ? text.substr(0, x) : text.substr(x + 1);
        char* end = nullptr;
        errno = 0;
        const long v = std::strtol(part.c_str(), &end, 10);
        if (part.empty() || !std::isdigit(static_cast<unsigned char>(part[0])) || *end != '\0' || errno == ERANGE || v < 1 || v > 16384)
            return fail();
        side[i] = int(v);
    }
    return std::pair{side[0], side[1]};
}

Result<std::vector<Camera>> parseCameraPath(const std::string& text, const std::string& what) {
    nlohmann::json doc = nlohmann::json::parse(text, nullptr, false);
    if (doc.is_discarded()) return Status::error(what + ": not valid JSON");
    if (!doc.is_object() || !doc.contains("frames") || !doc["frames"].is_array())
        return Status::error(what + ": want an object with a \"frames\" array");
    auto vec = [&](const nlohmann::json& f, const char* key, size_t i, Vec3d fallback, bool required) -> Result<Vec3d> {
        if (!f.contains(key)) {
            if (required) return Status::error(what + ": frame " + std::to_string(i) + " lacks \"" + key + "\"");
            return fallback;
        }
        const auto& a = f[key];
        if (!a.is_array() || a.size() != 3 || !a[0].is_number() || !a[1].is_number() || !a[2].is_number())
            return Status::error(what + ": frame " + std::to_string(i) + " \"" + key + "\" is not an array of 3 numbers");
        return Vec3d{a[0].get<double>(), a[1].get<double>(), a[2].get<double>()};
    };
    std::vector<Camera> cameras;
    const auto& frames = doc["frames"];
    for (size_t i = 0; i < frames.size(); ++i) {
        const auto& f = frames[i];
        if (!f.is_object()) return Status::error(what + ": frame " + std::to_string(i) + " is not an object");
        Camera c;
        { auto r = vec(f, "eye", i, {}, true); if (!r) return r.status(); c.eye = *r; }
        { auto r = vec(f, "target", i, {}, true); if (!r) return r.status(); c.target = *r; }
        { auto r = vec(f, "up", i, {0, 0, 1}, false); if (!r) return r.status(); c.up = *r; }
        if (f.contains("fov")) {
            if (!f["fov"].is_number()) return Status::error(what + ": frame " + std::to_string(i) + " \"fov\" is not a number");
            c.fovYDegrees = f["fov"].get<double>();
        }
        Status s = checkCamera(c);
        if (!s) return Status::error(what + ": frame " + std::to_string(i) + ": " + s.message());
        cameras.push_back(c);
    }
    if (cameras.empty()) return Status::error(what + ": \"frames\" is empty");
    return cameras;
}

std::array<Vec3d, 8> frameDirections() {
    std::array<Vec3d, 8> d;
    for (int i = 0; i < 8; ++i)
        d[size_t(i)] = normalizeOrZero(Vec3d{i & 1 ? -0.35 : 0.35, i & 2 ? 1.0 : -1.0, i & 4 ? -0.55 : 0.55});
    return d;
}

Camera frameBox(const Box3d& box, double aspect, double fovYDegrees, int direction) {
    Camera c;
    c.fovYDegrees = fovYDegrees;
    if (box.empty()) {
        c.eye = {0, -1, 0};
        c.target = {0, 0, 0};
        return c;
    }
    const Vec3d centre = (box.min + box.max) * 0.5;
    const Vec3d d = frameDirections()[size_t(std::clamp(direction, 0, 7))];
    c.target = centre;
    c.up = {0, 0, 1};
    c.eye = centre + d;
    const CameraAxes a = cameraAxes(c);
    // The eye at D along d from a target moved across the view by (s_r, s_u)
    // from the centre: corner p (from the centre) lies at depth z = D - p.d
    // and across at p.r - s_r, which must stay within tan_x z (and the same
    // in u). Some s_r fits iff a_i - tan_x z_i <= a_j + tan_x z_j for every
    // pair (a = p.r, b = p.d), i.e. D >= (a_i - a_j) / (2 tan_x) + (b_i + b_j) / 2;
    // the nearest D is the largest of those over both axes, and s is the
    // middle of what fits, so the box is centred in the view.
    const double tanY = defaults::kFrameMargin * std::tan(0.5 * fovYDegrees * M_PI / 180.0), tanX = tanY * aspect;
    std::array<Vec3d, 8> p;
    for (int i = 0; i < 8; ++i)
        p[size_t(i)] = Vec3d{i & 1 ? box.max.x : box.min.x, i & 2 ? box.max.y : box.min.y, i & 4 ? box.max.z : box.min.z} - centre;
    // At least a step a double can take at the box's coordinates: a box of
    // one point still gets an eye apart from its target.
    double distance = 1e-9 * std::max({1.0, length(box.max - box.min), length(centre)});
    for (const Vec3d& pi : p)
        for (const Vec3d& pj : p)
            distance = std::max({distance, (dot(pi - pj, a.right) / tanX + dot(pi + pj, d)) / 2,
                                 (dot(pi - pj, a.up) / tanY + dot(pi + pj, d)) / 2});
    auto middle = [&](const Vec3d& axis, double tan) {
        double lo = -HUGE_VAL, hi = HUGE_VAL;
        for (const Vec3d& q : p) {
            const double z = distance - dot(q, d);
            lo = std::max(lo, dot(q, axis) - tan * z);
            hi = std::min(hi, dot(q, axis) + tan * z);
        }
        return 0.5 * (lo + hi);
    };
    c.target = centre + a.right * middle(a.right, tanX) + a.up * middle(a.up, tanY);
    c.eye = c.target + d * distance;
    return c;
}

CameraAxes cameraAxes(const Camera& camera) {
    Vec3d forward = normalizeOrZero(camera.target - camera.eye);
    Vec3d right = normalizeOrZero(cross(forward, camera.up));
    return {right, cross(right, forward), forward};
}

double viewportScale(const Camera& camera, int height) {
    return height / (2.0 * std::tan(0.5 * camera.fovYDegrees * M_PI / 180.0));
}

Result<ViewTransform> makeViewTransform(const Camera& camera, const Vec3d& origin, int width, int height) {
    SC_TRY(checkCamera(camera));
    if (width <= 0 || height <= 0) return Status::error("image size must be positive");
    const CameraAxes a = cameraAxes(camera);
    Vec3d eye = camera.eye - origin;
    ViewTransform v{};
    const Vec3d axes[3] = {a.right, a.up, a.forward};
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) v.rows[r][c] = float(axes[r][c]);
        v.rows[r][3] = float(-dot(axes[r], eye));
    }
    v.eta = float(viewportScale(camera, height));
    v.width = width;
    v.height = height;
    v.origin = origin;
    return v;
}

}  // namespace surfcast
