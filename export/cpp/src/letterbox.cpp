// The letterbox (export/CONTRACT.md "Pre-processing").
#include "slimseg/letterbox.hpp"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace slimseg {

Letterbox letterbox_params(int h, int w, int out_h, int out_w) {
    if (h <= 0 || w <= 0) throw Error("letterbox: empty frame " + std::to_string(h) + "x" +
                                      std::to_string(w));
    if (out_h <= 0 || out_w <= 0) throw Error("letterbox: empty network input");
    Letterbox lb;
    lb.scale = std::min(static_cast<double>(out_h) / h, static_cast<double>(out_w) / w);
    lb.new_w = std::min(out_w, static_cast<int>(std::floor(w * lb.scale + 0.5)));
    lb.new_h = std::min(out_h, static_cast<int>(std::floor(h * lb.scale + 0.5)));
    lb.left = (out_w - lb.new_w) / 2;
    lb.top = (out_h - lb.new_h) / 2;
    lb.out_w = out_w;
    lb.out_h = out_h;
    return lb;
}

std::array<double, 2> to_frame(const Letterbox& lb, double x_input, double y_input) {
    return {(x_input - lb.left) / lb.scale, (y_input - lb.top) / lb.scale};
}

namespace {
// Half-pixel-centre bilinear taps of one axis (src clamped to the border).
void taps(int out, int in, std::vector<int>& i0, std::vector<int>& i1, std::vector<float>& f) {
    i0.resize(out);
    i1.resize(out);
    f.resize(out);
    double s = static_cast<double>(in) / out;
    for (int o = 0; o < out; ++o) {
        double src = std::max((o + 0.5) * s - 0.5, 0.0);
        int a = std::min(static_cast<int>(std::floor(src)), in - 1);
        i0[o] = a;
        i1[o] = std::min(a + 1, in - 1);
        f[o] = static_cast<float>(std::min(src - a, 1.0));
    }
}
}  // namespace

void letterbox_image(const std::uint8_t* rgb, int h, int w, const Letterbox& lb, float* chw) {
    const size_t plane = static_cast<size_t>(lb.out_h) * lb.out_w;
    const float pad = 114.0f / 255.0f;
    for (size_t i = 0; i < 3 * plane; ++i) chw[i] = pad;
    std::vector<int> x0, x1, y0, y1;
    std::vector<float> fx, fy;
    taps(lb.new_w, w, x0, x1, fx);
    taps(lb.new_h, h, y0, y1, fy);
    for (int y = 0; y < lb.new_h; ++y) {
        const std::uint8_t* r0 = rgb + static_cast<size_t>(y0[y]) * w * 3;
        const std::uint8_t* r1 = rgb + static_cast<size_t>(y1[y]) * w * 3;
        for (int x = 0; x < lb.new_w; ++x) {
            for (int c = 0; c < 3; ++c) {
                float top = r0[x0[x] * 3 + c] * (1 - fx[x]) + r0[x1[x] * 3 + c] * fx[x];
                float bot = r1[x0[x] * 3 + c] * (1 - fx[x]) + r1[x1[x] * 3 + c] * fx[x];
                float v = std::nearbyint(top * (1 - fy[y]) + bot * fy[y]);
                size_t at = static_cast<size_t>(c) * plane +
                            static_cast<size_t>(y + lb.top) * lb.out_w + (x + lb.left);
                chw[at] = std::min(std::max(v, 0.0f), 255.0f) / 255.0f;
            }
        }
    }
}

}  // namespace slimseg
