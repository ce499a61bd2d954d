// ORB features and their ratio-test matching (include/slimseg/features.hpp).
#include "slimseg/features.hpp"

#include <algorithm>
#include <climits>
#include <cstring>
#include <numeric>
#include <string>

#include "slimseg/error.hpp"

namespace slimseg {
namespace {

// Set bits of a 64-bit word (SWAR: no popcount instruction assumed).
int popcount64(std::uint64_t x) {
    x = x - ((x >> 1) & 0x5555555555555555ULL);
    x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0FULL;
    return static_cast<int>((x * 0x0101010101010101ULL) >> 56);
}

// The best and second-best Hamming distances of descriptor x (four words) among the nb of
// wb, and the index of the best (the first of equals).
template <typename Count>
void nearest_two_with(const std::uint64_t* x, const std::uint64_t* wb, int nb, int& best,
                      int& second, int& at, Count count) {
    for (int j = 0; j < nb; ++j) {
        const std::uint64_t* y = wb + static_cast<size_t>(j) * 4;
        const int d = count(x[0] ^ y[0]) + count(x[1] ^ y[1]) + count(x[2] ^ y[2]) +
                      count(x[3] ^ y[3]);
        if (d < best) second = best, best = d, at = j;
        else if (d < second) second = d;
    }
}

#if (defined(__GNUC__) || defined(__clang__)) && (defined(__x86_64__) || defined(__i386__))
// x86 CPUs with the popcnt instruction (checked at run time) count with it.
__attribute__((target("popcnt"))) void nearest_two_popcnt(const std::uint64_t* x,
                                                          const std::uint64_t* wb, int nb,
                                                          int& best, int& second, int& at) {
    nearest_two_with(x, wb, nb, best, second, at,
                     [](std::uint64_t v) { return __builtin_popcountll(v); });
}

void nearest_two(const std::uint64_t* x, const std::uint64_t* wb, int nb, int& best,
                 int& second, int& at) {
    static const bool has_popcnt = __builtin_cpu_supports("popcnt");
    if (has_popcnt) return nearest_two_popcnt(x, wb, nb, best, second, at);
    nearest_two_with(x, wb, nb, best, second, at, popcount64);
}
#else
void nearest_two(const std::uint64_t* x, const std::uint64_t* wb, int nb, int& best,
                 int& second, int& at) {
    nearest_two_with(x, wb, nb, best, second, at, popcount64);
}
#endif

}  // namespace

void Features::check() const {
    if (xy.size() % 2) throw Error("features: keypoints are not (x, y) pairs");
    if (desc.size() != size() * 32)
        throw Error("features: " + std::to_string(size()) + " keypoints but " +
                    std::to_string(desc.size()) + " descriptor bytes (expected 32 each)");
}

int hamming32(const std::uint8_t* a, const std::uint8_t* b) {
    int d = 0;  // four 64-bit words (byte order does not change a bit count)
    for (int i = 0; i < 32; i += 8) {
        std::uint64_t x, y;
        std::memcpy(&x, a + i, 8);
        std::memcpy(&y, b + i, 8);
        d += popcount64(x ^ y);
    }
    return d;
}

std::vector<std::array<int, 2>> match_features(const Features& a, const Features& b,
                                               double ratio) {
    std::vector<std::array<int, 2>> out;
    const int na = static_cast<int>(a.size()), nb = static_cast<int>(b.size());
    if (na < 2 || nb < 2) return out;
    std::vector<std::uint64_t> wa(static_cast<size_t>(na) * 4), wb(static_cast<size_t>(nb) * 4);
    std::memcpy(wa.data(), a.desc.data(), wa.size() * 8);  // 32 bytes: four 64-bit words
    std::memcpy(wb.data(), b.desc.data(), wb.size() * 8);
    struct Row { int qa, tb, dist; };
    std::vector<Row> rows;
    for (int i = 0; i < na; ++i) {
        int best = INT_MAX, second = INT_MAX, at = -1;
        nearest_two(&wa[static_cast<size_t>(i) * 4], wb.data(), nb, best, second, at);
        if (static_cast<double>(best) < ratio * static_cast<double>(second))
            rows.push_back({i, at, best});
    }
    std::stable_sort(rows.begin(), rows.end(),
                     [](const Row& x, const Row& y) { return x.dist < y.dist; });
    std::vector<char> used(nb, 0);
    for (const Row& r : rows) {
        if (used[r.tb]) continue;
        used[r.tb] = 1;
        out.push_back({r.qa, r.tb});
    }
    return out;
}

Features subsample(const Features& f, std::vector<int>& index) {
    const int n = static_cast<int>(f.size());
    const int m = generated::multi_frame::kMotionFeatures;
    const int step = std::max(1, (n + m - 1) / m);
    Features out;
    index.clear();
    for (int i = 0; i < n; i += step) {
        index.push_back(i);
        out.xy.push_back(f.xy[2 * static_cast<size_t>(i)]);
        out.xy.push_back(f.xy[2 * static_cast<size_t>(i) + 1]);
        out.desc.insert(out.desc.end(), f.desc.begin() + static_cast<std::ptrdiff_t>(i) * 32,
                        f.desc.begin() + static_cast<std::ptrdiff_t>(i + 1) * 32);
    }
    return out;
}

}  // namespace slimseg
