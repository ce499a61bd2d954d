#!/usr/bin/env bash
# One short GPU check (<= 10 minutes on one NVIDIA GPU), installing nothing beyond the project:
#   1. synthetic set (640 px);  2. train yolov8s-seg-gs-rep 2 epochs at 640, AMP on cuda
#   (images/s, peak memory);  3. slimseg val on cuda;  4. FP16 and INT8 ONNX exports
#   (INT8: `slimseg export --int8 --calib DATA.yaml`);  5. TensorRT engines (trtexec through
#   export/build_engine.sh, else the tensorrt Python package);  6. engine latency, and
#   onnxruntime-gpu latency when that package is installed.
# Every step that cannot run is reported FAILED (never skipped silently); the script exits 1
# if any step failed, after running the others.
#
#   benchmarks/gpu_check.sh [--device cpu] [OUT_DIR]
# --device cpu is a dry run of the same plumbing on a CPU machine (tiny sizes); the GPU-only
# steps (TensorRT, onnxruntime CUDA provider) are then reported NOT RUN (cpu dry run).
set -uo pipefail

device=cuda
if [ "${1:-}" = "--device" ]; then device=${2:?--device needs cpu or cuda}; shift 2; fi
out=${1:-gpu-check}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
py=(${PYTHON:-python})
slimseg=(${SLIMSEG:-slimseg})
if [ "$device" = cuda ]; then
  imgsz=640 train_images=512 val_images=64 epochs=2 batch=16 workers=8
else
  imgsz=96 train_images=16 val_images=4 epochs=1 batch=4 workers=0
fi
model=yolov8s-seg-gs-rep
mkdir -p "$out"
log="$out/gpu_check.log"
: >"$log"
failed=()

step() {  # step NAME CMD...: run, tee the output to the log, record a failure
  local name=$1; shift
  echo "=== $name: $*" | tee -a "$log"
  local t0=$SECONDS
  if "$@" 2>&1 | tee -a "$log"; then
    echo "--- $name: ok ($((SECONDS - t0)) s)" | tee -a "$log"
  else
    echo "--- $name: FAILED ($((SECONDS - t0)) s)" | tee -a "$log"
    failed+=("$name")
  fi
}

not_run() {  # not_run NAME REASON: a step that does not apply, said out loud
  echo "--- $1: NOT RUN ($2)" | tee -a "$log"
}

if [ "$device" = cuda ]; then
  step "gpu visible" nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
fi
step "synthetic set" "${slimseg[@]}" data synth --out "$out/data" --imgsz "$imgsz" \
  --train "$train_images" --val "$val_images" --overwrite --quiet
data=$out/data/data.yaml

step "train ($model, $epochs epochs, $imgsz px, on $device; AMP 16-mixed on cuda)" "${py[@]}" "$here/gpu_check.py" \
  train --data "$data" --out "$out/run" --model "$model" --imgsz "$imgsz" --epochs "$epochs" \
  --batch "$batch" --workers "$workers" --train-images "$train_images" --device "$device"
weights=$out/run/weights/last.pt

step "val on $device" "${slimseg[@]}" val --weights "$weights" --data "$data" \
  --device "$device" --workers "$workers"

step "export FP16 ONNX" "${slimseg[@]}" export --weights "$weights" --imgsz "$imgsz" --half \
  --out "$out/fp16.onnx"
step "export FP32 ONNX" "${slimseg[@]}" export --weights "$weights" --imgsz "$imgsz" \
  --out "$out/fp32.onnx"
# INT8 (QDQ, calibrated on the data's images): needs the --int8/--calib export flags
step "export INT8 ONNX" "${slimseg[@]}" export --weights "$weights" --imgsz "$imgsz" --int8 \
  --calib "$data" --out "$out/int8.onnx"

if [ "$device" != cuda ]; then
  not_run "TensorRT engines and latency" "cpu dry run"
  step "onnxruntime CPU latency (FP32)" "${py[@]}" "$here/gpu_check.py" ort "$out/fp32.onnx" \
    --device cpu --runs 5 --warmup 1
elif command -v trtexec >/dev/null; then
  step "TensorRT FP16 engine (trtexec)" "$here/../export/build_engine.sh" "$out/fp32.onnx" \
    "$out/fp16.engine"
  step "TensorRT INT8 engine (trtexec)" trtexec --onnx="$out/int8.onnx" \
    --saveEngine="$out/int8.engine" --int8 --fp16 --skipInference
  for e in fp16 int8; do
    step "TensorRT $e latency (trtexec)" trtexec --loadEngine="$out/$e.engine" --iterations=200
  done
else
  echo "trtexec not on PATH: building with the tensorrt Python package" | tee -a "$log"
  step "TensorRT FP16 engine (python)" "${py[@]}" "$here/gpu_check.py" trt-build "$out/fp32.onnx" \
    "$out/fp16.engine"
  step "TensorRT INT8 engine (python)" "${py[@]}" "$here/gpu_check.py" trt-build "$out/int8.onnx" \
    "$out/int8.engine" --int8
  for e in fp16 int8; do
    step "TensorRT $e latency (python)" "${py[@]}" "$here/gpu_check.py" trt-latency "$out/$e.engine"
  done
fi
if [ "$device" = cuda ]; then
  for e in fp32 fp16; do
    step "onnxruntime-gpu latency ($e)" "${py[@]}" "$here/gpu_check.py" ort "$out/$e.onnx"
  done
fi

echo "=== summary (log: $log)"
grep -h '^{' "$log" || true
if [ ${#failed[@]} -gt 0 ]; then
  printf 'FAILED steps: %s\n' "${failed[*]}" | tee -a "$log"
  exit 1
fi
echo "all steps ok" | tee -a "$log"
