// Raw dumps (`slimseg predict --dump-raw DIR`, docs/cpp_consumer.md): named tensors in one
// little-endian file, read and written.
//
// The format: "SLSGRAW1", uint32 count, then per tensor uint32 name length, the name (UTF-8),
// uint32 dtype (0 float32, 1 float16, 2 int32, 3 uint8), uint32 ndim, int64 dims[ndim], the
// data in C order; every number little-endian.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "slimseg/error.hpp"
#include "slimseg/tensor.hpp"

namespace slimseg {

enum class RawType : std::uint32_t { Float32 = 0, Float16 = 1, Int32 = 2, UInt8 = 3 };

struct RawTensor {
    std::string name;
    RawType type = RawType::Float32;
    std::vector<std::int64_t> shape;
    std::vector<std::uint8_t> bytes;
    TensorView view() const;  // float32 / float16 tensors only
    std::int64_t numel() const;
};

struct RawDump {
    std::vector<RawTensor> tensors;
    const RawTensor* find(const std::string& name) const;
    const RawTensor& need(const std::string& name) const;  // Error naming the file and tensor
    void add(const std::string& name, RawType type, std::vector<std::int64_t> shape,
             const void* data);
    static RawDump load(const std::string& path);
    void save(const std::string& path) const;  // written to path.tmp, then renamed
    std::string path;
};

}  // namespace slimseg
