#!/usr/bin/env bash
# Build a TensorRT FP16 engine from a slimseg ONNX export with trtexec.
#   export/build_engine.sh export/yolov8s-seg-gs-rep.onnx [engine_path] [max_batch]
# Static exports get exactly their shape. --dynamic exports get an optimisation profile:
# min 1x3x320x320, opt 1x3xHxW (the export's imgsz from the sidecar JSON), max BxHxW.
# The sidecar NAME.json (the ONNX metadata) travels with the engine: engines carry no metadata.
set -euo pipefail
onnx=${1:?usage: build_engine.sh MODEL.onnx [ENGINE] [MAX_BATCH]}
engine=${2:-${onnx%.onnx}.engine}
max_batch=${3:-4}
sidecar=${onnx%.onnx}.json
command -v trtexec >/dev/null || { echo "trtexec not found: install TensorRT and add its bin/ to PATH" >&2; exit 2; }
[ -f "$sidecar" ] || { echo "$sidecar missing: export with 'slimseg export' (it writes the sidecar)" >&2; exit 2; }
read -r h w dynamic < <(python3 -c "import json,sys; m=json.load(open(sys.argv[1])); print(m['imgsz'][0], m['imgsz'][1], int(m['dynamic_shapes']))" "$sidecar")
args=(--onnx="$onnx" --saveEngine="$engine" --fp16 --skipInference)
if [ "$dynamic" = 1 ]; then
  args+=(--minShapes=images:1x3x320x320 --optShapes=images:1x3x${h}x${w} --maxShapes=images:${max_batch}x3x${h}x${w})
fi
trtexec "${args[@]}"
[ "$sidecar" -ef "${engine%.engine}.json" ] || cp "$sidecar" "${engine%.engine}.json"
echo "engine: $engine  metadata: ${engine%.engine}.json"
