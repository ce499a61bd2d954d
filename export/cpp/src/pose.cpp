// The camera's motion from matches with depth (include/slimseg/geometry.hpp): RANSAC over
// 3-point rigid fits (Horn's quaternion), scored and refined on reprojection error.
#include <algorithm>
#include <cmath>

#include "linalg.hpp"
#include "slimseg/geometry.hpp"

namespace slimseg {
namespace {

namespace mf = generated::multi_frame;
using P3 = std::array<double, 3>;

// The depth at the pixel nearest (x, y) (rounded half to even, clipped); NaN without one.
double depth_at(const float* depth, int h, int w, double x, double y) {
    if (depth == nullptr) return NAN;
    const int xi = std::min(std::max(static_cast<int>(std::nearbyint(x)), 0), w - 1);
    const int yi = std::min(std::max(static_cast<int>(std::nearbyint(y)), 0), h - 1);
    const double z = depth[static_cast<size_t>(yi) * w + xi];
    return std::isfinite(z) && z > 0 ? z : NAN;
}

P3 back_project(const Camera& c, double x, double y, double z) {
    return {(x - c.cx) * z / c.fx, (y - c.cy) * z / c.fy, z};
}

// R, t with b ~ R a + t (least squares over the points `idx`, Horn's unit quaternion).
bool rigid_fit(const std::vector<P3>& a, const std::vector<P3>& b, const std::vector<int>& idx,
               Pose& out) {
    P3 ca{0, 0, 0}, cb{0, 0, 0};
    for (int i : idx)
        for (int k = 0; k < 3; ++k) ca[k] += a[i][k], cb[k] += b[i][k];
    for (int k = 0; k < 3; ++k) ca[k] /= idx.size(), cb[k] /= idx.size();
    double s[3][3] = {};
    for (int i : idx)
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) s[r][c] += (a[i][r] - ca[r]) * (b[i][c] - cb[c]);
    const double sxx = s[0][0], sxy = s[0][1], sxz = s[0][2], syx = s[1][0], syy = s[1][1],
                 syz = s[1][2], szx = s[2][0], szy = s[2][1], szz = s[2][2];
    std::vector<double> n = {sxx + syy + szz, syz - szy,       szx - sxz,        sxy - syx,
                             syz - szy,       sxx - syy - szz, sxy + syx,        szx + sxz,
                             szx - sxz,       sxy + syx,       -sxx + syy - szz, syz + szy,
                             sxy - syx,       szx + sxz,       syz + szy,        -sxx - syy + szz};
    std::vector<double> values, vectors;
    linalg::symmetric_eigen(4, n, values, vectors);
    const double q0 = vectors[3], qx = vectors[7], qy = vectors[11], qz = vectors[15];
    if (!std::isfinite(q0)) return false;
    out.r = {q0 * q0 + qx * qx - qy * qy - qz * qz, 2 * (qx * qy - q0 * qz),
             2 * (qx * qz + q0 * qy),               2 * (qx * qy + q0 * qz),
             q0 * q0 - qx * qx + qy * qy - qz * qz, 2 * (qy * qz - q0 * qx),
             2 * (qx * qz - q0 * qy),               2 * (qy * qz + q0 * qx),
             q0 * q0 - qx * qx - qy * qy + qz * qz};
    for (int r = 0; r < 3; ++r)
        out.t[r] = cb[r] - (out.r[r * 3] * ca[0] + out.r[r * 3 + 1] * ca[1] + out.r[r * 3 + 2] * ca[2]);
    return true;
}

P3 transform(const Pose& p, const P3& x) {
    P3 y;
    for (int r = 0; r < 3; ++r)
        y[r] = p.r[r * 3] * x[0] + p.r[r * 3 + 1] * x[1] + p.r[r * 3 + 2] * x[2] + p.t[r];
    return y;
}

// Squared reprojection error of X (previous camera) against the current pixel (u, v).
double reprojection2(const Pose& p, const Camera& c, const P3& x, double u, double v) {
    const P3 y = transform(p, x);
    if (!(y[2] > 0)) return INFINITY;
    const double du = c.fx * y[0] / y[2] + c.cx - u, dv = c.fy * y[1] / y[2] + c.cy - v;
    return du * du + dv * dv;
}

// Levenberg-Marquardt on the reprojection error of the points `idx` (rotation updated on the
// left, R <- exp([w]x) R).
void refine(Pose& pose, const Camera& c, const std::vector<P3>& x, const std::vector<double>& p1,
            const std::vector<int>& idx) {
    auto cost = [&](const Pose& p) {
        double s = 0;
        for (int i : idx) s += reprojection2(p, c, x[i], p1[2 * i], p1[2 * i + 1]);
        return s;
    };
    double lambda = 1e-3, now = cost(pose);
    for (int it = 0; it < 20 && std::isfinite(now); ++it) {
        std::vector<double> jtj(36, 0.0), jtr(6, 0.0);
        for (int i : idx) {
            const P3 y = transform(pose, x[i]);
            if (!(y[2] > 0)) continue;
            const P3 rx = y;  // Y' = exp([w]x) Y + dt
            const double iz = 1.0 / y[2];
            const double ru = c.fx * y[0] * iz + c.cx - p1[2 * i];
            const double rv = c.fy * y[1] * iz + c.cy - p1[2 * i + 1];
            const double du[3] = {c.fx * iz, 0, -c.fx * y[0] * iz * iz};
            const double dv[3] = {0, c.fy * iz, -c.fy * y[1] * iz * iz};
            // dY/dw = -[RX]x, dY/dt = I
            const double dyw[3][3] = {{0, rx[2], -rx[1]}, {-rx[2], 0, rx[0]}, {rx[1], -rx[0], 0}};
            double ju[6], jv[6];
            for (int k = 0; k < 3; ++k) {
                ju[k] = du[0] * dyw[0][k] + du[1] * dyw[1][k] + du[2] * dyw[2][k];
                jv[k] = dv[0] * dyw[0][k] + dv[1] * dyw[1][k] + dv[2] * dyw[2][k];
                ju[k + 3] = du[k];
                jv[k + 3] = dv[k];
            }
            for (int a = 0; a < 6; ++a) {
                jtr[a] += ju[a] * ru + jv[a] * rv;
                for (int b = 0; b < 6; ++b) jtj[a * 6 + b] += ju[a] * ju[b] + jv[a] * jv[b];
            }
        }
        bool better = false;
        for (int tries = 0; tries < 10 && !better; ++tries) {
            std::vector<double> a = jtj, b(6), step;
            for (int k = 0; k < 6; ++k) a[k * 6 + k] *= 1.0 + lambda, b[k] = -jtr[k];
            if (!linalg::solve(6, a, b, step)) break;
            Pose next;
            next.r = linalg::mul(linalg::rotation({step[0], step[1], step[2]}), pose.r);
            const P3 moved = {pose.t[0], pose.t[1], pose.t[2]};
            // t' = exp(w) t + dt keeps Y = R X + t consistent with the left update
            const Mat3 e = linalg::rotation({step[0], step[1], step[2]});
            for (int r = 0; r < 3; ++r)
                next.t[r] = e[r * 3] * moved[0] + e[r * 3 + 1] * moved[1] +
                            e[r * 3 + 2] * moved[2] + step[3 + r];
            const double after = cost(next);
            if (after < now) {
                better = true;
                const double gain = now - after;
                pose = next;
                now = after;
                lambda = std::max(lambda / 10, 1e-9);
                if (gain < 1e-10 * std::max(now, 1e-12)) return;
            } else {
                lambda *= 10;
            }
        }
        if (!better) return;
    }
}

}  // namespace

bool pnp_pose(const std::vector<double>& p0, const std::vector<double>& p1,
              const std::vector<std::uint8_t>& use, const float* depth_prev,
              const float* depth_cur, int h, int w, const Camera& cam, Pose& out) {
    const int n = static_cast<int>(p0.size() / 2);
    std::vector<P3> prev(n), cur(n);
    std::vector<int> fit, both;  // with previous depth; with both depths
    for (int i = 0; i < n; ++i) {
        const double z0 = depth_at(depth_prev, h, w, p0[2 * i], p0[2 * i + 1]);
        if (!use[i] || !std::isfinite(z0)) continue;
        prev[i] = back_project(cam, p0[2 * i], p0[2 * i + 1], z0);
        fit.push_back(i);
        const double z1 = depth_at(depth_cur, h, w, p1[2 * i], p1[2 * i + 1]);
        if (std::isfinite(z1)) {
            cur[i] = back_project(cam, p1[2 * i], p1[2 * i + 1], z1);
            both.push_back(i);
        }
    }
    if (static_cast<int>(fit.size()) < mf::kPnpMinPoints || both.size() < 3) return false;
    const double thr = mf::kPnpPx * mf::kPnpPx;
    auto inliers = [&](const Pose& p) {
        std::vector<int> in;
        for (int i : fit)
            if (reprojection2(p, cam, prev[i], p1[2 * i], p1[2 * i + 1]) < thr) in.push_back(i);
        return in;
    };
    linalg::Draws draws;
    std::vector<int> sample, best;
    Pose best_pose;
    int need = mf::kPnpIterations;
    for (int it = 0; it < need; ++it) {
        draws.distinct(3, static_cast<int>(both.size()), sample);
        for (int& s : sample) s = both[s];
        Pose p;  // the rigid fit of the three, then their reprojection error (a P3P solution)
        if (!rigid_fit(prev, cur, sample, p)) continue;
        refine(p, cam, prev, p1, sample);
        std::vector<int> in = inliers(p);
        if (in.size() > best.size()) {
            best.swap(in);
            best_pose = p;
            need = std::min(need, linalg::ransac_draws(mf::kPnpConfidence,
                                                       static_cast<double>(best.size()) / fit.size(),
                                                       3, mf::kPnpIterations));
        }
    }
    if (best.size() < 3) return false;
    if (static_cast<int>(best.size()) >= mf::kPnpRefineMin) {  // refined on its inliers, twice
        refine(best_pose, cam, prev, p1, best);
        std::vector<int> again = inliers(best_pose);
        if (static_cast<int>(again.size()) >= mf::kPnpRefineMin) refine(best_pose, cam, prev, p1, again);
    }
    out = best_pose;
    return true;
}

bool camera_pose(const Features& previous, const float* depth_prev, const Features& current,
                 const float* depth_cur, int h, int w, const Camera& cam, Pose& out) {
    if (depth_prev == nullptr) return false;
    std::vector<int> ia, ib;
    const Features a = subsample(previous, ia), b = subsample(current, ib);
    const auto pairs = match_features(a, b);
    if (static_cast<int>(pairs.size()) < mf::kPnpMinPoints) return false;
    std::vector<double> p0, p1;
    for (const auto& m : pairs) {
        p0.push_back(previous.xy[2 * static_cast<size_t>(ia[m[0]])]);
        p0.push_back(previous.xy[2 * static_cast<size_t>(ia[m[0]]) + 1]);
        p1.push_back(current.xy[2 * static_cast<size_t>(ib[m[1]])]);
        p1.push_back(current.xy[2 * static_cast<size_t>(ib[m[1]]) + 1]);
    }
    return pnp_pose(p0, p1, std::vector<std::uint8_t>(pairs.size(), 1), depth_prev, depth_cur, h,
                    w, cam, out);
}

}  // namespace slimseg
