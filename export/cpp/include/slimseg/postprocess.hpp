// Post-processing (export/CONTRACT.md "Post-processing, step by step"): the network's raw
// outputs -> detections in frame pixels, instance masks or a class map.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "slimseg/error.hpp"
#include "slimseg/letterbox.hpp"
#include "slimseg/mask.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/tensor.hpp"

namespace slimseg {

struct Detection {
    std::array<float, 4> box{};      // xyxy, frame pixels, clipped to the frame
    std::array<float, 4> box_input{};// xyxy, network-input pixels (what the mask is cropped to)
    float score = 0.f;
    int cls = 0;
};

struct FramePrediction {
    int h = 0, w = 0;
    std::vector<Detection> detections;    // sorted by decreasing score
    std::vector<WindowMask> masks;        // one per detection (segmenters), else empty
    std::vector<std::uint8_t> class_map;  // semantic models: h*w, 0 = background, k+1 = class k
    bool segmenter = false;  // masks holds one mask per detection
    bool semantic = false;
};

struct RawOutputs {
    TensorView output0;        // [1, 4+nc(+nm), A]; darknet [1, 5+nc, A]; semantic: logits
    const TensorView* output1 = nullptr;  // prototypes [1, nm, H/s, W/s] (segmenters)
};

// One frame's outputs of an end-to-end export (export/CONTRACT.md "End-to-end exports"): the
// decoding, NMS and top-K already ran inside the graph.
struct End2EndOutputs {
    std::int32_t num_dets = 0;              // num_dets[b]: the first rows are valid
    TensorView boxes;                       // [1, K, 4] float32 x1, y1, x2, y2 (input pixels)
    TensorView scores;                      // [1, K] float32, decreasing
    const std::int32_t* classes = nullptr;  // K int32 class ids
    const TensorView* masks = nullptr;      // [1, K, Hp, Wp] probabilities (segmenters)
};

class Postprocessor {
public:
    explicit Postprocessor(Metadata meta);
    const Metadata& metadata() const { return meta_; }
    // Steps 1-5 for the frame of h x w pixels whose letterboxed input produced `raw`; conf/iou/
    // max_det default to the metadata's nms entry (give slam_masking.conf for SLAM masks).
    FramePrediction run(const RawOutputs& raw, int h, int w) const;
    FramePrediction run(const RawOutputs& raw, int h, int w, double conf) const;
    FramePrediction run(const RawOutputs& raw, int h, int w, double conf, double iou,
                        int max_det) const;
    // An end-to-end export's frame: its valid rows with score > conf (at most max_det), boxes
    // back to the frame and masks by steps 4-5 from the graph's probabilities; needs
    // metadata().end2end. Error naming the tensor on a wrong shape or class id.
    FramePrediction run(const End2EndOutputs& e2e, int h, int w, double conf, int max_det) const;

private:
    Metadata meta_;
    FramePrediction instances(const RawOutputs& raw, const Letterbox& lb, int h, int w,
                              double conf, double iou, int max_det) const;
    FramePrediction semantic(const TensorView& logits, const Letterbox& lb, int h, int w) const;
};

}  // namespace slimseg
