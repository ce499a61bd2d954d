// The epipolar check of the multi-frame chain (slimseg.dynamic.epipolar.check_motion, without
// the opt-in depth-aided residual): which candidate objects move between the previous frame
// and this one, judged on their matched ORB points against the background's geometry.
#pragma once

#include <cstdint>
#include <vector>

#include "slimseg/features.hpp"
#include "slimseg/mask.hpp"

namespace slimseg {

struct MotionCheck {
    std::vector<std::uint8_t> decided, moving;  // per candidate
    std::vector<double> median_px;              // NaN: no matched point inside
    std::vector<int> points;                    // matched points inside each candidate
    double threshold = 0;                       // px
    bool fitted = false;                        // a fundamental matrix was found
    char model = 'F';                           // 'F' epipolar or 'H' homography distances
    int matches = 0, background = 0;
};

// The check on `regions` (the candidates' instance masks, frame pixels, h x w frame):
// ratio-test matches previous -> current; F by RANSAC from the matches outside every region
// (all of them with fewer than kMinBackground); H likewise, whose transfer distances replace
// the epipolar ones when H explains at least kHRatio as many background matches within 1 px;
// threshold max(kFloorPx, median + kKMad * 1.4826 * MAD) of the background's distances; a
// candidate with at least kMinPoints matched points moves when their median exceeds it.
MotionCheck check_motion(const Features& previous, const Features& current,
                         const std::vector<const WindowMask*>& regions, int h, int w);

// slimseg.dynamic.motion_evidence.weigh_odds: 0 < p < 1 after a decided check, its odds times
// `odds` (moving) or divided by them (static).
double weigh_odds(double p, bool moving, double odds);

}  // namespace slimseg
