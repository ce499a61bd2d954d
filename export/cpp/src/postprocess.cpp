// Post-processing (export/CONTRACT.md "Post-processing, step by step"): decode, class-aware
// NMS, prototype masks cropped to the box and resized to the frame; MSNET class maps.
//
// The float arithmetic follows slimseg's Python reference (slimseg.ops.nms, slimseg.ops.masks,
// slimseg.ops.letterbox.boxes_to_frame) operation by operation, in float32 where it is float32,
// so boxes and scores come out bit-identical and masks differ at most on pixels whose
// probability is within float rounding of 0.5.
#include "slimseg/postprocess.hpp"

#include "mask_assembly.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace slimseg {
namespace {

using detail::shape_str;
using detail::unbatched;

constexpr int kMaxCandidates = 30000;  // slimseg.ops.nms.non_max_suppression max_candidates
constexpr int kTorchvisionVanillaNumel = 4000;  // torchvision batched_nms: per-class loop above

struct Candidate {
    int anchor;
    float score;
    int cls;
    std::array<float, 4> box;  // xyxy input pixels
};

float iou_f32(const std::array<float, 4>& a, float area_a, const std::array<float, 4>& b,
              float area_b) {
    // torchvision nms_kernel_cpu, float32
    float xx1 = std::max(a[0], b[0]), yy1 = std::max(a[1], b[1]);
    float xx2 = std::min(a[2], b[2]), yy2 = std::min(a[3], b[3]);
    float w = std::max(0.0f, xx2 - xx1), h = std::max(0.0f, yy2 - yy1);
    float inter = w * h;
    float denom = area_a + area_b;
    denom = denom - inter;
    return inter / denom;
}

// Greedy NMS over `idx` (indices into boxes/scores), ordered by decreasing score (stable: ties
// keep their order); returns the kept indices in that order.
std::vector<int> greedy_nms(const std::vector<std::array<float, 4>>& boxes,
                            const std::vector<float>& scores, std::vector<int> idx, double iou) {
    std::stable_sort(idx.begin(), idx.end(), [&](int a, int b) { return scores[a] > scores[b]; });
    std::vector<float> area(idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
        const auto& b = boxes[idx[k]];
        area[k] = (b[2] - b[0]) * (b[3] - b[1]);
    }
    std::vector<char> gone(idx.size(), 0);
    std::vector<int> keep;
    for (size_t i = 0; i < idx.size(); ++i) {
        if (gone[i]) continue;
        keep.push_back(idx[i]);
        for (size_t j = i + 1; j < idx.size(); ++j) {
            if (gone[j]) continue;
            float ovr = iou_f32(boxes[idx[i]], area[i], boxes[idx[j]], area[j]);
            if (static_cast<double>(ovr) > iou) gone[j] = 1;
        }
    }
    return keep;
}

// torchvision.ops.batched_nms as slimseg calls it: the coordinate-offset trick for up to 1000
// boxes, one NMS per class above (then a sort by decreasing score; ties: anchor order).
std::vector<int> batched_nms(const std::vector<Candidate>& c, double iou, bool class_aware) {
    const int n = static_cast<int>(c.size());
    if (n == 0) return {};
    std::vector<float> scores(n);
    for (int i = 0; i < n; ++i) scores[i] = c[i].score;
    std::vector<int> all(n);
    std::iota(all.begin(), all.end(), 0);
    if (!class_aware) {
        std::vector<std::array<float, 4>> boxes(n);
        for (int i = 0; i < n; ++i) boxes[i] = c[i].box;
        return greedy_nms(boxes, scores, all, iou);
    }
    if (4 * n <= kTorchvisionVanillaNumel) {
        float maxc = c[0].box[0];
        for (const auto& d : c)
            for (float v : d.box) maxc = std::max(maxc, v);
        std::vector<std::array<float, 4>> boxes(n);
        for (int i = 0; i < n; ++i) {
            float off = static_cast<float>(c[i].cls) * (maxc + 1.0f);
            for (int k = 0; k < 4; ++k) boxes[i][k] = c[i].box[k] + off;
        }
        return greedy_nms(boxes, scores, all, iou);
    }
    std::vector<std::array<float, 4>> boxes(n);
    for (int i = 0; i < n; ++i) boxes[i] = c[i].box;
    std::vector<int> classes;
    for (const auto& d : c) classes.push_back(d.cls);
    std::sort(classes.begin(), classes.end());
    classes.erase(std::unique(classes.begin(), classes.end()), classes.end());
    std::vector<char> kept(n, 0);
    for (int cls : classes) {
        std::vector<int> idx;
        for (int i = 0; i < n; ++i)
            if (c[i].cls == cls) idx.push_back(i);
        for (int k : greedy_nms(boxes, scores, idx, iou)) kept[k] = 1;
    }
    std::vector<int> keep;
    for (int i = 0; i < n; ++i)
        if (kept[i]) keep.push_back(i);
    std::stable_sort(keep.begin(), keep.end(), [&](int a, int b) { return scores[a] > scores[b]; });
    return keep;
}

}  // namespace

Postprocessor::Postprocessor(Metadata meta) : meta_(std::move(meta)) {
    if (meta_.names.empty()) throw Error("metadata names: no classes");
}

FramePrediction Postprocessor::run(const RawOutputs& raw, int h, int w) const {
    return run(raw, h, w, meta_.nms.conf, meta_.nms.iou, meta_.nms.max_det);
}

FramePrediction Postprocessor::run(const RawOutputs& raw, int h, int w, double conf) const {
    return run(raw, h, w, conf, meta_.nms.iou, meta_.nms.max_det);
}

FramePrediction Postprocessor::run(const RawOutputs& raw, int h, int w, double conf, double iou,
                                   int max_det) const {
    Letterbox lb = letterbox_params(h, w, meta_.input_h, meta_.input_w);
    if (meta_.semantic()) return semantic(raw.output0, lb, h, w);
    return instances(raw, lb, h, w, conf, iou, max_det);
}

FramePrediction Postprocessor::instances(const RawOutputs& raw, const Letterbox& lb, int h,
                                         int w, double conf, double iou, int max_det) const {
    const int nc = meta_.num_classes(), nm = meta_.num_masks;
    const bool dark = meta_.darknet();
    const int rows = dark ? 5 + nc : 4 + nc + nm;
    const std::string expect = "[1, " + std::to_string(rows) + ", A] (" + std::to_string(nc) +
                               " classes" + (nm ? ", " + std::to_string(nm) + " mask coefficients"
                                                : std::string()) + ")";
    auto s0 = unbatched(raw.output0, 2, "output0", expect);
    if (s0[0] != rows)
        throw Error("output0: shape " + shape_str(raw.output0.shape) + ", expected " + expect);
    std::int64_t cells = 0;
    for (int s : meta_.strides) cells += (lb.out_h / s) * (lb.out_w / s);
    const std::int64_t anchors = dark ? 3 * cells : cells;
    if (s0[1] != anchors)
        throw Error("output0: " + std::to_string(s0[1]) + " anchors, but input " +
                    std::to_string(lb.out_h) + "x" + std::to_string(lb.out_w) + " with strides " +
                    "in metadata strides gives " + std::to_string(anchors));
    const int A = static_cast<int>(anchors);
    int hp = 0, wp = 0;
    if (nm) {
        if (raw.output1 == nullptr) throw Error("output1: missing (the model is a segmenter)");
        hp = lb.out_h / meta_.proto_stride;
        wp = lb.out_w / meta_.proto_stride;
        std::string e1 = "[1, " + std::to_string(nm) + ", " + std::to_string(hp) + ", " +
                         std::to_string(wp) + "]";
        auto s1 = unbatched(*raw.output1, 3, "output1", e1);
        if (s1[0] != nm || s1[1] != hp || s1[2] != wp)
            throw Error("output1: shape " + shape_str(raw.output1->shape) + ", expected " + e1);
    }
    const std::vector<float> out0 = to_float(raw.output0);
    auto at = [&](int row, int a) { return out0[static_cast<size_t>(row) * A + a]; };

    // 1-2: best class per anchor, score > conf (compared in float32, as torch does)
    const float thr = static_cast<float>(conf);
    std::vector<Candidate> cand;
    for (int a = 0; a < A; ++a) {
        float best = 0.f;
        int cls = 0;
        for (int k = 0; k < nc; ++k) {
            float s = dark ? at(4, a) * at(5 + k, a) : at(4 + k, a);
            if (k == 0 || s > best) best = s, cls = k;
        }
        if (!(best > thr)) continue;
        float cx = at(0, a), cy = at(1, a), bw = at(2, a) / 2.0f, bh = at(3, a) / 2.0f;
        cand.push_back({a, best, cls, {cx - bw, cy - bh, cx + bw, cy + bh}});
    }
    if (static_cast<int>(cand.size()) > kMaxCandidates) {  // torch.topk; ties: anchor order
        std::stable_sort(cand.begin(), cand.end(),
                         [](const Candidate& x, const Candidate& y) { return x.score > y.score; });
        cand.resize(kMaxCandidates);
    }
    // 3: class-aware NMS, best max_det
    std::vector<int> keep = batched_nms(cand, iou, meta_.nms.class_aware);
    if (static_cast<int>(keep.size()) > max_det) keep.resize(std::max(max_det, 0));

    FramePrediction out;
    out.h = h;
    out.w = w;
    out.segmenter = nm > 0;
    for (int k : keep) {
        Detection d;
        const Candidate& c = cand[k];
        d.box_input = c.box;
        d.score = c.score;
        d.cls = c.cls;
        // slimseg.ops.letterbox.boxes_to_frame, float32
        const float left = static_cast<float>(lb.left), top = static_cast<float>(lb.top);
        const float scale = static_cast<float>(lb.scale);
        for (int j = 0; j < 4; ++j) {
            float v = (c.box[j] - (j % 2 == 0 ? left : top)) / scale;
            float hi = static_cast<float>(j % 2 == 0 ? w : h);
            d.box[j] = std::min(std::max(v, 0.0f), hi);
        }
        out.detections.push_back(d);
    }
    if (nm == 0) return out;

    // 4-5: masks (slimseg.ops.masks_numpy.frame_masks)
    const std::vector<float> proto = to_float(*raw.output1);
    const size_t plane = static_cast<size_t>(hp) * wp;
    const detail::MaskGeometry g = detail::mask_geometry(lb, h, w, hp, wp);
    std::vector<float> prob;
    std::vector<double> acc;
    for (int k : keep) {
        const Candidate& c = cand[k];
        const detail::ProtoWindow win = detail::proto_window(g, c.box);
        if (win.empty()) {
            out.masks.emplace_back();
            continue;
        }
        prob.assign(static_cast<size_t>(win.pw) * win.ph, 0.0f);
        acc.assign(static_cast<size_t>(win.pw), 0.0);
        for (int iy = 0; iy < win.ph; ++iy) {  // coefficients . prototypes, in double
            std::fill(acc.begin(), acc.end(), 0.0);
            const size_t off = static_cast<size_t>(win.py0 + iy) * wp + win.px0;
            for (int j = 0; j < nm; ++j) {
                const double cj = at(4 + nc + j, c.anchor);
                const float* row = proto.data() + j * plane + off;
                for (int ix = 0; ix < win.pw; ++ix) acc[ix] += cj * row[ix];
            }
            float* dst = prob.data() + static_cast<size_t>(iy) * win.pw;
            for (int ix = 0; ix < win.pw; ++ix)
                dst[ix] = 1.0f / (1.0f + std::exp(-static_cast<float>(acc[ix])));
        }
        out.masks.push_back(detail::frame_mask(g, win, prob.data(), win.pw));
    }
    return out;
}

FramePrediction Postprocessor::semantic(const TensorView& logits, const Letterbox& lb, int h,
                                        int w) const {
    const int k1 = meta_.num_classes() + 1;
    const std::string expect = "[1, " + std::to_string(k1) + ", " + std::to_string(lb.out_h) +
                               ", " + std::to_string(lb.out_w) + "] (background + " +
                               std::to_string(k1 - 1) + " classes)";
    auto s = unbatched(logits, 3, "logits", expect);
    if (s[0] != k1 || s[1] != lb.out_h || s[2] != lb.out_w)
        throw Error("logits: shape " + shape_str(logits.shape) + ", expected " + expect);
    const std::vector<float> v = to_float(logits);
    const size_t plane = static_cast<size_t>(lb.out_h) * lb.out_w;
    const detail::Taps tx = detail::interpolate_taps(w, lb.new_w),
                       ty = detail::interpolate_taps(h, lb.new_h);
    FramePrediction out;
    out.h = h;
    out.w = w;
    out.semantic = true;
    out.class_map.assign(static_cast<size_t>(h) * w, 0);
    for (int y = 0; y < h; ++y) {
        size_t r0 = static_cast<size_t>(ty.i0[y] + lb.top) * lb.out_w + lb.left;
        size_t r1 = static_cast<size_t>(ty.i1[y] + lb.top) * lb.out_w + lb.left;
        for (int x = 0; x < w; ++x) {
            float best = 0.0f;
            int arg = 0;
            for (int c = 0; c < k1; ++c) {
                const float* p = v.data() + c * plane;
                float val = detail::interp_torch(p[r0 + tx.i0[x]], p[r0 + tx.i1[x]], p[r1 + tx.i0[x]],
                                   p[r1 + tx.i1[x]], tx.w1[x], ty.w1[y]);
                if (c == 0 || val > best) best = val, arg = c;
            }
            out.class_map[static_cast<size_t>(y) * w + x] = static_cast<std::uint8_t>(arg);
        }
    }
    return out;
}

}  // namespace slimseg
