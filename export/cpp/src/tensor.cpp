// Raw tensors: element counts and the float16 <-> float32 conversions.
#include "slimseg/tensor.hpp"

#include <cstring>

namespace slimseg {

std::int64_t TensorView::numel() const {
    std::int64_t n = 1;
    for (auto d : shape) n *= d;
    return shape.empty() ? 0 : n;
}

float half_to_float(std::uint16_t h) {
    std::uint32_t sign = static_cast<std::uint32_t>(h & 0x8000u) << 16;
    std::uint32_t exp = (h >> 10) & 0x1Fu;
    std::uint32_t man = h & 0x3FFu;
    std::uint32_t bits;
    if (exp == 0) {
        if (man == 0) {
            bits = sign;
        } else {  // subnormal: normalise
            int e = -1;
            do {
                ++e;
                man <<= 1;
            } while ((man & 0x400u) == 0);
            bits = sign | static_cast<std::uint32_t>(127 - 15 - e) << 23 | (man & 0x3FFu) << 13;
        }
    } else if (exp == 0x1F) {
        bits = sign | 0x7F800000u | man << 13;  // inf / nan
    } else {
        bits = sign | (exp + 127 - 15) << 23 | man << 13;
    }
    float f;
    std::memcpy(&f, &bits, sizeof f);
    return f;
}

std::uint16_t float_to_half(float f) {
    std::uint32_t x;
    std::memcpy(&x, &f, sizeof x);
    const std::uint16_t sign = static_cast<std::uint16_t>((x >> 16) & 0x8000u);
    const std::uint32_t abs = x & 0x7FFFFFFFu;
    if (abs >= 0x7F800000u)  // inf / nan
        return sign | 0x7C00u | (abs > 0x7F800000u ? 0x200u : 0u);
    if (abs >= 0x477FF000u) return sign | 0x7C00u;  // rounds past 65504: infinity
    if (abs < 0x38800000u) {  // below the smallest normal half: subnormal (or zero)
        if (abs < 0x33000000u) return sign;  // below half the smallest subnormal
        const std::uint32_t man = (abs & 0x7FFFFFu) | 0x800000u;
        const int shift = 126 - static_cast<int>(abs >> 23);  // 14 .. 24
        std::uint32_t v = man >> shift;
        const std::uint32_t rest = man & ((1u << shift) - 1), half = 1u << (shift - 1);
        if (rest > half || (rest == half && (v & 1u))) ++v;
        return sign | static_cast<std::uint16_t>(v);
    }
    std::uint32_t v = abs - 0x38000000u;  // rebias the exponent (127 -> 15)
    const std::uint32_t rest = v & 0x1FFFu;
    v >>= 13;
    if (rest > 0x1000u || (rest == 0x1000u && (v & 1u))) ++v;
    return sign | static_cast<std::uint16_t>(v);
}

std::vector<float> to_float(const TensorView& t) {
    std::int64_t n = t.numel();
    if (t.data == nullptr && n > 0) throw Error("tensor: no data");
    std::vector<float> out(static_cast<size_t>(n));
    if (t.dtype == DType::Float32) {
        std::memcpy(out.data(), t.data, static_cast<size_t>(n) * sizeof(float));
    } else {
        const auto* p = static_cast<const std::uint16_t*>(t.data);
        for (std::int64_t i = 0; i < n; ++i) out[i] = half_to_float(p[i]);
    }
    return out;
}

}  // namespace slimseg
