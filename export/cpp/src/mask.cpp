// Window masks: area, and dilation by OpenCV's elliptic structuring element.
#include "slimseg/mask.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <utility>

namespace slimseg {

std::int64_t WindowMask::area() const {
    std::int64_t n = 0;
    for (auto p : pixels) n += p != 0;
    return n;
}

std::vector<std::uint8_t> disc_element(int radius) {
    // OpenCV getStructuringElement(MORPH_ELLIPSE, (2r+1, 2r+1)): row half-widths rounded
    // half to even
    int k = 2 * radius + 1, r = radius, c = radius;
    double inv_r2 = r ? 1.0 / (static_cast<double>(r) * r) : 0.0;
    std::vector<std::uint8_t> e(static_cast<size_t>(k) * k, 0);
    for (int i = 0; i < k; ++i) {
        int dy = i - r;
        int dx = static_cast<int>(std::lrint(c * std::sqrt((r * r - dy * dy) * inv_r2)));
        int j1 = std::max(c - dx, 0), j2 = std::min(c + dx + 1, k);
        for (int j = j1; j < j2; ++j) e[static_cast<size_t>(i) * k + j] = 1;
    }
    return e;
}

WindowMask dilate(const WindowMask& m, int radius, int h, int w) {
    if (radius <= 0 || m.w == 0 || m.h == 0) return m;
    const std::vector<std::uint8_t> e = disc_element(radius);
    const int k = 2 * radius + 1;
    std::vector<int> half(k, -1);  // per kernel row: half-width (-1: empty row)
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j)
            if (e[static_cast<size_t>(i) * k + j]) half[i] = std::max(half[i], std::abs(j - radius));
    WindowMask out;
    out.x0 = std::max(m.x0 - radius, 0);
    out.y0 = std::max(m.y0 - radius, 0);
    int x1 = std::min(m.x0 + m.w + radius, w), y1 = std::min(m.y0 + m.h + radius, h);
    out.w = x1 - out.x0;
    out.h = y1 - out.y0;
    out.pixels.assign(static_cast<size_t>(out.w) * out.h, 0);
    // runs of each source row, in output-window columns
    std::vector<std::vector<std::pair<int, int>>> runs(m.h);
    for (int y = 0; y < m.h; ++y) {
        const std::uint8_t* row = &m.pixels[static_cast<size_t>(y) * m.w];
        for (int x = 0; x < m.w;) {
            if (!row[x]) {
                ++x;
                continue;
            }
            int b = x;
            while (b < m.w && row[b]) ++b;
            runs[y].emplace_back(m.x0 + x - out.x0, m.x0 + b - out.x0);
            x = b;
        }
    }
    // each output row: the union of its kernel rows' runs widened by their half-widths
    // (coverage counts: +1 where a widened run starts, -1 where it ends)
    std::vector<int> cover(static_cast<size_t>(out.w) + 1);
    for (int y = 0; y < out.h; ++y) {
        std::fill(cover.begin(), cover.end(), 0);
        bool any = false;
        for (int i = 0; i < k; ++i) {
            int sy = out.y0 + y + i - radius - m.y0;  // source row of this kernel row
            if (half[i] < 0 || sy < 0 || sy >= m.h) continue;
            for (auto [a, b] : runs[sy]) {
                ++cover[std::max(a - half[i], 0)];
                --cover[std::min(b + half[i], out.w)];
                any = true;
            }
        }
        if (!any) continue;
        std::uint8_t* row = &out.pixels[static_cast<size_t>(y) * out.w];
        int depth = 0;
        for (int x = 0; x < out.w; ++x) {
            depth += cover[x];
            row[x] = depth > 0;
        }
    }
    return out;
}

}  // namespace slimseg
