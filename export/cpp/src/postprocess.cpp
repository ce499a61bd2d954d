// Post-processing (export/CONTRACT.md "Post-processing, step by step"): decode, class-aware
// NMS, prototype masks cropped to the box and resized to the frame; MSNET class maps.
//
// The float arithmetic follows slimseg's Python reference (slimseg.ops.nms, slimseg.ops.masks,
// slimseg.ops.letterbox.boxes_to_frame) operation by operation, in float32 where it is float32,
// so boxes and scores come out bit-identical and masks differ at most on pixels whose
// probability is within float rounding of 0.5.
#include "slimseg/postprocess.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace slimseg {
namespace {

constexpr int kMaxCandidates = 30000;  // slimseg.ops.nms.non_max_suppression max_candidates
constexpr int kTorchvisionVanillaNumel = 4000;  // torchvision batched_nms: per-class loop above

std::string shape_str(const std::vector<std::int64_t>& s) {
    std::string out = "[";
    for (size_t i = 0; i < s.size(); ++i) out += (i ? ", " : "") + std::to_string(s[i]);
    return out + "]";
}

// Drop a leading batch axis of 1.
std::vector<std::int64_t> unbatched(const TensorView& t, size_t ndim, const std::string& name,
                                    const std::string& expected) {
    std::vector<std::int64_t> s = t.shape;
    if (s.size() == ndim + 1) {
        if (s[0] != 1)
            throw Error(name + ": shape " + shape_str(t.shape) + " has batch " +
                        std::to_string(s[0]) + "; pass one frame's slice (batch 1)");
        s.erase(s.begin());
    }
    if (s.size() != ndim)
        throw Error(name + ": shape " + shape_str(t.shape) + ", expected " + expected);
    if (t.data == nullptr) throw Error(name + ": no data");
    return s;
}

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

// slimseg.ops.masks._pixel_span: first pixel and count whose centres lie in [lo, hi).
std::pair<int, int> pixel_span(float lo, float hi, int size) {
    float first = std::min(std::max(std::ceil(lo - 0.5f), 0.0f), static_cast<float>(size));
    float end = std::min(std::max(std::ceil(hi - 0.5f), 0.0f), static_cast<float>(size));
    return {static_cast<int>(first), std::max(static_cast<int>(end - first), 0)};
}

// Bilinear taps (half-pixel centres) resizing size_in -> size_out, the way slimseg's window
// resize computes them (slimseg.ops.masks._bilinear_taps): scale = float(size_in / size_out).
struct Taps {
    std::vector<int> i0, i1;
    std::vector<float> w1;
};

Taps window_taps(int size_out, int size_in) {
    Taps t;
    const float s = static_cast<float>(static_cast<double>(size_in) / size_out);
    for (int o = 0; o < size_out; ++o) {
        float src = std::max((static_cast<float>(o) + 0.5f) * s - 0.5f, 0.0f);
        int a = std::min(static_cast<int>(std::floor(src)), size_in - 1);
        t.i0.push_back(a);
        t.i1.push_back(std::min(a + 1, size_in - 1));
        t.w1.push_back(std::min(std::max(src - static_cast<float>(a), 0.0f), 1.0f));
    }
    return t;
}

// Bilinear taps as torch's F.interpolate (align_corners=False) computes them: scale =
// float(in) / float(out); an axis of equal sizes is copied.
Taps interpolate_taps(int size_out, int size_in) {
    Taps t;
    const float s = static_cast<float>(size_in) / static_cast<float>(size_out);
    for (int o = 0; o < size_out; ++o) {
        if (size_in == size_out) {
            t.i0.push_back(o);
            t.i1.push_back(o);
            t.w1.push_back(0.0f);
            continue;
        }
        float src = std::max(std::fma(s, static_cast<float>(o) + 0.5f, -0.5f), 0.0f);
        int a = std::min(static_cast<int>(std::floor(src)), size_in - 1);
        t.i0.push_back(a);
        t.i1.push_back(a + (a < size_in - 1 ? 1 : 0));
        t.w1.push_back(std::min(std::max(src - static_cast<float>(a), 0.0f), 1.0f));
    }
    return t;
}

// torch's CPU bilinear kernel (F.interpolate; its AVX2/AVX-512 builds contract a*b + c*d into
// fma(a, b, c*d)): x first, then y. Bit-identical on the prototype upsampling (ratio 2 or 4).
inline float interp_torch(float v00, float v01, float v10, float v11, float wx, float wy) {
    float r0 = std::fma(v00, 1.0f - wx, v01 * wx);
    float r1 = std::fma(v10, 1.0f - wx, v11 * wx);
    return std::fma(r0, 1.0f - wy, r1 * wy);
}

// slimseg.ops.masks._resize_window: separate torch element-wise ops, each rounded.
inline float interp(float v00, float v01, float v10, float v11, float wx, float wy) {
    float r0 = v00 * (1.0f - wx);
    r0 = r0 + v01 * wx;
    float r1 = v10 * (1.0f - wx);
    r1 = r1 + v11 * wx;
    float out = r0 * (1.0f - wy);
    return out + r1 * wy;
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

    // 4-5: masks (slimseg.ops.masks: assemble_masks, then masks_to_frame)
    const std::vector<float> proto = to_float(*raw.output1);
    const size_t plane = static_cast<size_t>(hp) * wp;
    const Taps ux = interpolate_taps(lb.out_w, wp), uy = interpolate_taps(lb.out_h, hp);
    const bool same = lb.new_h == h && lb.new_w == w;
    Taps fx, fy;
    if (!same) {
        fx = window_taps(w, lb.new_w);
        fy = window_taps(h, lb.new_h);
    }
    std::vector<float> prob, up;
    std::vector<double> acc;
    for (int k : keep) {
        const Candidate& c = cand[k];
        auto [x0, nx] = pixel_span(c.box[0], c.box[2], lb.out_w);
        auto [y0, ny] = pixel_span(c.box[1], c.box[3], lb.out_h);
        WindowMask m;
        if (nx > 0 && ny > 0) {
            // prototype window the upsampling of the span reads
            int px0 = ux.i0[x0], px1 = ux.i1[x0 + nx - 1], py0 = uy.i0[y0],
                py1 = uy.i1[y0 + ny - 1];
            int pw = px1 - px0 + 1, ph = py1 - py0 + 1;
            prob.assign(static_cast<size_t>(pw) * ph, 0.0f);
            acc.assign(static_cast<size_t>(pw), 0.0);
            for (int iy = 0; iy < ph; ++iy) {  // coefficients . prototypes, in double
                std::fill(acc.begin(), acc.end(), 0.0);
                const size_t off = static_cast<size_t>(py0 + iy) * wp + px0;
                for (int j = 0; j < nm; ++j) {
                    const double cj = at(4 + nc + j, c.anchor);
                    const float* row = proto.data() + j * plane + off;
                    for (int ix = 0; ix < pw; ++ix) acc[ix] += cj * row[ix];
                }
                float* out = prob.data() + static_cast<size_t>(iy) * pw;
                for (int ix = 0; ix < pw; ++ix)
                    out[ix] = 1.0f / (1.0f + std::exp(-static_cast<float>(acc[ix])));
            }
            auto P = [&](int iy, int ix) { return prob[static_cast<size_t>(iy - py0) * pw + ix - px0]; };
            // upsampled probabilities on the span (input pixels), 0 elsewhere
            up.assign(static_cast<size_t>(nx) * ny, 0.0f);
            for (int y = 0; y < ny; ++y) {
                int yy = y0 + y;
                for (int x = 0; x < nx; ++x) {
                    int xx = x0 + x;
                    up[static_cast<size_t>(y) * nx + x] =
                        interp_torch(P(uy.i0[yy], ux.i0[xx]), P(uy.i0[yy], ux.i1[xx]),
                               P(uy.i1[yy], ux.i0[xx]), P(uy.i1[yy], ux.i1[xx]), ux.w1[xx],
                               uy.w1[yy]);
                }
            }
            if (same) {  // no resize: threshold at input resolution, drop the padding
                int fx0 = std::max(x0, lb.left), fx1 = std::min(x0 + nx, lb.left + lb.new_w);
                int fy0 = std::max(y0, lb.top), fy1 = std::min(y0 + ny, lb.top + lb.new_h);
                if (fx1 > fx0 && fy1 > fy0) {
                    m.x0 = fx0 - lb.left;
                    m.y0 = fy0 - lb.top;
                    m.w = fx1 - fx0;
                    m.h = fy1 - fy0;
                    m.pixels.resize(static_cast<size_t>(m.w) * m.h);
                    for (int y = 0; y < m.h; ++y)
                        for (int x = 0; x < m.w; ++x)
                            m.pixels[static_cast<size_t>(y) * m.w + x] =
                                up[static_cast<size_t>(fy0 + y - y0) * nx + (fx0 + x - x0)] > 0.5f;
                }
            } else {
                // frame pixels whose taps can reach the span (slimseg.ops.masks._frame_spans)
                auto frame_span = [](int first, int count, int offset, int nw, int dst) {
                    float c0 = static_cast<float>(std::min(std::max(first - offset, 0), nw));
                    float c1 = static_cast<float>(std::min(std::max(first + count - offset, 0), nw));
                    float r = static_cast<float>(static_cast<double>(dst) / nw);
                    float f0 = std::ceil((c0 - 0.5f) * r - 0.5f) - 1.0f;
                    float f1 = std::ceil((c1 + 0.5f) * r - 0.5f) + 1.0f;
                    f0 = std::min(std::max(f0, 0.0f), static_cast<float>(dst));
                    f1 = std::min(std::max(f1, 0.0f), static_cast<float>(dst));
                    if (!(c1 > c0)) f1 = f0;
                    return std::pair<int, int>(static_cast<int>(f0), static_cast<int>(f1 - f0));
                };
                auto [wx0, wnx] = frame_span(x0, nx, lb.left, lb.new_w, w);
                auto [wy0, wny] = frame_span(y0, ny, lb.top, lb.new_h, h);
                m.x0 = wx0;
                m.y0 = wy0;
                m.w = wnx;
                m.h = wny;
                m.pixels.assign(static_cast<size_t>(wnx) * wny, 0);
                // content pixel (cy, cx) is input pixel (cy + top, cx + left)
                auto U = [&](int cy, int cx) {
                    int yy = cy + lb.top - y0, xx = cx + lb.left - x0;
                    return (yy >= 0 && yy < ny && xx >= 0 && xx < nx)
                               ? up[static_cast<size_t>(yy) * nx + xx]
                               : 0.0f;
                };
                for (int y = 0; y < wny; ++y) {
                    int Y = wy0 + y;
                    for (int x = 0; x < wnx; ++x) {
                        int X = wx0 + x;
                        float v = interp(U(fy.i0[Y], fx.i0[X]), U(fy.i0[Y], fx.i1[X]),
                                         U(fy.i1[Y], fx.i0[X]), U(fy.i1[Y], fx.i1[X]), fx.w1[X],
                                         fy.w1[Y]);
                        m.pixels[static_cast<size_t>(y) * wnx + x] = v > 0.5f;
                    }
                }
            }
        }
        out.masks.push_back(std::move(m));
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
    const Taps tx = interpolate_taps(w, lb.new_w), ty = interpolate_taps(h, lb.new_h);
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
                float val = interp_torch(p[r0 + tx.i0[x]], p[r0 + tx.i1[x]], p[r1 + tx.i0[x]],
                                   p[r1 + tx.i1[x]], tx.w1[x], ty.w1[y]);
                if (c == 0 || val > best) best = val, arg = c;
            }
            out.class_map[static_cast<size_t>(y) * w + x] = static_cast<std::uint8_t>(arg);
        }
    }
    return out;
}

}  // namespace slimseg
