// A small JSON reader (the metadata sidecar and the ONNX metadata_props values).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "slimseg/error.hpp"

namespace slimseg {

class Json {
public:
    enum class Kind { Null, Bool, Number, String, Array, Object };
    Kind kind = Kind::Null;
    bool boolean = false;
    double number = 0.0;
    std::string string;
    std::vector<Json> array;
    std::vector<std::pair<std::string, Json>> object;

    // Parse a complete JSON text; Error("JSON (<what>): ... at offset N") on malformed text.
    static Json parse(const std::string& text, const std::string& what = "metadata");
    // The member `key` of an object, nullptr when absent (or when this is not an object).
    const Json* find(const std::string& key) const;
};

}  // namespace slimseg
