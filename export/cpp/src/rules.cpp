// The SLAM-facing rules (export/CONTRACT.md "The SLAM mask with keypoints"): mobility per
// class, Eq. 1's adaptive threshold over the caller's keypoints, Eq. 3's dynamic-frame test,
// Eq. 4's seg/box choice, dilation; as slimseg.dynamic.pipeline's seg / box / fusion modes.
#include "slimseg/rules.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstddef>
#include <cstdlib>

namespace slimseg {
namespace {

// an object's depth is this quantile of its mask's; Eq. 4's t_o where the depth cut cannot act
// (no depth under it): both generated from the Python chain's (settings_generated.hpp)
constexpr double kReferenceQuantile = generated::kReferenceQuantile;
constexpr double kUncutTO = generated::kUncutTO;

// Frame pixels whose centre lies in an xyxy box (c + 0.5 >= x1 and c + 0.5 < x2), as a window.
WindowMask box_window(const std::array<float, 4>& b, int h, int w) {
    auto span = [](float lo, float hi, int size) {
        double a = std::ceil(static_cast<double>(lo) - 0.5);
        double e = std::ceil(static_cast<double>(hi) - 0.5);
        int first = static_cast<int>(std::min(std::max(a, 0.0), static_cast<double>(size)));
        int end = static_cast<int>(std::min(std::max(e, 0.0), static_cast<double>(size)));
        return std::pair<int, int>(first, std::max(end, first));
    };
    auto [x0, x1] = span(b[0], b[2], w);
    auto [y0, y1] = span(b[1], b[3], h);
    WindowMask m;
    m.x0 = x0;
    m.y0 = y0;
    m.w = x1 - x0;
    m.h = y1 - y0;
    m.pixels.assign(static_cast<size_t>(m.w) * m.h, 1);
    return m;
}

// slimseg.dynamic.threshold.keypoint_mobility: the highest prior among the regions under each
// keypoint (rounded half to even, clipped to the frame), else 0.
std::vector<float> keypoint_mobility(const std::vector<float>& kps,
                                     const std::vector<WindowMask>& regions,
                                     const std::vector<float>& mob, int h, int w) {
    size_t n = kps.size() / 2;
    std::vector<float> out(n, 0.0f);
    if (regions.empty()) return out;
    for (size_t i = 0; i < n; ++i) {
        int x = static_cast<int>(std::nearbyint(kps[2 * i]));
        int y = static_cast<int>(std::nearbyint(kps[2 * i + 1]));
        x = std::min(std::max(x, 0), w - 1);
        y = std::min(std::max(y, 0), h - 1);
        float best = 0.0f;
        bool any = false;
        for (size_t k = 0; k < regions.size(); ++k) {
            float v = regions[k].at(y, x) ? mob[k] : 0.0f;
            if (!any || v > best) best = v, any = true;
        }
        out[i] = best;
    }
    return out;
}

// Python's round(x, 4): correctly rounded through the shortest decimal text.
double round4(double x) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.4f", x);
    return std::strtod(buf, nullptr);
}

void paint(std::vector<std::uint8_t>& mask, int w, const WindowMask& m) {
    for (int y = 0; y < m.h; ++y)
        for (int x = 0; x < m.w; ++x)
            if (m.pixels[static_cast<size_t>(y) * m.w + x])
                mask[static_cast<size_t>(m.y0 + y) * w + (m.x0 + x)] = 255;
}

// slimseg.dynamic.depth_cut.reference_depths: of the valid depths under the mask inside its
// box, sampled on a grid of step max(1, int(sqrt(area / 400))), the one at sorted index
// int(0.1 * (n - 1)) (REFERENCE_QUANTILE: the object's near layer); NaN without any.
float reference_depth(const WindowMask& mask, const WindowMask& box, const float* depth, int w) {
    std::int64_t area = 0;
    for (int y = box.y0; y < box.y0 + box.h; ++y)
        for (int x = box.x0; x < box.x0 + box.w; ++x) area += mask.at(y, x);
    if (area == 0) return std::nanf("");
    const int step = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(area) / 400.0)));
    std::vector<float> d;
    for (int y = box.y0; y < box.y0 + box.h; y += step)
        for (int x = box.x0; x < box.x0 + box.w; x += step) {
            const float v = depth[static_cast<size_t>(y) * w + x];
            if (mask.at(y, x) && std::isfinite(v) && v > 0) d.push_back(v);
        }
    if (d.empty()) return std::nanf("");
    const auto i = static_cast<std::ptrdiff_t>(kReferenceQuantile * static_cast<double>(d.size() - 1));
    std::nth_element(d.begin(), d.begin() + i, d.end());
    return d[static_cast<size_t>(i)];
}

// slimseg.dynamic.depth_cut.cut_behind: the region's pixels inside the box deeper than
// ref + band (compared in float32; NaN depth or reference: kept) are cleared, except those
// within band of the object's motion layer (NaN: none).
void cut_behind(WindowMask& region, const WindowMask& box, const float* depth, int w, float ref,
                double band, float layer) {
    if (!std::isfinite(ref)) return;
    const float thr = static_cast<float>(static_cast<double>(ref) + band);
    const float near = static_cast<float>(band);
    const bool keep_layer = std::isfinite(layer);
    const int y0 = std::max(box.y0, region.y0), y1 = std::min(box.y0 + box.h, region.y0 + region.h);
    const int x0 = std::max(box.x0, region.x0), x1 = std::min(box.x0 + box.w, region.x0 + region.w);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            if (const float d = depth[static_cast<size_t>(y) * w + x];
                d > thr && !(keep_layer && std::fabs(d - layer) <= near))
                region.pixels[static_cast<size_t>(y - region.y0) * region.w + (x - region.x0)] = 0;
}

// slimseg.dynamic.degrade.degrade with the keypoints as the static support: candidates
// (mobility > m_th_start) leave the mask least certain first (score x mobility; ties: the
// larger region, then the later object) while fewer than min_static keypoints lie outside
// it; scores >= keep_score stay.
// hits[k][i]: region k holds point i (rounded half to even, clipped to the frame)
std::vector<std::vector<std::uint8_t>> hits(const std::vector<WindowMask>& regions,
                                            const std::vector<float>& pts, int h, int w) {
    const size_t m = regions.size(), n = pts.size() / 2;
    std::vector<std::vector<std::uint8_t>> hit(m, std::vector<std::uint8_t>(n, 0));
    for (size_t i = 0; i < n; ++i) {
        int x = static_cast<int>(std::nearbyint(pts[2 * i]));
        int y = static_cast<int>(std::nearbyint(pts[2 * i + 1]));
        x = std::min(std::max(x, 0), w - 1);
        y = std::min(std::max(y, 0), h - 1);
        for (size_t k = 0; k < m; ++k) hit[k][i] = regions[k].at(y, x);
    }
    return hit;
}

// `support`: the static support counted (null: the keypoints)
void degrade(DynamicResult& res, const std::vector<WindowMask>& regions,
             const std::vector<float>& mob, const std::vector<float>& scores,
             const std::vector<float>& kps, const std::vector<float>* support, const Rules& rules,
             float start, int h, int w) {
    const size_t m = regions.size(), n = kps.size() / 2;
    std::vector<std::uint8_t> masked(m, 0);
    for (size_t k = 0; k < m; ++k) masked[k] = mob[k] > start;
    const auto hit = hits(regions, kps, h, w);
    const auto held = support ? hits(regions, *support, h, w) : hit;
    const size_t p = support ? support->size() / 2 : n;
    auto score = [&](size_t k) { return scores.empty() ? 1.0f : scores[k]; };
    auto left = [&]() {
        std::int64_t out = 0;
        for (size_t i = 0; i < p; ++i) {
            bool covered = false;
            for (size_t k = 0; k < m && !covered; ++k) covered = masked[k] && held[k][i];
            out += !covered;
        }
        return out;
    };
    std::vector<size_t> order;
    for (size_t k = 0; k < m; ++k)
        if (masked[k] && score(k) < static_cast<float>(rules.masking.keep_score))
            order.push_back(k);
    std::int64_t have = left();
    if (have >= rules.masking.min_static) order.clear();
    std::vector<std::int64_t> area(m, 0);  // ties: the larger region first, then the later one
    for (size_t k : order)
        for (std::uint8_t v : regions[k].pixels) area[k] += v;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) {
        const float ca = score(a) * mob[a], cb = score(b) * mob[b];
        if (ca != cb) return ca < cb;
        if (area[a] != area[b]) return area[a] > area[b];
        return a > b;
    });
    for (size_t k : order) {
        if (have >= rules.masking.min_static) break;
        masked[k] = 0;
        res.dropped.push_back(static_cast<int>(k));
        have = left();
    }
    for (size_t i = 0; i < n; ++i)
        for (size_t k = 0; k < m; ++k)
            if (masked[k] && hit[k][i]) res.dynamic[i] = 1;
    for (size_t k = 0; k < m; ++k)
        if (masked[k]) paint(res.mask, w, regions[k]);
    res.m_th = round4(rules.masking.m_th_start);
}

}  // namespace

Mode parse_mode(const std::string& name) {
    if (name == "seg") return Mode::Seg;
    if (name == "box") return Mode::Box;
    if (name == "fusion") return Mode::Fusion;
    throw Error("mode '" + name + "': expected seg, box or fusion");
}

Rules Rules::from_metadata(const Metadata& meta, Mode mode, const std::string& preset) {
    const MaskingSettings& s = meta.masking(preset);
    Rules r;
    r.class_mobility = meta.mobility;
    r.mode = mode;
    r.masking = s;
    return r;
}

std::vector<std::string> unapplied(const MaskingSettings& s) {
    std::vector<std::string> out;
    auto number = [](double v) {
        char buf[32];
        std::snprintf(buf, sizeof buf, "%g", v);
        return std::string(buf);
    };
    if (s.motion_odds != generated::kOffMotionOdds)
        out.push_back("motion_odds " + number(s.motion_odds));
    if (s.motion_layer_px != generated::kOffMotionLayerPx)
        out.push_back("motion_layer_px " + std::to_string(s.motion_layer_px));
    if (s.still_frames != generated::kOffStillFrames)
        out.push_back("still_frames " + std::to_string(s.still_frames));
    return out;
}

int scaled_dilation_px(const MaskingSettings& s, int h, int w) {
    return static_cast<int>(
        std::nearbyint(s.dilation_px * static_cast<double>(std::max(h, w)) /
                       s.dilation_reference_px));
}

DynamicResult dynamic_mask(const FramePrediction& p, const std::vector<float>& keypoints_xy,
                           const Rules& rules, const float* depth_m, const Evidence* evidence) {
    return dynamic_mask(objects_of(p), p.h, p.w, keypoints_xy, rules, depth_m, evidence);
}

DynamicResult dynamic_mask(const Objects& objects, int h, int w,
                           const std::vector<float>& keypoints_xy, const Rules& rules,
                           const float* depth_m, const Evidence* evidence) {
    const MaskingSettings& s = rules.masking;
    if (keypoints_xy.size() % 2) throw Error("keypoints: expected (x, y) pairs, got an odd count");
    const size_t m = objects.boxes.size(), n = keypoints_xy.size() / 2;
    if (objects.classes.size() != m || (objects.has_masks && objects.masks.size() != m) ||
        (!objects.scores.empty() && objects.scores.size() != m))
        throw Error("objects: boxes, classes, scores and masks differ in count");
    std::vector<float> mob(m);
    for (size_t i = 0; i < m; ++i) {
        int c = objects.classes[i];
        if (c < 0 || c >= static_cast<int>(rules.class_mobility.size()))
            throw Error("objects: class " + std::to_string(c) + " has no mobility prior (" +
                        std::to_string(rules.class_mobility.size()) + " classes)");
        mob[i] = rules.class_mobility[c];
    }
    if (evidence && !evidence->mobility.empty()) {  // decided by the multi-frame chain
        if (evidence->mobility.size() != m)
            throw Error("evidence: " + std::to_string(evidence->mobility.size()) +
                        " mobilities for " + std::to_string(m) + " objects");
        mob = evidence->mobility;
    }
    if (rules.mode != Mode::Box && !objects.has_masks)
        throw Error("mode seg/fusion needs instance masks (a segmentation model); use box");
    std::vector<WindowMask> boxes, regions;
    for (const auto& b : objects.boxes) boxes.push_back(box_window(b, h, w));
    regions = rules.mode == Mode::Box ? boxes : objects.masks;
    const bool cut = depth_m != nullptr && s.cut_behind_m > 0 && rules.mode != Mode::Box;
    std::vector<float> ref(m, std::nanf("")), layer(m, std::nanf(""));
    for (size_t i = 0; cut && i < m; ++i)  // masks that stay on their object
        ref[i] = reference_depth(regions[i], boxes[i], depth_m, w);
    if (cut && evidence && evidence->layers) {  // what moved in behind the near layer stays
        std::vector<std::uint8_t> behind(static_cast<size_t>(h) * w, 0);
        const float* d = depth_m;
        for (size_t i = 0; i < m; ++i) {
            if (!std::isfinite(ref[i])) continue;
            const float thr = static_cast<float>(static_cast<double>(ref[i]) + s.cut_behind_m);
            const WindowMask& b = boxes[i];
            for (int y = b.y0; y < b.y0 + b.h; ++y)
                for (int x = b.x0; x < b.x0 + b.w; ++x)
                    if (d[static_cast<size_t>(y) * w + x] > thr) behind[static_cast<size_t>(y) * w + x] = 1;
        }
        std::vector<float> got = evidence->layers(behind, ref);
        if (got.size() == m) layer = got;
    }
    for (size_t i = 0; cut && i < m; ++i)
        cut_behind(regions[i], boxes[i], depth_m, w, ref[i], s.cut_behind_m, layer[i]);
    if (s.dilation_px > 0)  // points near a mask edge belong to the object (ORB patches)
        for (auto& r : regions) r = dilate(r, s.dilation_px, h, w);
    DynamicResult res;
    std::vector<float> point_mob = keypoint_mobility(keypoints_xy, regions, mob, h, w);
    // Eq. 3 counts the points inside the detection boxes
    std::vector<float> box_mob = keypoint_mobility(keypoints_xy, boxes, mob, h, w);
    if (n > 0) {
        size_t movers = 0;
        for (float v : box_mob) movers += v > 0.5f;
        res.dynamic_frame = static_cast<double>(movers) / static_cast<double>(n) > s.frame_ratio;
    }
    if (rules.mode == Mode::Fusion && res.dynamic_frame && m > 0) {  // Eq. 4
        res.used_seg.assign(m, 0);
        for (size_t i = 0; i < m; ++i) {
            const WindowMask& b = boxes[i];
            const WindowMask& r = regions[i];
            std::int64_t inter = 0;  // the box is a full rectangle: count r's pixels inside it
            const int x0 = std::max(b.x0, r.x0), x1 = std::min(b.x0 + b.w, r.x0 + r.w);
            const int y0 = std::max(b.y0, r.y0), y1 = std::min(b.y0 + b.h, r.y0 + r.h);
            for (int y = y0; y < y1; ++y) {
                const std::uint8_t* row = &r.pixels[static_cast<size_t>(y - r.y0) * r.w];
                for (int x = x0; x < x1; ++x) inter += row[x - r.x0];
            }
            double s_o = static_cast<double>(inter) /
                         static_cast<double>(std::max<std::int64_t>(b.area(), 1));
            // slimseg.dynamic.pipeline.eq4_thresholds: a box no depth cut can trim replaces only
            // a seg mask covering at most the papers' t_o of it
            const double t_o = s.cut_behind_m > 0 && !std::isfinite(ref[i])
                                   ? std::min(s.t_o, kUncutTO) : s.t_o;
            res.used_seg[i] = s_o > t_o;
            if (!res.used_seg[i]) {
                regions[i] = b;
                if (cut) cut_behind(regions[i], b, depth_m, w, ref[i], s.cut_behind_m, layer[i]);
            }
        }
        point_mob = keypoint_mobility(keypoints_xy, regions, mob, h, w);
    }
    res.mask.assign(static_cast<size_t>(h) * w, 0);
    res.dynamic.assign(n, 0);
    const float start = static_cast<float>(s.m_th_start + 1e-9);
    if (rules.degrade()) {
        degrade(res, regions, mob, objects.scores, keypoints_xy,
                evidence ? evidence->support : nullptr, rules, start, h, w);
        return res;
    }
    // Eq. 1: raise m_th until at least min_static points stay static (compared in float32,
    // as NumPy compares a float32 array with a Python float)
    double m_th = s.m_th_start;
    while (m_th <= 1.0 + 1e-9) {
        const float thr = static_cast<float>(m_th + 1e-9);
        size_t stat = 0;
        for (size_t i = 0; i < n; ++i) stat += !(point_mob[i] > thr);
        if (static_cast<std::int64_t>(stat) >= s.min_static) {
            for (size_t i = 0; i < n; ++i) res.dynamic[i] = point_mob[i] > thr;
            res.m_th = round4(m_th);
            const float sel = static_cast<float>(res.m_th);
            for (size_t i = 0; i < m; ++i) {
                if (mob[i] > sel) paint(res.mask, w, regions[i]);
                else if (mob[i] > start) res.dropped.push_back(static_cast<int>(i));
            }
            return res;
        }
        m_th += s.m_th_step;
    }
    res.gave_up = true;
    for (size_t i = 0; i < m; ++i)
        if (mob[i] > start) res.dropped.push_back(static_cast<int>(i));
    return res;
}

std::vector<std::uint8_t> class_mask(const FramePrediction& p, const std::vector<int>& classes,
                                     int radius) {
    WindowMask full;
    full.w = p.w;
    full.h = p.h;
    full.pixels.assign(static_cast<size_t>(p.w) * p.h, 0);
    auto wanted = [&](int c) { return std::find(classes.begin(), classes.end(), c) != classes.end(); };
    if (p.semantic) {
        for (size_t i = 0; i < p.class_map.size(); ++i)
            full.pixels[i] = p.class_map[i] > 0 && wanted(p.class_map[i] - 1);
    } else {
        for (size_t k = 0; k < p.detections.size(); ++k) {
            if (!wanted(p.detections[k].cls)) continue;
            WindowMask m = p.segmenter ? p.masks[k] : box_window(p.detections[k].box, p.h, p.w);
            for (int y = 0; y < m.h; ++y)
                for (int x = 0; x < m.w; ++x)
                    if (m.pixels[static_cast<size_t>(y) * m.w + x])
                        full.pixels[static_cast<size_t>(m.y0 + y) * p.w + (m.x0 + x)] = 1;
        }
    }
    WindowMask d = dilate(full, radius, p.h, p.w);
    std::vector<std::uint8_t> out(d.pixels.size());
    for (size_t i = 0; i < out.size(); ++i) out[i] = d.pixels[i] ? 255 : 0;
    return out;
}

}  // namespace slimseg
