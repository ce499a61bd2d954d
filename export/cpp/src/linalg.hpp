// The small dense linear algebra the multi-frame stages need (no third-party library): the
// eigen-decomposition of a small symmetric matrix (cyclic Jacobi), a linear solve (Gaussian
// elimination with partial pivoting) and a deterministic sample generator for RANSAC.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace slimseg::linalg {

using Mat3 = std::array<double, 9>;  // row-major

// Eigenvalues (ascending) and eigenvectors (column j of `vectors`, row-major n x n) of the
// symmetric n x n row-major matrix `a`.
void symmetric_eigen(int n, std::vector<double> a, std::vector<double>& values,
                     std::vector<double>& vectors);

// x with a x = b (n x n row-major); false when a is singular.
bool solve(int n, std::vector<double> a, std::vector<double> b, std::vector<double>& x);

Mat3 mul(const Mat3& a, const Mat3& b);
Mat3 transpose(const Mat3& a);
bool inverse(const Mat3& a, Mat3& out);
// R = exp([w]x) (Rodrigues)
Mat3 rotation(const std::array<double, 3>& w);

// RANSAC's draws: splitmix64 from a fixed seed, so a fit depends on its input only.
class Draws {
public:
    explicit Draws(std::uint64_t seed = 0x5111AB5EEDULL) : state_(seed) {}
    std::uint64_t next();
    int below(int n);  // uniform in [0, n)
    // k distinct indices in [0, n) (k <= n)
    void distinct(int k, int n, std::vector<int>& out);

private:
    std::uint64_t state_;
};

// RANSAC draws needed for `confidence` with an inlier share `share` and `k`-point samples,
// at most `cap`.
int ransac_draws(double confidence, double share, int k, int cap);

}  // namespace slimseg::linalg
