// The fundamental matrix and the homography between two frames (include/slimseg/geometry.hpp).
#include <algorithm>
#include <cmath>

#include "linalg.hpp"
#include "slimseg/geometry.hpp"

namespace slimseg {
namespace {

using linalg::Draws;

// Hartley's normalisation of the points `idx` of p: centroid to 0, mean distance sqrt(2).
Mat3 normaliser(const std::vector<double>& p, const std::vector<int>& idx) {
    double mx = 0, my = 0;
    for (int i : idx) mx += p[2 * i], my += p[2 * i + 1];
    mx /= idx.size(), my /= idx.size();
    double d = 0;
    for (int i : idx) d += std::hypot(p[2 * i] - mx, p[2 * i + 1] - my);
    d /= idx.size();
    const double s = d > 1e-12 ? std::sqrt(2.0) / d : 1.0;
    return {s, 0, -s * mx, 0, s, -s * my, 0, 0, 1};
}

std::array<double, 2> apply(const Mat3& t, double x, double y) {
    return {t[0] * x + t[1] * y + t[2], t[3] * x + t[4] * y + t[5]};
}

// The unit null vector of the stacked rows (the eigenvector of A^T A's smallest eigenvalue);
// eight rows (a minimal sample): solved with the last entry 1 where that system is regular.
std::array<double, 9> null_vector(const std::vector<std::array<double, 9>>& rows) {
    if (rows.size() == 8) {
        std::vector<double> a(64), b(8), x;
        for (int r = 0; r < 8; ++r) {
            for (int c = 0; c < 8; ++c) a[r * 8 + c] = rows[r][c];
            b[r] = -rows[r][8];
        }
        if (linalg::solve(8, a, b, x)) {
            std::array<double, 9> out;
            double norm = 1.0;
            for (int i = 0; i < 8; ++i) out[i] = x[i], norm += x[i] * x[i];
            out[8] = 1.0;
            norm = std::sqrt(norm);
            bool finite = std::isfinite(norm) && norm < 1e12;
            if (finite) {
                for (double& v : out) v /= norm;
                return out;
            }
        }
    }
    std::vector<double> ata(81, 0.0);
    for (const auto& r : rows)
        for (int i = 0; i < 9; ++i)
            for (int j = 0; j < 9; ++j) ata[i * 9 + j] += r[i] * r[j];
    std::vector<double> values, vectors;
    linalg::symmetric_eigen(9, ata, values, vectors);
    std::array<double, 9> out;
    for (int i = 0; i < 9; ++i) out[i] = vectors[i * 9];
    return out;
}

bool fit_f(const std::vector<double>& p0, const std::vector<double>& p1,
           const std::vector<int>& idx, Mat3& f) {
    if (idx.size() < 8) return false;
    const Mat3 t0 = normaliser(p0, idx), t1 = normaliser(p1, idx);
    std::vector<std::array<double, 9>> rows;
    for (int i : idx) {
        const auto a = apply(t0, p0[2 * i], p0[2 * i + 1]);
        const auto b = apply(t1, p1[2 * i], p1[2 * i + 1]);
        rows.push_back({b[0] * a[0], b[0] * a[1], b[0], b[1] * a[0], b[1] * a[1], b[1], a[0],
                        a[1], 1.0});
    }
    const auto n = null_vector(rows);
    Mat3 g;
    std::copy(n.begin(), n.end(), g.begin());
    // rank 2: G (I - v v^T), v the right singular vector of G's smallest singular value
    std::vector<double> gtg(9, 0.0), values, vectors;
    const Mat3 gt = linalg::transpose(g), m = linalg::mul(gt, g);
    std::copy(m.begin(), m.end(), gtg.begin());
    linalg::symmetric_eigen(3, gtg, values, vectors);
    const double v[3] = {vectors[0], vectors[3], vectors[6]};
    Mat3 proj;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) proj[i * 3 + j] = (i == j) - v[i] * v[j];
    g = linalg::mul(g, proj);
    f = linalg::mul(linalg::mul(linalg::transpose(t1), g), t0);
    double norm = 0;
    for (double x : f) norm += x * x;
    if (!(norm > 0) || !std::isfinite(norm)) return false;
    for (double& x : f) x /= std::sqrt(norm);
    return true;
}

bool fit_h(const std::vector<double>& p0, const std::vector<double>& p1,
           const std::vector<int>& idx, Mat3& h) {
    if (idx.size() < 4) return false;
    const Mat3 t0 = normaliser(p0, idx), t1 = normaliser(p1, idx);
    std::vector<std::array<double, 9>> rows;
    for (int i : idx) {
        const auto a = apply(t0, p0[2 * i], p0[2 * i + 1]);
        const auto b = apply(t1, p1[2 * i], p1[2 * i + 1]);
        rows.push_back({a[0], a[1], 1, 0, 0, 0, -b[0] * a[0], -b[0] * a[1], -b[0]});
        rows.push_back({0, 0, 0, a[0], a[1], 1, -b[1] * a[0], -b[1] * a[1], -b[1]});
    }
    const auto n = null_vector(rows);
    Mat3 g, t1inv;
    std::copy(n.begin(), n.end(), g.begin());
    if (!linalg::inverse(t1, t1inv)) return false;
    h = linalg::mul(linalg::mul(t1inv, g), t0);
    if (!std::isfinite(h[8]) || std::fabs(h[8]) < 1e-12) return false;
    for (double& x : h) x /= h[8];
    return true;
}

// Squared residuals: F, the larger of the two point-to-line distances; H, |p1 - H p0|.
double f_error(const Mat3& f, const double* a, const double* b) {
    const double l1[3] = {f[0] * a[0] + f[1] * a[1] + f[2], f[3] * a[0] + f[4] * a[1] + f[5],
                          f[6] * a[0] + f[7] * a[1] + f[8]};
    const double l0[3] = {f[0] * b[0] + f[3] * b[1] + f[6], f[1] * b[0] + f[4] * b[1] + f[7],
                          f[2] * b[0] + f[5] * b[1] + f[8]};
    const double alg = b[0] * l1[0] + b[1] * l1[1] + l1[2];
    const double d1 = alg * alg / std::max(l1[0] * l1[0] + l1[1] * l1[1], 1e-24);
    const double d0 = alg * alg / std::max(l0[0] * l0[0] + l0[1] * l0[1], 1e-24);
    return std::max(d0, d1);
}

double h_error(const Mat3& h, const double* a, const double* b) {
    const double w = h[6] * a[0] + h[7] * a[1] + h[8];
    const double iw = w != 0 ? 1.0 / w : 0.0;
    const double x = (h[0] * a[0] + h[1] * a[1] + h[2]) * iw;
    const double y = (h[3] * a[0] + h[4] * a[1] + h[5]) * iw;
    return (x - b[0]) * (x - b[0]) + (y - b[1]) * (y - b[1]);
}

template <typename Fit, typename Err>
bool ransac(const std::vector<double>& p0, const std::vector<double>& p1, int k, double px,
            double confidence, int cap, Fit fit, Err err, Mat3& model) {
    const int n = static_cast<int>(p0.size() / 2);
    if (n < k) return false;
    Draws draws;
    std::vector<int> sample, best;
    int draws_needed = cap;
    const double thr = px * px;
    for (int it = 0; it < draws_needed; ++it) {
        draws.distinct(k, n, sample);
        Mat3 m;
        if (!fit(p0, p1, sample, m)) continue;
        std::vector<int> in;
        for (int i = 0; i < n; ++i)
            if (err(m, &p0[2 * i], &p1[2 * i]) <= thr) in.push_back(i);
        if (in.size() > best.size()) {
            best.swap(in);
            model = m;
            draws_needed = std::min(
                draws_needed,
                linalg::ransac_draws(confidence, static_cast<double>(best.size()) / n, k, cap));
        }
    }
    if (static_cast<int>(best.size()) < k) return false;
    Mat3 refit;  // the best draw's inliers, all of them
    if (fit(p0, p1, best, refit)) model = refit;
    return true;
}

}  // namespace

bool fundamental_8point(const std::vector<double>& p0, const std::vector<double>& p1, Mat3& f) {
    std::vector<int> all(p0.size() / 2);
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
    return fit_f(p0, p1, all, f);
}

bool fundamental_ransac(const std::vector<double>& p0, const std::vector<double>& p1, double px,
                        double confidence, Mat3& f) {
    return ransac(p0, p1, 8, px, confidence, 1000, fit_f, f_error, f);
}

bool homography_ransac(const std::vector<double>& p0, const std::vector<double>& p1, double px,
                       double confidence, Mat3& h) {
    return ransac(p0, p1, 4, px, confidence, 2000, fit_h, h_error, h);
}

std::vector<double> epipolar_distance(const Mat3& f, const std::vector<double>& p0,
                                      const std::vector<double>& p1) {
    const size_t n = p0.size() / 2;
    std::vector<double> out(n);
    for (size_t i = 0; i < n; ++i) {
        const double* a = &p0[2 * i];
        const double* b = &p1[2 * i];
        const double l1[3] = {f[0] * a[0] + f[1] * a[1] + f[2], f[3] * a[0] + f[4] * a[1] + f[5],
                              f[6] * a[0] + f[7] * a[1] + f[8]};
        const double l0[3] = {f[0] * b[0] + f[3] * b[1] + f[6], f[1] * b[0] + f[4] * b[1] + f[7],
                              f[2] * b[0] + f[5] * b[1] + f[8]};
        const double alg = std::fabs(b[0] * l1[0] + b[1] * l1[1] + l1[2]);
        const double d1 = alg / std::max(std::hypot(l1[0], l1[1]), 1e-12);
        const double d0 = alg / std::max(std::hypot(l0[0], l0[1]), 1e-12);
        out[i] = 0.5 * (d0 + d1);
    }
    return out;
}

std::vector<double> transfer_distance(const Mat3& h, const std::vector<double>& p0,
                                      const std::vector<double>& p1) {
    const size_t n = p0.size() / 2;
    Mat3 inv;
    if (!linalg::inverse(h, inv)) return std::vector<double>(n, INFINITY);
    std::vector<double> out(n);
    for (size_t i = 0; i < n; ++i)
        out[i] = 0.5 * (std::sqrt(h_error(h, &p0[2 * i], &p1[2 * i])) +
                        std::sqrt(h_error(inv, &p1[2 * i], &p0[2 * i])));
    return out;
}

}  // namespace slimseg
