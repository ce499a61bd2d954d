// The multi-frame chain's pieces on small synthetic inputs: Hamming matching with the ratio
// test, the 8-point / 4-point RANSAC (deterministic draws), the pose from depth, the motion
// odds, the depth filters, the stillness test and the motion layers, the chain's history.
#include <cmath>
#include <cstdint>
#include <vector>

#include "check.hpp"
#include "slimseg/chain.hpp"
#include "slimseg/depth_evidence.hpp"
#include "slimseg/geometry.hpp"
#include "slimseg/motion_check.hpp"

using namespace slimseg;

namespace {

std::uint64_t state = 12345;
double uniform() {  // a small LCG: the test's own scene, independent of the library's draws
    state = state * 6364136223846793005ULL + 1442695040888963407ULL;
    return static_cast<double>(state >> 11) / 9007199254740992.0;
}

std::vector<std::uint8_t> descriptor(int seed) {
    std::vector<std::uint8_t> d(32);
    for (int i = 0; i < 32; ++i) d[i] = static_cast<std::uint8_t>((seed * 131 + i * 29) ^ (seed >> 3));
    return d;
}

void test_hamming_and_matching() {
    std::vector<std::uint8_t> a(32, 0), b(32, 0);
    CHECK_EQ(hamming32(a.data(), b.data()), 0);
    b[0] = 0xFF, b[31] = 0x01;
    CHECK_EQ(hamming32(a.data(), b.data()), 9);
    Features f, g;  // g: f's descriptors in reverse order, one with 3 bits flipped
    for (int i = 0; i < 6; ++i) {
        f.xy.insert(f.xy.end(), {float(i), float(i)});
        auto d = descriptor(i + 1);
        f.desc.insert(f.desc.end(), d.begin(), d.end());
    }
    for (int i = 5; i >= 0; --i) {
        g.xy.insert(g.xy.end(), {float(i), float(i)});
        auto d = descriptor(i + 1);
        if (i == 2) d[4] ^= 0x07;
        g.desc.insert(g.desc.end(), d.begin(), d.end());
    }
    const auto m = match_features(f, g);
    CHECK_EQ(m.size(), size_t(6));
    for (const auto& p : m) CHECK_EQ(p[1], 5 - p[0]);
    CHECK_EQ(m.back()[0], 2);  // ordered by distance: the flipped one last
    Features dup = g;  // two identical b descriptors: the ratio test rejects the ambiguity
    dup.desc.insert(dup.desc.end(), g.desc.begin(), g.desc.begin() + 32);
    dup.xy.insert(dup.xy.end(), {0.f, 0.f});
    CHECK_EQ(match_features(f, dup).size(), size_t(5));
}

struct Scene {
    std::vector<double> p0, p1;
    int inliers = 0;
};

// Points of a 3-D cloud seen from two cameras (the second moved by rotation about y and
// translation), then `outliers` matches displaced at random.
Scene two_views(int n, int outliers, double tx, bool planar) {
    const Camera c{500, 500, 320, 240};
    const Mat3 r = {std::cos(0.05), 0, std::sin(0.05), 0, 1, 0, -std::sin(0.05), 0, std::cos(0.05)};
    Scene s;
    for (int i = 0; i < n; ++i) {
        const double x = uniform() * 4 - 2, y = uniform() * 3 - 1.5;
        const double z = planar ? 4.0 : 2.0 + uniform() * 6;
        const double X[3] = {x, y, z};
        double Y[3];
        for (int k = 0; k < 3; ++k) Y[k] = r[k * 3] * X[0] + r[k * 3 + 1] * X[1] + r[k * 3 + 2] * X[2];
        Y[0] += tx;
        s.p0.insert(s.p0.end(), {c.fx * X[0] / X[2] + c.cx, c.fy * X[1] / X[2] + c.cy});
        s.p1.insert(s.p1.end(), {c.fx * Y[0] / Y[2] + c.cx, c.fy * Y[1] / Y[2] + c.cy});
    }
    s.inliers = n - outliers;
    for (int i = s.inliers; i < n; ++i) s.p1[2 * i] += 20 + 40 * uniform(), s.p1[2 * i + 1] -= 15;
    return s;
}

void test_fundamental_and_homography() {
    const Scene s = two_views(120, 30, 0.3, false);
    Mat3 f, f2;
    CHECK(fundamental_ransac(s.p0, s.p1, 1.0, 0.999, f));
    CHECK(fundamental_ransac(s.p0, s.p1, 1.0, 0.999, f2));
    CHECK(f == f2);  // deterministic draws: the same input, the same fit
    const auto d = epipolar_distance(f, s.p0, s.p1);
    double worst_in = 0;
    int far_out = 0;
    for (int i = 0; i < 120; ++i) (i < s.inliers ? worst_in = std::max(worst_in, d[i]) : far_out += d[i] > 2);
    CHECK(worst_in < 1e-6);
    CHECK(far_out >= 25);
    Mat3 all;  // the plain 8-point fit on exact matches
    std::vector<double> q0(s.p0.begin(), s.p0.begin() + 2 * s.inliers),
        q1(s.p1.begin(), s.p1.begin() + 2 * s.inliers);
    CHECK(fundamental_8point(q0, q1, all));
    for (double v : epipolar_distance(all, q0, q1)) CHECK(v < 1e-6);
    const Scene plane = two_views(60, 10, 0.3, true);
    Mat3 h;
    CHECK(homography_ransac(plane.p0, plane.p1, 1.0, 0.999, h));
    const auto t = transfer_distance(h, plane.p0, plane.p1);
    for (int i = 0; i < plane.inliers; ++i) CHECK(t[i] < 1e-6);
    std::vector<double> few(14, 1.0);
    CHECK(!fundamental_ransac(few, few, 1.0, 0.999, f));  // 7 matches: no fit
}

void test_pose_from_depth() {
    const int h = 120, w = 160;
    const Camera c{100, 100, 80, 60};
    std::vector<float> d0(h * w), d1(h * w, 0.0f);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) d0[y * w + x] = 2.0f + 0.01f * x + 0.005f * y;
    Pose truth;
    truth.r = {std::cos(0.02), -std::sin(0.02), 0, std::sin(0.02), std::cos(0.02), 0, 0, 0, 1};
    truth.t = {0.05, -0.02, 0.03};
    std::vector<double> p0, p1;
    for (int i = 0; i < 40; ++i) {
        const int x = 20 + (i * 37) % 120, y = 10 + (i * 53) % 100;
        const double z = d0[y * w + x];
        const double X[3] = {(x - c.cx) * z / c.fx, (y - c.cy) * z / c.fy, z};
        double Y[3];
        for (int k = 0; k < 3; ++k)
            Y[k] = truth.r[k * 3] * X[0] + truth.r[k * 3 + 1] * X[1] + truth.r[k * 3 + 2] * X[2] + truth.t[k];
        const double u = c.fx * Y[0] / Y[2] + c.cx, v = c.fy * Y[1] / Y[2] + c.cy;
        p0.insert(p0.end(), {double(x), double(y)});
        p1.insert(p1.end(), {u + (i >= 34 ? 15 : 0), v});  // six outliers
        const int ui = int(std::nearbyint(u)), vi = int(std::nearbyint(v));
        if (ui >= 0 && ui < w && vi >= 0 && vi < h) d1[vi * w + ui] = static_cast<float>(Y[2]);
    }
    Pose got;
    CHECK(pnp_pose(p0, p1, std::vector<std::uint8_t>(40, 1), d0.data(), d1.data(), h, w, c, got));
    for (int k = 0; k < 9; ++k) CHECK_NEAR(got.r[k], truth.r[k], 1e-6);
    for (int k = 0; k < 3; ++k) CHECK_NEAR(got.t[k], truth.t[k], 1e-6);
    std::vector<double> q0(p0.begin(), p0.begin() + 22), q1(p1.begin(), p1.begin() + 22);
    CHECK(!pnp_pose(q0, q1, std::vector<std::uint8_t>(11, 1), d0.data(), d1.data(), h, w, c, got));
}

void test_motion_odds() {
    CHECK_NEAR(weigh_odds(0.75, false, 10), 0.075 / 0.325, 1e-12);
    CHECK_NEAR(weigh_odds(0.25, true, 10), 2.5 / 3.25, 1e-12);
}

void test_depth_filters_and_surfaces() {
    const int h = 5, w = 6;
    std::vector<float> d(h * w, 2.0f);
    d[2 * w + 3] = 0.0f;       // a hole
    d[0] = NAN;
    for (int y = 0; y < h; ++y) d[y * w + 5] = 3.0f;  // a step at the right edge
    const DepthImage img{d.data(), h, w};
    const auto z = zero_invalid(img);
    CHECK_EQ(z[0], 0.0f);
    const auto lo = min_filter(z, h, w, 1), hi = max_filter(z, h, w, 1);
    CHECK_EQ(lo[1 * w + 2], 0.0f);  // next to the hole
    CHECK_EQ(lo[4 * w + 0], 2.0f);
    CHECK_EQ(hi[4 * w + 4], 3.0f);
    const auto s = surfaces(img);
    const auto some = surface_pixels(img, std::vector<std::uint8_t>(h * w, 1));
    CHECK(some == s);
    CHECK_EQ(int(s[4 * w + 1]), 1);
    CHECK_EQ(int(s[4 * w + 4]), 0);  // the step: 1 m within a pixel
    CHECK_EQ(int(s[2 * w + 2]), 0);  // beside the hole
    const auto near = nearest_before(img);
    CHECK(std::isnan(near[2 * w + 2]));
}

// A wall at 3 m; a box of pixels at 1 m now that the earlier frame saw as wall (moved in),
// the camera still (identity pose).
void test_stillness_and_layers() {
    const int h = 40, w = 60;
    const Camera c{50, 50, 30, 20};
    std::vector<float> before(h * w, 3.0f), now = before;
    WindowMask obj;
    obj.x0 = 10, obj.y0 = 8, obj.w = 30, obj.h = 24;
    obj.pixels.assign(obj.w * obj.h, 1);
    for (int y = obj.y0; y < obj.y0 + obj.h; ++y)
        for (int x = obj.x0; x < obj.x0 + obj.w; ++x) now[y * w + x] = 1.0f;
    const DepthImage a{now.data(), h, w}, b{before.data(), h, w}, same{now.data(), h, w};
    const Pose still;
    const auto moved = changed_fractions(a, b, c, still, {&obj});
    CHECK(moved[0] > 0.9);  // it was not there: it moved
    const auto stayed = changed_fractions(a, same, c, still, {&obj});
    CHECK_NEAR(stayed[0], 0.0, 0.0);
    WindowMask tiny = obj;
    tiny.w = 4, tiny.h = 4, tiny.pixels.assign(16, 1);
    CHECK(std::isnan(changed_fractions(a, same, c, still, {&tiny})[0]));  // < kMinTested
    // motion layers: the moved-in pixels behind a near layer at 0.2 m (reference) stand
    std::vector<std::uint8_t> where(h * w, 1);
    const auto marked = moved_in(a, b, c, still, where);
    int count = 0;
    for (auto v : marked) count += v;
    CHECK_EQ(count, 15 * 12);  // the object's grid pixels (every 2nd of 30 x 24)
    const std::vector<std::array<float, 4>> boxes = {{0, 0, 60, 40}};
    const auto layers = motion_layers(marked, a, boxes, {0.2f}, 0.5, 100);
    CHECK_NEAR(layers[0], 1.0, 0.0);
    CHECK(std::isnan(motion_layers(marked, a, boxes, {0.2f}, 0.5, 4 * 181)[0]));
}

// The chain keeps its history: frame sizes are checked, a still object goes to mobility 0
// once still_frames / 2 frames are held and stays still while a little of it changes, and a
// setting without what it needs is named.
void test_chain() {
    const int h = 40, w = 60;
    Rules rules;
    rules.class_mobility = {1.0f};
    rules.mode = Mode::Seg;
    rules.masking.min_static = 0;
    rules.masking.cut_behind_m = 0.5;
    rules.masking.still_frames = 2;
    std::vector<float> depth(h * w, 3.0f);
    for (int y = 5; y < 35; ++y)
        for (int x = 10; x < 50; ++x) depth[y * w + x] = 1.5f;
    Features f;  // a grid of keypoints with distinct descriptors, the same every frame
    for (int i = 0; i < 60; ++i) {
        f.xy.insert(f.xy.end(), {float(2 + (i % 10) * 5.5), float(2 + (i / 10) * 6.0)});
        auto d = descriptor(i * 7 + 3);
        f.desc.insert(f.desc.end(), d.begin(), d.end());
    }
    Objects o;
    o.boxes = {{10, 5, 50, 35}};
    o.classes = {0};
    o.scores = {0.9f};
    WindowMask m;
    m.x0 = 10, m.y0 = 5, m.w = 40, m.h = 30;
    m.pixels.assign(m.w * m.h, 1);
    o.masks = {m};
    o.has_masks = true;
    FrameChain chain(rules, Camera{50, 50, 30, 20});
    chain.step(o, h, w, f, depth.data());
    CHECK_EQ(chain.mobility()[0], 1.0f);  // no history yet
    chain.step(o, h, w, f, depth.data());
    CHECK_EQ(int(chain.still()[0]), 1);  // its depth has not changed: still
    CHECK_EQ(chain.mobility()[0], 0.0f);
    // something nearer over a fifth of it now (rows 5-10 of 5-34): found still the frame
    // before, it stays still (at most kStillKeepFraction changed); a chain that never found
    // it still does not; two fifths changed is too much even remembered
    std::vector<float> brushed = depth;
    for (int y = 5; y < 11; ++y)
        for (int x = 10; x < 50; ++x) brushed[y * w + x] = 1.0f;
    FrameChain fresh(rules, Camera{50, 50, 30, 20});
    fresh.step(o, h, w, f, depth.data());
    fresh.step(o, h, w, f, brushed.data());
    CHECK_EQ(int(fresh.still()[0]), 0);
    chain.step(o, h, w, f, brushed.data());
    CHECK_EQ(int(chain.still()[0]), 1);
    FrameChain again(rules, Camera{50, 50, 30, 20});
    again.step(o, h, w, f, depth.data());
    again.step(o, h, w, f, depth.data());
    std::vector<float> crossed = depth;
    for (int y = 5; y < 17; ++y)
        for (int x = 10; x < 50; ++x) crossed[y * w + x] = 1.0f;
    again.step(o, h, w, f, crossed.data());
    CHECK_EQ(int(again.still()[0]), 0);
    // grid_iou: counted on every 2nd pixel (frame coordinates)
    WindowMask half = m;
    half.w = 20, half.pixels.assign(half.w * half.h, 1);
    CHECK_NEAR(grid_iou(m, half), 0.5, 1e-12);
    WindowMask apart = m;
    apart.x0 = 100;
    CHECK_NEAR(grid_iou(m, apart), 0.0, 0.0);
    CHECK_ERROR(chain.step(o, 20, 30, f, nullptr),
                "frame 20x30: the first was 40x60; a chain serves one camera stream");
    Features bad = f;
    bad.desc.pop_back();
    CHECK_ERROR(chain.step(o, h, w, bad, depth.data()),
                "features: 60 keypoints but 1919 descriptor bytes (expected 32 each)");
    MaskingSettings s;
    s.cut_behind_m = 0.5, s.motion_odds = 10, s.motion_layer_px = 100, s.still_frames = 20;
    CHECK_EQ(unapplied(s, Have{true, true, true}).size(), size_t(0));
    const auto no_depth = unapplied(s, Have{false, true, true});
    CHECK_EQ(no_depth.size(), size_t(3));
    CHECK_EQ(no_depth[0], std::string("cut_behind_m 0.5"));
    CHECK_EQ(unapplied(s, Have{true, false, true}).size(), size_t(2));
}

}  // namespace

int main() {
    test_hamming_and_matching();
    test_fundamental_and_homography();
    test_pose_from_depth();
    test_motion_odds();
    test_depth_filters_and_surfaces();
    test_stillness_and_layers();
    test_chain();
    return slimseg_test::report("test_multi_frame");
}
