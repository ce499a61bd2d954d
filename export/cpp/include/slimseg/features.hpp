// A frame's ORB features as the multi-frame stages take them (the SLAM system's own, or the
// chain's from a raw dump) and their ratio-test matching (slimseg.dynamic.epipolar
// .match_features): brute-force Hamming distances on 32-byte descriptors.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "slimseg/settings_generated.hpp"

namespace slimseg {

struct Features {
    std::vector<float> xy;             // N (x, y) frame pixels, flattened
    std::vector<std::uint8_t> desc;    // N x 32 ORB descriptor bytes
    std::size_t size() const { return xy.size() / 2; }
    void check() const;                // Error unless desc holds 32 bytes per keypoint
};

// Hamming distance of two 32-byte descriptors.
int hamming32(const std::uint8_t* a, const std::uint8_t* b);

// Ratio-test matches a -> b: (index in a, index in b) with the best distance below `ratio`
// times the second best, each b index used once (the closest match wins); ordered by
// distance, ties by a's index (as match_features).
std::vector<std::array<int, 2>> match_features(const Features& a, const Features& b,
                                               double ratio = generated::multi_frame::kRatio);

// At most about kMotionFeatures of f's features (a regular stride) and their indices in f
// (slimseg.dynamic.occupancy.subsample).
Features subsample(const Features& f, std::vector<int>& index);

}  // namespace slimseg
