// Post-processing and the SLAM rules on hand-built cases with known answers: decode,
// class-aware NMS and the letterbox inverse; Eq. 1 keeping, raising and giving up its
// threshold; dilation by OpenCV's elliptic element.
#include <cstdint>
#include <vector>

#include "check.hpp"
#include "slimseg/mask.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/postprocess.hpp"
#include "slimseg/rules.hpp"
#include "slimseg/tensor.hpp"

using namespace slimseg;

namespace {

// A 32 x 32 detector with two classes: anchors 16 + 4 + 1 = 21 (strides 8, 16, 32).
const char* kDetector = R"({"names": ["person", "chair"], "mobility": [1.0, 0.1],
    "imgsz": [32, 32], "family": "yolov8", "task": "detect",
    "slam_masking": {"min_static": 5}})";
constexpr int kAnchors = 21, kRows = 6;

void set_anchor(std::vector<float>& out0, int a, float cx, float cy, float w, float h, int cls,
                float score) {
    const float v[4] = {cx, cy, w, h};
    for (int r = 0; r < 4; ++r) out0[r * kAnchors + a] = v[r];
    out0[(4 + cls) * kAnchors + a] = score;
}

int count(const std::vector<std::uint8_t>& m, std::uint8_t v) {
    int n = 0;
    for (auto p : m) n += p == v;
    return n;
}

void postprocess_decode_nms() {
    const Metadata meta = Metadata::from_json(kDetector);
    std::vector<float> out0(kRows * kAnchors, 0.f);
    set_anchor(out0, 0, 8, 8, 8, 8, 0, 0.9f);    // person (4, 4, 12, 12)
    set_anchor(out0, 1, 9, 8, 8, 8, 0, 0.8f);    // person, IoU 56/72 = 0.78 with anchor 0
    set_anchor(out0, 2, 9, 8, 8, 8, 1, 0.85f);   // chair on it: another class, kept
    set_anchor(out0, 3, 24, 24, 8, 8, 0, 0.3f);  // below conf 0.5
    const Postprocessor post(meta);
    // a 64 x 64 frame: scale 0.5, no padding -> frame boxes are input boxes x 2
    const FramePrediction p = post.run({TensorView{out0.data(), DType::Float32, {1, kRows, kAnchors}}},
                                       64, 64, 0.5);
    CHECK_EQ(p.detections.size(), 2u);
    if (p.detections.size() == 2) {
        const Detection& a = p.detections[0];
        const Detection& b = p.detections[1];
        CHECK_EQ(a.cls, 0);
        CHECK_EQ(a.score, 0.9f);
        CHECK(a.box == (std::array<float, 4>{8, 8, 24, 24}));
        CHECK(a.box_input == (std::array<float, 4>{4, 4, 12, 12}));
        CHECK_EQ(b.cls, 1);
        CHECK(b.box == (std::array<float, 4>{10, 8, 26, 24}));
    }
    CHECK(!p.segmenter && p.masks.empty());
    // the same outputs in float16 (all values exact in half but the scores)
    std::vector<std::uint16_t> half(out0.size());
    for (size_t i = 0; i < out0.size(); ++i) half[i] = float_to_half(out0[i]);
    const FramePrediction q = post.run({TensorView{half.data(), DType::Float16, {1, kRows, kAnchors}}},
                                       64, 64, 0.5);
    CHECK_EQ(q.detections.size(), 2u);
    if (!q.detections.empty()) CHECK_EQ(q.detections[0].score, half_to_float(float_to_half(0.9f)));
    // a 48 x 64 frame: scale 0.5, 4 input px of padding above
    const FramePrediction r = post.run({TensorView{out0.data(), DType::Float32, {kRows, kAnchors}}},
                                       48, 64, 0.5);
    CHECK_EQ(r.detections.size(), 2u);
    if (!r.detections.empty()) CHECK(r.detections[0].box == (std::array<float, 4>{8, 0, 24, 16}));

    CHECK_ERROR(post.run({TensorView{out0.data(), DType::Float32, {1, 7, 18}}}, 64, 64),
                "output0: shape [1, 7, 18], expected [1, 6, A] (2 classes)");
    CHECK_ERROR(post.run({TensorView{out0.data(), DType::Float32, {1, kRows, 20}}}, 64, 64),
                "output0: 20 anchors, but input 32x32 with strides in metadata strides gives 21");
}

// Boxes only (Mode::Box) on a 64 x 64 frame: a person box, a car box, 10 keypoints outside.
struct Scene {
    Objects objects;
    std::vector<float> keypoints;
};

Scene scene() {
    Scene s;
    s.objects.boxes = {{8, 8, 24, 24}, {40, 8, 56, 24}};
    s.objects.classes = {0, 2};
    s.objects.scores = {0.9f, 0.8f};
    s.keypoints = {12, 12, 20, 20,            // in the person box
                   44, 12, 48, 16, 52, 20};   // in the car box
    for (int i = 0; i < 10; ++i) {            // static background
        s.keypoints.push_back(4.f + 5.f * i);
        s.keypoints.push_back(40.f);
    }
    return s;
}

Rules box_rules(int min_static) {
    Rules r;
    r.class_mobility = {1.0f, 0.1f, 0.3f};  // person, chair, car
    r.mode = Mode::Box;
    r.masking.min_static = min_static;
    return r;
}

void eq1_outcomes() {
    const Scene s = scene();
    // 10 static points suffice: m_th stays 0.25, both boxes (16 x 16 pixels each) masked
    DynamicResult keep = dynamic_mask(s.objects, 64, 64, s.keypoints, box_rules(10));
    CHECK(!keep.gave_up);
    CHECK_EQ(keep.m_th, 0.25);
    CHECK_EQ(count(keep.mask, 255), 2 * 16 * 16);
    CHECK_EQ(keep.mask[8 * 64 + 8], 255);
    CHECK_EQ(keep.mask[7 * 64 + 8], 0);
    CHECK_EQ(keep.mask[8 * 64 + 24], 0);  // a pixel's centre must lie inside the box
    CHECK(keep.dynamic == std::vector<std::uint8_t>({1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}));
    CHECK(keep.dynamic_frame);  // 2 of 15 points in boxes of mobility > 0.5: > frame_ratio 0.05
    // 11 needed: the car (mobility 0.3) is given up at m_th 0.35
    DynamicResult raise = dynamic_mask(s.objects, 64, 64, s.keypoints, box_rules(11));
    CHECK(!raise.gave_up);
    CHECK_EQ(raise.m_th, 0.35);
    CHECK(raise.dropped == std::vector<int>({1}));
    CHECK_EQ(count(raise.mask, 255), 16 * 16);
    CHECK_EQ(raise.mask[8 * 64 + 40], 0);
    CHECK_EQ(count(raise.dynamic, 1), 2);
    // 14 needed: even the person's points cannot be static below m_th 1: the frame is given up
    DynamicResult give_up = dynamic_mask(s.objects, 64, 64, s.keypoints, box_rules(14));
    CHECK(give_up.gave_up);
    CHECK_EQ(count(give_up.mask, 255), 0);
    CHECK(give_up.dropped == std::vector<int>({0, 1}));
    CHECK_EQ(count(give_up.dynamic, 1), 0);

    Rules seg = box_rules(10);
    seg.mode = Mode::Seg;
    CHECK_ERROR(dynamic_mask(s.objects, 64, 64, s.keypoints, seg),
                "mode seg/fusion needs instance masks (a segmentation model); use box");
    CHECK_ERROR(dynamic_mask(s.objects, 64, 64, {1, 2, 3}, box_rules(10)),
                "keypoints: expected (x, y) pairs, got an odd count");
    CHECK(parse_mode("fusion") == Mode::Fusion && parse_mode("box") == Mode::Box);
}

void rules_from_metadata() {
    const Metadata meta = Metadata::from_json(kDetector);
    const Rules r = Rules::from_metadata(meta, Mode::Box);
    CHECK_EQ(r.masking.min_static, 5);
    CHECK(r.class_mobility == std::vector<float>({1.0f, 0.1f}));
    MaskingSettings s;
    s.dilation_px = 3;
    CHECK_EQ(scaled_dilation_px(s, 480, 640), 3);
    CHECK_EQ(scaled_dilation_px(s, 240, 320), 2);  // 1.5: half to even
    CHECK_EQ(scaled_dilation_px(s, 300, 1280), 6);
}

void dilation() {
    // OpenCV's 5 x 5 MORPH_ELLIPSE: 17 pixels (rows of 1, 5, 5, 5, 1)
    const std::vector<std::uint8_t> e = disc_element(2);
    CHECK(e == std::vector<std::uint8_t>({0, 0, 1, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1,
                                          1, 1, 1, 1, 1, 0, 0, 1, 0, 0}));
    WindowMask dot;
    dot.x0 = 4, dot.y0 = 4, dot.w = 1, dot.h = 1;
    dot.pixels = {1};
    const WindowMask d = dilate(dot, 2, 9, 9);
    CHECK_EQ(d.area(), 17);
    CHECK(d.at(2, 4) && d.at(3, 2) && !d.at(2, 3) && !d.at(4, 7));
    WindowMask corner = dot;
    corner.x0 = 0, corner.y0 = 0;
    CHECK_EQ(dilate(corner, 2, 9, 9).area(), 7);  // clipped to the frame: 3 + 3 + 1
    CHECK_EQ(dilate(dot, 0, 9, 9).area(), 1);

    // class_mask: the person's box, dilated by 1 (+ 4 * 16 edge pixels), as 255s
    FramePrediction p;
    p.h = p.w = 32;
    Detection person, chair;
    person.box = {8, 8, 24, 24};
    chair.box = {0, 0, 4, 4};
    chair.cls = 1;
    p.detections = {person, chair};
    CHECK_EQ(count(class_mask(p, {0}, 0), 255), 256);
    CHECK_EQ(count(class_mask(p, {0}, 1), 255), 256 + 4 * 16);
    CHECK_EQ(count(class_mask(p, {0, 1}, 0), 255), 256 + 16);
}

}  // namespace

int main() {
    postprocess_decode_nms();
    eq1_outcomes();
    rules_from_metadata();
    dilation();
    return slimseg_test::report("test_postprocess_rules");
}
