// Metadata: the export's JSON (sidecar or ONNX metadata_props) -> slimseg::Metadata, checked.
#include "slimseg/metadata.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace slimseg {
namespace {

[[noreturn]] void bad(const std::string& field, const std::string& why) {
    throw Error("metadata " + field + ": " + why);
}

const Json& need(const Json& obj, const std::string& key, const std::string& field) {
    const Json* v = obj.find(key);
    if (v == nullptr) bad(field, "missing (not a slimseg export? re-export with slimseg export)");
    return *v;
}

std::string text(const Json& v, const std::string& field) {
    if (v.kind != Json::Kind::String) bad(field, "expected a string");
    return v.string;
}

double num(const Json& v, const std::string& field) {
    if (v.kind != Json::Kind::Number) bad(field, "expected a number");
    return v.number;
}

int integer(const Json& v, const std::string& field, int lo, int hi) {
    double d = num(v, field);
    if (d != std::floor(d) || d < lo || d > hi)
        bad(field, "expected a whole number in " + std::to_string(lo) + ".." + std::to_string(hi) +
                       ", got " + std::to_string(d));
    return static_cast<int>(d);
}

bool flag(const Json& v, const std::string& field) {
    if (v.kind != Json::Kind::Bool) bad(field, "expected true or false");
    return v.boolean;
}

const Json& array(const Json& v, const std::string& field) {
    if (v.kind != Json::Kind::Array) bad(field, "expected an array");
    return v;
}

double in_range(double v, double lo, double hi, bool open_lo, bool open_hi,
                const std::string& field) {
    bool ok = (open_lo ? v > lo : v >= lo) && (open_hi ? v < hi : v <= hi);
    if (!ok || std::isnan(v))
        bad(field, "value " + std::to_string(v) + " outside " + (open_lo ? "(" : "[") +
                       std::to_string(lo) + ", " + std::to_string(hi) + (open_hi ? ")" : "]"));
    return v;
}

// slimseg.dynamic.masking_settings: the papers preset, then the entry's own values, each
// checked against its knob's range (settings_generated.hpp, from slimseg.dynamic.knobs).
double knob(const Json& e, const std::string& field, const char* key, double fallback) {
    const Json* v = e.find(key);
    if (v == nullptr) return fallback;
    for (const auto& r : generated::kMaskingRanges) {
        if (std::string(r.key) != key) continue;
        const std::string name = field + "." + key;
        if (r.integer) return integer(*v, name, static_cast<int>(r.low), static_cast<int>(r.high));
        return in_range(num(*v, name), r.low, r.high, r.open_low, r.open_high, name);
    }
    bad(field + "." + key, "not a masking knob");
}

MaskingSettings masking_entry(const Json& e, const std::string& field) {
    if (e.kind != Json::Kind::Object) bad(field, "expected an object");
    MaskingSettings s;  // papers preset defaults
    s.conf = knob(e, field, "conf", s.conf);
    s.m_th_start = knob(e, field, "m_th_start", s.m_th_start);
    s.m_th_step = knob(e, field, "m_th_step", s.m_th_step);
    s.frame_ratio = knob(e, field, "frame_ratio", s.frame_ratio);
    s.t_o = knob(e, field, "t_o", s.t_o);
    s.dilation_px = static_cast<int>(knob(e, field, "dilation_px", s.dilation_px));
    s.min_static = static_cast<int>(knob(e, field, "min_static", s.min_static));
    if (const Json* v = e.find("dilation_reference_px"))
        s.dilation_reference_px = integer(*v, field + ".dilation_reference_px", 1, 1 << 20);
    s.keep_score = knob(e, field, "keep_score", s.keep_score);
    s.cut_behind_m = knob(e, field, "cut_behind_m", s.cut_behind_m);
    s.motion_odds = knob(e, field, "motion_odds", s.motion_odds);
    s.motion_layer_px = static_cast<int>(knob(e, field, "motion_layer_px", s.motion_layer_px));
    s.still_frames = static_cast<int>(knob(e, field, "still_frames", s.still_frames));
    if (const Json* v = e.find("rule")) {
        s.rule = text(*v, field + ".rule");
        if (s.rule != "eq1" && s.rule != "degrade")
            bad(field + ".rule", "'" + s.rule + "' is not eq1 or degrade");
    }
    return s;
}

}  // namespace

Metadata Metadata::from_object(const Json& root) {
    if (root.kind != Json::Kind::Object) bad("(root)", "expected a JSON object");
    Metadata m;
    for (const Json& n : array(need(root, "names", "names"), "names").array)
        m.names.push_back(text(n, "names[]"));
    if (m.names.empty()) bad("names", "no classes");
    const Json& imgsz = array(need(root, "imgsz", "imgsz"), "imgsz");
    if (imgsz.array.size() != 2) bad("imgsz", "expected [H, W]");
    m.input_h = integer(imgsz.array[0], "imgsz[0]", 1, 1 << 16);
    m.input_w = integer(imgsz.array[1], "imgsz[1]", 1, 1 << 16);
    m.family = text(need(root, "family", "family"), "family");
    m.task = text(need(root, "task", "task"), "task");
    if (m.family != "yolov8" && m.family != "darknet-yolov3" && m.family != "msnet")
        bad("family", "'" + m.family + "' is not one this consumer knows (yolov8, "
                      "darknet-yolov3, msnet)");
    if (m.task != "detect" && m.task != "segment" && m.task != "semantic")
        bad("task", "'" + m.task + "' is not detect, segment or semantic");
    if (const Json* v = root.find("model")) m.model = text(*v, "model");
    if (const Json* v = root.find("precision")) m.precision = text(*v, "precision");
    if (const Json* v = root.find("dynamic_shapes")) m.dynamic_shapes = flag(*v, "dynamic_shapes");
    // slimseg.deploy.metadata.read_onnx_metadata: a missing or malformed mobility is 1 per class
    const Json* mob = root.find("mobility");
    bool mob_ok = mob != nullptr && mob->kind == Json::Kind::Array &&
                  mob->array.size() == m.names.size();
    for (size_t i = 0; mob_ok && i < mob->array.size(); ++i)
        mob_ok = mob->array[i].kind == Json::Kind::Number;
    for (size_t i = 0; i < m.names.size(); ++i)
        m.mobility.push_back(mob_ok ? static_cast<float>(mob->array[i].number) : 1.0f);
    if (const Json* v = root.find("dynamic_classes"))
        for (const Json& c : array(*v, "dynamic_classes").array)
            m.dynamic_classes.push_back(
                integer(c, "dynamic_classes[]", 0, static_cast<int>(m.names.size()) - 1));
    if (const Json* v = root.find("strides"))
        for (const Json& s : array(*v, "strides").array)
            m.strides.push_back(integer(s, "strides[]", 1, 1024));
    if (m.strides.empty() && !m.semantic()) m.strides = {8, 16, 32};
    if (m.task == "segment") {
        m.num_masks = integer(need(root, "num_masks", "num_masks"), "num_masks", 1, 4096);
        m.proto_stride = integer(need(root, "proto_stride", "proto_stride"), "proto_stride", 1, 64);
        if (m.input_h % m.proto_stride || m.input_w % m.proto_stride)
            bad("proto_stride", "imgsz is not a multiple of it");
    }
    if (const Json* v = root.find("nms")) {
        if (v->kind != Json::Kind::Object) bad("nms", "expected an object");
        if (const Json* c = v->find("conf"))
            m.nms.conf = in_range(num(*c, "nms.conf"), 0, 1, false, true, "nms.conf");
        if (const Json* c = v->find("iou"))
            m.nms.iou = in_range(num(*c, "nms.iou"), 0, 1, false, false, "nms.iou");
        if (const Json* c = v->find("max_det"))
            m.nms.max_det = integer(*c, "nms.max_det", 1, 1 << 20);
        if (const Json* c = v->find("class_aware")) m.nms.class_aware = flag(*c, "nms.class_aware");
    }
    if (const Json* v = root.find("end2end")) {  // NMS inside the graph (export --end2end)
        if (v->kind != Json::Kind::Object) bad("end2end", "expected an object");
        if (m.family != "yolov8" || m.semantic()) bad("end2end", "only yolov8 models have it");
        m.end2end = true;
        m.end2end_nms.conf =
            in_range(num(need(*v, "conf", "end2end.conf"), "end2end.conf"), 0, 1, false, true,
                     "end2end.conf");
        m.end2end_nms.iou = in_range(num(need(*v, "iou", "end2end.iou"), "end2end.iou"), 0, 1,
                                     false, false, "end2end.iou");
        m.end2end_nms.max_det =
            integer(need(*v, "max_det", "end2end.max_det"), "end2end.max_det", 1, 1 << 20);
    }
    if (const Json* v = root.find("recommended_mask_dilation_px"))
        m.recommended_mask_dilation_px = num(*v, "recommended_mask_dilation_px");
    // slimseg.deploy.metadata.masking_from_metadata
    if (const Json* e = root.find("slam_masking"); e != nullptr && e->kind == Json::Kind::Object) {
        m.slam_masking = masking_entry(*e, "slam_masking");
        if (const Json* p = e->find("presets")) {
            if (p->kind != Json::Kind::Object) bad("slam_masking.presets", "expected an object");
            for (const auto& kv : p->object) {
                MaskingSettings s = masking_entry(kv.second, "slam_masking.presets." + kv.first);
                s.dilation_reference_px = m.slam_masking.dilation_reference_px;
                m.masking_presets[kv.first] = s;
            }
        }
    } else {  // exports older than slam_masking: the papers preset with the two legacy keys
        if (const Json* v = root.find("mobility_threshold"))
            m.slam_masking.m_th_start = in_range(num(*v, "mobility_threshold"), 0, 1, false,
                                                 false, "mobility_threshold");
        if (root.find("recommended_mask_dilation_px") != nullptr) {
            double side = std::max(m.input_h, m.input_w);
            double px = m.recommended_mask_dilation_px * generated::kDilationReferencePx / side;
            m.slam_masking.dilation_px = static_cast<int>(std::nearbyint(px));  // half to even
            in_range(m.slam_masking.dilation_px, 0, 200, false, false,
                     "recommended_mask_dilation_px");
        }
    }
    return m;
}

Metadata Metadata::from_json(const std::string& text) {
    return from_object(Json::parse(text, "metadata sidecar"));
}

Metadata Metadata::from_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open the metadata file");
    std::stringstream ss;
    ss << f.rdbuf();
    try {
        return from_json(ss.str());
    } catch (const Error& e) {
        throw Error(path + ": " + e.what());
    }
}

Metadata Metadata::from_props(const std::map<std::string, std::string>& props) {
    Json root;
    root.kind = Json::Kind::Object;
    for (const auto& kv : props) {
        try {
            root.object.emplace_back(kv.first, Json::parse(kv.second, "metadata_props " + kv.first));
        } catch (const Error&) {  // another tool's plain-text value: keep it as a string
            Json s;
            s.kind = Json::Kind::String;
            s.string = kv.second;
            root.object.emplace_back(kv.first, s);
        }
    }
    return from_object(root);
}

const MaskingSettings& Metadata::masking(const std::string& preset) const {
    if (preset.empty()) return slam_masking;
    auto it = masking_presets.find(preset);
    if (it == masking_presets.end()) {
        std::string known;
        for (const auto& kv : masking_presets) known += (known.empty() ? "" : ", ") + kv.first;
        throw Error("metadata slam_masking.presets: no preset '" + preset + "' (has: " +
                    (known.empty() ? "none" : known) + ")");
    }
    return it->second;
}

}  // namespace slimseg
