#!/usr/bin/env bash
# Build a TensorRT engine from a slimseg ONNX export with trtexec.
#   export/build_engine.sh export/yolov8s-seg-gs-rep.onnx [engine_path] [max_batch]
#   export/build_engine.sh --help
# Static exports get exactly their shape. --dynamic exports get an optimisation profile:
# min 1x3xMINxMIN (MIN: 320, or the export's own side when that is smaller), opt 1x3xHxW
# (the export's imgsz from the sidecar JSON), max BxHxW; MIN_SIZE=N sets MIN (a multiple of 32,
# at most the export's smaller side), so min <= opt <= max holds at every size.
# The sidecar NAME.json (the ONNX metadata) travels with the engine: engines carry no metadata.
# The file checks (sidecar, INT8 target) run before trtexec is looked for.
#
# Precision follows the sidecar's "precision" and the TensorRT version (an INT8 file made for
# onnxruntime, int8.target "onnxruntime", is refused: TensorRT takes only symmetric int8 Q/DQ):
#   fp32/fp16 exports, TensorRT 8.6 / 10 (weakly typed) -> --fp16 (FP16 kernels allowed).
#   fp32/fp16 exports, TensorRT 11 (strongly typed only; it refuses --fp16) or 10 with
#     STRONGLY_TYPED=1 -> --stronglyTyped: every tensor keeps the file's type, so an FP32 file
#     builds an FP32 engine; give it the --half file (NAME-fp16.onnx, FP16 tensors; an
#     end-to-end one keeps its boxes, scores and NMS in FP32) for FP16 speed.
# End-to-end exports (sidecar "end2end": NMS inside, NonMaxSuppression/TopK) need TensorRT >= 8.6.
#   int8 (Q/DQ) exports, explicit quantization: the scales come from the file's Q/DQ nodes, never
#   from a TensorRT calibrator.
#     TensorRT 8.6 / 10 (weakly typed): --int8 --fp16 lets the quantized convs run in INT8 and the
#       layers the file keeps in floating point run in FP16.
#     TensorRT 10 with STRONGLY_TYPED=1, and TensorRT 11 (strongly typed only): --stronglyTyped;
#       every tensor keeps the type the file declares, so the float parts of a slimseg INT8
#       file (FP32 there) run in FP32. FP16 float parts would need FP16 tensors in the file.
set -euo pipefail
usage="usage: build_engine.sh MODEL.onnx [ENGINE] [MAX_BATCH]   (MIN_SIZE=N, STRONGLY_TYPED=1; --help)"
if [ "${1:-}" = --help ] || [ "${1:-}" = -h ]; then
  sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
  exit 0
fi
[ $# -ge 1 ] && [ $# -le 3 ] || { echo "$usage" >&2; exit 2; }
onnx=$1
engine=${2:-${onnx%.onnx}.engine}
max_batch=${3:-4}
sidecar=${onnx%.onnx}.json
[[ "$max_batch" =~ ^[1-9][0-9]*$ ]] || { echo "MAX_BATCH $max_batch: expected a whole number >= 1" >&2; exit 2; }
[ -f "$onnx" ] || { echo "$onnx: file not found" >&2; exit 2; }
[ -f "$sidecar" ] || { echo "$sidecar missing: export with 'slimseg export' (it writes the sidecar)" >&2; exit 2; }
read -r h w dynamic precision target end2end < <(python3 -c "import json,sys; m=json.load(open(sys.argv[1])); print(m['imgsz'][0], m['imgsz'][1], int(m['dynamic_shapes']), m.get('precision', 'fp32'), (m.get('int8') or {}).get('target', 'tensorrt'), int('end2end' in m))" "$sidecar") \
  || { echo "$sidecar: not a slimseg sidecar (imgsz, dynamic_shapes): re-export with 'slimseg export'" >&2; exit 2; }
if [ "$precision" = int8 ] && [ "$target" != tensorrt ]; then
  echo "$onnx: an INT8 file for $target (uint8 activations), not for TensorRT: re-export with 'slimseg export --int8 --int8-target tensorrt'" >&2
  exit 2
fi
# the profile: min <= opt <= max in every dimension
side=$(( h < w ? h : w ))
min_hw=${MIN_SIZE:-320}
[[ "$min_hw" =~ ^[1-9][0-9]*$ ]] && [ $((min_hw % 32)) = 0 ] \
  || { echo "MIN_SIZE $min_hw: expected a multiple of 32" >&2; exit 2; }
if [ "$min_hw" -gt "$side" ]; then
  [ -n "${MIN_SIZE:-}" ] && { echo "MIN_SIZE $min_hw: larger than the export's ${h}x${w}; give at most $side" >&2; exit 2; }
  min_hw=$side
fi
command -v trtexec >/dev/null || { echo "trtexec not found: install TensorRT and add its bin/ to PATH (the file checks passed)" >&2; exit 2; }
# trtexec prints e.g. "TensorRT v8601" (8.6.1) or "TensorRT v100300" (10.3.0).
ver=$(trtexec --help 2>&1 | grep -o 'TensorRT v[0-9]*' | head -n1 | grep -o '[0-9]*$' || true)
if [ -z "$ver" ]; then major=10; elif [ ${#ver} -ge 6 ]; then major=$((ver / 10000)); else major=$((ver / 1000)); fi
if [ "$end2end" = 1 ] && [ "$major" -lt 9 ] && [ -n "$ver" ] && [ "$ver" -lt 8600 ]; then
  echo "$onnx: an end-to-end export (NonMaxSuppression, TopK inside) needs TensorRT >= 8.6" >&2
  exit 2
fi
strongly_typed=0
if [ "$major" -ge 11 ] || [ "${STRONGLY_TYPED:-0}" = 1 ]; then strongly_typed=1; fi
args=(--onnx="$onnx" --saveEngine="$engine" --skipInference)
if [ "$strongly_typed" = 1 ]; then
  args+=(--stronglyTyped)
  if [ "$precision" = fp32 ]; then
    echo "note: TensorRT $major builds this FP32 file in FP32 (strongly typed); export --half for FP16" >&2
  fi
elif [ "$precision" = int8 ]; then
  args+=(--int8 --fp16)
else
  args+=(--fp16)
fi
if [ "$dynamic" = 1 ]; then
  args+=(--minShapes=images:1x3x${min_hw}x${min_hw} --optShapes=images:1x3x${h}x${w} --maxShapes=images:${max_batch}x3x${h}x${w})
fi
trtexec "${args[@]}"
[ "$sidecar" -ef "${engine%.engine}.json" ] || cp "$sidecar" "${engine%.engine}.json"
echo "engine: $engine ($precision, TensorRT $major)  metadata: ${engine%.engine}.json"
