// This frame's depth moved into an earlier camera, and the neighbourhood filters the depth
// evidence compares it with (include/slimseg/depth_evidence.hpp).
#include <algorithm>
#include <cmath>

#include "slimseg/depth_evidence.hpp"

namespace slimseg {

namespace mf = generated::multi_frame;

Warped warp_grid(const DepthImage& depth, const Camera& cam, const Pose& pose,
                 const std::vector<std::uint8_t>* where) {
    const int s = mf::kStride;
    const float fx = static_cast<float>(cam.fx), fy = static_cast<float>(cam.fy);
    const float cx = static_cast<float>(cam.cx), cy = static_cast<float>(cam.cy);
    float r[9], t[3];
    for (int i = 0; i < 9; ++i) r[i] = static_cast<float>(pose.r[i]);
    for (int i = 0; i < 3; ++i) t[i] = static_cast<float>(pose.t[i]);
    Warped out;
    for (int y = 0, gy = 0; y < depth.h; y += s, ++gy)
        for (int x = 0, gx = 0; x < depth.w; x += s, ++gx) {
            if (where && !(*where)[static_cast<size_t>(y) * depth.w + x]) continue;
            const float z = depth.at(y, x);
            if (!(std::isfinite(z) && z > 0)) continue;
            const float u0 = static_cast<float>(gx) * static_cast<float>(s);
            const float v0 = static_cast<float>(gy) * static_cast<float>(s);
            const float c[3] = {(u0 - cx) * z / fx - t[0], (v0 - cy) * z / fy - t[1], z - t[2]};
            float p[3];  // X_prev = R^T (X_cur - t)
            for (int j = 0; j < 3; ++j) p[j] = c[0] * r[j] + c[1] * r[3 + j] + c[2] * r[6 + j];
            if (!(p[2] > 0)) continue;
            const float u = std::nearbyint(p[0] / p[2] * fx + cx);
            const float v = std::nearbyint(p[1] / p[2] * fy + cy);
            if (!(u >= 0 && u < depth.w && v >= 0 && v < depth.h)) continue;
            out.gy.push_back(gy);
            out.gx.push_back(gx);
            out.u.push_back(static_cast<int>(u));
            out.v.push_back(static_cast<int>(v));
            out.z.push_back(p[2]);
        }
    return out;
}

namespace {

template <typename Pick>
std::vector<float> window_filter(const std::vector<float>& d, int h, int w, int radius, Pick pick) {
    std::vector<float> rows(d.size()), out(d.size());
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            float v = d[static_cast<size_t>(y) * w + x];
            for (int k = std::max(0, x - radius); k <= std::min(w - 1, x + radius); ++k)
                v = pick(v, d[static_cast<size_t>(y) * w + k]);
            rows[static_cast<size_t>(y) * w + x] = v;
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            float v = rows[static_cast<size_t>(y) * w + x];
            for (int k = std::max(0, y - radius); k <= std::min(h - 1, y + radius); ++k)
                v = pick(v, rows[static_cast<size_t>(k) * w + x]);
            out[static_cast<size_t>(y) * w + x] = v;
        }
    return out;
}

}  // namespace

std::vector<float> min_filter(const std::vector<float>& d, int h, int w, int radius) {
    return window_filter(d, h, w, radius, [](float a, float b) { return std::min(a, b); });
}

std::vector<float> max_filter(const std::vector<float>& d, int h, int w, int radius) {
    return window_filter(d, h, w, radius, [](float a, float b) { return std::max(a, b); });
}

std::vector<float> zero_invalid(const DepthImage& depth) {
    std::vector<float> out(static_cast<size_t>(depth.h) * depth.w);
    for (size_t i = 0; i < out.size(); ++i) {
        const float v = depth.d[i];
        out[i] = std::isfinite(v) && v > 0 ? v : 0.0f;
    }
    return out;
}

}  // namespace slimseg
