// slimseg::Error: the one exception type of the reference consumer.
#pragma once

#include <stdexcept>

namespace slimseg {

// Every error of this library: a one-line message naming the field, tensor or file.
struct Error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

}  // namespace slimseg
