// The multi-frame chain, one frame at a time (include/slimseg/chain.hpp).
#include "slimseg/chain.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "slimseg/motion_check.hpp"

namespace slimseg {

namespace mf = generated::multi_frame;

namespace {

std::string number(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

}  // namespace

std::vector<std::string> unapplied(const MaskingSettings& s, const Have& have) {
    std::vector<std::string> out;
    if (s.cut_behind_m != generated::kOffCutBehindM && !have.depth)
        out.push_back("cut_behind_m " + number(s.cut_behind_m));
    if (s.motion_odds != generated::kOffMotionOdds && !have.descriptors)
        out.push_back("motion_odds " + number(s.motion_odds));
    const bool history = have.depth && have.camera && have.descriptors;
    if (s.motion_layer_px != generated::kOffMotionLayerPx && !history)
        out.push_back("motion_layer_px " + std::to_string(s.motion_layer_px));
    if (s.still_frames != generated::kOffStillFrames && !history)
        out.push_back("still_frames " + std::to_string(s.still_frames));
    return out;
}

FrameChain::FrameChain(Rules rules, std::optional<Camera> camera)
    : rules_(std::move(rules)), camera_(camera) {}

std::vector<std::uint8_t> FrameChain::find_still(const Objects& objects, const DepthImage& depth,
                                                 const Features& current,
                                                 const std::vector<float>& base) const {
    const size_t m = objects.boxes.size();
    std::vector<std::uint8_t> still(m, 0);
    // stillness.compared_frames: the frames t - n // 2 and t - n, n the history up to
    // still_frames; none until it holds half of them
    const int sf = rules_.masking.still_frames;
    const int n = std::min(static_cast<int>(history_.size()), sf);
    if (sf <= 0 || n < (sf + 1) / 2 || !objects.has_masks || !depth.d || !camera_) return still;
    const int size = static_cast<int>(history_.size());
    const Past* earlier[2] = {&history_[size - std::max(n / 2, 1)], &history_[size - n]};
    // stillness.still_objects: an object overlapping a mask found still the frame before is
    // still while at most kStillKeepFraction changed (undecided: the verdict stands)
    std::vector<std::uint8_t> known(m, 0);
    std::vector<double> limit(m, mf::kStillFraction), frac(m, INFINITY);
    for (size_t k = 0; k < m; ++k) {
        if (!(base[k] > 0)) continue;
        frac[k] = 0.0;
        for (const WindowMask& b : still_masks_)
            if (grid_iou(objects.masks[k], b) >= mf::kStillMatchIou) known[k] = 1;
        if (known[k]) limit[k] = mf::kStillKeepFraction;
    }
    for (const Past* frame : earlier) {
        std::vector<size_t> pick;
        for (size_t k = 0; k < m; ++k)
            if (frac[k] <= limit[k]) pick.push_back(k);
        if (pick.empty()) break;
        Pose pose;
        if (frame->depth.empty() ||
            !camera_pose(frame->features, frame->depth.data(), current, depth.d, depth.h, depth.w,
                         *camera_, pose))
            return std::vector<std::uint8_t>(m, 0);
        std::vector<const WindowMask*> masks;
        for (size_t k : pick) masks.push_back(&objects.masks[k]);
        const DepthImage then{frame->depth.data(), depth.h, depth.w};
        const std::vector<double> f = changed_fractions(depth, then, *camera_, pose, masks);
        for (size_t j = 0; j < pick.size(); ++j) {
            const size_t k = pick[j];
            // NaN: undecided, dynamic; a remembered object keeps its verdict
            const double v = std::isnan(f[j]) ? (known[k] ? 0.0 : INFINITY) : f[j];
            frac[k] = std::max(frac[k], v);
        }
    }
    for (size_t k = 0; k < m; ++k) still[k] = frac[k] <= limit[k];
    return still;
}

void FrameChain::weigh_motion(const Objects& objects, int h, int w, const Features& current,
                              std::vector<float>& mob) const {
    const MaskingSettings& s = rules_.masking;
    if (rules_.mode == Mode::Box || !(s.motion_odds > 1) || !objects.has_masks ||
        history_.empty())
        return;
    std::vector<size_t> checked;
    std::vector<const WindowMask*> regions;
    for (size_t k = 0; k < mob.size(); ++k)
        if (mob[k] > 0 && mob[k] < 1) {
            checked.push_back(k);
            regions.push_back(&objects.masks[k]);
        }
    if (checked.empty()) return;
    const MotionCheck r = check_motion(history_.back().features, current, regions, h, w);
    for (size_t j = 0; j < checked.size(); ++j) {
        const double p = mob[checked[j]];
        if (r.decided[j] && p > 0.0 && p < 1.0)
            mob[checked[j]] = static_cast<float>(weigh_odds(p, r.moving[j], s.motion_odds));
    }
}

DynamicResult FrameChain::step(const Objects& objects, int h, int w, const Features& features,
                               const float* depth_m, const std::vector<float>* support) {
    features.check();
    if (h_ >= 0 && (h != h_ || w != w_))
        throw Error("frame " + std::to_string(h) + "x" + std::to_string(w) + ": the first was " +
                    std::to_string(h_) + "x" + std::to_string(w_) +
                    "; a chain serves one camera stream");
    h_ = h, w_ = w;
    const size_t m = objects.boxes.size();
    std::vector<float> base(m);
    for (size_t k = 0; k < m; ++k) {
        const int c = objects.classes.at(k);
        if (c < 0 || c >= static_cast<int>(rules_.class_mobility.size()))
            throw Error("objects: class " + std::to_string(c) + " has no mobility prior");
        base[k] = rules_.class_mobility[c];
    }
    const DepthImage depth{depth_m, h, w};
    still_ = find_still(objects, depth, features, base);
    still_masks_.clear();  // the masks found still: the next frame's memory (none untested)
    for (size_t k = 0; k < m; ++k)
        if (still_[k]) still_masks_.push_back(objects.masks[k]);
    std::vector<float> mob = base;
    for (size_t k = 0; k < m; ++k)
        if (still_[k]) mob[k] = 0.0f;  // standing still: static structure
    weigh_motion(objects, h, w, features, mob);
    Evidence ev;
    ev.mobility = mob;
    ev.support = support;
    const MaskingSettings& s = rules_.masking;
    const Past* prev = history_.empty() ? nullptr : &history_.back();
    if (s.motion_layer_px > 0 && s.cut_behind_m > 0 && depth_m && camera_ && prev &&
        !prev->depth.empty()) {
        ev.layers = [&, prev](const std::vector<std::uint8_t>& behind,
                              const std::vector<float>& reference) -> std::vector<float> {
            const std::vector<std::uint8_t> where = surface_pixels(depth, behind);
            bool any = false;
            for (std::uint8_t v : where) any |= v != 0;
            Pose pose;
            if (!any || !camera_pose(prev->features, prev->depth.data(), features, depth_m, h, w,
                                     *camera_, pose))
                return {};
            const DepthImage before{prev->depth.data(), h, w};
            const auto marked = moved_in(depth, before, *camera_, pose, where);
            return motion_layers(marked, depth, objects.boxes, reference, s.cut_behind_m,
                                 s.motion_layer_px);
        };
    }
    DynamicResult res = dynamic_mask(objects, h, w, features.xy, rules_, depth_m, &ev);
    mobility_ = mob;
    Past now;  // the next frames' history (with its depth where the camera is known)
    now.features = features;
    if (depth_m && camera_) now.depth.assign(depth_m, depth_m + static_cast<size_t>(h) * w);
    history_.push_back(std::move(now));
    while (static_cast<int>(history_.size()) > std::max(1, s.still_frames)) history_.pop_front();
    return res;
}

}  // namespace slimseg
