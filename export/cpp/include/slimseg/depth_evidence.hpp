// The depth evidence of the multi-frame chain: this frame's depth moved into an earlier
// camera and compared with what that camera saw (slimseg.dynamic.occupancy, stillness):
// the stillness test (an object whose depth has not changed is still) and the motion layers
// (what moved in behind an object's near layer).
#pragma once

#include <cstdint>
#include <vector>

#include "slimseg/geometry.hpp"
#include "slimseg/mask.hpp"

namespace slimseg {

// A depth image: h*w metres (0 or NaN: none), row-major.
struct DepthImage {
    const float* d = nullptr;
    int h = 0, w = 0;
    float at(int y, int x) const { return d[static_cast<size_t>(y) * w + x]; }
};

// The pixels of `where` (h*w, 0/1; null: every pixel) on the grid of every kStride-th pixel
// with valid depth, moved into the earlier camera by `pose` (X_cur = R X_prev + t): grid
// indices (gy, gx), the earlier pixel (u, v) they land on and their depth z there; only those
// landing inside the frame in front of the camera (occupancy.warp_grid, in float32).
struct Warped {
    std::vector<int> gy, gx, u, v;
    std::vector<float> z;
};
Warped warp_grid(const DepthImage& depth, const Camera& cam, const Pose& pose,
                 const std::vector<std::uint8_t>* where);

// Nearest / farthest valid depth within `radius` px (a grey erosion / dilation where pixels
// without depth count 0; the frame's outside ignored).
std::vector<float> min_filter(const std::vector<float>& d, int h, int w, int radius);
std::vector<float> max_filter(const std::vector<float>& d, int h, int w, int radius);
// d with NaN, +inf and values <= 0 as 0 (what the filters take)
std::vector<float> zero_invalid(const DepthImage& depth);

// stillness.grid_iou: the IoU of two masks counted on the grid of every kStride-th pixel in x
// and y (frame coordinates).
double grid_iou(const WindowMask& a, const WindowMask& b);

// stillness.changed_fractions: per mask, of its grid pixels with depth that land in the
// earlier frame and were not hidden then, the fraction more than kTauM nearer than every
// depth that frame saw within kNeighbourhoodPx; NaN with fewer than kMinTested tested.
std::vector<double> changed_fractions(const DepthImage& depth, const DepthImage& earlier,
                                      const Camera& cam, const Pose& pose,
                                      const std::vector<const WindowMask*>& masks);

// occupancy.surfaces: pixels whose depths within kSurfacePx all lie within kTauM (none
// invalid), h*w 0/1.
std::vector<std::uint8_t> surfaces(const DepthImage& depth);
// occupancy.nearest_before: the nearest valid previous depth within kNeighbourhoodPx (NaN:
// none valid there).
std::vector<float> nearest_before(const DepthImage& previous);
// surfaces() on the pixels of `where` only (h*w 0/1; 0 elsewhere).
std::vector<std::uint8_t> surface_pixels(const DepthImage& depth,
                                         const std::vector<std::uint8_t>& where);
// occupancy.moved_in: the kStride grid's pixels of `where` that the previous frame saw more
// than kTauM farther along the same ray, nearest_before(previous) looked up where they land
// (grid rows ceil(h / kStride) x ceil(w / kStride)).
std::vector<std::uint8_t> moved_in(const DepthImage& depth, const DepthImage& previous,
                                   const Camera& cam, const Pose& pose,
                                   const std::vector<std::uint8_t>& where);
// occupancy.motion_layers: per object, the median depth of the marked grid pixels in its box
// deeper than reference + band, where they stand for at least min_px frame pixels (NaN: none).
std::vector<float> motion_layers(const std::vector<std::uint8_t>& marked, const DepthImage& depth,
                                 const std::vector<std::array<float, 4>>& boxes,
                                 const std::vector<float>& reference, double band, int min_px);

}  // namespace slimseg
