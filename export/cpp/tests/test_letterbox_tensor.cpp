// The letterbox (sizes, padding, the inverse, the network input's layout) and float16.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "check.hpp"
#include "slimseg/letterbox.hpp"
#include "slimseg/tensor.hpp"

using namespace slimseg;

namespace {

void letterbox_sizes() {
    // landscape into a wider input: scale 0.8, 512 x 384 resized, 64 px either side
    Letterbox a = letterbox_params(480, 640, 384, 640);
    CHECK_NEAR(a.scale, 0.8, 1e-15);
    CHECK_EQ(a.new_w, 512);
    CHECK_EQ(a.new_h, 384);
    CHECK_EQ(a.left, 64);
    CHECK_EQ(a.top, 0);
    CHECK_EQ(a.out_w, 640);
    CHECK_EQ(a.out_h, 384);
    // portrait
    Letterbox b = letterbox_params(200, 120, 160, 160);
    CHECK_EQ(b.new_w, 96);
    CHECK_EQ(b.new_h, 160);
    CHECK_EQ(b.left, 32);
    CHECK_EQ(b.top, 0);
    // upscaled, sides not multiples of anything: 97 * 160 / 131 = 118.47 -> 118, top 21
    Letterbox c = letterbox_params(97, 131, 160, 160);
    CHECK_EQ(c.new_w, 160);
    CHECK_EQ(c.new_h, 118);
    CHECK_EQ(c.left, 0);
    CHECK_EQ(c.top, 21);
    // odd padding rounds down on the left: 45 * 0.64 = 28.8 -> 29, 35 px to share -> 17 | 18
    Letterbox d = letterbox_params(100, 45, 64, 64);
    CHECK_EQ(d.new_w, 29);
    CHECK_EQ(d.left, 17);
    // the inverse
    auto p = to_frame(a, 64 + 256, 192);
    CHECK_NEAR(p[0], 320.0, 1e-12);
    CHECK_NEAR(p[1], 240.0, 1e-12);
    CHECK_ERROR(letterbox_params(0, 10, 64, 64), "letterbox: empty frame 0x10");
    CHECK_ERROR(letterbox_params(10, 10, 64, 0), "letterbox: empty network input");
}

void letterbox_image_layout() {
    // 2 x 3 frame into a 4 x 3 input: scale 1 (no resampling), one padding row above and below
    const std::uint8_t rgb[2 * 3 * 3] = {0,  1,  2,  10, 11, 12, 20, 21, 22,
                                         30, 31, 32, 40, 41, 42, 50, 51, 52};
    Letterbox lb = letterbox_params(2, 3, 4, 3);
    CHECK_EQ(lb.top, 1);
    CHECK_EQ(lb.left, 0);
    std::vector<float> chw(3 * 4 * 3, -1.f);
    letterbox_image(rgb, 2, 3, lb, chw.data());
    for (int c = 0; c < 3; ++c)
        for (int y = 0; y < 4; ++y)
            for (int x = 0; x < 3; ++x) {
                float want = (y == 0 || y == 3) ? 114.f / 255.f
                                                : rgb[((y - 1) * 3 + x) * 3 + c] / 255.f;
                CHECK_EQ(chw[(c * 4 + y) * 3 + x], want);
            }
    // a uniform frame stays uniform when resized (bilinear weights sum to one)
    std::vector<std::uint8_t> flat(7 * 5 * 3);
    for (size_t i = 0; i < flat.size(); ++i) flat[i] = static_cast<std::uint8_t>(60 + i % 3);
    Letterbox up = letterbox_params(7, 5, 16, 16);
    std::vector<float> big(3 * 16 * 16);
    letterbox_image(flat.data(), 7, 5, up, big.data());
    CHECK_EQ(big[(0 * 16 + 8) * 16 + 8], 60.f / 255.f);
    CHECK_EQ(big[(2 * 16 + 8) * 16 + 8], 62.f / 255.f);
    CHECK_EQ(big[(1 * 16 + 8) * 16 + 0], 114.f / 255.f);  // left padding
}

float bits_to_float(std::uint32_t b) {
    float f;
    std::memcpy(&f, &b, sizeof f);
    return f;
}

void float16_known_values() {
    CHECK_EQ(float_to_half(0.0f), 0x0000);
    CHECK_EQ(float_to_half(-0.0f), 0x8000);
    CHECK_EQ(float_to_half(1.0f), 0x3c00);
    CHECK_EQ(float_to_half(-2.5f), 0xc100);
    CHECK_EQ(float_to_half(0.1f), 0x2e66);
    CHECK_EQ(float_to_half(1.0f / 3.0f), 0x3555);
    CHECK_EQ(float_to_half(65504.f), 0x7bff);                // the largest half
    CHECK_EQ(float_to_half(65520.f), 0x7c00);                // halfway to 65536: infinity
    CHECK_EQ(float_to_half(1e6f), 0x7c00);
    CHECK_EQ(float_to_half(-std::numeric_limits<float>::infinity()), 0xfc00);
    CHECK_EQ(float_to_half(std::ldexp(1.0f, -24)), 0x0001);  // the smallest subnormal
    CHECK_EQ(float_to_half(std::ldexp(1.0f, -25)), 0x0000);  // half of it: ties to even (0)
    CHECK_EQ(float_to_half(std::ldexp(1.5f, -25)), 0x0001);  // above the tie
    CHECK_EQ(float_to_half(1e-8f), 0x0000);
    // ties to even: 1 + 2^-11 -> 1 (even), 1 + 3 * 2^-11 -> 1 + 2^-9 (even)
    CHECK_EQ(float_to_half(bits_to_float(0x3f801000u)), 0x3c00);
    CHECK_EQ(float_to_half(bits_to_float(0x3f803000u)), 0x3c02);
    CHECK_EQ(float_to_half(bits_to_float(0x3f801001u)), 0x3c01);  // just above the tie
    const std::uint16_t nan = float_to_half(std::numeric_limits<float>::quiet_NaN());
    CHECK((nan & 0x7c00) == 0x7c00 && (nan & 0x03ff) != 0);

    CHECK_EQ(half_to_float(0x3c00), 1.0f);
    CHECK_EQ(half_to_float(0x3555), 0.333251953125f);
    CHECK_EQ(half_to_float(0x0001), std::ldexp(1.0f, -24));
    CHECK_EQ(half_to_float(0x03ff), std::ldexp(1023.0f, -24));  // the largest subnormal
    CHECK_EQ(half_to_float(0x7bff), 65504.f);
    CHECK_EQ(half_to_float(0xfc00), -std::numeric_limits<float>::infinity());
    CHECK(std::isnan(half_to_float(0x7e00)));
    CHECK(std::signbit(half_to_float(0x8000)));
}

void float16_round_trip() {
    // every half widens exactly and narrows back to itself (NaNs stay NaN)
    int bad = 0;
    for (std::uint32_t h = 0; h <= 0xffff; ++h) {
        const float f = half_to_float(static_cast<std::uint16_t>(h));
        const std::uint16_t back = float_to_half(f);
        const bool is_nan = (h & 0x7c00) == 0x7c00 && (h & 0x03ff) != 0;
        if (is_nan ? !std::isnan(f) || (back & 0x7c00) != 0x7c00 || !(back & 0x03ff)
                   : back != h)
            ++bad;
    }
    CHECK_EQ(bad, 0);
}

void tensor_views() {
    const std::uint16_t halves[6] = {0x3c00, 0xc100, 0x0000, 0x3555, 0x7bff, 0x0001};
    TensorView v{halves, DType::Float16, {1, 2, 3}};
    CHECK_EQ(v.numel(), 6);
    std::vector<float> f = to_float(v);
    CHECK_EQ(f.size(), 6u);
    CHECK_EQ(f[1], -2.5f);
    CHECK_EQ(f[4], 65504.f);
    const float floats[2] = {0.25f, -7.0f};
    std::vector<float> g = to_float(TensorView{floats, DType::Float32, {2}});
    CHECK(g == std::vector<float>({0.25f, -7.0f}));
    CHECK_EQ(TensorView{}.numel(), 0);
    CHECK_ERROR(to_float(TensorView{nullptr, DType::Float32, {4}}), "tensor: no data");
}

}  // namespace

int main() {
    letterbox_sizes();
    letterbox_image_layout();
    float16_known_values();
    float16_round_trip();
    tensor_views();
    return slimseg_test::report("test_letterbox_tensor");
}
