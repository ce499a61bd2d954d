// Small dense linear algebra for the multi-frame stages (src/linalg.hpp).
#include "linalg.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace slimseg::linalg {

void symmetric_eigen(int n, std::vector<double> a, std::vector<double>& values,
                     std::vector<double>& vectors) {
    std::vector<double> v(static_cast<size_t>(n) * n, 0.0);
    for (int i = 0; i < n; ++i) v[static_cast<size_t>(i) * n + i] = 1.0;
    auto at = [n](std::vector<double>& m, int r, int c) -> double& {
        return m[static_cast<size_t>(r) * n + c];
    };
    for (int sweep = 0; sweep < 100; ++sweep) {
        double off = 0.0, diag = 0.0;
        for (int p = 0; p < n; ++p)
            for (int q = 0; q < n; ++q)
                (p == q ? diag : off) += at(a, p, q) * at(a, p, q);
        if (off <= 1e-30 * std::max(diag, 1e-300)) break;
        for (int p = 0; p < n - 1; ++p)
            for (int q = p + 1; q < n; ++q) {
                const double apq = at(a, p, q);
                if (apq == 0.0) continue;
                const double theta = (at(a, q, q) - at(a, p, p)) / (2.0 * apq);
                const double t = (theta >= 0 ? 1.0 : -1.0) /
                                 (std::fabs(theta) + std::sqrt(theta * theta + 1.0));
                const double c = 1.0 / std::sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < n; ++k) {  // columns p, q
                    const double akp = at(a, k, p), akq = at(a, k, q);
                    at(a, k, p) = c * akp - s * akq;
                    at(a, k, q) = s * akp + c * akq;
                }
                for (int k = 0; k < n; ++k) {  // rows p, q
                    const double apk = at(a, p, k), aqk = at(a, q, k);
                    at(a, p, k) = c * apk - s * aqk;
                    at(a, q, k) = s * apk + c * aqk;
                }
                for (int k = 0; k < n; ++k) {
                    const double vkp = at(v, k, p), vkq = at(v, k, q);
                    at(v, k, p) = c * vkp - s * vkq;
                    at(v, k, q) = s * vkp + c * vkq;
                }
            }
    }
    std::vector<int> order(n);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int i, int j) { return at(a, i, i) < at(a, j, j); });
    values.assign(n, 0.0);
    vectors.assign(static_cast<size_t>(n) * n, 0.0);
    for (int j = 0; j < n; ++j) {
        values[j] = at(a, order[j], order[j]);
        for (int k = 0; k < n; ++k) vectors[static_cast<size_t>(k) * n + j] = at(v, k, order[j]);
    }
}

bool solve(int n, std::vector<double> a, std::vector<double> b, std::vector<double>& x) {
    for (int c = 0; c < n; ++c) {
        int piv = c;
        for (int r = c + 1; r < n; ++r)
            if (std::fabs(a[static_cast<size_t>(r) * n + c]) >
                std::fabs(a[static_cast<size_t>(piv) * n + c]))
                piv = r;
        if (std::fabs(a[static_cast<size_t>(piv) * n + c]) < 1e-300) return false;
        if (piv != c) {
            for (int k = 0; k < n; ++k)
                std::swap(a[static_cast<size_t>(c) * n + k], a[static_cast<size_t>(piv) * n + k]);
            std::swap(b[c], b[piv]);
        }
        for (int r = c + 1; r < n; ++r) {
            const double f = a[static_cast<size_t>(r) * n + c] / a[static_cast<size_t>(c) * n + c];
            for (int k = c; k < n; ++k)
                a[static_cast<size_t>(r) * n + k] -= f * a[static_cast<size_t>(c) * n + k];
            b[r] -= f * b[c];
        }
    }
    x.assign(n, 0.0);
    for (int r = n - 1; r >= 0; --r) {
        double s = b[r];
        for (int k = r + 1; k < n; ++k) s -= a[static_cast<size_t>(r) * n + k] * x[k];
        x[r] = s / a[static_cast<size_t>(r) * n + r];
    }
    return true;
}

Mat3 mul(const Mat3& a, const Mat3& b) {
    Mat3 c{};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            for (int k = 0; k < 3; ++k) c[i * 3 + j] += a[i * 3 + k] * b[k * 3 + j];
    return c;
}

Mat3 transpose(const Mat3& a) {
    return {a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]};
}

bool inverse(const Mat3& m, Mat3& out) {
    const double c0 = m[4] * m[8] - m[5] * m[7], c1 = m[5] * m[6] - m[3] * m[8],
                 c2 = m[3] * m[7] - m[4] * m[6];
    const double det = m[0] * c0 + m[1] * c1 + m[2] * c2;
    if (!std::isfinite(det) || std::fabs(det) < 1e-300) return false;
    const double d = 1.0 / det;
    out = {c0 * d, (m[2] * m[7] - m[1] * m[8]) * d, (m[1] * m[5] - m[2] * m[4]) * d,
           c1 * d, (m[0] * m[8] - m[2] * m[6]) * d, (m[2] * m[3] - m[0] * m[5]) * d,
           c2 * d, (m[1] * m[6] - m[0] * m[7]) * d, (m[0] * m[4] - m[1] * m[3]) * d};
    return true;
}

Mat3 rotation(const std::array<double, 3>& w) {
    const double th = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    if (th < 1e-15) return {1, -w[2], w[1], w[2], 1, -w[0], -w[1], w[0], 1};
    const double x = w[0] / th, y = w[1] / th, z = w[2] / th;
    const double c = std::cos(th), s = std::sin(th), C = 1 - c;
    return {c + x * x * C,     x * y * C - z * s, x * z * C + y * s,
            y * x * C + z * s, c + y * y * C,     y * z * C - x * s,
            z * x * C - y * s, z * y * C + x * s, c + z * z * C};
}

std::uint64_t Draws::next() {
    std::uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

int Draws::below(int n) { return static_cast<int>(next() % static_cast<std::uint64_t>(n)); }

void Draws::distinct(int k, int n, std::vector<int>& out) {
    out.clear();
    while (static_cast<int>(out.size()) < k) {
        const int i = below(n);
        if (std::find(out.begin(), out.end(), i) == out.end()) out.push_back(i);
    }
}

int ransac_draws(double confidence, double share, int k, int cap) {
    if (share >= 1.0) return 1;
    const double good = std::pow(share, k);
    if (good <= 0.0) return cap;
    const double n = std::log(1.0 - confidence) / std::log(1.0 - good);
    return static_cast<int>(std::min(static_cast<double>(cap), std::ceil(n)));
}

}  // namespace slimseg::linalg
