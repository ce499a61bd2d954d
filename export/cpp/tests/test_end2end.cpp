// End-to-end outputs (export/CONTRACT.md "End-to-end exports") on hand-built tensors: the valid
// rows above conf, the detection cap, boxes back to the frame, masks from the graph's
// probabilities, and the one-line errors on a wrong shape, count or class id.
#include <cstdint>
#include <string>
#include <vector>

#include "check.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/postprocess.hpp"
#include "slimseg/tensor.hpp"

using namespace slimseg;

namespace {

// A 32 x 32 segmenter with two classes, 4 rows per image, prototypes 8 x 8 (stride 4).
const char* kSegmenter = R"({"names": ["person", "chair"], "mobility": [1.0, 0.1],
    "imgsz": [32, 32], "family": "yolov8", "task": "segment", "num_masks": 2,
    "proto_stride": 4, "end2end": {"conf": 0.1, "iou": 0.7, "max_det": 4}})";
constexpr int kRows = 4, kCells = 8 * 8;

struct Tensors {
    std::vector<float> boxes = std::vector<float>(kRows * 4, 0.f);
    std::vector<float> scores = std::vector<float>(kRows, 0.f);
    std::vector<std::int32_t> classes = std::vector<std::int32_t>(kRows, -1);
    std::vector<float> masks = std::vector<float>(kRows * kCells, 0.f);
    TensorView mask_view{nullptr, DType::Float32, {1, kRows, 8, 8}};
    End2EndOutputs outputs(std::int32_t n) {
        End2EndOutputs e;
        e.num_dets = n;
        e.boxes = TensorView{boxes.data(), DType::Float32, {1, kRows, 4}};
        e.scores = TensorView{scores.data(), DType::Float32, {1, kRows}};
        e.classes = classes.data();
        mask_view.data = masks.data();
        e.masks = &mask_view;
        return e;
    }
    void row(int i, float x1, float y1, float x2, float y2, float score, int cls) {
        const float b[4] = {x1, y1, x2, y2};
        for (int k = 0; k < 4; ++k) boxes[i * 4 + k] = b[k];
        scores[i] = score;
        classes[i] = cls;
        // probability 0.9 on every prototype cell of the box grown by a cell, as the graph does
        for (int y = 0; y < 8; ++y)
            for (int x = 0; x < 8; ++x) {
                const float cx = (x + 0.5f) * 4, cy = (y + 0.5f) * 4;
                if (cx >= x1 - 4 && cx <= x2 + 4 && cy >= y1 - 4 && cy <= y2 + 4)
                    masks[i * kCells + y * 8 + x] = 0.9f;
            }
    }
};

void valid_rows_boxes_and_masks() {
    const Postprocessor post(Metadata::from_json(kSegmenter));
    CHECK(post.metadata().end2end);
    CHECK_EQ(post.metadata().end2end_nms.max_det, 4);
    Tensors t;
    t.row(0, 4, 4, 12, 12, 0.9f, 0);
    t.row(1, 16, 8, 28, 20, 0.4f, 1);
    t.row(2, 0, 0, 8, 8, 0.2f, 0);  // under conf 0.25
    // a 64 x 64 frame: scale 2, no padding; masks are the box's pixels (probability 0.9)
    FramePrediction p = post.run(t.outputs(3), 64, 64, 0.25, 300);
    CHECK_EQ(p.detections.size(), 2u);
    CHECK_EQ(p.masks.size(), 2u);
    if (p.detections.size() == 2 && p.masks.size() == 2) {
        CHECK(p.detections[0].box == (std::array<float, 4>{8, 8, 24, 24}));
        CHECK(p.detections[0].box_input == (std::array<float, 4>{4, 4, 12, 12}));
        CHECK_EQ(p.detections[1].cls, 1);
        CHECK_EQ(p.detections[1].score, 0.4f);
        CHECK_EQ(p.masks[0].area(), 16 * 16);
        CHECK_EQ(p.masks[1].area(), 24 * 24);
    }
    // a 32 x 32 frame (no resize), the cap, rows past num_dets ignored
    CHECK_EQ(post.run(t.outputs(3), 32, 32, 0.1, 300).detections.size(), 3u);
    CHECK_EQ(post.run(t.outputs(3), 32, 32, 0.1, 1).detections.size(), 1u);
    CHECK_EQ(post.run(t.outputs(1), 32, 32, 0.1, 300).detections.size(), 1u);
    CHECK_EQ(post.run(t.outputs(3), 32, 32, 0.1, 300).masks[0].area(), 8 * 8);
}

void errors() {
    const Postprocessor post(Metadata::from_json(kSegmenter));
    Tensors t;
    t.row(0, 4, 4, 12, 12, 0.9f, 0);
    End2EndOutputs e = t.outputs(1);
    e.boxes.shape = {1, 3, 4};
    CHECK_ERROR(post.run(e, 32, 32, 0.25, 300),
                "boxes: shape [1, 3, 4], expected float32 [1, 4, 4]");
    CHECK_ERROR(post.run(t.outputs(5), 32, 32, 0.25, 300), "num_dets: 5 outside 0..4");
    t.classes[0] = 2;
    CHECK_ERROR(post.run(t.outputs(1), 32, 32, 0.25, 300),
                "classes: id 2 at row 0 outside 0..1");
    t.classes[0] = 0;
    e = t.outputs(1);
    e.masks = nullptr;
    CHECK_ERROR(post.run(e, 32, 32, 0.25, 300), "masks: missing (the model is a segmenter)");
    const Postprocessor raw(Metadata::from_json(R"({"names": ["a"], "imgsz": [32, 32],
        "family": "yolov8", "task": "detect"})"));
    CHECK_ERROR(raw.run(t.outputs(1), 32, 32, 0.25, 300),
                "metadata: no end2end entry; raw outputs go through run(RawOutputs, ...)");
    CHECK_ERROR(Metadata::from_json(R"({"names": ["a"], "imgsz": [32, 32], "family": "msnet",
        "task": "semantic", "end2end": {"conf": 0.1, "iou": 0.7, "max_det": 4}})"),
                "metadata end2end: only yolov8 models have it");
    CHECK_ERROR(Metadata::from_json(R"({"names": ["a"], "imgsz": [32, 32], "family": "yolov8",
        "task": "detect", "end2end": {"conf": 0.1, "iou": 0.7}})"),
                "metadata end2end.max_det: missing (not a slimseg export? re-export with "
                "slimseg export)");
}

}  // namespace

int main() {
    valid_rows_boxes_and_masks();
    errors();
    return slimseg_test::report("test_end2end");
}
