// The objects the rules work on (include/slimseg/rules.hpp): a prediction's instances, or a
// class map's 8-connected components (slimseg.dynamic.semantic.class_map_to_instances).
#include "slimseg/rules.hpp"

namespace slimseg {

Objects objects_of(const FramePrediction& p, int min_area) {
    Objects o;
    if (!p.semantic) {
        for (const auto& d : p.detections) {
            o.boxes.push_back(d.box);
            o.classes.push_back(d.cls);
            o.scores.push_back(d.score);
        }
        o.masks = p.masks;
        o.has_masks = p.segmenter;
        return o;
    }
    // slimseg.dynamic.semantic.class_map_to_instances: 8-connected components per class
    const int h = p.h, w = p.w;
    std::vector<int> label(static_cast<size_t>(h) * w, -1);
    std::vector<int> stack;
    int maxv = 0;
    for (auto v : p.class_map) maxv = std::max(maxv, static_cast<int>(v));
    for (int value = 1; value <= maxv; ++value) {
        for (int start = 0; start < h * w; ++start) {
            if (p.class_map[start] != value || label[start] >= 0) continue;
            int x0 = w, y0 = h, x1 = -1, y1 = -1;
            std::vector<int> pix;
            stack.assign(1, start);
            label[start] = start;
            while (!stack.empty()) {
                int q = stack.back();
                stack.pop_back();
                pix.push_back(q);
                int qy = q / w, qx = q % w;
                x0 = std::min(x0, qx), x1 = std::max(x1, qx);
                y0 = std::min(y0, qy), y1 = std::max(y1, qy);
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        int ny = qy + dy, nx = qx + dx;
                        if (ny < 0 || ny >= h || nx < 0 || nx >= w) continue;
                        int r = ny * w + nx;
                        if (p.class_map[r] == value && label[r] < 0) {
                            label[r] = start;
                            stack.push_back(r);
                        }
                    }
            }
            if (static_cast<int>(pix.size()) < min_area) continue;
            WindowMask m;
            m.x0 = x0;
            m.y0 = y0;
            m.w = x1 - x0 + 1;
            m.h = y1 - y0 + 1;
            m.pixels.assign(static_cast<size_t>(m.w) * m.h, 0);
            for (int q : pix) m.pixels[static_cast<size_t>(q / w - y0) * m.w + (q % w - x0)] = 1;
            o.boxes.push_back({static_cast<float>(x0), static_cast<float>(y0),
                               static_cast<float>(x1 + 1), static_cast<float>(y1 + 1)});
            o.classes.push_back(value - 1);
            o.masks.push_back(std::move(m));
        }
    }
    o.has_masks = true;
    return o;
}

}  // namespace slimseg
