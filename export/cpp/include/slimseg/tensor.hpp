// Raw tensors: views of the network's output buffers (float32 or float16) and the float16
// conversions.
#pragma once

#include <cstdint>
#include <vector>

#include "slimseg/error.hpp"

namespace slimseg {

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

}  // namespace slimseg
