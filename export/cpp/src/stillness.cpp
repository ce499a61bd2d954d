// The stillness test's comparison of one earlier frame (include/slimseg/depth_evidence.hpp;
// slimseg.dynamic.stillness.changed_fractions).
#include <algorithm>
#include <cmath>

#include "slimseg/depth_evidence.hpp"

namespace slimseg {

namespace mf = generated::multi_frame;

std::vector<double> changed_fractions(const DepthImage& depth, const DepthImage& earlier,
                                      const Camera& cam, const Pose& pose,
                                      const std::vector<const WindowMask*>& masks) {
    std::vector<double> out(masks.size(), NAN);
    if (masks.empty()) return out;
    std::vector<std::uint8_t> where(static_cast<size_t>(depth.h) * depth.w, 0);
    for (const WindowMask* m : masks)
        for (int y = 0; y < m->h; ++y)
            for (int x = 0; x < m->w; ++x)
                if (m->pixels[static_cast<size_t>(y) * m->w + x])
                    where[static_cast<size_t>(m->y0 + y) * depth.w + m->x0 + x] = 1;
    const Warped g = warp_grid(depth, cam, pose, &where);
    const int r = mf::kNeighbourhoodPx, s = mf::kStride;
    const float tau = static_cast<float>(mf::kTauM);
    const size_t n = g.z.size();
    std::vector<std::uint8_t> valid(n, 0), changed(n, 0);
    for (size_t i = 0; i < n; ++i) {
        float lo = INFINITY, hi = 0.0f;  // the span the earlier frame saw around the landing
        for (int y = std::max(0, g.v[i] - r); y <= std::min(earlier.h - 1, g.v[i] + r); ++y)
            for (int x = std::max(0, g.u[i] - r); x <= std::min(earlier.w - 1, g.u[i] + r); ++x) {
                float d = earlier.at(y, x);
                if (!(std::isfinite(d) && d > 0)) d = 0.0f;
                lo = std::min(lo, d);
                hi = std::max(hi, d);
            }
        if (!(lo > 0)) continue;  // a pixel without depth around there: not tested
        valid[i] = g.z[i] <= hi + tau;  // farther than all of it: hidden then
        changed[i] = valid[i] && g.z[i] < lo - tau;
    }
    for (size_t k = 0; k < masks.size(); ++k) {
        std::int64_t on = 0, moved = 0;
        for (size_t i = 0; i < n; ++i) {
            if (!valid[i] || !masks[k]->at(g.gy[i] * s, g.gx[i] * s)) continue;
            ++on;
            moved += changed[i];
        }
        if (on >= mf::kMinTested) out[k] = static_cast<double>(moved) / static_cast<double>(on);
    }
    return out;
}

double grid_iou(const WindowMask& a, const WindowMask& b) {
    const int s = mf::kStride;
    const auto grid = [s](int v) { return v + (s - v % s) % s; };  // first grid line >= v
    // the grid pixels of one mask, then of both, over the rows and columns [y0, y1) x [x0, x1)
    const auto count = [&](int y0, int y1, int x0, int x1, const WindowMask* other,
                           const WindowMask& m) {
        std::int64_t n = 0;
        for (int y = grid(y0); y < y1; y += s)
            for (int x = grid(x0); x < x1; x += s) n += m.at(y, x) && (!other || other->at(y, x));
        return n;
    };
    const std::int64_t na = count(a.y0, a.y0 + a.h, a.x0, a.x0 + a.w, nullptr, a);
    const std::int64_t nb = count(b.y0, b.y0 + b.h, b.x0, b.x0 + b.w, nullptr, b);
    const std::int64_t both = count(std::max(a.y0, b.y0), std::min(a.y0 + a.h, b.y0 + b.h),
                                    std::max(a.x0, b.x0), std::min(a.x0 + a.w, b.x0 + b.w), &b, a);
    const std::int64_t uni = na + nb - both;
    return uni > 0 ? static_cast<double>(both) / static_cast<double>(uni) : 0.0;
}

}  // namespace slimseg
