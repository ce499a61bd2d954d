// slimseg reference consumer: the after-the-network half of export/CONTRACT.md in C++17.
//
// The network call stays the caller's (TensorRT, onnxruntime, OpenVINO, ...): this library
// takes the raw output tensors (float32 or float16 buffers with their shapes) and the export's
// metadata, and produces what slimseg.deploy.Predictor and `slimseg dynamic` produce in Python:
//
//   Metadata meta = Metadata::from_file("model.json");          // or from_props(onnx props)
//   Letterbox lb = letterbox_params(h, w, meta.input_h, meta.input_w);
//   letterbox_image(rgb, h, w, lb, input_chw);                  // the network input
//   ... run the network ...
//   Postprocessor post(meta);
//   FramePrediction p = post.run({out0, out1}, h, w, meta.slam_masking.conf);
//   Rules rules = Rules::from_metadata(meta, Mode::Fusion);
//   DynamicResult r = dynamic_mask(p, keypoints_xy, rules);     // r.mask: uint8, 255 = dynamic
//
// No third-party dependency. Every malformed input throws slimseg::Error with a message that
// names the field or tensor. docs/cpp_consumer.md documents the library and the parity tests.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace slimseg {

// Every error of this library: a one-line message naming the field, tensor or file.
struct Error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// ---- a small JSON reader (the metadata sidecar and the ONNX metadata_props values) ----------

class Json {
public:
    enum class Kind { Null, Bool, Number, String, Array, Object };
    Kind kind = Kind::Null;
    bool boolean = false;
    double number = 0.0;
    std::string string;
    std::vector<Json> array;
    std::vector<std::pair<std::string, Json>> object;

    // Parse a complete JSON text; Error("JSON (<what>): ... at offset N") on malformed text.
    static Json parse(const std::string& text, const std::string& what = "metadata");
    // The member `key` of an object, nullptr when absent (or when this is not an object).
    const Json* find(const std::string& key) const;
};

// ---- metadata (export/CONTRACT.md "Metadata keys") -------------------------------------------

struct NmsSettings {
    double conf = 0.25;   // keep scores strictly above it
    double iou = 0.7;     // suppress overlaps strictly above it (within a class)
    int max_det = 300;    // detections kept per frame
    bool class_aware = true;
};

struct MaskingSettings {  // slam_masking: the SLAM-facing defaults
    double conf = 0.25;
    int dilation_px = 0;
    int min_static = 100;
    double m_th_start = 0.25;
    double m_th_step = 0.1;
    double frame_ratio = 0.05;
    double t_o = 0.25;
    int dilation_reference_px = 640;
    std::string rule = "eq1";  // eq1 | degrade (what happens when static support runs short)
    double keep_score = 0.5;   // degrade: a candidate scoring this or more is never given up
    double cut_behind_m = 0.0; // with depth: mask pixels this far behind the object are cut
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

// ---- the letterbox (export/CONTRACT.md "Pre-processing") ------------------------------------

struct Letterbox {
    double scale = 1.0;
    int new_w = 0, new_h = 0, left = 0, top = 0, out_w = 0, out_h = 0;
};

// scale = min(H/h, W/w); new = floor(side * scale + 0.5); padding centred, rounded down.
Letterbox letterbox_params(int h, int w, int out_h, int out_w);
// RGB uint8 [h, w, 3] -> float [3, H, W] (value / 255): bilinear (half-pixel centres), pad 114.
// The resize is computed in float and rounded to uint8; cv2.INTER_LINEAR's fixed-point kernel
// can differ by one grey level (export/CONTRACT.md says why that is harmless).
void letterbox_image(const std::uint8_t* rgb, int h, int w, const Letterbox& lb, float* chw);
// Inverse for a point in input pixels -> frame pixels (unclipped).
std::array<double, 2> to_frame(const Letterbox& lb, double x_input, double y_input);

// ---- raw tensors --------------------------------------------------------------------------

enum class DType { Float32, Float16 };

struct TensorView {
    const void* data = nullptr;
    DType dtype = DType::Float32;
    std::vector<std::int64_t> shape;
    std::int64_t numel() const;
};

float half_to_float(std::uint16_t h);
// Round to the nearest float16 (ties to even; overflow to infinity): FP16 exports' input.
std::uint16_t float_to_half(float f);
// The tensor's elements as float32 (float16 widened exactly).
std::vector<float> to_float(const TensorView& t);

// ---- post-processing (export/CONTRACT.md "Post-processing, step by step") -------------------

// A mask on a window of the frame: pixel (y, x) of the frame is pixels[(y - y0) * w + x - x0]
// inside the window, 0 outside.
struct WindowMask {
    int x0 = 0, y0 = 0, w = 0, h = 0;
    std::vector<std::uint8_t> pixels;  // 0 / 1
    bool at(int y, int x) const {
        return y >= y0 && y < y0 + h && x >= x0 && x < x0 + w &&
               pixels[static_cast<size_t>(y - y0) * w + (x - x0)];
    }
    std::int64_t area() const;
};

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

private:
    Metadata meta_;
    FramePrediction instances(const RawOutputs& raw, const Letterbox& lb, int h, int w,
                              double conf, double iou, int max_det) const;
    FramePrediction semantic(const TensorView& logits, const Letterbox& lb, int h, int w) const;
};

// ---- the SLAM-facing rules (export/CONTRACT.md "The SLAM mask with keypoints") --------------

enum class Mode { Seg, Box, Fusion };
Mode parse_mode(const std::string& name);  // "seg", "box", "fusion"

struct Rules {
    std::vector<float> class_mobility;  // prior per class
    Mode mode = Mode::Fusion;
    int min_static = 100;
    int dilation_px = 0;  // frame pixels, applied as given (see scaled_dilation_px)
    double m_th_start = 0.25, m_th_step = 0.1, frame_ratio = 0.05, t_o = 0.25;
    // eq1: Eq. 1 raises the threshold, then gives up the frame; degrade: the least certain
    // candidates (score x mobility) go one at a time while fewer than min_static keypoints
    // stay outside the mask, those scoring >= keep_score never (slimseg.dynamic.degrade; the
    // caller's keypoints are the static support)
    bool degrade = false;
    double keep_score = 0.5;
    // with a depth image (seg / fusion): pixels inside an object's box more than cut_behind_m
    // behind the median depth under its seg mask leave its region (slimseg.dynamic.depth_cut)
    double cut_behind_m = 0.0;

    static Rules from_metadata(const Metadata& meta, Mode mode, const std::string& preset = "");
};

// dilation_px scaled to a frame: round(dilation_px * max(h, w) / dilation_reference_px).
int scaled_dilation_px(const MaskingSettings& s, int h, int w);

// The objects the rules work on: a prediction's instances, or a class map's 8-connected
// components (>= min_area pixels) for semantic models.
struct Objects {
    std::vector<std::array<float, 4>> boxes;  // frame pixels, xyxy
    std::vector<int> classes;
    std::vector<float> scores;                // empty: all 1 (class-map components)
    std::vector<WindowMask> masks;            // empty for detection-only models
    bool has_masks = false;
};
Objects objects_of(const FramePrediction& p, int min_area = 32);

struct DynamicResult {
    std::vector<std::uint8_t> mask;  // h*w, 255 = dynamic region
    std::vector<std::uint8_t> dynamic;  // per keypoint, 0/1
    bool gave_up = false;            // Eq. 1 found no threshold: nothing masked
    std::vector<int> dropped;        // candidates left out of the mask (degrade: in order)
    double m_th = 0.0;
    bool dynamic_frame = false;      // Eq. 3
    std::vector<std::uint8_t> used_seg;  // Eq. 4 per object (fusion on dynamic frames)
};

// keypoints_xy: N (x, y) pairs in frame pixels, flattened.
// depth_m: optional h*w metres (0 or NaN: no depth), for rules.cut_behind_m.
DynamicResult dynamic_mask(const FramePrediction& p, const std::vector<float>& keypoints_xy,
                           const Rules& rules, const float* depth_m = nullptr);
DynamicResult dynamic_mask(const Objects& objects, int h, int w,
                           const std::vector<float>& keypoints_xy, const Rules& rules,
                           const float* depth_m = nullptr);

// The contract's step 6 without keypoints: union of the masks (boxes for detection models,
// class pixels for class maps) of `classes`, dilated by `radius` frame pixels.
std::vector<std::uint8_t> class_mask(const FramePrediction& p, const std::vector<int>& classes,
                                     int radius);

// ---- raw dumps (`slimseg predict --dump-raw DIR`, docs/cpp_consumer.md) --------------------
// A file of named tensors: "SLSGRAW1", uint32 count, then per tensor uint32 name length, the
// name (UTF-8), uint32 dtype (0 float32, 1 float16, 2 int32, 3 uint8), uint32 ndim, int64
// dims[ndim], the data in C order; every number little-endian.

enum class RawType : std::uint32_t { Float32 = 0, Float16 = 1, Int32 = 2, UInt8 = 3 };

struct RawTensor {
    std::string name;
    RawType type = RawType::Float32;
    std::vector<std::int64_t> shape;
    std::vector<std::uint8_t> bytes;
    TensorView view() const;  // float32 / float16 tensors only
    std::int64_t numel() const;
};

struct RawDump {
    std::vector<RawTensor> tensors;
    const RawTensor* find(const std::string& name) const;
    const RawTensor& need(const std::string& name) const;  // Error naming the file and tensor
    void add(const std::string& name, RawType type, std::vector<std::int64_t> shape,
             const void* data);
    static RawDump load(const std::string& path);
    void save(const std::string& path) const;  // written to path.tmp, then renamed
    std::string path;
};

// Dilation by a disc of `radius` (OpenCV's MORPH_ELLIPSE (2r+1) x (2r+1) element).
WindowMask dilate(const WindowMask& m, int radius, int h, int w);
std::vector<std::uint8_t> disc_element(int radius);

}  // namespace slimseg
