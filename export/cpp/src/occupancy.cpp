// The motion layers: what moved in behind an object's near layer (include/slimseg/
// depth_evidence.hpp; slimseg.dynamic.occupancy).
#include <algorithm>
#include <cmath>

#include "slimseg/depth_evidence.hpp"

namespace slimseg {

namespace mf = generated::multi_frame;

std::vector<std::uint8_t> surfaces(const DepthImage& depth) {
    const std::vector<float> d = zero_invalid(depth);
    const std::vector<float> lo = min_filter(d, depth.h, depth.w, mf::kSurfacePx);
    const std::vector<float> hi = max_filter(d, depth.h, depth.w, mf::kSurfacePx);
    std::vector<std::uint8_t> out(d.size());
    const float tau = static_cast<float>(mf::kTauM);
    for (size_t i = 0; i < d.size(); ++i) out[i] = lo[i] > 0 && hi[i] - lo[i] <= tau;
    return out;
}

std::vector<float> nearest_before(const DepthImage& previous) {
    std::vector<float> near = min_filter(zero_invalid(previous), previous.h, previous.w,
                                         mf::kNeighbourhoodPx);
    for (float& v : near)
        if (!(v > 0)) v = NAN;
    return near;
}

std::vector<std::uint8_t> surface_pixels(const DepthImage& depth,
                                         const std::vector<std::uint8_t>& where) {
    std::vector<std::uint8_t> out(where.size(), 0);
    const int r = mf::kSurfacePx;
    const float tau = static_cast<float>(mf::kTauM);
    for (int y = 0; y < depth.h; ++y)
        for (int x = 0; x < depth.w; ++x) {
            const size_t i = static_cast<size_t>(y) * depth.w + x;
            if (!where[i]) continue;
            float lo = INFINITY, hi = 0.0f;
            for (int v = std::max(0, y - r); v <= std::min(depth.h - 1, y + r); ++v)
                for (int u = std::max(0, x - r); u <= std::min(depth.w - 1, x + r); ++u) {
                    float d = depth.at(v, u);
                    if (!(std::isfinite(d) && d > 0)) d = 0.0f;
                    lo = std::min(lo, d);
                    hi = std::max(hi, d);
                }
            out[i] = lo > 0 && hi - lo <= tau;
        }
    return out;
}

std::vector<std::uint8_t> moved_in(const DepthImage& depth, const DepthImage& previous,
                                   const Camera& cam, const Pose& pose,
                                   const std::vector<std::uint8_t>& where) {
    const int s = mf::kStride, gh = (depth.h + s - 1) / s, gw = (depth.w + s - 1) / s;
    std::vector<std::uint8_t> out(static_cast<size_t>(gh) * gw, 0);
    const Warped g = warp_grid(depth, cam, pose, &where);
    const float tau = static_cast<float>(mf::kTauM);
    const int r = mf::kNeighbourhoodPx;
    for (size_t i = 0; i < g.z.size(); ++i) {
        float near = INFINITY;  // nearest_before at the landing pixel, looked up there only
        for (int y = std::max(0, g.v[i] - r); y <= std::min(previous.h - 1, g.v[i] + r); ++y)
            for (int x = std::max(0, g.u[i] - r); x <= std::min(previous.w - 1, g.u[i] + r); ++x) {
                const float d = previous.at(y, x);
                near = std::min(near, std::isfinite(d) && d > 0 ? d : 0.0f);
            }
        if (near > 0 && near > g.z[i] + tau)  // no depth near there: marks nothing
            out[static_cast<size_t>(g.gy[i]) * gw + g.gx[i]] = 1;
    }
    return out;
}

std::vector<float> motion_layers(const std::vector<std::uint8_t>& marked, const DepthImage& depth,
                                 const std::vector<std::array<float, 4>>& boxes,
                                 const std::vector<float>& reference, double band, int min_px) {
    const int s = mf::kStride, gh = (depth.h + s - 1) / s, gw = (depth.w + s - 1) / s;
    const int need = std::max(1, (min_px + s * s - 1) / (s * s));
    std::vector<float> out(boxes.size(), NAN);
    auto span = [](float lo, float hi, int size) {  // seg_box.box_spans on the grid
        const double a = std::min(std::max(std::ceil(static_cast<double>(lo) - 0.5), 0.0),
                                  static_cast<double>(size));
        const double e = std::min(std::max(std::ceil(static_cast<double>(hi) - 0.5), 0.0),
                                  static_cast<double>(size));
        return std::pair<int, int>(static_cast<int>(a), static_cast<int>(std::max(a, e)));
    };
    const float fs = static_cast<float>(s);
    for (size_t k = 0; k < boxes.size(); ++k) {
        if (!std::isfinite(reference[k])) continue;
        const auto [x0, x1] = span(boxes[k][0] / fs, boxes[k][2] / fs, gw);
        const auto [y0, y1] = span(boxes[k][1] / fs, boxes[k][3] / fs, gh);
        const float thr = static_cast<float>(static_cast<double>(reference[k]) + band);
        std::vector<float> d;
        for (int y = y0; y < y1; ++y)
            for (int x = x0; x < x1; ++x) {
                const float v = depth.at(y * s, x * s);
                if (marked[static_cast<size_t>(y) * gw + x] && v > thr) d.push_back(v);
            }
        if (static_cast<int>(d.size()) < need) continue;
        const size_t mid = d.size() / 2;
        std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid), d.end());
        float med = d[mid];
        if (d.size() % 2 == 0) {
            const float lo = *std::max_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid));
            med = (lo + med) / 2.0f;
        }
        out[k] = med;
    }
    return out;
}

}  // namespace slimseg
