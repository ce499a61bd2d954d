// Internal to the library (not installed): the mask steps 4-5 of export/CONTRACT.md shared by
// the raw-output path (postprocess.cpp) and the end-to-end path (end2end.cpp), and the
// bilinear kernels the MSNET class map uses.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "slimseg/letterbox.hpp"
#include "slimseg/mask.hpp"
#include "slimseg/tensor.hpp"

namespace slimseg {
namespace detail {

std::string shape_str(const std::vector<std::int64_t>& s);
// `t`'s shape without a leading batch axis of 1 (Error naming `name` otherwise, or when the
// rank is not `ndim`).
std::vector<std::int64_t> unbatched(const TensorView& t, size_t ndim, const std::string& name,
                                    const std::string& expected);

// Bilinear taps along one axis: i0, i1 and the weight of i1.
struct Taps {
    std::vector<int> i0, i1;
    std::vector<float> w1;
};
// slimseg.ops.masks window resize: scale = float(size_in / size_out).
Taps window_taps(int size_out, int size_in);
// torch's F.interpolate (align_corners=False): scale = float(in) / float(out); equal sizes copy.
Taps interpolate_taps(int size_out, int size_in);

// torch's CPU bilinear kernel (its AVX2/AVX-512 builds contract a*b + c*d into fma(a, b, c*d)).
float interp_torch(float v00, float v01, float v10, float v11, float wx, float wy);

// Steps 4-5 for one frame: the taps of the prototype upsampling and of the frame resize.
struct MaskGeometry {
    Letterbox lb;
    int h = 0, w = 0;
    Taps ux, uy, fx, fy;
    bool same = false;  // the letterbox did not resize the frame
};
MaskGeometry mask_geometry(const Letterbox& lb, int h, int w, int hp, int wp);

// A box's input-pixel span and the prototype window [py0, py0 + ph) x [px0, px0 + pw) its
// upsampling reads; empty when the span is.
struct ProtoWindow {
    int x0 = 0, nx = 0, y0 = 0, ny = 0;
    int px0 = 0, py0 = 0, pw = 0, ph = 0;
    bool empty() const { return nx <= 0 || ny <= 0; }
};
ProtoWindow proto_window(const MaskGeometry& g, const std::array<float, 4>& box_input);

// The mask on the frame from the probabilities of the window: prob[(iy - py0) * stride + ix -
// px0] is prototype cell (iy, ix) (a window buffer: stride = pw; a whole plane: its width).
WindowMask frame_mask(const MaskGeometry& g, const ProtoWindow& win, const float* prob,
                      size_t stride);

}  // namespace detail
}  // namespace slimseg
