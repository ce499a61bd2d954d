// Masks on a window of the frame, and their dilation by a disc.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace slimseg {

// A mask on a window of the frame: pixel (y, x) of the frame is pixels[(y - y0) * w + x - x0]
// inside the window, 0 outside.
struct WindowMask {
    int x0 = 0, y0 = 0, w = 0, h = 0;
    std::vector<std::uint8_t> pixels;  // 0 / 1
    bool at(int y, int x) const {
        return y >= y0 && y < y0 + h && x >= x0 && x < x0 + w &&
               pixels[static_cast<size_t>(y - y0) * w + (x - x0)];
    }
    std::int64_t area() const;
};

// Dilation by a disc of `radius` (OpenCV's MORPH_ELLIPSE (2r+1) x (2r+1) element).
WindowMask dilate(const WindowMask& m, int radius, int h, int w);
std::vector<std::uint8_t> disc_element(int radius);

}  // namespace slimseg
