// Raw dumps: named tensors in one little-endian file (the format of `slimseg predict
// --dump-raw`; the example program writes its results in it too).
#include "slimseg/raw_dump.hpp"

#include <cstdio>
#include <cstring>
#include <fstream>
#include <algorithm>

namespace slimseg {
namespace {

constexpr char kMagic[8] = {'S', 'L', 'S', 'G', 'R', 'A', 'W', '1'};

size_t item_size(RawType t) {
    switch (t) {
        case RawType::Float32: return 4;
        case RawType::Float16: return 2;
        case RawType::Int32: return 4;
        case RawType::UInt8: return 1;
    }
    return 0;
}

bool little_endian() {
    const std::uint16_t one = 1;
    std::uint8_t b;
    std::memcpy(&b, &one, 1);
    return b == 1;
}

class Reader {
public:
    Reader(const std::vector<std::uint8_t>& data, const std::string& path)
        : d_(data), path_(path) {}
    template <typename T>
    T get(const char* what) {
        T v;
        bytes(&v, sizeof v, what);
        return v;
    }
    void bytes(void* out, size_t n, const char* what) {
        if (n > d_.size() - pos_)
            throw Error(path_ + ": truncated raw dump (reading " + what + " at byte " +
                        std::to_string(pos_) + ")");
        std::memcpy(out, d_.data() + pos_, n);
        pos_ += n;
    }
    bool done() const { return pos_ == d_.size(); }

private:
    const std::vector<std::uint8_t>& d_;
    const std::string& path_;
    size_t pos_ = 0;
};

}  // namespace

std::int64_t RawTensor::numel() const {
    std::int64_t n = 1;
    for (auto v : shape) n *= v;
    return n;
}

TensorView RawTensor::view() const {
    if (type != RawType::Float32 && type != RawType::Float16)
        throw Error("tensor " + name + ": expected float32 or float16 data");
    TensorView v;
    v.data = bytes.data();
    v.dtype = type == RawType::Float32 ? DType::Float32 : DType::Float16;
    v.shape = shape;
    return v;
}

const RawTensor* RawDump::find(const std::string& name) const {
    for (const auto& t : tensors)
        if (t.name == name) return &t;
    return nullptr;
}

const RawTensor& RawDump::need(const std::string& name) const {
    const RawTensor* t = find(name);
    if (t == nullptr) throw Error(path + ": no tensor '" + name + "' in the raw dump");
    return *t;
}

void RawDump::add(const std::string& name, RawType type, std::vector<std::int64_t> shape,
                  const void* data) {
    RawTensor t;
    t.name = name;
    t.type = type;
    t.shape = std::move(shape);
    size_t n = static_cast<size_t>(t.numel()) * item_size(type);
    t.bytes.resize(n);
    if (n) std::memcpy(t.bytes.data(), data, n);
    tensors.push_back(std::move(t));
}

RawDump RawDump::load(const std::string& path) {
    if (!little_endian()) throw Error("raw dumps are little-endian; this machine is not");
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open the raw dump");
    f.seekg(0, std::ios::end);
    std::vector<std::uint8_t> data(static_cast<size_t>(std::max<std::streamoff>(f.tellg(), 0)));
    f.seekg(0, std::ios::beg);
    f.read(reinterpret_cast<char*>(data.data()), static_cast<std::streamsize>(data.size()));
    if (!f) throw Error(path + ": cannot read the raw dump");
    Reader r(data, path);
    char magic[8];
    r.bytes(magic, 8, "the magic");
    if (std::memcmp(magic, kMagic, 8) != 0)
        throw Error(path + ": not a slimseg raw dump (no SLSGRAW1 header)");
    RawDump dump;
    dump.path = path;
    std::uint32_t count = r.get<std::uint32_t>("the tensor count");
    for (std::uint32_t i = 0; i < count; ++i) {
        RawTensor t;
        std::uint32_t len = r.get<std::uint32_t>("a name length");
        if (len > 4096) throw Error(path + ": implausible tensor name length");
        t.name.resize(len);
        r.bytes(t.name.data(), len, "a name");
        std::uint32_t type = r.get<std::uint32_t>("a dtype");
        if (type > 3) throw Error(path + ": tensor " + t.name + " has unknown dtype " +
                                  std::to_string(type));
        t.type = static_cast<RawType>(type);
        std::uint32_t ndim = r.get<std::uint32_t>("ndim");
        if (ndim > 8) throw Error(path + ": tensor " + t.name + " has " + std::to_string(ndim) +
                                  " dimensions");
        std::int64_t n = 1;
        for (std::uint32_t k = 0; k < ndim; ++k) {
            std::int64_t d = r.get<std::int64_t>("a dimension");
            if (d < 0 || d > (std::int64_t(1) << 32))
                throw Error(path + ": tensor " + t.name + " has a bad dimension");
            t.shape.push_back(d);
            n *= d;
        }
        t.bytes.resize(static_cast<size_t>(n) * item_size(t.type));
        r.bytes(t.bytes.data(), t.bytes.size(), t.name.c_str());
        dump.tensors.push_back(std::move(t));
    }
    if (!r.done()) throw Error(path + ": trailing bytes after the last tensor");
    return dump;
}

void RawDump::save(const std::string& out) const {
    const std::string tmp = out + ".tmp";
    {
        std::ofstream f(tmp, std::ios::binary);
        if (!f) throw Error(tmp + ": cannot write");
        auto put = [&](const void* p, size_t n) { f.write(static_cast<const char*>(p), n); };
        put(kMagic, 8);
        std::uint32_t count = static_cast<std::uint32_t>(tensors.size());
        put(&count, 4);
        for (const auto& t : tensors) {
            std::uint32_t len = static_cast<std::uint32_t>(t.name.size());
            put(&len, 4);
            put(t.name.data(), len);
            std::uint32_t type = static_cast<std::uint32_t>(t.type);
            put(&type, 4);
            std::uint32_t ndim = static_cast<std::uint32_t>(t.shape.size());
            put(&ndim, 4);
            for (auto d : t.shape) put(&d, 8);
            put(t.bytes.data(), t.bytes.size());
        }
        if (!f) throw Error(tmp + ": write failed");
    }
    if (std::rename(tmp.c_str(), out.c_str()) != 0) throw Error(out + ": cannot rename " + tmp);
}

}  // namespace slimseg
