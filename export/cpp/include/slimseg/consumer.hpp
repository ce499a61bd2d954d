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
//   FramePrediction p = post.run({out0, &out1}, h, w, meta.slam_masking.conf);
//   Rules rules = Rules::from_metadata(meta, Mode::Fusion);
//   DynamicResult r = dynamic_mask(p, keypoints_xy, rules);     // r.mask: uint8, 255 = dynamic
//
// or, with the multi-frame evidence of the preset (stillness, motion odds, motion layers):
//
//   FrameChain chain(rules, Camera{fx, fy, cx, cy});             // once per camera stream
//   DynamicResult r = chain.step(objects_of(p), h, w, Features{keypoints_xy, descriptors},
//                                depth_m);                       // per frame, in order
//
// No third-party dependency. Every malformed input throws slimseg::Error with a message that
// names the field or tensor. docs/cpp_consumer.md documents the library and the parity tests.
//
// This umbrella header includes every part; each can also be included on its own:
//   slimseg/error.hpp        slimseg::Error
//   slimseg/json.hpp         the small JSON reader
//   slimseg/metadata.hpp     Metadata, NmsSettings, MaskingSettings
//   slimseg/letterbox.hpp    letterbox_params, letterbox_image, to_frame
//   slimseg/tensor.hpp       TensorView, float16 <-> float32
//   slimseg/mask.hpp         WindowMask, dilate
//   slimseg/postprocess.hpp  Postprocessor, FramePrediction
//   slimseg/rules.hpp        Rules, dynamic_mask, class_mask
//   slimseg/raw_dump.hpp     RawDump (`slimseg predict --dump-raw` files)
//   slimseg/features.hpp     Features (ORB keypoints + descriptors), match_features
//   slimseg/geometry.hpp     fundamental / homography RANSAC, pose from depth
//   slimseg/motion_check.hpp the epipolar check and its odds
//   slimseg/depth_evidence.hpp  the stillness test's and the motion layers' depth stages
//   slimseg/chain.hpp        FrameChain: the multi-frame chain per frame, unapplied(s, have)
#pragma once

#include "slimseg/chain.hpp"
#include "slimseg/error.hpp"
#include "slimseg/json.hpp"
#include "slimseg/letterbox.hpp"
#include "slimseg/mask.hpp"
#include "slimseg/metadata.hpp"
#include "slimseg/postprocess.hpp"
#include "slimseg/raw_dump.hpp"
#include "slimseg/rules.hpp"
#include "slimseg/tensor.hpp"
