// Two-view geometry of the multi-frame stages, written for this library (no OpenCV): the
// fundamental matrix (normalized 8-point in a RANSAC whose draws are deterministic), the
// homography (normalized 4-point DLT, likewise), their residuals, and the camera's motion from
// matches with depth (slimseg.dynamic.epipolar.pnp_pose / occupancy.camera_pose).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "slimseg/features.hpp"

namespace slimseg {

using Mat3 = std::array<double, 9>;  // row-major

struct Camera {  // pinhole intrinsics, px
    double fx = 0, fy = 0, cx = 0, cy = 0;
};

// x_cur^T F x_prev = 0 from matches p0 (previous) -> p1 (current), flattened (x, y) pairs:
// RANSAC over 8-point samples (inlier: both point-to-line distances within `px`), refitted on
// the best draw's inliers; false with fewer than 8 matches or no fit.
bool fundamental_ransac(const std::vector<double>& p0, const std::vector<double>& p1, double px,
                        double confidence, Mat3& f);
// p1 ~ H p0: RANSAC over 4-point samples (inlier: |p1 - H p0| within `px`), refitted likewise.
bool homography_ransac(const std::vector<double>& p0, const std::vector<double>& p1, double px,
                       double confidence, Mat3& h);
// The normalized 8-point fit on all the matches (rank 2 enforced); false if degenerate.
bool fundamental_8point(const std::vector<double>& p0, const std::vector<double>& p1, Mat3& f);

// Symmetric epipolar distance (px) per match: mean of both point-to-line distances.
std::vector<double> epipolar_distance(const Mat3& f, const std::vector<double>& p0,
                                      const std::vector<double>& p1);
// Symmetric transfer distance (px) per match: mean of |p1 - H p0| and |p0 - H^-1 p1|.
std::vector<double> transfer_distance(const Mat3& h, const std::vector<double>& p0,
                                      const std::vector<double>& p1);

// The camera's motion previous -> current: X_cur = R X_prev + t (metres).
struct Pose {
    Mat3 r{1, 0, 0, 0, 1, 0, 0, 0, 1};
    std::array<double, 3> t{0, 0, 0};
};

// The pose from matches p0 -> p1 (px), the previous points back-projected with depth_prev
// (h*w metres, 0/NaN: none) on the `use` ones with depth: RANSAC over 3-point rigid fits
// (the current points back-projected with depth_cur) scored by reprojection error within
// kPnpPx, then Gauss-Newton on the inliers' reprojection error; false with fewer than
// kPnpMinPoints such matches or no fit.
bool pnp_pose(const std::vector<double>& p0, const std::vector<double>& p1,
              const std::vector<std::uint8_t>& use, const float* depth_prev,
              const float* depth_cur, int h, int w, const Camera& cam, Pose& out);

// occupancy.camera_pose: the pose on the matches of the subsampled features.
bool camera_pose(const Features& previous, const float* depth_prev, const Features& current,
                 const float* depth_cur, int h, int w, const Camera& cam, Pose& out);

}  // namespace slimseg
