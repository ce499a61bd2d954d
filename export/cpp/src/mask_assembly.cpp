// Mask steps 4-5 of export/CONTRACT.md (slimseg.ops.masks_numpy, operation by operation): the
// probabilities of a box's prototype window upsampled to its input-pixel span, cropped to the
// box, then thresholded on the frame (no resize) or resized to the frame window first.
#include "mask_assembly.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>

#include "slimseg/error.hpp"

namespace slimseg {
namespace detail {
namespace {

// slimseg.ops.masks_numpy.pixel_span: first pixel and count whose centres lie in [lo, hi).
std::pair<int, int> pixel_span(float lo, float hi, int size) {
    float first = std::min(std::max(std::ceil(lo - 0.5f), 0.0f), static_cast<float>(size));
    float end = std::min(std::max(std::ceil(hi - 0.5f), 0.0f), static_cast<float>(size));
    return {static_cast<int>(first), std::max(static_cast<int>(end - first), 0)};
}

// slimseg.ops.masks_numpy.resample: separate float32 operations, each rounded.
inline float interp(float v00, float v01, float v10, float v11, float wx, float wy) {
    float r0 = v00 * (1.0f - wx);
    r0 = r0 + v01 * wx;
    float r1 = v10 * (1.0f - wx);
    r1 = r1 + v11 * wx;
    float out = r0 * (1.0f - wy);
    return out + r1 * wy;
}

// Frame pixels whose taps can reach the span (slimseg.ops.masks_numpy._frame_span).
std::pair<int, int> frame_span(int first, int count, int offset, int nw, int dst) {
    float c0 = static_cast<float>(std::min(std::max(first - offset, 0), nw));
    float c1 = static_cast<float>(std::min(std::max(first + count - offset, 0), nw));
    float r = static_cast<float>(static_cast<double>(dst) / nw);
    float f0 = std::ceil((c0 - 0.5f) * r - 0.5f) - 1.0f;
    float f1 = std::ceil((c1 + 0.5f) * r - 0.5f) + 1.0f;
    f0 = std::min(std::max(f0, 0.0f), static_cast<float>(dst));
    f1 = std::min(std::max(f1, 0.0f), static_cast<float>(dst));
    if (!(c1 > c0)) f1 = f0;
    return {static_cast<int>(f0), static_cast<int>(f1 - f0)};
}

}  // namespace

std::string shape_str(const std::vector<std::int64_t>& s) {
    std::string out = "[";
    for (size_t i = 0; i < s.size(); ++i) out += (i ? ", " : "") + std::to_string(s[i]);
    return out + "]";
}

std::vector<std::int64_t> unbatched(const TensorView& t, size_t ndim, const std::string& name,
                                    const std::string& expected) {
    std::vector<std::int64_t> s = t.shape;
    if (s.size() == ndim + 1) {
        if (s[0] != 1)
            throw Error(name + ": shape " + shape_str(t.shape) + " has batch " +
                        std::to_string(s[0]) + "; pass one frame's slice (batch 1)");
        s.erase(s.begin());
    }
    if (s.size() != ndim)
        throw Error(name + ": shape " + shape_str(t.shape) + ", expected " + expected);
    if (t.data == nullptr) throw Error(name + ": no data");
    return s;
}

Taps window_taps(int size_out, int size_in) {
    Taps t;
    const float s = static_cast<float>(static_cast<double>(size_in) / size_out);
    for (int o = 0; o < size_out; ++o) {
        float src = std::max((static_cast<float>(o) + 0.5f) * s - 0.5f, 0.0f);
        int a = std::min(static_cast<int>(std::floor(src)), size_in - 1);
        t.i0.push_back(a);
        t.i1.push_back(std::min(a + 1, size_in - 1));
        t.w1.push_back(std::min(std::max(src - static_cast<float>(a), 0.0f), 1.0f));
    }
    return t;
}

Taps interpolate_taps(int size_out, int size_in) {
    Taps t;
    const float s = static_cast<float>(size_in) / static_cast<float>(size_out);
    for (int o = 0; o < size_out; ++o) {
        if (size_in == size_out) {
            t.i0.push_back(o);
            t.i1.push_back(o);
            t.w1.push_back(0.0f);
            continue;
        }
        float src = std::max(std::fma(s, static_cast<float>(o) + 0.5f, -0.5f), 0.0f);
        int a = std::min(static_cast<int>(std::floor(src)), size_in - 1);
        t.i0.push_back(a);
        t.i1.push_back(a + (a < size_in - 1 ? 1 : 0));
        t.w1.push_back(std::min(std::max(src - static_cast<float>(a), 0.0f), 1.0f));
    }
    return t;
}

float interp_torch(float v00, float v01, float v10, float v11, float wx, float wy) {
    float r0 = std::fma(v00, 1.0f - wx, v01 * wx);
    float r1 = std::fma(v10, 1.0f - wx, v11 * wx);
    return std::fma(r0, 1.0f - wy, r1 * wy);
}

MaskGeometry mask_geometry(const Letterbox& lb, int h, int w, int hp, int wp) {
    MaskGeometry g;
    g.lb = lb;
    g.h = h;
    g.w = w;
    g.ux = interpolate_taps(lb.out_w, wp);
    g.uy = interpolate_taps(lb.out_h, hp);
    g.same = lb.new_h == h && lb.new_w == w;
    if (!g.same) {
        g.fx = window_taps(w, lb.new_w);
        g.fy = window_taps(h, lb.new_h);
    }
    return g;
}

ProtoWindow proto_window(const MaskGeometry& g, const std::array<float, 4>& box) {
    ProtoWindow win;
    std::tie(win.x0, win.nx) = pixel_span(box[0], box[2], g.lb.out_w);
    std::tie(win.y0, win.ny) = pixel_span(box[1], box[3], g.lb.out_h);
    if (win.empty()) return win;
    win.px0 = g.ux.i0[win.x0];
    win.py0 = g.uy.i0[win.y0];
    win.pw = g.ux.i1[win.x0 + win.nx - 1] - win.px0 + 1;
    win.ph = g.uy.i1[win.y0 + win.ny - 1] - win.py0 + 1;
    return win;
}

WindowMask frame_mask(const MaskGeometry& g, const ProtoWindow& win, const float* prob,
                      size_t stride) {
    WindowMask m;
    if (win.empty()) return m;
    const Letterbox& lb = g.lb;
    const int x0 = win.x0, nx = win.nx, y0 = win.y0, ny = win.ny;
    auto P = [&](int iy, int ix) {
        return prob[static_cast<size_t>(iy - win.py0) * stride + (ix - win.px0)];
    };
    // upsampled probabilities on the span (input pixels), 0 elsewhere
    std::vector<float> up(static_cast<size_t>(nx) * ny, 0.0f);
    for (int y = 0; y < ny; ++y) {
        int yy = y0 + y;
        for (int x = 0; x < nx; ++x) {
            int xx = x0 + x;
            up[static_cast<size_t>(y) * nx + x] =
                interp_torch(P(g.uy.i0[yy], g.ux.i0[xx]), P(g.uy.i0[yy], g.ux.i1[xx]),
                             P(g.uy.i1[yy], g.ux.i0[xx]), P(g.uy.i1[yy], g.ux.i1[xx]),
                             g.ux.w1[xx], g.uy.w1[yy]);
        }
    }
    if (g.same) {  // no resize: threshold at input resolution, drop the padding
        int fx0 = std::max(x0, lb.left), fx1 = std::min(x0 + nx, lb.left + lb.new_w);
        int fy0 = std::max(y0, lb.top), fy1 = std::min(y0 + ny, lb.top + lb.new_h);
        if (fx1 > fx0 && fy1 > fy0) {
            m.x0 = fx0 - lb.left;
            m.y0 = fy0 - lb.top;
            m.w = fx1 - fx0;
            m.h = fy1 - fy0;
            m.pixels.resize(static_cast<size_t>(m.w) * m.h);
            for (int y = 0; y < m.h; ++y)
                for (int x = 0; x < m.w; ++x)
                    m.pixels[static_cast<size_t>(y) * m.w + x] =
                        up[static_cast<size_t>(fy0 + y - y0) * nx + (fx0 + x - x0)] > 0.5f;
        }
        return m;
    }
    auto [wx0, wnx] = frame_span(x0, nx, lb.left, lb.new_w, g.w);
    auto [wy0, wny] = frame_span(y0, ny, lb.top, lb.new_h, g.h);
    m.x0 = wx0;
    m.y0 = wy0;
    m.w = wnx;
    m.h = wny;
    m.pixels.assign(static_cast<size_t>(wnx) * wny, 0);
    // content pixel (cy, cx) is input pixel (cy + top, cx + left)
    auto U = [&](int cy, int cx) {
        int yy = cy + lb.top - y0, xx = cx + lb.left - x0;
        return (yy >= 0 && yy < ny && xx >= 0 && xx < nx) ? up[static_cast<size_t>(yy) * nx + xx]
                                                          : 0.0f;
    };
    for (int y = 0; y < wny; ++y) {
        int Y = wy0 + y;
        for (int x = 0; x < wnx; ++x) {
            int X = wx0 + x;
            float v = interp(U(g.fy.i0[Y], g.fx.i0[X]), U(g.fy.i0[Y], g.fx.i1[X]),
                             U(g.fy.i1[Y], g.fx.i0[X]), U(g.fy.i1[Y], g.fx.i1[X]), g.fx.w1[X],
                             g.fy.w1[Y]);
            m.pixels[static_cast<size_t>(y) * wnx + x] = v > 0.5f;
        }
    }
    return m;
}

}  // namespace detail
}  // namespace slimseg
