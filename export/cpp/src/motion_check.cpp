// The epipolar check (include/slimseg/motion_check.hpp).
#include "slimseg/motion_check.hpp"

#include <algorithm>
#include <cmath>

#include "slimseg/geometry.hpp"

namespace slimseg {
namespace {

namespace mf = generated::multi_frame;

// numpy's median: the mean of the two middle values of an even count.
double median(std::vector<double> v) {
    const size_t n = v.size(), mid = n / 2;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
    const double hi = v[mid];
    if (n % 2) return hi;
    const double lo = *std::max_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid));
    return lo + (hi - lo) * 0.5;
}

double adaptive_threshold(const std::vector<double>& d) {
    if (d.empty()) return mf::kFloorPx;
    const double med = median(d);
    std::vector<double> dev(d.size());
    for (size_t i = 0; i < d.size(); ++i) dev[i] = std::fabs(d[i] - med);
    return std::max(mf::kFloorPx, med + mf::kKMad * 1.4826 * median(dev));
}

}  // namespace

double weigh_odds(double p, bool moving, double odds) {
    const double ratio = moving ? odds : 1.0 / odds;
    return p * ratio / (p * ratio + 1.0 - p);
}

MotionCheck check_motion(const Features& previous, const Features& current,
                         const std::vector<const WindowMask*>& regions, int h, int w) {
    const size_t k = regions.size();
    MotionCheck r;
    r.decided.assign(k, 0);
    r.moving.assign(k, 0);
    r.median_px.assign(k, NAN);
    r.points.assign(k, 0);
    r.threshold = mf::kFloorPx;
    const auto pairs = match_features(previous, current);
    r.matches = static_cast<int>(pairs.size());
    if (pairs.size() < 8) return r;
    const size_t m = pairs.size();
    std::vector<double> p0(2 * m), p1(2 * m);
    std::vector<std::vector<std::uint8_t>> inside(k, std::vector<std::uint8_t>(m, 0));
    std::vector<std::uint8_t> background(m, 1);
    for (size_t i = 0; i < m; ++i) {
        for (int c = 0; c < 2; ++c) {
            p0[2 * i + c] = previous.xy[2 * static_cast<size_t>(pairs[i][0]) + c];
            p1[2 * i + c] = current.xy[2 * static_cast<size_t>(pairs[i][1]) + c];
        }
        // the current point's pixel: float32 rounded half to even, clipped (as numpy)
        const float fx = current.xy[2 * static_cast<size_t>(pairs[i][1])];
        const float fy = current.xy[2 * static_cast<size_t>(pairs[i][1]) + 1];
        const int x = std::min(std::max(static_cast<int>(std::nearbyint(fx)), 0), w - 1);
        const int y = std::min(std::max(static_cast<int>(std::nearbyint(fy)), 0), h - 1);
        for (size_t j = 0; j < k; ++j)
            if (regions[j]->at(y, x)) inside[j][i] = 1, background[i] = 0;
    }
    std::vector<int> fit;
    for (size_t i = 0; i < m; ++i)
        if (background[i]) fit.push_back(static_cast<int>(i));
    r.background = static_cast<int>(fit.size());
    if (static_cast<int>(fit.size()) < mf::kMinBackground) {
        fit.resize(m);
        for (size_t i = 0; i < m; ++i) fit[i] = static_cast<int>(i);
    }
    std::vector<double> f0, f1;
    for (int i : fit) {
        f0.insert(f0.end(), {p0[2 * i], p0[2 * i + 1]});
        f1.insert(f1.end(), {p1[2 * i], p1[2 * i + 1]});
    }
    Mat3 f, hom;
    if (!fundamental_ransac(f0, f1, mf::kRansacPx, mf::kRansacConfidence, f)) return r;
    r.fitted = true;
    std::vector<double> d = epipolar_distance(f, p0, p1);
    if (homography_ransac(f0, f1, mf::kRansacPx, mf::kRansacConfidence, hom)) {
        std::vector<double> dh = transfer_distance(hom, p0, p1);
        double share_h = 0, share_f = 0;
        for (int i : fit) share_h += dh[i] < 1.0, share_f += d[i] < 1.0;
        if (share_h / fit.size() >= mf::kHRatio * (share_f / fit.size())) d.swap(dh), r.model = 'H';
    }
    std::vector<double> bg;
    for (int i : fit) bg.push_back(d[i]);
    r.threshold = adaptive_threshold(bg);
    for (size_t j = 0; j < k; ++j) {
        std::vector<double> mine;
        for (size_t i = 0; i < m; ++i)
            if (inside[j][i]) mine.push_back(d[i]);
        r.points[j] = static_cast<int>(mine.size());
        if (!mine.empty()) r.median_px[j] = median(mine);
        r.decided[j] = r.points[j] >= mf::kMinPoints;
        r.moving[j] = r.decided[j] && r.median_px[j] > r.threshold;
    }
    return r;
}

}  // namespace slimseg
