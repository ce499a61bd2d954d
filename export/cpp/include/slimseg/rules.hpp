// The SLAM-facing rules (export/CONTRACT.md "The SLAM mask with keypoints"): mobility per
// class, Eq. 1's adaptive threshold or the degrading rule over the caller's keypoints, Eq. 3,
// Eq. 4, the depth cut and dilation, as `slimseg dynamic`'s seg / box / fusion modes.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "slimseg/error.hpp"
#include "slimseg/mask.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/postprocess.hpp"

namespace slimseg {

enum class Mode { Seg, Box, Fusion };
Mode parse_mode(const std::string& name);  // "seg", "box", "fusion"

struct Rules {
    std::vector<float> class_mobility;  // prior per class
    Mode mode = Mode::Fusion;
    // the export's slam_masking settings, as they are (one home: metadata.hpp): Eq. 1's
    // min_static / m_th_start / m_th_step, Eq. 3's frame_ratio, Eq. 4's t_o, dilation_px
    // (frame pixels, applied as given: see scaled_dilation_px), the shortfall rule (eq1:
    // Eq. 1 raises the threshold, then gives up the frame; degrade: the least certain
    // candidates (score x mobility) go one at a time while fewer than min_static keypoints
    // stay outside the mask, those scoring >= keep_score never, slimseg.dynamic.degrade; the
    // caller's keypoints are the static support) and, with a depth image (seg / fusion),
    // cut_behind_m (slimseg.dynamic.depth_cut); conf acts on the detector, not here
    MaskingSettings masking;

    bool degrade() const { return masking.rule == "degrade"; }
    static Rules from_metadata(const Metadata& meta, Mode mode, const std::string& preset = "");
};

// The settings of `s` switched on that dynamic_mask alone does not apply (the multi-frame
// evidence of `slimseg dynamic`: motion_odds, motion_layer_px, still_frames; FrameChain in
// slimseg/chain.hpp applies them), each as "key value"; empty: its masks follow every
// setting. A caller says so once, or refuses.
std::vector<std::string> unapplied(const MaskingSettings& s);

// dilation_px scaled to a frame: round(dilation_px * max(h, w) / dilation_reference_px).
int scaled_dilation_px(const MaskingSettings& s, int h, int w);

// The objects the rules work on: a prediction's instances, or a class map's 8-connected
// components (>= min_area pixels) for semantic models.
struct Objects {
    std::vector<std::array<float, 4>> boxes;  // frame pixels, xyxy
    std::vector<int> classes;
    std::vector<float> scores;                // empty: all 1 (class-map components)
    std::vector<WindowMask> masks;            // empty for detection-only models
    bool has_masks = false;
};
Objects objects_of(const FramePrediction& p, int min_area = 32);

struct DynamicResult {
    std::vector<std::uint8_t> mask;  // h*w, 255 = dynamic region
    std::vector<std::uint8_t> dynamic;  // per keypoint, 0/1
    bool gave_up = false;            // Eq. 1 found no threshold: nothing masked
    std::vector<int> dropped;        // candidates left out of the mask (degrade: in order)
    double m_th = 0.0;
    bool dynamic_frame = false;      // Eq. 3
    std::vector<std::uint8_t> used_seg;  // Eq. 4 per object (fusion on dynamic frames)
};

// What the multi-frame chain (slimseg/chain.hpp) brings to one frame's rules: the objects'
// decided mobility (empty: the class priors), their motion layers given the pixels the depth
// cut would drop (h*w 0/1) and the objects' near depths (NaN: none; null or a result of
// another size: none), and the degrading rule's static support (x, y pairs; null: the
// keypoints).
struct Evidence {
    std::vector<float> mobility;
    std::function<std::vector<float>(const std::vector<std::uint8_t>& behind,
                                      const std::vector<float>& reference)>
        layers;
    const std::vector<float>* support = nullptr;
};

// keypoints_xy: N (x, y) pairs in frame pixels, flattened.
// depth_m: optional h*w metres (0 or NaN: no depth), for rules.cut_behind_m.
DynamicResult dynamic_mask(const FramePrediction& p, const std::vector<float>& keypoints_xy,
                           const Rules& rules, const float* depth_m = nullptr,
                           const Evidence* evidence = nullptr);
DynamicResult dynamic_mask(const Objects& objects, int h, int w,
                           const std::vector<float>& keypoints_xy, const Rules& rules,
                           const float* depth_m = nullptr, const Evidence* evidence = nullptr);

// The contract's step 6 without keypoints: union of the masks (boxes for detection models,
// class pixels for class maps) of `classes`, dilated by `radius` frame pixels.
std::vector<std::uint8_t> class_mask(const FramePrediction& p, const std::vector<int>& classes,
                                     int radius);

}  // namespace slimseg
