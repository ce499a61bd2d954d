// The multi-frame chain of `slimseg dynamic` (slimseg.dynamic.frame_masker, per frame, no
// track stage) for a SLAM system's loop: call step() once per frame, in order, with what the
// SLAM system has (the frame's objects, its ORB keypoints and descriptors, its depth, the
// intrinsics); the chain keeps the history itself. Per frame:
//   stillness   an object whose depth has not changed against the frames still_frames and
//               half as many back gets mobility 0; one overlapping a mask found still the
//               frame before stays still while at most kStillKeepFraction of it changed
//               (slimseg.dynamic.stillness)
//   motion odds the epipolar check on the objects of uncertain mobility (0 < p < 1) weighs
//               their odds by motion_odds (slimseg.dynamic.mobility, motion_evidence)
//   rules       Eq. 1/3/4 and the depth cut, which keeps each object's motion layer: what
//               moved in behind its near layer since the previous frame (occupancy)
// A setting whose needs the stream lacks (no depth, no intrinsics) cannot act: unapplied()
// names it (the caller says so once, or refuses).
#pragma once

#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "slimseg/depth_evidence.hpp"
#include "slimseg/features.hpp"
#include "slimseg/geometry.hpp"
#include "slimseg/rules.hpp"

namespace slimseg {

// What a caller has, for unapplied(): depth images, intrinsics, ORB descriptors per frame.
struct Have {
    bool depth = false, camera = false, descriptors = false;
};

// The settings of `s` switched on whose needs `have` lacks (the knob registry's needs:
// cut_behind_m depth; motion_odds descriptors; motion_layer_px and still_frames depth,
// intrinsics and descriptors), each as "key value".
std::vector<std::string> unapplied(const MaskingSettings& s, const Have& have);

class FrameChain {
public:
    // camera: the intrinsics (nullopt: the stillness test and the motion layers cannot act)
    FrameChain(Rules rules, std::optional<Camera> camera);

    // One frame (h x w): its objects (masks for seg/fusion), its ORB features (the keypoints
    // judged and their descriptors), depth_m h*w metres (null: none), the degrading rule's
    // static support (x, y pairs: ORB-SLAM's FAST corners; null: the keypoints). Error on a
    // frame of another size than the first, or features without 32 descriptor bytes each.
    DynamicResult step(const Objects& objects, int h, int w, const Features& features,
                       const float* depth_m = nullptr, const std::vector<float>* support = nullptr);

    // The mobility the last step's rules used, per object, and which objects were found still.
    const std::vector<float>& mobility() const { return mobility_; }
    const std::vector<std::uint8_t>& still() const { return still_; }
    const Rules& rules() const { return rules_; }

private:
    struct Past {
        Features features;
        std::vector<float> depth;  // empty: none (or no camera)
    };
    std::vector<std::uint8_t> find_still(const Objects& objects, const DepthImage& depth,
                                         const Features& current,
                                         const std::vector<float>& base) const;
    void weigh_motion(const Objects& objects, int h, int w, const Features& current,
                      std::vector<float>& mob) const;

    Rules rules_;
    std::optional<Camera> camera_;
    std::deque<Past> history_;  // oldest first; back(): the previous frame
    int h_ = -1, w_ = -1;
    std::vector<float> mobility_;
    std::vector<std::uint8_t> still_;
    std::vector<WindowMask> still_masks_;  // the masks found still the frame before
};

}  // namespace slimseg
