// The export's metadata (export/CONTRACT.md "Metadata keys"), read from the sidecar NAME.json
// or the ONNX metadata_props and checked field by field.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "slimseg/error.hpp"
#include "slimseg/json.hpp"
#include "slimseg/settings_generated.hpp"

namespace slimseg {

struct NmsSettings {
    double conf = 0.25;   // keep scores strictly above it
    double iou = 0.7;     // suppress overlaps strictly above it (within a class)
    int max_det = 300;    // detections kept per frame
    bool class_aware = true;
};

struct MaskingSettings {  // slam_masking: the SLAM-facing defaults (the papers preset)
    double conf = generated::kConf;
    int dilation_px = generated::kDilationPx;
    int min_static = generated::kMinStatic;
    double m_th_start = generated::kMThStart;
    double m_th_step = generated::kMThStep;
    double frame_ratio = generated::kFrameRatio;
    double t_o = generated::kTO;
    int dilation_reference_px = generated::kDilationReferencePx;
    std::string rule = generated::kRule;  // eq1 | degrade (when static support runs short)
    double keep_score = generated::kKeepScore;  // degrade: scoring this or more: never given up
    double cut_behind_m = generated::kCutBehindM;  // with depth: pixels this far behind: cut
    // the multi-frame evidence (slimseg.dynamic.mobility, occupancy, stillness): applied by
    // FrameChain (slimseg/chain.hpp); dynamic_mask alone does not (unapplied() names them)
    double motion_odds = generated::kMotionOdds;
    int motion_layer_px = generated::kMotionLayerPx;
    int still_frames = generated::kStillFrames;
};

struct Metadata {
    std::string model, family, task, precision = "fp32";
    std::vector<std::string> names;
    std::vector<float> mobility;          // per class (float32, as the Python rules use it)
    std::vector<int> dynamic_classes;
    int input_h = 0, input_w = 0;         // imgsz
    std::vector<int> strides;
    int num_masks = 0, proto_stride = 0;  // segmenters
    bool dynamic_shapes = false;
    NmsSettings nms;
    bool end2end = false;     // an end-to-end export: NMS and the mask product inside the graph
    NmsSettings end2end_nms;  // its baked-in conf, iou and max_det (K, rows per image)
    MaskingSettings slam_masking;                                 // the default preset
    std::map<std::string, MaskingSettings> masking_presets;       // slam_masking.presets
    double recommended_mask_dilation_px = 0.0;

    // The sidecar NAME.json (one JSON object).
    static Metadata from_json(const std::string& text);
    static Metadata from_file(const std::string& path);
    // ONNX metadata_props: every value a JSON string.
    static Metadata from_props(const std::map<std::string, std::string>& props);
    static Metadata from_object(const Json& root);

    int num_classes() const { return static_cast<int>(names.size()); }
    bool semantic() const { return task == "semantic"; }
    bool darknet() const { return family == "darknet-yolov3"; }
    bool segmenter() const { return num_masks > 0; }
    // The named masking preset ("" = the default); Error naming the preset if unknown.
    const MaskingSettings& masking(const std::string& preset = "") const;
};

}  // namespace slimseg
