// The JSON reader and the metadata checks: values, defaults, and one-line errors that name
// the field.
#include <cstdio>
#include <fstream>
#include <map>
#include <string>

#include "check.hpp"
#include "slimseg/json.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/rules.hpp"

using namespace slimseg;

namespace {

void json_document() {
    const Json j = Json::parse(
        R"( {"a": [1, 2.5, -3e2], "b": {"c": "x\"y\u00e9\ud83d\ude00"}, "d": true, "e": null} )");
    CHECK(j.kind == Json::Kind::Object);
    CHECK_EQ(j.object.size(), 4u);
    const Json* a = j.find("a");
    CHECK(a != nullptr && a->kind == Json::Kind::Array && a->array.size() == 3);
    if (a != nullptr && a->array.size() == 3) {
        CHECK_EQ(a->array[0].number, 1.0);
        CHECK_EQ(a->array[1].number, 2.5);
        CHECK_EQ(a->array[2].number, -300.0);
    }
    const Json* c = j.find("b") ? j.find("b")->find("c") : nullptr;
    CHECK(c != nullptr && c->kind == Json::Kind::String);
    if (c != nullptr) CHECK_EQ(c->string, std::string("x\"y\xc3\xa9\xf0\x9f\x98\x80"));
    CHECK(j.find("d") != nullptr && j.find("d")->boolean);
    CHECK(j.find("e") != nullptr && j.find("e")->kind == Json::Kind::Null);
    CHECK(j.find("missing") == nullptr);
    CHECK(a != nullptr && a->find("a") == nullptr);  // not an object

    CHECK_ERROR(Json::parse(R"({"a": [1, 2})"), "JSON (metadata): expected ',' or ']' at offset 11");
    CHECK_ERROR(Json::parse("[1] 2", "test"), "JSON (test): unexpected text after the JSON value at offset 4");
    CHECK_ERROR(Json::parse(R"(["abc)"), "JSON (metadata): unterminated string at offset 5");
    CHECK_ERROR(Json::parse("[NaN]"), "JSON (metadata): NaN/Infinity is not JSON at offset 1");
}

const char* kSegmenter = R"({
    "model": "yolov8n-seg", "family": "yolov8", "task": "segment", "precision": "fp16",
    "names": ["person", "chair", "car"], "mobility": [1.0, 0.1, 0.3],
    "dynamic_classes": [0, 2], "imgsz": [384, 640], "num_masks": 32, "proto_stride": 4,
    "nms": {"conf": 0.3, "iou": 0.6, "max_det": 100, "class_aware": false},
    "slam_masking": {"conf": 0.4, "dilation_px": 5, "min_static": 80, "rule": "degrade",
                     "presets": {"papers": {"t_o": 0.25},
                                 "wide": {"dilation_px": 9, "motion_odds": 10, "still_frames": 20}}}
})";

void metadata_fields() {
    const Metadata m = Metadata::from_json(kSegmenter);
    CHECK_EQ(m.model, std::string("yolov8n-seg"));
    CHECK_EQ(m.num_classes(), 3);
    CHECK_EQ(m.mobility[2], 0.3f);
    CHECK(m.dynamic_classes == std::vector<int>({0, 2}));
    CHECK_EQ(m.input_h, 384);
    CHECK_EQ(m.input_w, 640);
    CHECK(m.strides == std::vector<int>({8, 16, 32}));  // the default
    CHECK(m.segmenter() && !m.semantic() && !m.darknet());
    CHECK_EQ(m.num_masks, 32);
    CHECK_EQ(m.nms.conf, 0.3);
    CHECK_EQ(m.nms.max_det, 100);
    CHECK(!m.nms.class_aware);
    CHECK_EQ(m.slam_masking.conf, 0.4);
    CHECK_EQ(m.slam_masking.dilation_px, 5);
    CHECK_EQ(m.slam_masking.rule, std::string("degrade"));
    CHECK_EQ(m.slam_masking.t_o, 0.25);  // not given: the papers preset's
    CHECK_EQ(m.masking("wide").dilation_px, 9);
    CHECK_EQ(m.masking("wide").min_static, 100);  // presets start from the papers preset
    CHECK_EQ(&m.masking(""), &m.slam_masking);
    // the multi-frame evidence: read and checked, named as not applied by this consumer
    CHECK_EQ(m.masking("wide").still_frames, 20);
    CHECK(unapplied(m.masking("wide")) ==
          std::vector<std::string>({"motion_odds 10", "still_frames 20"}));
    CHECK(unapplied(m.slam_masking).empty());
    CHECK_ERROR(m.masking("nope"), "metadata slam_masking.presets: no preset 'nope' (has: papers, wide)");

    // a missing or malformed mobility is 1 per class; legacy keys without slam_masking
    const Metadata legacy = Metadata::from_json(
        R"({"names": ["a", "b"], "imgsz": [320, 320], "family": "darknet-yolov3",
            "task": "detect", "mobility": [0.5], "mobility_threshold": 0.4,
            "recommended_mask_dilation_px": 2.5})");
    CHECK(legacy.mobility == std::vector<float>({1.0f, 1.0f}));
    CHECK(legacy.darknet());
    CHECK_EQ(legacy.slam_masking.m_th_start, 0.4);
    CHECK_EQ(legacy.slam_masking.dilation_px, 5);  // 2.5 * 640 / 320

    // ONNX metadata_props: JSON values, another tool's plain text kept as a string
    const Metadata props = Metadata::from_props(std::map<std::string, std::string>{
        {"names", R"(["person"])"}, {"imgsz", "[64, 64]"}, {"family", R"("msnet")"},
        {"task", R"("semantic")"}, {"model", "msnet-t"}, {"producer", "some tool 1.0"}});
    CHECK_EQ(props.model, std::string("msnet-t"));
    CHECK(props.semantic());
    CHECK(props.strides.empty());
}

void metadata_errors() {
    const std::string base = R"("names": ["a"], "imgsz": [64, 64], "family": "yolov8")";
    CHECK_ERROR(Metadata::from_json(R"({"names": ["a"], "imgsz": [64, 64]})"),
                "metadata family: missing (not a slimseg export? re-export with slimseg export)");
    CHECK_ERROR(Metadata::from_json("[]"), "metadata (root): expected a JSON object");
    CHECK_ERROR(Metadata::from_json(R"({"names": [], "imgsz": [64, 64]})"), "metadata names: no classes");
    CHECK_ERROR(Metadata::from_json(R"({"names": ["a"], "imgsz": [64]})"), "metadata imgsz: expected [H, W]");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "track"})"),
                "metadata task: 'track' is not detect, segment or semantic");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "segment", "num_masks": 32, "proto_stride": 3})"),
                "metadata proto_stride: imgsz is not a multiple of it");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "slam_masking": {"t_o": 2}})"),
                "metadata slam_masking.t_o: value 2.000000 outside [0.000000, 1.000000]");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "slam_masking": {"motion_odds": 0.5}})"),
                "metadata slam_masking.motion_odds: value 0.500000 outside [1.000000, 1000000.000000]");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "slam_masking": {"still_frames": 2.5}})"),
                "metadata slam_masking.still_frames: expected a whole number in 0..1000, got 2.500000");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "slam_masking": {"presets": {"x": {"rule": "all"}}}})"),
                "metadata slam_masking.presets.x.rule: 'all' is not eq1 or degrade");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "dynamic_classes": [1]})"),
                "metadata dynamic_classes[]: expected a whole number in 0..0, got 1.000000");
    CHECK_ERROR(Metadata::from_json("{" + base + R"(, "task": "detect", "nms": {"conf": "high"}})"),
                "metadata nms.conf: expected a number");
    CHECK_ERROR(Metadata::from_json(R"({"names": ["a"],)"),
                "JSON (metadata sidecar): expected a member name at offset 16");

    // files: the path leads the message
    const std::string path = "test_metadata_json.tmp.json";
    {
        std::ofstream f(path);
        f << "{" << base << "}";
    }
    CHECK_ERROR(Metadata::from_file(path), path + ": metadata task: missing (not a slimseg export? re-export with slimseg export)");
    std::remove(path.c_str());
    CHECK_ERROR(Metadata::from_file(path), path + ": cannot open the metadata file");
}

}  // namespace

int main() {
    json_document();
    metadata_fields();
    metadata_errors();
    return slimseg_test::report("test_metadata_json");
}
