// The letterbox (export/CONTRACT.md "Pre-processing"): the network input from a frame, and
// network-input pixels back to frame pixels.
#pragma once

#include <array>
#include <cstdint>

#include "slimseg/error.hpp"

namespace slimseg {

struct Letterbox {
    double scale = 1.0;
    int new_w = 0, new_h = 0, left = 0, top = 0, out_w = 0, out_h = 0;
};

// scale = min(H/h, W/w); new = floor(side * scale + 0.5); padding centred, rounded down.
Letterbox letterbox_params(int h, int w, int out_h, int out_w);
// RGB uint8 [h, w, 3] -> float [3, H, W] (value / 255): bilinear (half-pixel centres), pad 114.
// The resize is computed in float and rounded to uint8; cv2.INTER_LINEAR's fixed-point kernel
// can differ by one grey level (export/CONTRACT.md says why that is harmless).
void letterbox_image(const std::uint8_t* rgb, int h, int w, const Letterbox& lb, float* chw);
// Inverse for a point in input pixels -> frame pixels (unclipped).
std::array<double, 2> to_frame(const Letterbox& lb, double x_input, double y_input);

}  // namespace slimseg
