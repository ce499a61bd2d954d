// End-to-end exports (export/CONTRACT.md "End-to-end exports"): the graph already decoded,
// suppressed and ranked the detections and computed sigmoid(coefficients . prototypes); what is
// left is the letterbox's inverse and mask steps 4-5, the code the raw path runs.
#include <algorithm>

#include "mask_assembly.hpp"
#include "slimseg/postprocess.hpp"

namespace slimseg {

FramePrediction Postprocessor::run(const End2EndOutputs& e2e, int h, int w, double conf,
                                   int max_det) const {
    if (!meta_.end2end)
        throw Error("metadata: no end2end entry; raw outputs go through run(RawOutputs, ...)");
    const int K = meta_.end2end_nms.max_det, nc = meta_.num_classes();
    const std::string k = std::to_string(K);
    auto sb = detail::unbatched(e2e.boxes, 2, "boxes", "[1, " + k + ", 4]");
    auto ss = detail::unbatched(e2e.scores, 1, "scores", "[1, " + k + "]");
    if (sb[0] != K || sb[1] != 4 || e2e.boxes.dtype != DType::Float32)
        throw Error("boxes: shape " + detail::shape_str(e2e.boxes.shape) + ", expected float32 [1, " +
                    k + ", 4]");
    if (ss[0] != K || e2e.scores.dtype != DType::Float32)
        throw Error("scores: shape " + detail::shape_str(e2e.scores.shape) +
                    ", expected float32 [1, " + k + "]");
    if (e2e.num_dets < 0 || e2e.num_dets > K)
        throw Error("num_dets: " + std::to_string(e2e.num_dets) + " outside 0.." + k);
    if (e2e.num_dets > 0 && e2e.classes == nullptr) throw Error("classes: no data");
    Letterbox lb = letterbox_params(h, w, meta_.input_h, meta_.input_w);
    const float* boxes = static_cast<const float*>(e2e.boxes.data);
    const float* scores = static_cast<const float*>(e2e.scores.data);
    FramePrediction out;
    out.h = h;
    out.w = w;
    out.segmenter = meta_.segmenter();
    const float thr = static_cast<float>(conf);
    std::vector<int> rows;
    for (int i = 0; i < e2e.num_dets && static_cast<int>(rows.size()) < max_det; ++i) {
        if (!(scores[i] > thr)) continue;
        if (e2e.classes[i] < 0 || e2e.classes[i] >= nc)
            throw Error("classes: id " + std::to_string(e2e.classes[i]) + " at row " +
                        std::to_string(i) + " outside 0.." + std::to_string(nc - 1));
        rows.push_back(i);
        Detection d;
        std::copy(boxes + 4 * i, boxes + 4 * i + 4, d.box_input.begin());
        d.score = scores[i];
        d.cls = e2e.classes[i];
        const float left = static_cast<float>(lb.left), top = static_cast<float>(lb.top);
        const float scale = static_cast<float>(lb.scale);
        for (int j = 0; j < 4; ++j) {  // slimseg.ops.letterbox.boxes_to_frame, float32
            float v = (d.box_input[j] - (j % 2 == 0 ? left : top)) / scale;
            float hi = static_cast<float>(j % 2 == 0 ? w : h);
            d.box[j] = std::min(std::max(v, 0.0f), hi);
        }
        out.detections.push_back(d);
    }
    if (!meta_.segmenter()) return out;
    if (e2e.masks == nullptr) throw Error("masks: missing (the model is a segmenter)");
    const int hp = lb.out_h / meta_.proto_stride, wp = lb.out_w / meta_.proto_stride;
    const std::string em = "[1, " + k + ", " + std::to_string(hp) + ", " + std::to_string(wp) + "]";
    auto sm = detail::unbatched(*e2e.masks, 3, "masks", em);
    if (sm[0] != K || sm[1] != hp || sm[2] != wp)
        throw Error("masks: shape " + detail::shape_str(e2e.masks->shape) + ", expected " + em);
    const std::vector<float> probs = to_float(*e2e.masks);
    const size_t plane = static_cast<size_t>(hp) * wp;
    const detail::MaskGeometry g = detail::mask_geometry(lb, h, w, hp, wp);
    for (size_t n = 0; n < rows.size(); ++n) {
        const detail::ProtoWindow win = detail::proto_window(g, out.detections[n].box_input);
        const float* origin = probs.data() + rows[n] * plane +
                              static_cast<size_t>(win.py0) * wp + win.px0;
        out.masks.push_back(detail::frame_mask(g, win, origin, static_cast<size_t>(wp)));
    }
    return out;
}

}  // namespace slimseg
