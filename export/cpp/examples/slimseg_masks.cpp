// slimseg_masks: the reference consumer on a folder of raw dumps (`slimseg predict --dump-raw`).
//
//   slimseg_masks --meta MODEL.json --dumps DUMPS/ --out OUT/ [--frames FRAMES/]
//                 [--mode fusion|seg|box] [--preset NAME] [--conf C] [--iou I] [--max-det N]
//                 [--results] [--strict]
//
// Per DUMPS/<stem>.ssraw: post-processing (boxes, scores, classes, masks or a class map) at the
// masking score threshold (slam_masking.conf unless --conf), then the SLAM rules with the
// dump's keypoints; writes OUT/<stem>.pgm (uint8 dynamic mask, 255 = dynamic). The frame size
// comes from FRAMES/<stem>.ppm (binary PPM) when --frames is given, else from the dump; with a
// frame, the letterbox is recomputed and compared with the dump's network input (largest
// difference in grey levels). --results
// also writes OUT/<stem>.ssres (the same container: boxes, scores, classes, masks, class_map,
// dynamic, keypoint_dynamic, used_seg, m_th) for comparisons. Exit 2 with one line on bad input.
// Dumps of an end-to-end export (metadata end2end) carry num_dets, boxes, scores, classes and
// masks instead of output0/output1: the NMS ran in the graph (--iou does not apply).
// Dumps with the chain's ORB descriptors (`predict --dump-raw` writes them) run the whole
// preset through the multi-frame chain (slimseg/chain.hpp: stillness, motion odds, motion
// layers), the frames in sorted order as one sequence; with --dump-depth they carry the depth
// and the camera those need. Settings of the preset that cannot act on what the dumps carry
// (no depth, no camera, no descriptors) are named once on stderr; --strict refuses them.
#include <slimseg/chain.hpp>
#include <slimseg/consumer.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace slimseg;

namespace {

struct Image {
    int w = 0, h = 0;
    std::vector<std::uint8_t> rgb;
};

// Binary PPM (P6, maxval 255), comments allowed in the header.
Image read_ppm(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open the frame");
    auto token = [&]() {
        std::string t;
        char c;
        while (f.get(c)) {
            if (c == '#') {
                std::string skip;
                std::getline(f, skip);
            } else if (std::isspace(static_cast<unsigned char>(c))) {
                if (!t.empty()) break;
            } else {
                t += c;
            }
        }
        return t;
    };
    if (token() != "P6") throw Error(path + ": not a binary PPM (P6)");
    Image im;
    try {
        im.w = std::stoi(token());
        im.h = std::stoi(token());
        if (std::stoi(token()) != 255) throw Error(path + ": PPM maxval must be 255");
    } catch (const std::logic_error&) {
        throw Error(path + ": malformed PPM header");
    }
    if (im.w <= 0 || im.h <= 0) throw Error(path + ": empty PPM");
    im.rgb.resize(static_cast<size_t>(im.w) * im.h * 3);
    f.read(reinterpret_cast<char*>(im.rgb.data()), static_cast<std::streamsize>(im.rgb.size()));
    if (!f) throw Error(path + ": truncated PPM");
    return im;
}

void write_pgm(const std::string& path, const std::vector<std::uint8_t>& px, int w, int h) {
    const std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::binary);
        f << "P5\n" << w << " " << h << "\n255\n";
        f.write(reinterpret_cast<const char*>(px.data()), static_cast<std::streamsize>(px.size()));
        if (!f) throw Error(tmp + ": write failed");
    }
    fs::rename(tmp, path);
}

struct Args {
    std::string meta, dumps, out, frames, preset;
    Mode mode = Mode::Fusion;
    double conf = -1, iou = -1;
    int max_det = -1;
    bool results = false;
    bool strict = false;
};

Args parse(int argc, char** argv) {
    Args a;
    for (int i = 1; i < argc; ++i) {
        std::string k = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) throw Error(k + ": needs a value");
            return argv[++i];
        };
        auto number = [&](const std::string& v) {
            try {
                return std::stod(v);
            } catch (const std::logic_error&) {
                throw Error(k + ": '" + v + "' is not a number");
            }
        };
        if (k == "--meta") a.meta = value();
        else if (k == "--dumps") a.dumps = value();
        else if (k == "--out") a.out = value();
        else if (k == "--frames") a.frames = value();
        else if (k == "--preset") a.preset = value();
        else if (k == "--mode") a.mode = parse_mode(value());
        else if (k == "--conf") a.conf = number(value());
        else if (k == "--iou") a.iou = number(value());
        else if (k == "--max-det") a.max_det = static_cast<int>(number(value()));
        else if (k == "--results") a.results = true;
        else if (k == "--strict") a.strict = true;
        else throw Error("unknown option " + k + " (see the comment at the top of slimseg_masks.cpp)");
    }
    if (a.meta.empty() || a.dumps.empty() || a.out.empty())
        throw Error("usage: slimseg_masks --meta MODEL.json --dumps DIR --out DIR [--frames DIR] "
                    "[--mode fusion|seg|box] [--preset NAME] [--conf C] [--results] [--strict]");
    return a;
}

struct PgmOut {
    std::string path;
    std::vector<std::uint8_t> px;
    int w = 0, h = 0;
};

void write_results(const std::string& path, const FramePrediction& p, const DynamicResult& r,
                   float letterbox_diff, std::vector<std::pair<std::string, RawDump>>* later,
                   const FrameChain* chain) {
    RawDump out;
    const std::int64_t n = static_cast<std::int64_t>(p.detections.size());
    std::vector<float> boxes, boxes_in, scores;
    std::vector<std::int32_t> classes;
    for (const auto& d : p.detections) {
        boxes.insert(boxes.end(), d.box.begin(), d.box.end());
        boxes_in.insert(boxes_in.end(), d.box_input.begin(), d.box_input.end());
        scores.push_back(d.score);
        classes.push_back(d.cls);
    }
    out.add("boxes", RawType::Float32, {n, 4}, boxes.data());
    out.add("boxes_input", RawType::Float32, {n, 4}, boxes_in.data());
    out.add("scores", RawType::Float32, {n}, scores.data());
    out.add("classes", RawType::Int32, {n}, classes.data());
    if (p.segmenter) {
        std::vector<std::uint8_t> masks(static_cast<size_t>(n) * p.h * p.w, 0);
        for (std::int64_t k = 0; k < n; ++k) {
            const WindowMask& m = p.masks[k];
            for (int y = 0; y < m.h; ++y)
                for (int x = 0; x < m.w; ++x)
                    masks[(static_cast<size_t>(k) * p.h + m.y0 + y) * p.w + m.x0 + x] =
                        m.pixels[static_cast<size_t>(y) * m.w + x];
        }
        out.add("masks", RawType::UInt8, {n, p.h, p.w}, masks.data());
    }
    if (p.semantic) out.add("class_map", RawType::UInt8, {p.h, p.w}, p.class_map.data());
    out.add("dynamic", RawType::UInt8, {p.h, p.w}, r.mask.data());
    out.add("keypoint_dynamic", RawType::UInt8, {static_cast<std::int64_t>(r.dynamic.size())},
            r.dynamic.data());
    out.add("used_seg", RawType::UInt8, {static_cast<std::int64_t>(r.used_seg.size())},
            r.used_seg.data());
    float m_th = r.gave_up ? -1.0f : static_cast<float>(r.m_th);
    out.add("m_th", RawType::Float32, {1}, &m_th);
    out.add("letterbox_max_diff", RawType::Float32, {1}, &letterbox_diff);
    if (chain) {  // the multi-frame chain's decisions: the mobility the rules used, stillness
        const auto& mob = chain->mobility();
        const auto& still = chain->still();
        out.add("mobility", RawType::Float32, {static_cast<std::int64_t>(mob.size())}, mob.data());
        out.add("still", RawType::UInt8, {static_cast<std::int64_t>(still.size())}, still.data());
    }
    later->emplace_back(path, std::move(out));
}

// An int32 tensor of a dump (end-to-end exports' num_dets and classes).
std::vector<std::int32_t> int32s(const RawTensor& t, const std::string& where) {
    if (t.type != RawType::Int32) throw Error(where + ": " + t.name + " must be int32");
    std::vector<std::int32_t> v(static_cast<size_t>(t.numel()));
    std::memcpy(v.data(), t.bytes.data(), v.size() * sizeof(std::int32_t));
    return v;
}

// What a dump carries for the multi-frame chain (the first dump's say; the others must agree).
Have carried(const RawDump& dump) {
    Have h;
    h.depth = dump.find("depth_m") != nullptr;
    h.camera = dump.find("camera") != nullptr;
    h.descriptors = dump.find("descriptors") != nullptr;
    return h;
}

std::vector<float> floats(const RawDump& dump, const std::string& name, std::int64_t cols) {
    std::vector<float> v;
    if (const RawTensor* t = dump.find(name)) {
        if (t->type != RawType::Float32 || t->shape.size() != (cols == 4 ? 1u : 2u) ||
            t->shape.back() != cols)
            throw Error(dump.path + ": " + name + " must be float32 " +
                        (cols == 4 ? "[4]" : "[N, " + std::to_string(cols) + "]"));
        v.resize(static_cast<size_t>(t->numel()));
        std::memcpy(v.data(), t->bytes.data(), t->bytes.size());
    }
    return v;
}

int run(const Args& a) {
    Metadata meta = Metadata::from_file(a.meta);
    Postprocessor post(meta);
    Rules rules = Rules::from_metadata(meta, a.mode, a.preset);
    const MaskingSettings& masking = meta.masking(a.preset);
    if (!fs::is_directory(a.dumps)) throw Error(a.dumps + ": no such folder of raw dumps");
    std::vector<fs::path> dumps;
    for (const auto& e : fs::directory_iterator(a.dumps))
        if (e.path().extension() == ".ssraw") dumps.push_back(e.path());
    std::sort(dumps.begin(), dumps.end());
    if (dumps.empty()) throw Error(a.dumps + ": no .ssraw files (write them with slimseg predict "
                                   "--dump-raw)");
    const Have have = carried(RawDump::load(dumps.front().string()));
    std::string idle_note;  // said once, after the run (an error stays the only line)
    if (const auto idle = unapplied(rules.masking, have); !idle.empty()) {
        std::string list;
        for (const auto& s : idle) list += (list.empty() ? "" : ", ") + s;
        idle_note = list + ": settings that cannot act on these dumps (they carry no " +
                    (have.descriptors ? "" : "descriptors, ") + (have.depth ? "" : "depth, ") +
                    (have.camera ? "" : "camera, ") +
                    "see docs/cpp_consumer.md; the masks are slimseg dynamic's with them off)";
        if (a.strict) throw Error(idle_note + " (--strict)");
    }
    std::optional<FrameChain> chain;  // the multi-frame chain, where the dumps carry descriptors
    if (have.descriptors) {
        std::optional<Camera> cam;
        if (have.camera) {
            const std::vector<float> c = floats(RawDump::load(dumps.front().string()), "camera", 4);
            if (!(c[0] > 0 && c[1] > 0 && std::isfinite(c[0]) && std::isfinite(c[1]) &&
                  std::isfinite(c[2]) && std::isfinite(c[3])))
                throw Error(dumps.front().string() + ": camera must be finite (fx, fy, cx, cy) "
                            "with fx, fy > 0");
            cam = Camera{c[0], c[1], c[2], c[3]};
        }
        chain.emplace(rules, cam);
    }
    const double conf = a.conf >= 0 ? a.conf : masking.conf;
    const double iou = a.iou >= 0 ? a.iou : meta.nms.iou;
    const int max_det = a.max_det > 0 ? a.max_det : meta.nms.max_det;
    double ms = 0, ms_post = 0, ms_chain = 0;
    std::vector<PgmOut> pgms;  // written after the last frame
    std::vector<std::pair<std::string, RawDump>> results;
    float worst_letterbox = 0;
    for (const auto& path : dumps) {
        const std::string stem = path.stem().string();
        RawDump dump = RawDump::load(path.string());
        if (const Have h = carried(dump); h.depth != have.depth || h.camera != have.camera ||
                                          h.descriptors != have.descriptors)
            throw Error(path.string() + ": carries other tensors (depth_m, camera, descriptors) "
                        "than " + dumps.front().string() + "; dump the sequence in one run");
        const RawTensor& hw = dump.need("frame_hw");
        if (hw.type != RawType::Int32 || hw.numel() != 2)
            throw Error(path.string() + ": frame_hw must be int32 [2]");
        std::int32_t fhw[2];
        std::memcpy(fhw, hw.bytes.data(), sizeof fhw);
        int h = fhw[0], w = fhw[1];
        float diff = -1.0f;
        if (!a.frames.empty()) {
            Image im = read_ppm((fs::path(a.frames) / (stem + ".ppm")).string());
            if (im.h != h || im.w != w)
                throw Error(stem + ": frame is " + std::to_string(im.h) + "x" +
                            std::to_string(im.w) + " but the dump was made for " +
                            std::to_string(h) + "x" + std::to_string(w));
            if (const RawTensor* images = dump.find("images")) {
                Letterbox lb = letterbox_params(h, w, meta.input_h, meta.input_w);
                std::vector<float> mine(static_cast<size_t>(3) * lb.out_h * lb.out_w);
                letterbox_image(im.rgb.data(), h, w, lb, mine.data());
                std::vector<float> theirs = to_float(images->view());
                if (theirs.size() != mine.size())
                    throw Error(stem + ": images tensor is not [1, 3, H, W] of the metadata's imgsz");
                diff = 0;
                for (size_t i = 0; i < mine.size(); ++i)
                    diff = std::max(diff, std::fabs(std::nearbyint(mine[i] * 255.0f) -
                                                    std::nearbyint(theirs[i] * 255.0f)));
                worst_letterbox = std::max(worst_letterbox, diff);
            }
        }
        std::vector<float> kps;
        if (const RawTensor* k = dump.find("keypoints")) {
            if (k->type != RawType::Float32 || k->shape.size() != 2 || k->shape[1] != 2)
                throw Error(path.string() + ": keypoints must be float32 [N, 2]");
            kps.resize(static_cast<size_t>(k->numel()));
            std::memcpy(kps.data(), k->bytes.data(), k->bytes.size());
        }
        RawOutputs raw;
        TensorView out1, masks;
        End2EndOutputs e2e;  // an end-to-end export's dump: NMS already ran in the graph
        std::vector<std::int32_t> num_dets, classes;
        if (meta.end2end) {
            num_dets = int32s(dump.need("num_dets"), path.string());
            classes = int32s(dump.need("classes"), path.string());
            if (num_dets.size() != 1) throw Error(path.string() + ": num_dets must be int32 [1]");
            e2e.num_dets = num_dets[0];
            e2e.classes = classes.data();
            e2e.boxes = dump.need("boxes").view();
            e2e.scores = dump.need("scores").view();
            if (meta.segmenter()) {
                masks = dump.need("masks").view();
                e2e.masks = &masks;
            }
        } else {
            raw.output0 = dump.need(meta.semantic() ? "logits" : "output0").view();
            if (meta.segmenter()) {
                out1 = dump.need("output1").view();
                raw.output1 = &out1;
            }
        }
        using clock = std::chrono::steady_clock;
        auto t0 = clock::now();
        FramePrediction p = meta.end2end ? post.run(e2e, h, w, conf, max_det)
                                         : post.run(raw, h, w, conf, iou, max_det);
        auto t1 = clock::now();
        std::vector<float> depth;  // optional depth_m float32 [H, W] (metres)
        if (const RawTensor* d = dump.find("depth_m")) {
            if (d->type != RawType::Float32 || d->shape.size() != 2 || d->shape[0] != h ||
                d->shape[1] != w)
                throw Error(path.string() + ": depth_m must be float32 [H, W] of the frame");
            depth.resize(static_cast<size_t>(d->numel()));
            std::memcpy(depth.data(), d->bytes.data(), d->bytes.size());
        }
        const float* dm = depth.empty() ? nullptr : depth.data();
        DynamicResult r;
        std::vector<float> corners;
        if (chain) {
            Features f;
            f.xy = kps;
            const RawTensor& d = dump.need("descriptors");
            if (d.type != RawType::UInt8 || d.shape.size() != 2 || d.shape[1] != 32 ||
                static_cast<size_t>(d.shape[0]) != kps.size() / 2)
                throw Error(path.string() + ": descriptors must be uint8 [N, 32] of the keypoints");
            f.desc = d.bytes;
            corners = floats(dump, "corners", 2);
            const bool support = dump.find("corners") != nullptr && rules.degrade();
            t1 = clock::now();  // the chain's own cost, without post-processing
            r = chain->step(objects_of(p), h, w, f, dm, support ? &corners : nullptr);
        } else {
            r = dynamic_mask(p, kps, rules, dm);
        }
        auto t2 = clock::now();
        ms_chain += std::chrono::duration<double, std::milli>(t2 - t1).count();
        ms_post += std::chrono::duration<double, std::milli>(t1 - t0).count();
        ms += std::chrono::duration<double, std::milli>(t2 - t0).count();
        PgmOut pgm{(fs::path(a.out) / (stem + ".pgm")).string(), std::move(r.mask), w, h};
        if (a.results) {
            r.mask = pgm.px;
            write_results((fs::path(a.out) / (stem + ".ssres")).string(), p, r, diff, &results,
                          chain ? &*chain : nullptr);
        }
        pgms.push_back(std::move(pgm));
    }
    // written when every frame is done: a bad frame leaves nothing half-written
    fs::create_directories(a.out);
    for (const auto& g : pgms) write_pgm(g.path, g.px, g.w, g.h);
    for (const auto& [where, res] : results) res.save(where);
    std::printf("%zu frames: dynamic masks in %s; post-processing + masking %.3f ms per frame "
                "(post-processing %.3f ms; %s %.3f ms)",
                dumps.size(), a.out.c_str(), ms / dumps.size(), ms_post / dumps.size(),
                chain ? "multi-frame chain" : "rules", ms_chain / dumps.size());
    if (!a.frames.empty()) std::printf("; letterbox vs dump: max %.2f grey levels", worst_letterbox);
    std::printf("\n");
    if (!idle_note.empty()) std::fprintf(stderr, "slimseg_masks: note: %s\n", idle_note.c_str());
    if (a.preset.empty() && meta.masking_presets.count("calibrated") == 0)
        std::fprintf(stderr, "slimseg_masks: note: %s has no calibrated masking preset; its "
                     "recommended (shipped) settings were used (slimseg calibrate chooses the "
                     "model's own)\n", a.meta.c_str());
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        return run(parse(argc, argv));
    } catch (const Error& e) {
        std::fprintf(stderr, "slimseg_masks: %s\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "slimseg_masks: %s\n", e.what());
        return 2;
    }
}
