// Raw dumps: a save / load round trip keeps names, types, shapes and bytes; a truncated file,
// a foreign file and a missing tensor are refused with a one-line error naming the file.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "check.hpp"
#include "slimseg/raw_dump.hpp"
#include "slimseg/tensor.hpp"

using namespace slimseg;

namespace {

void round_trip(const std::string& path) {
    const float images[6] = {0.f, 0.5f, 1.f, -1.f, 2.25f, 114.f / 255.f};
    const std::uint16_t logits[4] = {0x3c00, 0xc100, 0x0001, 0x7bff};
    const std::int32_t frame_hw[2] = {480, 640};
    const std::uint8_t flags[3] = {0, 255, 7};
    RawDump out;
    out.add("images", RawType::Float32, {1, 3, 1, 2}, images);
    out.add("logits", RawType::Float16, {2, 2}, logits);
    out.add("frame_hw", RawType::Int32, {2}, frame_hw);
    out.add("flags", RawType::UInt8, {3}, flags);
    out.add("empty", RawType::Float32, {0, 4}, nullptr);
    out.save(path);
    CHECK(!std::ifstream(path + ".tmp"));  // staged, then renamed

    const RawDump in = RawDump::load(path);
    CHECK_EQ(in.path, path);
    CHECK_EQ(in.tensors.size(), 5u);
    const RawTensor& im = in.need("images");
    CHECK(im.type == RawType::Float32);
    CHECK(im.shape == std::vector<std::int64_t>({1, 3, 1, 2}));
    const std::vector<float> f = to_float(im.view());
    CHECK(f == std::vector<float>(images, images + 6));
    const std::vector<float> h = to_float(in.need("logits").view());
    CHECK(h == std::vector<float>({1.f, -2.5f, half_to_float(0x0001), 65504.f}));
    const RawTensor& hw = in.need("frame_hw");
    CHECK_EQ(hw.bytes.size(), 8u);
    std::int32_t back[2];
    std::memcpy(back, hw.bytes.data(), sizeof back);
    CHECK(back[0] == 480 && back[1] == 640);
    CHECK_EQ(static_cast<int>(in.need("flags").bytes[1]), 255);
    CHECK_EQ(in.need("empty").numel(), 0);
    CHECK(in.find("masks") == nullptr);
    CHECK_ERROR(in.need("masks"), path + ": no tensor 'masks' in the raw dump");
    CHECK_ERROR(hw.view(), "tensor frame_hw: expected float32 or float16 data");
}

void refused(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    f.close();
    // cut inside the first tensor's data: magic 8, count 4, name length 4, "images" 6, dtype 4,
    // ndim 4, dims 32 -> the data starts at byte 62
    const std::string cut = path + ".cut";
    std::ofstream(cut, std::ios::binary) << bytes.substr(0, 70);
    CHECK_ERROR(RawDump::load(cut), cut + ": truncated raw dump (reading images at byte 62)");
    std::ofstream(cut, std::ios::binary) << bytes << "x";
    CHECK_ERROR(RawDump::load(cut), cut + ": trailing bytes after the last tensor");
    std::ofstream(cut, std::ios::binary) << "P6\n2 2\n255\n";
    CHECK_ERROR(RawDump::load(cut), cut + ": not a slimseg raw dump (no SLSGRAW1 header)");
    std::remove(cut.c_str());
    CHECK_ERROR(RawDump::load(cut), cut + ": cannot open the raw dump");
}

}  // namespace

int main() {
    const std::string path = "test_raw_dump.tmp.ssraw";
    round_trip(path);
    refused(path);
    std::remove(path.c_str());
    return slimseg_test::report("test_raw_dump");
}
